"""The feedback integrator: the field, the step policy and the run loop.

:mod:`~liefi.integrator.feedback` (the field ``X - A grad V`` and the user's entry point),
:mod:`~liefi.integrator.run` (the run loop: it resolves the scheme, the gains and the step
policy once, and drives), :mod:`~liefi.integrator.policy` with the rules it asks
(:mod:`~liefi.integrator.tolerance`, :mod:`~liefi.integrator.gains`,
:mod:`~liefi.integrator.guard`, :mod:`~liefi.integrator.stability`,
:mod:`~liefi.integrator.drift`) and :mod:`~liefi.integrator.dense` (dense output, events), and
:mod:`~liefi.integrator.linearize` (the linearized constrained dynamics at a steady
motion, ``system.linearize``: exact through the engine's trace, which ``systems/`` may
not import).  Sensitivities (variational equations along a run) belong here.  Imports systems,
reduction, schemes and the engine; nothing above.
"""
