"""Systems from ``sympy.physics.mechanics`` models, with their parameters as runtime constants.

:func:`from_mechanics` takes the model a PyDy / sympy user already holds -- a
``LagrangesMethod``, a ``KanesMethod`` with its nonholonomic constraints, or a
``System`` -- and builds the liefi system on ``CotangentBundle(n)`` in the model's
coordinates ``q``, state ``(q, p)``.  It forms the Lagrangian

.. math:: L(q, \\dot q) = T(q, \\dot q) - U(q),

where ``T`` is the kinetic energy of the bodies (``sympy.physics.mechanics.kinetic_energy``)
with the generalized speeds ``u = W(q) qdot`` from the kinematic differential equations,
solved numerically at each evaluation (Kane: :class:`_Speeds`), or the model's own ``L``
(Lagrange, whose ``U`` holds the bodies' potential energies), and ``U`` is the
potential of the loads and springs: a constant force ``F`` at a
point ``P`` (gravity) has ``U = -F . r_P`` with ``r_P`` the position of ``P`` from a
point fixed in the inertial frame.  The velocity constraints ``a_i(q) . qdot = 0`` are
the model's nonholonomic constraints in ``qdot``.  The metric, vector potential,
potential and rows are then extracted by :func:`liefi.systems.sympy_input.lagrangian_data`
(the one home of that extraction) and the system is
:meth:`~liefi.NonholonomicSystem.from_velocity_constraints`: Lagrange--d'Alembert,
the equations Kane's method gives for the same model with dependent speeds.  Loads with no
potential (dampers, torques, ``LinearDamper``, ``TorqueActuator``, time-dependent loads and
specified inputs ``F(t)``) become the system's ``force`` (:mod:`liefi.systems._loads`,
:mod:`liefi.integrator.forced`).

Symbolic parameters (``m``, ``I``, ``r``, ``g`` ...) stay symbolic: each datum is
generated (code printed by liefi from the model's expressions, :mod:`liefi.systems._sympy_code`) into a numpy
function of ``x`` and of the constants vector :attr:`MechanicsSystem.constants`, as
PyDy's ``constants``.  Changing a mass is an assignment, not a rebuild; constants of
shape ``(N, P)`` give each member of an ensemble of ``N`` states its own parameters
(the constants' batch axes are the last batch axes of the states: an ensemble
``(N, n)`` or a time-major stack ``(T, N, n)``, as the per-member gains and targets; where liefi
evaluates a few members standing for the ensemble it names them, :mod:`liefi._members`, and any
other states -- one state, a batch of another shape -- are refused with a ``ValueError`` naming
``constants``, never read with another member's values: :mod:`liefi.systems._constants`).

sympy is an optional dependency (``pip install "liefi[sympy]"``), imported only here.
"""

from __future__ import annotations

import contextlib

import numpy as np

from ._kinematics import (MinimalSpeedsError, NonConservativeLoadError, _annihilator, _Checks, _fixed_point,
                          _kinematics, _regular_rows, _restore, _speed_coordinates, _Speeds)
from ._components import model_expressions
from ._sympy_code import gc_paused, sympy_function
from .sympy_input import _sympy, coordinate_names, is_zero, lagrangian_data, sympy_only
from . import _mechanics_constraints as _mc
from .. import _fingerprint, _members
from ._constants import _Constants
from .system import NonholonomicSystem

__all__ = ["from_mechanics", "MechanicsSystem", "NonConservativeLoadError", "MinimalSpeedsError"]


def _numbers(exprs):
    """The Python numbers that the generated code of ``exprs`` would return if every one is a real number (ints for
    integers, floats else), else ``None``."""
    if not all(e.is_Number and e.is_finite and e.is_extended_real for e in exprs):
        return None
    return [int(e) if e.is_Integer else float(e) for e in exprs]


def _bound(sympy, args, params, exprs, shape, holder, what):
    """``(..., n) -> (..., *shape)``: the generated function of ``exprs`` (:func:`~liefi.systems._sympy_code.sympy_function`)
    with the constants bound (complex safe)."""
    # |e| as sqrt(e^2) (of the plain, not real, symbols: it stays so), which is complex-step safe
    # (a spring's pathway length |q| along one coordinate)
    exprs = list(exprs)
    holder.bound.append((list(args), list(params), exprs, tuple(shape), what))
    exprs = [sympy.sympify(e, strict=True).replace(sympy.Abs, lambda a: sympy.sqrt(a**2)) for e in exprs]
    # constant entries (K_u = -1 of kinematic equations qdot - u, the zeros of a metric ...: 97 of a sleigh's 100)
    # are filled from one template, no code generated, no assignment each
    constant = [_numbers([e]) for e in exprs]
    live = [k for k, v in enumerate(constant) if v is None]
    held = [k for k, v in enumerate(constant) if v is not None]
    template = np.array([constant[k][0] for k in held], float)
    f = sympy_function(sympy, list(args) + list(params), [exprs[k] for k in live], what) if live else None
    n, P, K = len(args), len(params), len(exprs)
    shape = tuple(shape)

    def fun(x):
        x = np.asarray(x)
        if x.dtype == object and holder.values.ndim > 1:
            raise ValueError("per-member constants run on the numpy path (a compiled kernel holds one set of "
                             "constants, folded into its code)")
        batch = x.shape[:-1]
        c = holder.aligned(batch)
        vals = f(*[x[..., i] for i in range(n)], *[c[..., k] for k in range(P)]) if live else []
        if x.dtype != object:  # numbers: one array filled (a broadcast_to per entry dominated small batches)
            out = np.empty(batch + (K,), complex if np.iscomplexobj(x) or np.iscomplexobj(c) else float)
            if held:
                out[..., held] = template
            for k, v in zip(live, vals):
                out[..., k] = v
            return out.reshape(batch + shape)
        vals = dict(zip(live, vals))
        vals = [vals[k] if constant[k] is None else constant[k][0] for k in range(K)]
        return np.stack([np.broadcast_to(np.asarray(v), batch) for v in vals], -1).reshape(batch + shape)

    return fun


class MechanicsSystem(NonholonomicSystem):
    """A :class:`~liefi.NonholonomicSystem` built by :func:`from_mechanics`, with its constants and velocity maps.

    Attributes
    ----------
    parameters : tuple of sympy.Symbol
        The model's symbolic parameters, in the order of :attr:`constants`.
    coordinates, speeds : tuple
        The model's ``q`` and (Kane models) ``u``; ``speeds`` is ``()`` for a Lagrange model.
    """

    def __init__(self, *args, mechanics=None, **kw):
        self._mech = mechanics
        super().__init__(*args, **kw)
        if mechanics is not None:
            self.parameters = mechanics["constants"].symbols
            self.coordinates = tuple(mechanics["q"])
            self.speeds = tuple(mechanics["u"])

    # --- constants ------------------------------------------------------------
    @property
    def constant_names(self):
        """Names of the parameters, in the order of :attr:`constants`."""
        return self._mech["constants"].names

    @property
    def constants(self):
        """The parameter values, shape ``(P,)`` or ``(..., P)`` for per-member values (a read-only view).

        Assign an array ``(..., P)`` or a mapping ``{m: 2.0}`` / ``{"m": [1, 2, 3]}`` (other
        parameters keep their values; array values broadcast into per-member constants).
        Build the :class:`~liefi.FeedbackIntegrator` after setting them (its energy target is
        taken at its start).
        """
        v = self._mech["constants"].values.view()
        v.setflags(write=False)
        return v

    @constants.setter
    def constants(self, value):
        holder = self._mech["constants"]
        holder.values = holder.parse(value)

    @property
    def member_shape(self):
        """The ensemble's shape the constants are given per member of (``constants.shape[:-1]``), else ``()``.

        A :class:`~liefi.FeedbackIntegrator` of this system runs states whose batch ends in it.
        """
        return self._mech["constants"].values.shape[:-1]

    @property
    def data_key(self):
        """The current constants as bytes: the compiled engine keys its kernels by it (they fold them in)."""
        v = self._mech["constants"].values
        return v.shape, v.tobytes()

    def constants_dict(self):
        """``{name: value(s)}`` of the current constants."""
        v = self._mech["constants"].values
        return {s: v[..., k] for k, s in enumerate(self.constant_names)}

    # --- velocities and momenta ----------------------------------------------------
    def momenta(self, q, qdot):
        """``p = M(q) qdot + b(q)`` (the Legendre transform), batch-first."""
        q, qdot = np.asarray(q, float), np.asarray(qdot, float)
        self._check_shape(q, "q")
        self._check_shape(qdot, "qdot")
        p = np.einsum("...ij,...j->...i", self.metric(q), qdot)
        if self.vector_potential is not None:
            p = p + self.vector_potential(q)
        return p

    def state(self, q, qdot=None, *, u=None, restored=None):
        """The state ``z = (q, p)`` from the coordinates and the velocities ``qdot`` or the speeds ``u``.

        ``u`` (Kane models) holds every generalized speed in the model's order ``u_ind + u_dep``
        (:attr:`speeds`, the order :meth:`generalized_speeds` returns them in: an array, or that
        mapping ``{name: value}``), or the independent ones only: the dependent speeds are then
        solved from the velocity constraints ``k_nh(q) u = 0`` (with configuration constraints: the kept
        rows and ``f' = df(q) B(q) u = 0``), so the state is on the constraint set.  ``q`` holds the model's own coordinates, or those and the :attr:`restored_coordinates`
        (a model in minimal speeds, :func:`from_mechanics`); their values are ``restored``
        (default 0), and their rates are the model's (its restored rows).
        """
        if (qdot is None) == (u is None):
            raise ValueError("state: give the velocities qdot or (Kane models) the generalized speeds u, one of them")
        q = self._full_q(q, restored)
        if u is not None:
            if isinstance(u, dict):
                u = self._speeds_in_order(u)
            u = np.asarray(u, float)
            m, K0 = len(self.speeds), self._mech["model_rows"]
            K = K0 + (0 if self.holonomic is None else self.holonomic.H)  # with the rows f' = df B(q) u
            if not np.all(np.isfinite(u)) or u.shape[-1:] not in ((m,), (m - K,)) or not self.speeds:
                want = f"{m} speeds {[str(s.func) for s in self.speeds]}" + (
                    f" (or the {m - K} independent ones)" if K else "")
                raise ValueError(f"u: expected {want}, finite, got shape {u.shape}" if self.speeds else
                                 "u: a Lagrange model has no generalized speeds; give qdot")
            if K and u.shape[-1:] == (m - K,):
                A = self._speed_rows(q, m, K0)  # (..., K, m): rows in u
                dep = np.linalg.solve(A[..., m - K :], -np.einsum("...ij,...j->...i", A[..., : m - K], u)[..., None])[..., 0]
                batch = np.broadcast_shapes(u.shape[:-1], dep.shape[:-1])
                u = np.concatenate([np.broadcast_to(u, batch + u.shape[-1:]), np.broadcast_to(dep, batch + (K,))], -1)
            batch = np.broadcast_shapes(q.shape[:-1], u.shape[:-1])
            qdot = self._mech["qdot_of_u"](np.concatenate([np.broadcast_to(q, batch + q.shape[-1:]),
                                                          np.broadcast_to(u, batch + u.shape[-1:])], -1))
        qdot = np.asarray(qdot, float)
        self._check_shape(qdot, "qdot")
        return np.concatenate(np.broadcast_arrays(q, self.momenta(q, qdot)), -1)

    def _speed_rows(self, q, m, K0):
        """The velocity constraints in ``u`` at ``q``: the model's kept rows, then ``df(q) B(q)`` (``qdot = B u``)."""
        rows = [self._mech["speed_constraints"](q)] if K0 else []
        if self.holonomic is not None:
            n = q.shape[-1]
            E = np.broadcast_to(np.eye(m), q.shape[:-1] + (m, m))
            B = self._mech["qdot_of_u"](np.concatenate([np.broadcast_to(q[..., None, :], q.shape[:-1] + (m, n)), E], -1))
            rows.append(np.asarray(self.holonomic.differential(q), float) @ np.swapaxes(B, -1, -2))
        return np.concatenate(rows, -2)

    @property
    def restored_coordinates(self):
        """Names of the coordinates liefi restored (a model in minimal speeds: ``("x_C", "y_C")``), else ``()``."""
        return tuple(str(s.func) for s in self._mech["restored"]) if self._mech else ()

    def velocities(self, z):
        """``qdot = M(q)^{-1} (p - b(q))`` of states ``z`` (``(..., 2n)``) or of a Solution (``(..., n, n_t)``)."""
        return self._of_states(z, self._qdot)

    def generalized_speeds(self, z):
        """The model's speeds ``u(q, qdot)`` (Kane models) of states ``z`` or of a Solution, by name.

        One rule for speeds: they come out and go in in the model's order ``u_ind + u_dep``
        (:attr:`speeds`).  This returns the mapping ``{name: values}`` in that order (``values``
        of shape ``(...)`` for states ``(..., 2n)``, ``(..., n_t)`` for a Solution);
        ``state(q, u=...)`` takes the same mapping, or an array in the same order
        (``np.stack(list(speeds.values()), -1)``).
        """
        if not self.speeds:
            raise ValueError("generalized_speeds: a Lagrange model has no generalized speeds; use velocities()")
        n = self.space.n
        sol = hasattr(z, "y") and hasattr(z, "t")
        U = self._of_states(z, lambda zz: self._map("u_of_qdot", zz[..., :n], self._qdot(zz), "qdot"))
        U = np.moveaxis(U, -2, 0) if sol else np.moveaxis(U, -1, 0)
        return {str(s.func): U[k] for k, s in enumerate(self.speeds)}

    def _speeds_in_order(self, u):
        names = [str(s.func) for s in self.speeds]
        keys = {k if isinstance(k, str) else str(getattr(k, "func", k)): v for k, v in u.items()}
        unknown = sorted(set(keys) - set(names))
        K = self._mech["model_rows"] + (0 if self.holonomic is None else self.holonomic.H)
        if unknown or not (set(names) <= set(keys) or set(names[: len(names) - K]) == set(keys)):
            raise ValueError(f"u: expected the speeds {names} by name (or the independent ones {names[: len(names) - K]}), "
                             f"got {sorted(keys)}")
        given = [n for n in names if n in keys]
        return np.stack(np.broadcast_arrays(*[np.asarray(keys[n], float) for n in given]), -1)

    def _full_q(self, q, restored):
        q = np.asarray(q, float)
        extra = self.restored_coordinates
        if extra and q.shape[-1:] == (self.space.n - len(extra),):
            r = np.zeros(len(extra)) if restored is None else np.asarray(restored, float)
            if r.shape[-1:] != (len(extra),):
                raise ValueError(f"restored: expected {len(extra)} values for {list(extra)}, got shape {r.shape}")
            q = np.concatenate([q, np.broadcast_to(r, q.shape[:-1] + (len(extra),))], -1)
        elif restored is not None:
            raise ValueError(f"restored: the model has no restored coordinates, or q already holds them "
                             f"({list(extra)})")
        self._check_shape(q, "q")
        return q

    def _qdot(self, z):
        n = self.space.n
        q, p = z[..., :n], z[..., n:]
        if self.vector_potential is not None:
            p = p - self.vector_potential(q)
        return np.linalg.solve(self.metric(q), p[..., None])[..., 0]

    def _of_states(self, z, f):
        n = self.space.n
        if hasattr(z, "y") and hasattr(z, "t"):  # a Solution: state axis before time
            y = np.asarray(z.y, float)
            if y.shape[-2] != 2 * n:
                raise ValueError(f"z: a Solution of {y.shape[-2]} components, expected the {2 * n} of (q, p)")
            return np.moveaxis(f(np.moveaxis(y, -1, 0)), 0, -1)  # time-major: the members are the last batch axes
        z = np.asarray(z, float)
        if z.shape[-1:] != (2 * n,):
            raise ValueError(f"z: expected states (q, p) of {2 * n} numbers {self.state_names}, got shape {z.shape}")
        return f(z)

    def _map(self, which, q, v, name):
        v = np.asarray(v, float)
        self._check_shape(v, name)
        fun = self._mech[which]
        if fun is None:
            raise ValueError(f"{name}: a Lagrange model has no generalized speeds; give qdot")
        return fun(np.concatenate(np.broadcast_arrays(q, v), -1))

    def _check_shape(self, a, name):
        n = self.space.n
        if a.shape[-1:] != (n,) or not np.all(np.isfinite(a)):
            raise ValueError(f"{name}: expected {n} finite numbers (one per coordinate {self.space.shape_names}), got shape {a.shape}")


@gc_paused
def from_mechanics(model, constants=None, *, potential=None, names=None, scaling="unit", **kw):
    """A :class:`MechanicsSystem` on ``CotangentBundle(len(q))`` from a ``sympy.physics.mechanics`` model.

    Parameters
    ----------
    model : LagrangesMethod, KanesMethod or System
        * ``LagrangesMethod(L, q, forcelist=..., frame=N, nonhol_coneqs=...)``: the Lagrangian
          ``L`` (with the potential energies it holds), the nonholonomic constraints
          ``nonhol_coneqs`` (linear, homogeneous in ``qdot``) and the potentials of the
          loads in ``forcelist``.
        * ``KanesMethod(N, q_ind, u_ind, kd_eqs=..., u_dependent=..., velocity_constraints=...,
          bodies=..., forcelist=...)`` (bodies and loads also from ``kanes_equations(bodies,
          loads)``): the kinetic energy of the bodies, ``u = W(q) qdot`` solved numerically at
          each evaluation from ``K_qdot qdot + K_u u = 0`` (no symbolic inverse), the velocity
          constraints in ``qdot``; auxiliary speeds are zero, as in sympy's equations, and the
          loads at points moving with them only (reactions) do no work.  Kane's equations take
          forces only from the loads: a body's ``potential_energy`` is ignored, with a warning.
          *Minimal speeds* run as written: a body whose velocity is given from a contact point
          of zero velocity (``v2pt_theory``) gets the contact point's place restored (coordinates
          ``x_C, y_C``, reported by :attr:`MechanicsSystem.restored_coordinates`), its kinetic
          energy from the derivative of its position, and the rows "the model's velocity is the
          true one"; so does a root point given a velocity but no place (``D.set_vel(N, u2*A.y)``,
          ``x_D, y_D, z_D``); fewer speeds than coordinates (``qdot = B(q) u``) give the annihilator rows
          of ``B`` (``liefi.systems._kinematics._restore``, ``_annihilator``).
        * ``System``: its bodies, loads, actuators (``LinearSpring``/``DuffingSpring`` potential
          ``k (l - l0)^2 / 2`` ...), kinematic differential equations and velocity constraints;
          ``potential_energy`` counts if it was formed with ``LagrangesMethod``.
        * Configuration constraints (Kane's, Lagrange's ``hol_coneqs``, a System's) become the
          ``holonomic=`` datum, dependent coordinates kept (:mod:`~liefi.systems._mechanics_constraints`).
    constants : dict, optional
        ``{symbol or name: value}`` for every symbolic parameter of the model (PyDy's
        ``constants``); they become :attr:`MechanicsSystem.constants`, changeable without a
        rebuild.  Values of shape ``(N,)`` give per-member constants for an ensemble of ``N``.
    potential : sympy expression, optional
        ``U(q)`` of the model's loads, when liefi cannot derive it (a spring given as a load).
        liefi checks at random states that the loads' power equals ``-dU/dt``.  Without it,
        loads with no potential liefi derives become the system's ``force``: a
        :class:`liefi.systems.forcing.ForceLaw` whose inputs are the model's specified
        dynamicsymbols ``F(t)`` by name, given with ``FeedbackIntegrator(..., inputs={"F": ...})``.
    names : sequence of str, optional
        Names of the coordinates (default: those of ``q``).
    scaling : {"unit", "orthonormal", None}
        See :meth:`~liefi.NonholonomicSystem.from_velocity_constraints`.
    **kw
        Passed on (``sample``, ``check`` ...).

    Returns
    -------
    MechanicsSystem
        State ``(q, p)``, ``p = dL/dqdot``; :meth:`~MechanicsSystem.state` starts from
        ``(q, qdot)`` or ``(q, u)``, :meth:`~MechanicsSystem.velocities` and
        :meth:`~MechanicsSystem.generalized_speeds` read the velocities of states or of a
        :class:`~liefi.schemes.Solution`.

    Raises
    ------
    NonConservativeLoadError
        For a ``potential`` whose ``-dU/dt`` is not the power of the loads.
    MinimalSpeedsError
        If bodies located from the same zero-velocity point give it different velocities (their
        velocities minus the derivatives of their positions from it differ), so that no one
        restored place of that point fits them all.
    ValueError
        For missing constants and every error of :func:`liefi.from_sympy` (a ``T`` not quadratic,
        nonlinear constraints ...); ``ConstraintRowsError`` (a ``ValueError``) for velocity constraints
        that are derivatives of the configuration constraints at some configurations only.

    References
    ----------
    Kane, T. R. & Levinson, D. A., *Dynamics: Theory and Applications*, 1985 (Ch. 6:
    nonholonomic systems); Bloch, A. M., *Nonholonomic Mechanics and Control*, 2003, Sec. 1.6
    (Lagrange--d'Alembert).
    """
    sympy = _sympy()
    import sympy.physics.mechanics as me
    from ..phase_space import CotangentBundle

    user_kw = dict(kw)  # as given (holonomic_data adds liefi's own functions to kw)
    parts = _parts(sympy, me, model)
    sympy_only(sympy, model_expressions(sympy, me, parts), "model")  # sympy's classes only, before any is used
    q, qd, u = parts["q"], parts["qd"], parts["u"]
    n = len(q)
    if set(u) & set(qd):  # speeds that are the velocities themselves (a joint given u = q')
        if list(u) != list(qd):
            raise ValueError(f"model: the speeds {list(u)} are partly the coordinates' derivatives {list(qd)}; "
                             "give independent speeds with kinematic differential equations, or u = q' for all")
        u = parts["u"] = []
    aux0 = dict.fromkeys(parts["aux"], sympy.S.Zero)  # sympy forms the equations with the auxiliary speeds at zero
    Kq = Ku = None
    if u and len(u) > n:  # speeds of coordinates the model does not carry (a wheel's spin): those added
        q, qd, parts["kd"] = _speed_coordinates(sympy, me, parts["kd"], q, qd, u)
        parts["q"], parts["qd"], n = q, qd, len(q)
    if u:
        Kq, Ku = _kinematics(sympy, parts["kd"], q, qd, u)
    frame, bodies = parts["frame"], parts["bodies"]
    model_rows = _regular_rows(sympy, [sympy.sympify(c, strict=True).xreplace(aux0) for c in parts["constraints"]], q)
    # minimal speeds: the eliminated places and rows restored (_restore), the velocities in the range of B
    restored = None if parts["L"] is not None else _restore(sympy, me, frame, bodies, parts["fixed"], q, qd, u, Kq, Ku,
                                                            model_rows, aux0)
    extra = [] if restored is None else restored["coords"]
    parts["offsets"] = {} if restored is None else restored["offsets"]
    kin_rows = [] if not u or len(u) == n else [sum((a * v for a, v in zip(row, qd)), sympy.S.Zero)
                                                 for row in _annihilator(sympy, Kq, Ku)]
    own = restored["velocities"] if restored else {}
    q_all, qd_all = list(q) + extra, list(qd) + [s.diff(me.dynamicsymbols._t) for s in extra]
    if parts["L"] is not None:
        L = parts["L"]
    else:
        if not bodies:
            raise ValueError(f"model: the {parts['kind']} has no bodies; pass bodies= (or call kanes_equations(bodies, loads))")
        L = me.kinetic_energy(frame, *bodies) if not (u or own) else sympy.S.Zero  # else _kinetic_form below
        if parts["potential_energy"]:  # a System formed with LagrangesMethod: its Lagrangian holds them
            L = L - sum((b.potential_energy for b in bodies), sympy.S.Zero)
        else:
            _warn_ignored_potential_energy(sympy, parts, bodies)
            from ._accelerations import warn_stored_accelerations

            warn_stored_accelerations(sympy, me, frame, bodies, q, qd, u, Kq, Ku, aux0)
    L = sympy.sympify(L, strict=True).xreplace(aux0)
    constraints = model_rows + kin_rows + ([] if restored is None else restored["rows"])
    hol = [sympy.sympify(c, strict=True).xreplace(aux0) for c in parts["holonomic"]]  # f(q) = 0 (liefi.systems.holonomic)

    # the parameters: the model's free symbols, in the order of `constants` first
    t = me.dynamicsymbols._t
    free = set()
    H = c_w = None
    if (u or own) and parts["L"] is None:
        H, c_w, T0 = _kinetic_form(sympy, me, frame, bodies, qd_all + list(u), aux0, own)
        L = L + T0
    for e in [L, *constraints, *hol, *(list(Kq) + list(Ku) if u else []), *(list(H) + list(c_w) if H is not None else [])]:
        free |= e.free_symbols
    free.discard(t)
    checks = _Checks(sympy, q_all, qd_all, u, frame, aux0)
    U_loads, power, forced, power_of = _load_potential(sympy, me, parts, checks, potential)
    free |= (U_loads.free_symbols | power.free_symbols) - {t}
    if forced:  # non-conservative loads: their generalized forces on w = (qdot, u) (liefi.systems._loads)
        from . import _loads

        forced = _loads.generalized_forces(sympy, me, forced, power_of, qd_all, list(u), q_all)
        free |= forced.free_symbols
    sympy_only(sympy, [L, *constraints, *hol, U_loads, power], "model")  # the derived ones (positions, velocities)
    params, values = _parameters(sympy, free, constants)
    holder = _Constants(params, None)
    holder.values = holder.parse(values) if params else np.zeros((0,))
    speeds = None
    if u:  # the kinematic map, solved numerically at each evaluation (never a symbolic inverse)
        Xk = [sympy.Dummy(f"x{i}") for i in range(n)]
        flat = lambda K: [e.xreplace(dict(zip(q, Xk))) for e in K]  # noqa: E731
        kin = lambda K, shape: _bound(sympy, Xk, params, flat(K), shape, holder, "kinematic differential equations")  # noqa: E731
        # K_u a constant matrix: W = -K_u^{-1} K_qdot once, symbolically exact (no solve per evaluation)
        W = None if Ku.free_symbols or len(u) != n else kin(-Ku.inv() * Kq, (n, n))
        speeds = _Speeds(kin(Kq, (n, n)), kin(Ku, (n, len(u))), len(u), W=W, extra=len(extra))
    checks.values = np.asarray(holder.values, float).reshape(-1, len(params))[0] if params else np.zeros(0)
    checks.params, checks.speeds = params, speeds
    if parts["loads"] or parts["actuators"]:
        checks.power_is_minus_dU_dt(power, U_loads, parts["loads"] + parts["actuators"], potential is not None)
    if forced:
        forced = forced.bind(lambda args, e, shape, what: _bound(sympy, args, params, e, shape, holder, what), speeds)

    X, M, b, U, rows, q_all = lagrangian_data(sympy, L - U_loads, q_all, qd_all, constraints, params, speeds=u)
    w = len(M)  # n velocities qdot, or n + m: (qdot, u)
    if H is not None:  # T = 1/2 w.H w + c.w + T0 from the partial velocities, never expanded
        to_x = dict(zip(q_all, X))  # H is symmetric: its upper triangle, mirrored (one expression per pair)
        upper = {(i, j): H[i, j].xreplace(to_x) for i in range(w) for j in range(i, w)}
        M = [[upper[min(i, j), max(i, j)] for j in range(w)] for i in range(w)]
        b = [e + c.xreplace(dict(zip(q_all, X))) for e, c in zip(b, c_w)]
    metric = _bound(sympy, X, params, [e for row in M for e in row], (w, w), holder, "metric")
    pot = None if U == 0 else _bound(sympy, X, params, [U], (), holder, "potential")
    b = [sympy.expand(e) for e in b]
    vp = None if all(e == 0 for e in b) else _bound(sympy, X, params, b, (w,), holder, "vector potential")
    A = None if not rows else _bound(sympy, X, params, [e for row in rows for e in row], (len(rows), w), holder,
                                     "constraints")
    keep = list(range(len(rows)))
    if hol:  # the values f -> holonomic=, the velocity constraints less the derivatives of f
        A, kw, keep = _mc.holonomic_data(sympy, hol, parts["q"], X, A, len(rows), speeds if u else None, kw,
                                         lambda e, shape, what: _bound(sympy, X, params, e, shape, holder, what))
    r = len(extra)
    k_model = sum(1 for i in keep if i < len(model_rows))  # the model's own rows kept (less the derivatives of f)
    if r and keep[-r:] != list(range(len(rows) - r, len(rows))):  # pragma: no cover - f holds no restored place
        raise ValueError("model: a configuration constraint spans a restored contact point's row; "
                         "state the contact point's coordinates in the model")
    mech = dict(constants=holder, q=q, u=u, qdot_of_u=None, u_of_qdot=None, speed_constraints=None, restored=extra,
                model_rows=k_model, q_dependent=[q.index(s) for s in parts.get("qdep", ()) if s in q])
    if u:  # the data in qdot: u = W(q) qdot, (qdot, u) = S qdot with S = [1; W]
        Aw = A  # the rows in w = (qdot, u)
        if r:
            speeds.restored = lambda x: Aw(x)[..., len(keep) - r:, :]
        mech["u_of_qdot"], mech["qdot_of_u"] = speeds.u_of_qdot, speeds.qdot_of_u
        mech["speed_constraints"] = None if not k_model else speeds.rows_in_u(lambda x: Aw(x)[..., :k_model, :])
        metric, vp, A = speeds.metric(metric), speeds.covector(vp), speeds.rows(A)
    metric = _mc.regularized_metric(metric, A, kw) if hol else metric  # singular on the ambient space: regular off C
    if r and not hol and A is not None:  # a speed's coordinate (q_u2) whose rate only a restored row holds: no mass
        x0 = _mc.generic_points(n + r, 1)[0] if kw.get("sample") is None else kw["sample"]
        metric = _mc.regularized_metric(metric, A, {"sample": x0})
    space = CotangentBundle(n + r, names=coordinate_names(sympy, q_all) if names is None else names)
    # the build's checks at a sample point (symmetry, definiteness of the data): the first member's constants
    # stand for all when they are given per member (liefi._members)
    with _members.selected(holder.values.shape[:-1], 0) if holder.values.ndim > 1 else contextlib.nullcontext():
        if A is None:
            system = MechanicsSystem(space, metric, None, pot, vector_potential=vp, mechanics=mech, **kw)
        else:
            system = MechanicsSystem.from_velocity_constraints(
                space, metric, A, pot, scaling=scaling, vector_potential=vp, mechanics=mech, **kw
            )
    if forced:  # the non-conservative loads: a ForceLaw (liefi.systems.forcing), inputs by name; numpy runs only,
        system.force = forced  # so no kernel fingerprint
        return system
    # pure data: every data function is bound from the sympy expressions recorded in holder.bound, the
    # constants are the system's data_key (part of a kernel's fingerprint); kernels found without a trace
    return _fingerprint.stamp(system, "from_mechanics", holder.bound, user_kw, names, scaling, n, r, len(u),
                              W is not None if u else None, keep, k_model, mech["q_dependent"], space.state_names)

def _parts(sympy, me, model):
    """The model's coordinates, speeds, kinematics, Lagrangian or bodies, loads and constraints."""
    t = me.dynamicsymbols._t
    kind = type(model).__name__
    if isinstance(model, me.LagrangesMethod):
        hol = list(model._hol_coneqs)  # sympy puts their time derivatives first in coneqs
        q = list(model.q)
        return dict(kind=kind, q=q, qd=[s.diff(t) for s in q], u=[], kd=None, L=model._L[0], frame=model.inertial,
                    bodies=list(model._bodies or []), loads=list(model._forcelist or []), fixed=None,
                    constraints=list(model.coneqs)[len(hol):], aux=[], actuators=[], potential_energy=True,
                    holonomic=hol)
    if isinstance(model, me.KanesMethod):
        if model._qdot_u_map is None:
            raise ValueError("model: the KanesMethod has no kinematic differential equations (kd_eqs)")
        q, u = list(model.q), list(model.u)
        if hasattr(model, "_k_kqdot_implicit"):  # the model's own K_qdot qdot + K_u u + f_k, not sympy's solved form
            kd = list(model._k_kqdot_implicit * sympy.Matrix([s.diff(t) for s in q]) + model._k_ku_implicit * model.u
                      + model._f_k_implicit)
        else:  # pragma: no cover - older sympy
            kd = [qdi - e for qdi, e in model._qdot_u_map.items()]
        cons = []
        if len(model._udep):
            cons = list(model._k_nh * model.u + model._f_nh)
        return dict(kind=kind, q=q, qd=[s.diff(t) for s in q], u=u, kd=kd, L=None, frame=model._inertial,
                    bodies=list(model._bodylist or []), loads=list(model._forcelist or []), fixed=None, constraints=cons,
                    aux=list(model._uaux), actuators=[], potential_energy=False, holonomic=list(model._f_h),
                    qdep=list(model._qdep))
    if isinstance(model, me.System):
        hol = list(model.holonomic_constraints)  # their derivatives are among velocity_constraints
        q, u = list(model.q), list(model.u)
        u = [] if u == [s.diff(t) for s in q] else u  # joints given u = q': the velocities themselves
        if u and len(model.kdes) != len(q):
            raise ValueError(f"model: the System has {len(u)} speeds but {len(model.kdes)} kinematic differential "
                             f"equations for {len(q)} coordinates; add_kdes(...) one per coordinate")
        lagrange = isinstance(model.eom_method, me.LagrangesMethod) or not u
        return dict(kind=kind, q=q, qd=[s.diff(t) for s in q], u=u, kd=list(model.kdes), L=None, frame=model.frame,
                    bodies=list(model.bodies), loads=list(model.loads), fixed=model.fixed_point,
                    constraints=list(model.velocity_constraints if hol else model.nonholonomic_constraints),
                    aux=list(model.u_aux), actuators=list(model.actuators), potential_energy=lagrange, holonomic=hol,
                    qdep=list(model.q_dep))
    if isinstance(model, (sympy.Basic, sympy.MatrixBase)):
        raise TypeError("model: a sympy expression; for a Lagrangian use liefi.from_sympy(L, q, qd, constraints), "
                        "or wrap it: liefi.from_mechanics(LagrangesMethod(L, q, nonhol_coneqs=...))")
    raise TypeError(f"model: expected a sympy.physics.mechanics LagrangesMethod, KanesMethod or System, got {kind}")


def _kinetic_form(sympy, me, frame, bodies, w, aux0, velocities=None):
    r"""``(H, c, T0)`` with ``T = 1/2 w^T H w + c . w + T0``: the kinetic energy of the bodies in the velocities ``w``.

    Each velocity is affine in ``w`` (``v = J_v w + v_0``, ``omega = J_w w + omega_0``: the
    partial velocities), so ``H = sum m J_v^T J_v + J_w^T I J_w`` (``I`` the central inertia
    in the body's frame), ``c = sum m J_v^T v_0 + J_w^T I omega_0`` and
    ``T0 = sum m |v_0|^2/2 + omega_0 . I omega_0 / 2`` -- products of Jacobians, never an
    expansion of ``T`` (Kane & Levinson 1985, Sec. 2.14 and 4.11).  ``velocities``: the
    mass centres' velocities to use instead of the model's (:func:`_restore`).
    """
    from ._coefficients import linear_coefficients
    from ._components import dyadic_components, frame_of, oriented as _oriented, vector_components

    n = len(w)
    H, c, T0 = sympy.zeros(n, n), sympy.zeros(n, 1), sympy.S.Zero
    for body in bodies:
        m = body.mass
        ref = body.frame if isinstance(body, me.RigidBody) else frame
        if ref is not frame and not _oriented(ref, frame):  # a frame given its angular velocity only (a wheel):
            ref = body.central_inertia.args[0][1].args[0][1] if body.central_inertia.args else frame  # the inertia's
        v = (velocities or {}).get(body)  # a restored (derived) velocity (_restore), or the model's
        v = body.masscenter.vel(frame) if v is None else v
        own = {f for _, f in v.args}  # m |v|^2 is the same in every frame: v's own, if one (no rotation to ref)
        parts = [(m * sympy.eye(3), vector_components(sympy, v, own.pop() if len(own) == 1 else ref))]
        if isinstance(body, me.RigidBody):  # omega . I omega in the inertia's own frame, if one (read, not dotted)
            F = frame_of(body.central_inertia)
            ref = F if F is not None and (F is ref or _oriented(F, ref)) else ref
            parts.append((dyadic_components(sympy, body.central_inertia, ref),
                          vector_components(sympy, body.frame.ang_vel_in(frame), ref)))
        for inertia, vel in parts:
            J, v0, _ = linear_coefficients(sympy, vel.xreplace(aux0), w)  # J = d vel / d w, v0 = vel(w = 0)
            if any(J.has(s) for s in w):
                raise ValueError(f"model: the velocity of {body} is not linear in the speeds and qdot")
            IJ = inertia * J
            H += J.T * IJ
            if any(e != 0 for e in v0):
                c += IJ.T * v0
                T0 += (v0.T * inertia * v0)[0, 0] / 2
    return H, c, T0


def _parameters(sympy, free, constants):
    """``(symbols, {name: value})``: the order of ``constants``, then the other free symbols by name."""
    constants = {} if constants is None else constants
    if not isinstance(constants, dict):
        raise TypeError(f"constants: expected a dict {{symbol or name: value}}, got {type(constants).__name__}")
    sympy_only(sympy, [k for k in constants if isinstance(k, sympy.Basic)], "constants")  # before they are printed
    if any(k in ("t", sympy.physics.vector.dynamicsymbols._t) for k in constants):  # not a constant: the time
        raise ValueError("constants: 't' is the time of sympy.physics.mechanics (dynamicsymbols._t), not a constant; "
                         "rename the parameter")
    by_name = {str(s): s for s in free}
    params, values = [], {}
    for key, val in constants.items():
        if isinstance(key, str):
            if key not in by_name:
                raise ValueError(f"constants: {key!r} is not a symbol of the model; its symbols are {sorted(by_name)}")
            key = by_name[key]
        elif not isinstance(key, sympy.Symbol):
            raise ValueError(f"constants: keys are sympy Symbols or their names, got {type(key).__name__}")
        params.append(key)
        values[str(key)] = val
    params += sorted(free - set(params), key=str)
    missing = [str(s) for s in params if str(s) not in values]
    if missing:
        raise ValueError(f"constants: no value for the model's parameter(s) {missing}; pass "
                         f"constants={{{', '.join(f'{s}: ...' for s in missing)}}} (PyDy's constants)")
    return params, values


def _load_potential(sympy, me, parts, checks, potential):
    """``(U, W)``: the loads' potential (derived for constant forces and springs, or the given one) and their power.

    A ``LinearSpring`` actuator of stiffness ``k``, pathway length ``l`` and equilibrium
    length ``l0`` has ``U = k (l - l0)^2 / 2``; a ``DuffingSpring`` ``U = k1 d^2/2 + k3 d^4/4``
    with ``d = l - l0`` (their forces are ``-dU/dl`` along the pathway).  The power of every
    load and actuator is checked against ``-dU/dt`` (:meth:`_Checks.power_is_minus_dU_dt`).
    """
    from ._components import dot

    frame, t = parts["frame"], me.dynamicsymbols._t
    U, W, bad = sympy.S.Zero, sympy.S.Zero, []
    q = set(parts["q"])

    offsets, minimal = parts.get("offsets", {}), 0 < len(parts["u"]) < len(parts["q"])

    def power(where, vec):
        if isinstance(where, me.ReferenceFrame):
            return vec.dot(where.ang_vel_in(frame))
        O = (offsets or minimal) and _fixed_point(where, frame, aux0, offsets, parts["fixed"])
        if O and (O in offsets or minimal):  # minimal speeds: the derived velocity, the model's on its set only
            r = where.pos_from(O)
            # fewer speeds than coordinates: a frame's angular velocity set in the speeds (set_ang_vel(N, u1*A.x))
            # is the true one on the model's velocities only, where u = W(q) qdot is exact; the power is checked
            # against -dU/dt on all of TQ, so r's rate there is its components' time derivative (in qdot)
            rate = sum((e * b for e, b in zip(r.to_matrix(frame).diff(t), (frame.x, frame.y, frame.z))),
                       0 * frame.x) if minimal else r.dt(frame)
            return dot(sympy, vec, rate + offsets.get(O, 0 * frame.x).dt(frame))
        return dot(sympy, vec, where.vel(frame))

    aux0 = dict.fromkeys(parts["aux"], sympy.S.Zero)
    for load in parts["loads"]:
        try:
            where, vec = load
        except (TypeError, ValueError):
            raise ValueError(f"model: a load {load!r} is not a (Point or ReferenceFrame, Vector) pair") from None
        moves = where.ang_vel_in(frame) if isinstance(where, me.ReferenceFrame) else where.vel(frame)
        if aux0 and all(is_zero(sympy, e) for e in moves.to_matrix(frame).xreplace(aux0)):
            continue  # moves with the auxiliary speeds only: a constraint force of the auxiliary equations
        if isinstance(where, me.ReferenceFrame):
            bad.append(load)
            continue
        F = vec.to_matrix(frame)
        O = _fixed_point(where, frame, aux0, offsets, parts["fixed"])  # or a restored root point (_restore)
        if me.find_dynamicsymbols(F) or F.has(t) or O is None:
            bad.append(load)
            continue
        W += power(where, vec)
        U -= vec.dot(where.pos_from(O) + offsets.get(O, 0 * frame.x))  # with a restored place of O
    for act in parts["actuators"]:
        Ua = None
        if isinstance(act, (me.LinearSpring, getattr(me, "DuffingSpring", me.LinearSpring))):
            d = act.pathway.length - act.equilibrium_length
            if isinstance(act, me.LinearSpring):
                Ua = act.stiffness * d**2 / 2
            else:
                Ua = act.linear_stiffness * d**2 / 2 + act.nonlinear_stiffness * d**4 / 4
        if Ua is None or (me.find_dynamicsymbols(Ua) - q) or sympy.sympify(Ua, strict=True).xreplace(
                {s: sympy.Dummy() for s in q}).has(t):
            bad.append(act)
            continue
        for where, vec in act.to_loads():
            W += power(where, vec)
        U += Ua
    if potential is not None:
        if not isinstance(potential, sympy.Basic):
            raise TypeError(f"potential: expected a sympy expression U(q) (of the model's symbols), got "
                            f"{type(potential).__name__}; liefi does not parse strings")
        sympy_only(sympy, [potential], "potential")
        for b in bad:  # the user's potential stands for every load: their power is checked against it
            for where, vec in (b.to_loads() if hasattr(b, "to_loads") else [b]):
                W += power(where, vec)
        return potential, W, [], power
    # the loads with no potential (dampers, torques, time-dependent and specified loads) become the
    # system's force (liefi.systems._loads): their generalized forces from the partial velocities
    pairs = [pair for b in bad for pair in (b.to_loads() if hasattr(b, "to_loads") else [b])]
    return U, W, pairs, power


def _warn_ignored_potential_energy(sympy, parts, bodies):
    """A warning naming the bodies whose ``potential_energy`` the model's equations ignore (KanesMethod)."""
    import warnings

    named = [str(b) for b in bodies if sympy.sympify(getattr(b, "potential_energy", 0), strict=True) != 0]
    if named:
        how = ("KanesMethod (the default of System.form_eoms; form_eoms(LagrangesMethod) includes it)"
               if parts["kind"] == "System" else "KanesMethod")
        warnings.warn(
            f"model: the potential_energy of {named} is ignored, as {how} ignores it: Kane's equations take "
            "forces only from the loads; liefi follows the model (give the force as a load, e.g. gravity, or a "
            "LinearSpring actuator, to include it)", UserWarning, stacklevel=3)
