"""A model's own equations against ``liefi.from_mechanics`` of it (test and benchmark helper).

* :func:`collect` -- the models sympy's own mechanics tests build, by running those tests;
  :func:`constants_of` values for their parameters.

For any ``KanesMethod``, ``LagrangesMethod`` or ``System`` after its equations are formed:

* :func:`own_trajectory` -- the model's own equations, ``mass_matrix_full x' = forcing_full``, in the state
  ``(q, u_ind)`` (the independent speeds, the model's own choice): the dependent speeds are solved from the
  model's velocity constraints at each evaluation, the auxiliary speeds (and their rates) are zero, as sympy forms
  the equations; a Lagrange model with constraints names no dependent velocities, so its state is ``(q, q')``, moved
  onto the velocity constraints at each evaluation by the least change (``Own.project``; a dependent velocity
  chosen at the start divides by zero where it stops being a pivot); DOP853 at ``rtol = atol = 1e-12``;
* :func:`liefi_trajectory` -- liefi's constrained field of the built system from the same start, DOP853 at
  1e-12, read back in the model's coordinates (by name: restored coordinates are left out);
* :func:`declared_drift` -- along liefi's own run, every constraint the model declares, evaluated from the
  model's expressions (its configuration constraints, its velocity constraints at liefi's speeds), and the
  energy (liefi's ``H``, relative to ``max(1, |H(0)|)``);
* :func:`compare` -- the three together: ``dict(error=..., f=..., velocity=..., energy=...)``, where
  ``error`` is the largest difference in ``(q, q')`` over the times, relative to ``max(1, max |q'|)``.

A model with non-conservative loads (``system.force`` of the built system is not ``None``): every specified input
``F(t)`` left in sympy's equations gets the deterministic signal :func:`input_signal` (the same on both sides:
substituted into sympy's equations, handed to liefi as ``inputs=``), an explicit ``t`` is the time, liefi's side
is its forced field (state ``(g, z, W, time)``), and ``energy`` is the drift of the energy balance ``h - W``.

Imported only by tests and benchmarks (``tests/test_mechanics_corpus.py``, ``benchmarks/mechanics_corpus.py``).
"""

from __future__ import annotations

import importlib
import sys
import time
import zlib

import numpy as np
import sympy
import sympy.physics.mechanics as me
from scipy.integrate import solve_ivp
from scipy.linalg import qr

from test_mechanics_holonomic import _lam  # the one lambdify of dynamicsymbols and their derivatives

t = me.dynamicsymbols._t

#: sympy's test modules that form equations of motion (the others test vectors, inertia, pathways ...)
FILES = ["test_kane", "test_kane2", "test_kane3", "test_kane4", "test_kane5", "test_lagrange", "test_lagrange2",
         "test_linearize", "test_models", "test_jointsmethod", "test_system_class", "test_actuator"]


def collect(files=FILES, only=None):
    """``[(where, model, sympy_seconds)]``: every model whose equations sympy's own tests form, by running them.

    ``KanesMethod.kanes_equations``, ``LagrangesMethod.form_lagranges_equations`` and ``System.form_eoms`` are
    wrapped for the run; the outermost call is kept (a ``System``, not the ``KanesMethod`` it forms inside), one
    entry per model object.  ``only``: a substring of ``"file::test_function"`` (or several: any of them).
    """

    found, depth, spent = {}, [0], [0.0]
    where = [""]

    def wrap(cls, name):
        f = getattr(cls, name)

        def wrapper(self, *a, **k):
            depth[0] += 1
            t0 = time.process_time()
            try:
                out = f(self, *a, **k)
            finally:
                depth[0] -= 1
            if depth[0] == 0:
                found[id(self)] = (where[0], self, time.process_time() - t0)
            return out
        setattr(cls, name, wrapper)
        return f

    originals = [(c, n, wrap(c, n)) for c, n in ((me.KanesMethod, "kanes_equations"),
                                                  (me.LagrangesMethod, "form_lagranges_equations"),
                                                  (me.System, "form_eoms"))]
    try:
        for file in files:
            mod = importlib.import_module(f"sympy.physics.mechanics.tests.{file}")
            for name in sorted(n for n in dir(mod) if n.startswith("test_")):
                if only and not any(o in f"{file}::{name}" for o in ([only] if isinstance(only, str) else only)):
                    continue
                where[0] = f"{file}::{name}"
                try:
                    getattr(mod, name)()
                except Exception as exc:  # a test that needs what is not installed; its models so far are kept
                    print(f"# {where[0]}: {type(exc).__name__}: {exc}", file=sys.stderr)
    finally:
        for c, n, f in originals:
            setattr(c, n, f)
    out, count = [], {}
    for where_, model, sec in found.values():
        count[where_] = count.get(where_, 0) + 1
        out.append((f"{where_}#{count[where_]}", model, sec))
    return out


def value(symbol):
    """A deterministic value in ``[0.5, 1.4]`` by the symbol's name (``g``: 9.81)."""
    name = str(symbol)
    return 9.81 if name == "g" else 0.5 + (zlib.crc32(name.encode()) % 10) / 10


def constants_of(model):
    """:func:`value` of every parameter of the model's equations and of its loads (a load's parameter may vanish
    from sympy's equations, as a body-fixed force at a point moving with the auxiliary speeds only does, and still
    be a parameter of liefi's: its power off the constraint set)."""
    m = model.eom_method if isinstance(model, me.System) else model
    free = set()
    for e in (m.mass_matrix_full, m.forcing_full):
        free |= e.free_symbols
    for load in (getattr(model, "loads", None) or []):
        free |= {s for f in load[1].args for s in f[0].free_symbols}
    free.discard(me.dynamicsymbols._t)
    return {s: value(s) for s in sorted(free, key=str)}


def input_signal(name):
    """The value of the specified input ``name`` as a function of ``t``: ``(sympy expression, numpy callable)``,
    ``a + sin(2 t) / 2`` with ``a`` = :func:`value` of the name (smooth, deterministic, the same on both sides)."""
    a = value(name)
    expr = a + sympy.sin(2 * t) / 2
    return expr, (lambda tt: a + np.sin(2 * np.asarray(tt, float)) / 2)


def specified_inputs(model):
    """The specified inputs ``F(t)`` of ``model``'s equations (dynamicsymbols that are neither coordinates nor
    speeds nor auxiliary speeds), sorted by name."""
    m = model.eom_method if isinstance(model, me.System) else model
    own = set(m.q) | (set(m.lam_vec) if isinstance(m, me.LagrangesMethod) else set(m.u) | set(m._uaux))
    found = set()
    for e in (m.mass_matrix_full, m.forcing_full):
        found |= {f.expr if isinstance(f, sympy.Derivative) else f for f in me.find_dynamicsymbols(e)}
    return sorted(found - own, key=str)


class Own:
    """The model's own equations at the constants ``c`` (a symbol -> float mapping), ready to integrate;
    ``inputs``: ``{name: (sympy expression of t, numpy callable)}`` for the specified inputs (default:
    :func:`input_signal` of each)."""

    def __init__(self, model, c, q0, inputs=None):
        if isinstance(model, me.System):
            model = model.eom_method
        self.model, self.lagrange = model, isinstance(model, me.LagrangesMethod)
        q = list(model.q)
        self.q, self.n = q, len(q)
        if self.lagrange:
            v, aux = [s.diff(t) for s in q], []
            cons = sympy.Matrix(model.coneqs)
            hol = sympy.Matrix(getattr(model, "_hol_coneqs", []) or [])
        else:
            v, aux = list(model.u), list(model._uaux)
            cons = (model._k_nh * sympy.Matrix(v) + model._f_nh) if model._k_nh.shape[0] else sympy.Matrix()
            hol = sympy.Matrix(model._f_h)
        self.v, self.aux = v, aux
        c = {**c, **dict.fromkeys(list(aux) + [a.diff(t) for a in aux], 0)}
        self.c = c
        self.inputs = {str(f.func): (inputs or {}).get(str(f.func)) or input_signal(str(f.func))
                       for f in specified_inputs(model)}
        with_inputs = lambda e: e.subs({sympy.Function(k)(t): x for k, (x, _) in self.inputs.items()}).doit()  # noqa: E731
        cons = cons.xreplace(dict.fromkeys(aux, 0))
        self.names = [str(s.func) for s in q]
        self.speed_names = [str(s.func) for s in v] if not self.lagrange else None
        K = cons.shape[0]
        if self.lagrange and K:  # the start's independent velocities: a well-conditioned pivot there
            J = np.asarray(_lam([q], cons.jacobian(v), c)(np.asarray(q0, float)), float)
            dep = [v[i] for i in sorted(qr(J, pivoting=True)[2][:K])]
        else:
            dep = list(getattr(model, "_udep", []) or [])
        ind = [s for s in v if s not in dep]
        self.ii, self.di = [v.index(s) for s in ind], [v.index(s) for s in dep]
        self.K = len(dep)
        # explicit t (a clock, or the inputs' signals) is the first argument
        self.MM = _lam([[t], q, v], with_inputs(model.mass_matrix_full), c, cse=True)
        self.F = _lam([[t], q, v], with_inputs(model.forcing_full), c, cse=True)
        if self.K:
            self.Ad = _lam([q], cons.jacobian(dep), c)
            self.rest = _lam([q, ind], cons.xreplace(dict.fromkeys(dep, 0)), c)
        self.cons = _lam([q, v], cons, c) if K else None
        self.hol = _lam([q], hol, c) if hol.shape[0] else None
        # a Lagrange model names no dependent velocities: none is singled out along the run (see :meth:`project`),
        # since a pivot fixed at the start can become singular there
        self.projecting = self.lagrange and bool(K)
        if self.projecting:
            self.Jv = _lam([q], cons.jacobian(v), c)
            self.b = _lam([q], cons.xreplace(dict.fromkeys(v, 0)), c)

    def speeds(self, qq, vi):
        """Every speed (velocity) from the independent ones, solving the velocity constraints."""
        vv = np.zeros(len(self.v))
        vv[self.ii] = vi
        if self.K:
            vv[self.di] = np.linalg.solve(np.asarray(self.Ad(qq), float), -np.asarray(self.rest(qq, vi), float).ravel())
        return vv

    def rates(self, y, tt=0.0):
        """``(q', v_ind')`` at ``y = (q, v_ind)`` and the time ``tt``: ``mass_matrix_full \\ forcing_full``."""
        qq, vv = y[: self.n], self.speeds(y[: self.n], y[self.n:])
        xd = np.linalg.solve(np.asarray(self.MM([tt], qq, vv), float), np.asarray(self.F([tt], qq, vv), float).ravel())
        return np.concatenate([xd[: self.n], xd[self.n:][self.ii]])

    def project(self, qq, vv):
        """A Lagrange model's velocities ``vv`` moved onto its velocity constraints ``J(q) v + b(q) = 0`` by the
        least change, ``v - J^+ (J v + b)``: no velocity is singled out as dependent, so no ordinary configuration
        divides by a vanishing pivot (the pendulum ``q1^2 + q2^2 = L^2`` with ``q2'`` dependent divides by ``q2``,
        zero at the bottom of each swing), and the map is smooth in ``q`` where ``J`` has full rank (a pivot chosen
        anew at each evaluation would jump, and DOP853 loses ~1e-11 at each jump)."""
        J = np.asarray(self.Jv(qq), float)
        r = J @ np.asarray(vv, float) + np.asarray(self.b(qq), float).ravel()
        return np.asarray(vv, float) - np.linalg.lstsq(J, r, rcond=None)[0]

    def full_rates(self, y, tt=0.0):
        """``(q', v')`` at ``y = (q, v)`` (every velocity) of a Lagrange model with constraints: ``v`` projected
        (:meth:`project`), then ``mass_matrix_full \\ forcing_full``."""
        qq = y[: self.n]
        vv = self.project(qq, y[self.n:])
        xd = np.linalg.solve(np.asarray(self.MM([tt], qq, vv), float), np.asarray(self.F([tt], qq, vv), float).ravel())
        return xd[: 2 * self.n]


def own_trajectory(own, q0, v_ind0, t_eval):
    """``(Q, Qd, U)`` at ``t_eval``: the coordinates, their rates and every speed (velocity) of the model's own
    equations (DOP853, 1e-12)."""
    if own.projecting:  # every velocity in the state, moved onto the velocity constraints at each evaluation
        rates, y0 = own.full_rates, np.concatenate([q0, own.speeds(q0, v_ind0)])
    else:
        rates, y0 = own.rates, np.concatenate([q0, v_ind0])
    sol = solve_ivp(lambda tt, y: rates(y, tt), (t_eval[0], t_eval[-1]), y0,
                    method="DOP853", rtol=1e-12, atol=1e-12, t_eval=t_eval)
    if sol.status != 0 or sol.y.shape[1] != len(t_eval):
        raise RuntimeError(f"the model's own equations did not integrate: {sol.message} (at t = {sol.t[-1]:.6g})")
    Y = sol.y.T
    if own.projecting:
        return Y[:, : own.n], np.array([rates(y, tt)[: own.n] for y, tt in zip(Y, sol.t)]), \
            np.array([own.project(y[: own.n], y[own.n:]) for y in Y])
    return Y[:, : own.n], np.array([own.rates(y, tt)[: own.n] for y, tt in zip(Y, sol.t)]), \
        np.array([own.speeds(y[: own.n], y[own.n:]) for y in Y])


def liefi_start(system, own, q0, v0):
    """liefi's state at the model's coordinates ``q0`` (restored places 0) and every speed (velocity) ``v0``."""
    names = [str(s) for s in system.space.shape_names]
    q = np.zeros(len(names))
    q[[names.index(s) for s in own.names]] = q0
    return system.state(q, v0) if own.lagrange else system.state(q, u=v0)


def _model_columns(system, own, Y):
    names = [str(s) for s in system.space.shape_names]
    idx = [names.index(s) for s in own.names]
    return Y[:, idx], system.velocities(Y)[:, idx]


def forced_integrator(system, own, z0, **kw):
    """A forced model's :class:`~liefi.FeedbackIntegrator` from ``z0`` with the inputs' signals of ``own``
    (:func:`input_signal`), or ``None`` for a conservative one."""
    import liefi

    if getattr(system, "force", None) is None:
        return None
    return liefi.FeedbackIntegrator(system, z0, inputs={k: own.inputs[k][1] for k in system.force.inputs}, **kw)


def liefi_trajectory(system, own, z0, t_eval, tol=1e-12):
    """``(Q, Qd)`` at ``t_eval`` in the model's coordinates: liefi's constrained field (a forced model's: the
    forced field in ``(g, z, W, time)``, :func:`forced_integrator`), DOP853 at ``tol``."""
    fi = forced_integrator(system, own, z0)
    field = (lambda _, z: system.constrained_vector_field(z)) if fi is None else (lambda _, y: fi.vector_field(y))
    y0 = z0 if fi is None else fi.y0
    sol = solve_ivp(field, (t_eval[0], t_eval[-1]), y0, method="DOP853", rtol=tol, atol=tol, t_eval=t_eval)
    if sol.status != 0 or sol.y.shape[1] != len(t_eval):
        raise RuntimeError(f"liefi's field did not integrate: {sol.message}")
    return _model_columns(system, own, sol.y.T if fi is None else sol.y.T[:, : fi.nb])


def declared_drift(system, own, run, fi=None):
    """The model's declared constraints and the energy along liefi's run ``run`` (a solution):
    ``dict(f=max |f(q)|, velocity=max |constraint(q, u)|, energy=max |H - H(0)| / max(1, |H(0)|))``; a forced
    run (``fi``: its integrator): ``H`` is the energy balance ``h - W``."""
    Y = run.y.T if fi is None else run.y.T[:, : fi.nb]
    Q, Qd = _model_columns(system, own, Y)
    if own.lagrange:
        V = Qd
    else:
        speeds = system.generalized_speeds(Y)
        V = np.stack([speeds[s] for s in own.speed_names], -1)
    f = max((np.max(np.abs(np.asarray(own.hol(x), float))) for x in Q), default=0.0) if own.hol else 0.0
    vel = max((np.max(np.abs(np.asarray(own.cons(x, v), float))) for x, v in zip(Q, V)), default=0.0) \
        if own.cons else 0.0
    h = system.hamiltonian(Y) if fi is None else fi.invariant_values(run.y.T)["energy"]
    return dict(f=float(f), velocity=float(vel), energy=float(np.max(np.abs(h - h[0])) / max(1.0, abs(h[0]))))


def on_constraints(own, q_guess):
    """``q`` near ``q_guess`` with the model's configuration constraints ``f(q) = 0`` (Newton on the dependent
    coordinates: those of the Kane model, or a well-conditioned pivot of ``df``)."""
    x = np.array(q_guess, float)
    if own.hol is None:
        return x
    f = own.model._f_h if not own.lagrange else sympy.Matrix(own.model._hol_coneqs)
    DF = _lam([own.q], f.jacobian(own.q), own.c)
    qdep = list(getattr(own.model, "_qdep", []) or [])
    free = [own.q.index(s) for s in qdep] if qdep else sorted(qr(np.asarray(DF(x), float), pivoting=True)[2][:f.shape[0]])
    for _ in range(60):
        r = np.asarray(own.hol(x), float).ravel()
        if np.max(np.abs(r)) < 1e-15:
            break
        x[free] -= np.linalg.lstsq(np.asarray(DF(x), float)[:, free], r, rcond=None)[0]
    return x


def compare(model, constants, system, q0, v_ind0, t_final=2.0, run=None, tol=1e-12):
    """``dict(error, f, velocity, energy)``: the model's own equations against liefi's field over ``[0, t_final]``
    (21 times), and the drift of the model's declared constraints and energy along liefi's run (``run``: keyword
    arguments of ``FeedbackIntegrator.run``; default imex-rk8, ``dt = 0.01``, numpy); ``tol``: DOP853's tolerances
    for liefi's field (liefi's state holds momenta, which for small inertias are small: the rattleback's,
    about 1e-3, need 1e-14 for an absolute tolerance to be 1e-11 relative).  A forced model (module docstring):
    the inputs' signals :func:`input_signal` on both sides, liefi's forced field and run, ``energy`` the drift of
    ``h - W``."""
    import liefi

    own = Own(model, constants, q0)
    q0 = on_constraints(own, q0)
    t_eval = np.linspace(0.0, t_final, 21)
    Q, Qd, V = own_trajectory(own, q0, np.asarray(v_ind0, float), t_eval)
    z0 = liefi_start(system, own, q0, V[0])
    Ql, Qdl = liefi_trajectory(system, own, z0, t_eval, tol)
    scale = max(1.0, float(np.max(np.abs(Qd))))
    err = max(float(np.max(np.abs(Ql - Q))), float(np.max(np.abs(Qdl - Qd)))) / scale
    fi = forced_integrator(system, own, z0) or liefi.FeedbackIntegrator(system, z0)
    sol = fi.run(t_final, t_eval=t_eval, **(run or dict(dt=0.01, scheme="imex-rk8", backend="numpy")))
    return dict(error=err, **declared_drift(system, own, sol, fi if getattr(system, "force", None) is not None else None))
