"""A warning where a model's mass centre accelerations are not the derivatives of its velocities.

sympy's ``KanesMethod`` takes each mass centre's acceleration as the model stores it (``Point.a2pt_theory``,
``Point.set_acc``), and forms the velocity's derivative only where none is stored; liefi takes the bodies'
velocities (their kinetic energy) only, and so the derivatives of the velocities.  The two agree unless the stored
acceleration is not ``d v / dt``.  sympy's ``test_kane.py::test_aux`` disc is such a model: ``Dmc.a2pt_theory(C, N,
R)`` from the contact point ``C`` of velocity ``u4 L.x + u5 (Y.z x L.x)`` takes ``C``'s acceleration as the
derivative of that velocity, zero once the auxiliary speeds are zero, while the material contact point of a rolling
disc accelerates (``a2pt_theory`` takes both points fixed in ``R``, and ``r L.z`` is not): its own lean acceleration
is -1.232 where the disc's is -1.159.
"""

from __future__ import annotations

import warnings

import numpy as np


def warn_stored_accelerations(sympy, me, frame, bodies, q, qd, u, Kq, Ku, aux0, seed=0):
    """Warn, naming the bodies, where a mass centre's stored acceleration in ``frame`` differs from the time
    derivative of its velocity (both with the auxiliary speeds and their rates at zero), at one random state:
    ``q``, ``u``, ``u'`` and the parameters drawn in ``[0.5, 1.5]``, ``q'`` from the kinematic equations
    ``K_qdot q' + K_u u = 0`` (``u = q'`` without speeds).  A diagnostic: any failure to evaluate gives no warning.
    """
    t = me.dynamicsymbols._t
    stored = [(b, b.masscenter._acc_dict.get(frame)) for b in bodies if getattr(b.masscenter, "_acc_dict", None)]
    stored = [(b, a) for b, a in stored if a is not None]
    if not stored:
        return
    rng = np.random.default_rng(seed)
    try:
        val = {s: float(rng.uniform(0.5, 1.5)) for s in q}
        zero = {**aux0, **{s.diff(t): sympy.S.Zero for s in aux0}}
        if u:
            val.update({s: float(rng.uniform(0.5, 1.5)) for s in u})
            K = np.array(Kq.xreplace(val).evalf(), float)
            b = -np.array(Ku.xreplace(val).evalf(), float) @ np.array([val[s] for s in u])
            val.update(zip(qd, np.linalg.solve(K, b)))
            val.update({s.diff(t): float(rng.uniform(0.5, 1.5)) for s in u})
        else:
            val.update({s: float(rng.uniform(0.5, 1.5)) for s in qd})
            val.update({s.diff(t): float(rng.uniform(0.5, 1.5)) for s in qd})
        named = []
        for body, a in stored:
            d = (a - body.masscenter.vel(frame).dt(frame)).to_matrix(frame).xreplace(zero).xreplace(val)
            d = d.xreplace({s: float(rng.uniform(0.5, 1.5)) for s in d.free_symbols if s != t})
            d = np.array(d.evalf(), float)
            if not np.all(np.isfinite(d)):
                return
            if np.max(np.abs(d)) > 1e-9:
                named.append(str(body))
    except Exception:  # noqa: BLE001 -- a diagnostic only
        return
    if named:
        warnings.warn(
            f"model: the acceleration stored for the mass centre of {named} (a2pt_theory, set_acc) is not the time "
            "derivative of its velocity: KanesMethod forms its equations with the stored acceleration, liefi with "
            "the velocities (the kinetic energy), so the two differ; a2pt_theory from a point of zero velocity "
            "(a rolling contact) takes that point's acceleration as zero, which the material contact point's is not. "
            "Drop the a2pt_theory/set_acc call (sympy then differentiates the velocity) to make them agree",
            UserWarning, stacklevel=3)
