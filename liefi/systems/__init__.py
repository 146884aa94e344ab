"""Systems, and every way of building one: from data, from sympy, from a mechanics model, a rolling body.

:mod:`~liefi.systems.system` (a system given by its data), :mod:`~liefi.systems.invariant`
(the first integrals a system hands on), :mod:`~liefi.systems.sympy_input`,
:mod:`~liefi.systems.mechanics` and :mod:`~liefi.systems.rolling` (builders).
Holonomic constraints and minimal speeds belong here, as do a system's inputs: each
makes a system from a system (the linearization, which needs the engine's trace, is
:mod:`liefi.integrator.linearize`).  Imports groups, phase spaces
and the reduction formulas; nothing above.
"""
