"""Experiments built on the library: stability maps, the extreme-case battery, the stiff work-precision study.

* :mod:`~liefi.experiments.stability_maps` -- the measured stable region in the ``(dt, gain)`` plane;
* :mod:`~liefi.experiments.battery` -- the extreme-case battery and the stiff work-precision study;
* :mod:`~liefi.experiments.stability_cli` -- ``liefi stability`` and the report of ``docs/stability.md``.
"""
