"""What a run leaves: figures of a user's run, the figure helpers scenes draw with, sweeps and their stores.

:mod:`~liefi.results.plot` (``liefi.plot``: figures of a user's own run),
:mod:`~liefi.results.scene_figures` (liefi's own figures: the helpers scenes, bench and reproduce draw with),
:mod:`~liefi.results.sweep` (parallel sweeps and their result stores).  The
:class:`~liefi.schemes.Solution` itself and its pandas/xarray export live with the schemes
that return it.  Imports the integrator and below; nothing above.
"""
