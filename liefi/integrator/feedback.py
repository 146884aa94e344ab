"""Feedback integrators: the extended field plus ``-A grad V`` (Section 2.4).

Given a :class:`~liefi.NonholonomicSystem` and an initial state, a
:class:`FeedbackIntegrator` builds the Lyapunov function

.. math:: V(y) = \\frac{k_0}{4} \\sum_{\\text{blocks}} \\|R^T R - I\\|^2
          + \\sum_j \\frac{k_j}{2} (I_j(y) - I_{j0})^2

over the invariants the user selects -- the constraint momenta ``J_i`` (target
0), the extended energy ``h~`` or the original ``h`` (target: its initial
value), and any user first integral -- and the vector field
``y' = X(y) - A grad V(y)`` where ``X`` is the extended field (with the
reconstruction of the group element when the configuration is integrated).
``grad V . X = 0`` everywhere (each ``I_j`` is a first integral of ``X``;
``R^T R`` is constant along ``R' = R hat(xi)``), so ``V`` only decreases and its
zero set is invariant (Theorem ``(theorem:general)``).

The state is ``y = (g, z)``: the group element in its embedding (omitted with
``configuration=False``) then the reduced state ``z = (x, mu, p_x)``.
Everything is batch-first; :meth:`FeedbackIntegrator.fun` is the
``fun(t, y)`` of ``scipy.integrate.solve_ivp``.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numpy as np

from .. import _diff, _sparse
from ..reduction import core as _core
from .._keywords import RUN_FOREIGN, keywords, unknown_keyword
from .._parameters import gain_number, parse_gains, per_member, target_number, target_value  # noqa: F401
from ..systems.invariant import Invariant  # noqa: F401  (liefi.Invariant: a first integral the user adds)
from ..systems.system import NonholonomicSystem
from . import _ensemble, _run_gains


@dataclass(frozen=True)
class ParameterLayout:
    """Where each gain and target sits in the parameter vector ``p`` of the feedback field.

    :meth:`FeedbackIntegrator.field_parts` reads every gain and target from ``p``
    (so one compiled kernel serves every gain).  Indices into the last axis of ``p``.
    """

    J: slice  #: the gains ``k_{J_i}`` (empty without the constraints)
    energy: int | None  #: the gain of the energy
    energy_target: int | None  #: its target ``h~_0`` (or ``h_0``)
    user: tuple  #: the gains of the user invariants
    user_target: tuple  #: their targets
    penalty: int | None  #: the gain ``k_0`` of the embedding penalty
    size: int  #: length of ``p``


@dataclass(frozen=True)
class InvariantJet:
    """Residuals and gradients of the penalized invariants, see :meth:`FeedbackIntegrator.invariant_gradients`."""

    names: tuple  #: the invariants' names (``m``)
    residual: np.ndarray  #: (..., m) ``I_j(y) - I_j0``
    grad: np.ndarray  #: (..., m, n) ``dI_j/dy``
    gains: np.ndarray  #: (..., m) ``k_j`` (each member's own, for gains that differ between members)


def _gram_is_constant(system, z):
    """Whether the Gram matrix ``C(x)`` has zero ``x``-derivative at ``z`` (exactly, by complex step)."""
    if system.constant or system.orthonormalized or not system.K:
        return True
    x = np.asarray(z, float)[..., : system.space.data_dim]

    def gram(xx):
        E = system.constraints(xx)
        return E @ system.metric(xx) @ np.swapaxes(E, -1, -2)

    C, dC = _diff.jacobian(gram, x)
    return bool(np.max(np.abs(dC), initial=0.0) <= 1e-12 * max(1.0, float(np.max(np.abs(C)))))


def momentum_component(system, name):
    """The invariant ``z[name]`` (a momentum component that is conserved, e.g. ``p_phi``)."""
    i = system.state_names.index(name)

    def fun(z):
        return z[..., i]

    def grad(z):
        g = np.zeros(np.shape(z))
        g[..., i] = 1.0
        return g

    return Invariant(name, fun, grad)


class FeedbackIntegrator:
    """The feedback-integrator vector field of a nonholonomic system.

    Parameters
    ----------
    system : NonholonomicSystem
    y0 : array_like (..., n)
        Initial state ``(g, z)`` (or ``z`` with ``configuration=False``); sets the
        targets of the energy and user invariants.  A batch of states is an
        ensemble: every member keeps its own targets (its own initial energy,
        ...), and with ``gains="auto"`` its own gains, so that each member's
        trajectory is the one it has when run alone.  A system with a
        ``start_check`` (a rolling body's) refuses a start that is no state of it.
    invariants : sequence, optional
        Which invariants ``V`` penalizes: ``"constraints"`` (every ``J_i``, and the values
        ``f_j`` of holonomic constraints, :mod:`liefi.systems.holonomic`; target 0),
        ``"energy"`` (``h~`` or ``h`` by ``energy=``), and :class:`Invariant` objects.
        Default ``("constraints", "energy")`` followed by the Casimirs the phase
        space carries (``system.space.casimirs``: the six attitude Casimirs of a
        rolling body, :data:`liefi.systems.rolling.ATTITUDE_CASIMIRS`; none elsewhere).
    gains : float, dict or "auto"
        Default ``"auto"``.  One number for every gain, or ``{name: k}`` with names ``"J_1"``...,
        ``"energy"``, ``"penalty"``, the invariants' names; ``"constraints"`` sets every ``J_i``.
        For an ensemble a gain may differ between members: an array of shape
        ``y0.shape[:-1]`` (e.g. ``{"energy": [10.0, 100.0, 1000.0]}``).
        ``"auto"``: chosen by :meth:`run` for accuracy, from the scheme, ``dt`` and
        the horizon ``T`` (:mod:`liefi.integrator.gains`, which holds the derivation).  The
        residual ``r_j = I_j - I_j0`` relaxes at the rate ``kappa_j = k_j |grad I_j|^2``;
        with ``z = dt kappa`` one step of an explicit Runge--Kutta tableau
        ``(A, b, c)`` of order ``p`` maps ``r -> R(-z) r + delta(z)``, where
        ``delta(z) <= sum_{l=2}^{p+1} (dt omega)^l |eps_l - z b^T (I + zA)^{-1} d_l|``
        (``eps_l`` the scheme's own error coefficients, ``d_l`` its stage defects,
        ``omega`` the spectral radius of ``dX/dy``), so after ``N = T/dt`` steps
        ``|r| <= D(z) = delta(z) (1 - |R|^N)/(1 - |R|)`` plus a random walk of
        rounding.  ``gains="auto"`` takes ``z* = argmin D`` (0, no feedback,
        unless it buys a factor 2) and ``k_j = w_j z*/dt`` with ``w_j`` the
        unit-rate weights of :func:`liefi.integrator.gains.unit_rate_gains`
        (``1/|grad I_j|^2``, scaled so that ``lambda_max(Hess V) = 1``): Euler
        gets ``z* = 1`` (Bae & Chang's ``k = 1/(dt L)``), RK4 ``kappa* ~ 0.26 omega``,
        far below its stability limit, and short horizons ``z* = 0``.  Both
        ``z*`` (a number built from ``dt omega`` and ``N``) and the weights are
        unit-invariant: the same physics in other units gives the same relative
        trajectory.  The gains are fixed along the run unless ``z*`` reaches a
        quarter of the scheme's stability bound (Euler), where they are adapted
        at the rate ``z*`` (``adaptive=``).  On the split schemes (``imex-*``) the
        feedback step maps ``r -> (r + delta(0))/(1 + z)``: ``D`` falls for every
        ``z``, and ``"auto"`` takes ``z* = 1/sqrt(u)`` (a Gauss--Newton step onto
        the invariant set; :data:`liefi.integrator.gains.SPLIT_RATE_MAX`), fixed along the run.
    energy : {"extended", "original"}
        Penalize ``h~`` (default, the paper's main choice) or ``h`` (its Remarks).
    configuration : bool
        Integrate the group element too (default True).  Without it only the
        reduced state is integrated, which is all a reduced scene needs.
    field : {"extended", "projected"}
        The extension: :func:`~liefi.reduction.extended_vector_field` (default)
        or :func:`~liefi.reduction.projected_vector_field`.
    A : array_like (n, n), optional
        Constant matrix with positive definite symmetric part; the field is
        ``X - A grad V``.  Identity by default.
    targets : dict, optional
        Target values ``{name: I_j0}`` overriding those taken from ``y0``: a
        number, or for an ensemble one number per member (shape ``y0.shape[:-1]``).
    force, inputs : optional
        An external generalized force ``force(t, q, v[, u])`` (or a
        :class:`liefi.systems.forcing.ForceLaw`; default the system's ``force``, e.g.
        the loads of :func:`liefi.from_mechanics`) and the signals of its named inputs
        ``{name: signal}``: the state then gains the work ``W`` and the clock, and ``V``
        holds the energy balance ``h~ - W`` (:mod:`liefi.integrator.forced`).
    """

    def __new__(cls, system=None, *args, force=None, **kw):
        if cls is FeedbackIntegrator and (force is not None or getattr(system, "force", None) is not None):
            from .forced import ForcedFeedbackIntegrator  # a forced run: the work and the clock join the state

            return super().__new__(ForcedFeedbackIntegrator)
        return super().__new__(cls)

    #: ``(ensemble's shape, flat indices)`` of an integrator of :meth:`members`, else ``None`` (:meth:`selection`)
    _selected = None
    _data_key = None
    _y0_targets = frozenset()

    @keywords
    def __init__(
        self,
        system: NonholonomicSystem,
        y0,
        *,
        invariants=None,
        gains="auto",
        energy="extended",
        configuration=True,
        field="extended",
        A=None,
        targets=None,
        force=None,
        inputs=None,
        **unknown,
    ):
        if inputs is not None and force is None:
            raise ValueError("inputs: given without a force; pass force=... (or a system with loads)")
        if unknown:
            raise unknown_keyword("FeedbackIntegrator", unknown, FeedbackIntegrator.__init__)
        if not isinstance(system, NonholonomicSystem):
            raise TypeError(f"system: expected a liefi.NonholonomicSystem, got {system!r}")
        if energy not in ("extended", "original"):
            raise ValueError(f"energy: expected 'extended' or 'original', got {energy!r}")
        if field not in ("extended", "projected"):
            raise ValueError(f"field: expected 'extended' or 'projected', got {field!r}")
        self.system = system
        self.energy = energy
        self.field = field
        sp = system.space
        self.configuration = bool(configuration) and sp.group.config_dim > 0
        self.nc = sp.group.config_dim if self.configuration else 0
        self.n = self.nc + sp.nz
        self.names = (tuple(sp.group.config_names) if self.configuration else ()) + sp.state_names

        from .._data import as_float_array

        y0 = as_float_array(y0, "y0")
        if y0.shape[-1:] != (self.n,):
            raise ValueError(
                f"y0: expected a state of {self.n} numbers {self.names}, got shape {y0.shape}"
                + (" (did you mean configuration=False?)" if y0.shape[-1:] == (sp.nz,) else "")
            )
        if not np.all(np.isfinite(y0)):
            raise ValueError("y0: contains non-finite numbers")
        if getattr(system, "start_check", None) is not None:
            system.start_check(y0, self.configuration)  # a start that is no state of the system (a rolling body's)
        _ensemble.member_states(system, y0.shape[:-1], "y0")
        self.y0 = y0
        #: the shape of the ensemble (``()`` for one trajectory): per-member gains and targets have it
        self.batch = y0.shape[:-1]
        #: the system's data (``data_key``: its constants) the targets were taken with (:meth:`parameters`)
        self._data_key = _ensemble.data_state(system)

        # --- which invariants -------------------------------------------------
        if invariants is None:
            invariants = ("constraints", "energy") + tuple(sp.casimirs)
        self.use_constraints = False
        self.use_energy = False
        self.user = []
        for inv in invariants:
            if inv == "constraints":  # the J_i, and the values f_j of holonomic constraints
                self.use_constraints = system.K > 0
                self.user.extend(getattr(system, "holonomic_invariants", ()))
            elif inv == "energy":
                self.use_energy = True
            elif isinstance(inv, Invariant):
                self.user.append(inv)
            elif isinstance(inv, str) and inv in sp.state_names:
                self.user.append(momentum_component(system, inv))
            else:
                raise ValueError(
                    f"invariants: unknown entry {inv!r}; use 'constraints', 'energy', a state "
                    f"component name {sp.state_names} or a liefi.Invariant"
                )
        self.use_penalty = self.configuration and sp.group.penalty_hessian_bound() > 0
        #: the constraint momenta ``J_i`` (0-based ``i``) that ``V`` penalizes (all, unless dropped)
        self._J_kept = tuple(range(system.K)) if self.use_constraints else ()
        #: ``({"name", "reason"}, ...)``: invariants left out of ``V`` (:meth:`without`)
        self.dropped = ()
        self._dropped_user = []  # user invariants left out of V, still monitored
        reserved = {f"J_{i + 1}" for i in range(system.K)} | {"energy", "penalty", "h", "h~"}
        seen = set()
        for u in self.user:
            if u.name in reserved or u.name.startswith("J_") or u.name in seen:
                raise ValueError(
                    f"invariants: the name {u.name!r} is taken (reserved: J_<i> for the "
                    "constraint momenta, energy, penalty, h, h~; names must be unique); "
                    "rename the invariant (e.g. 'L_z')"
                )
            seen.add(u.name)
            if u.grad is None:
                _diff.check_complex_step(u.fun, y0[..., self.nc :], f"invariant {u.name!r}")
        if self.use_energy and energy == "original" and not _gram_is_constant(system, y0[..., self.nc :]):
            raise ValueError(
                "energy: 'original' penalizes h, which is a first integral of the extended "
                "field only where the Gram matrix C = <e_l^flat, e_i> is constant; here C "
                "depends on x, so V would not be a first integral (assumption A1 fails). "
                "Use energy='extended' (h~), or build the system with "
                "NonholonomicSystem(..., orthonormalize=True), for which h is conserved."
            )

        # --- gains ---------------------------------------------------------------
        #: "auto": gains chosen from dt and the Hessian of V when a run knows dt
        #: (liefi.integrator.gains.auto_gains); until then unit-rate gains (see below).
        self.gains_mode = "auto" if isinstance(gains, str) and gains == "auto" else "fixed"
        gains, drops = _run_gains.split(gains)  # a run's gains (sol.stability.gains) carry what it dropped
        self._set_gains(self._parse_gains(1.0 if self.gains_mode == "auto" else gains))

        # --- A --------------------------------------------------------------------
        if A is not None:
            A = as_float_array(A, "A")
            if A.shape != (self.n, self.n):
                raise ValueError(f"A: expected shape ({self.n}, {self.n}), got {A.shape}")
            if not np.all(np.isfinite(A)):
                raise ValueError("A: contains non-finite numbers")
            if np.any(np.linalg.eigvalsh(A + A.T) <= 0):
                raise ValueError("A: its symmetric part A + A^T must be positive definite")
        self.A = A

        # --- targets ---------------------------------------------------------------
        names = self.invariant_names
        vals = self.invariant_values(y0)
        constraint_names = {f"J_{i + 1}" for i in range(system.K)} | {u.name for u in system.holonomic_invariants}
        # every member of an ensemble keeps its own value (a float for one trajectory)
        self.targets = {
            k: 0.0 if k in constraint_names else per_member(v, self.batch, f"the value of {k!r} at y0")
            for k, v in vals.items()
            if k in names and k != "penalty"
        }
        if targets:
            for k, v in targets.items():
                if k not in self.targets:
                    raise ValueError(f"targets: unknown name {k!r}; targets exist for {list(self.targets)}")
                self.targets[k] = target_value(k, v, self.batch)
        #: the targets taken at y0 (not given): they hold the system's data at the construction
        self._y0_targets = {k for k in self.targets if k not in constraint_names and k not in (targets or {})}
        #: target of the penalized energy (``h~`` or ``h`` at ``y0`` unless given)
        self.energy_target = self.targets.get("energy", 0.0)
        #: targets of the user invariants, in the order of ``self.user``
        self.user_targets = [self.targets[u.name] for u in self.user]
        self._parameters = None
        if self.gains_mode == "auto":
            # Unit-rate gains (largest eigenvalue of Hess V at y0 equal to 1, every
            # invariant weighted by 1/|grad I_j|^2); run() scales them to dt.
            from .gains import unit_rate_gains

            self._set_gains(unit_rate_gains(self, y0))
        _run_gains.apply(self, drops)

    # --- gains -----------------------------------------------------------------------
    def _parse_gains(self, gains):
        """``gains`` (a number or ``{name: k}``) -> ``{name: k}`` over :attr:`invariant_names` (:func:`parse_gains`).

        A gain given per member (an array) must broadcast to :attr:`batch`; it is
        kept as a float array of that shape, a common gain as a float.
        """
        g = parse_gains(gains, self.invariant_names)
        if g == "auto":
            raise ValueError("gains: 'auto' is chosen by run() from dt; pass it to the constructor, not here")
        return {k: per_member(v, self.batch, f"gains: the gain of {k!r}") for k, v in g.items()}

    def _set_gains(self, g):
        self.gains = dict(g)
        self._parameters = None  # the parameter vector, rebuilt on first use

    @cached_property
    def parameter_layout(self) -> ParameterLayout:
        """The :class:`ParameterLayout` of :meth:`parameters` (gains, then targets)."""
        i = 0
        J = slice(0, 0)
        energy = energy_target = penalty = None
        if self.use_constraints:
            J = slice(0, len(self._J_kept))
            i = len(self._J_kept)
        if self.use_energy:
            energy, energy_target = i, i + 1
            i += 2
        user = tuple(range(i, i + 2 * len(self.user), 2))
        user_target = tuple(j + 1 for j in user)
        i += 2 * len(self.user)
        if self.use_penalty:
            penalty = i
            i += 1
        return ParameterLayout(J, energy, energy_target, user, user_target, penalty, i)

    def parameters(self, gains=None):
        """The parameter vector ``p`` (gains and targets, :attr:`parameter_layout`) of the field.

        ``gains`` (a dict ``{name: k}``, optional) overrides :attr:`gains`.  Shape
        ``(size,)`` when every gain and target is common to the ensemble, else
        ``(..., size)`` with ``...`` = :attr:`batch`: row ``b`` holds member
        ``b``'s own gains and targets (its initial energy, ...), which the numpy
        field and the compiled ensemble kernel both read per member.
        """
        if gains is None and self._parameters is not None:
            return self._parameters
        g = self.gains if gains is None else gains
        cols = []
        if self.use_constraints:
            cols += [g[f"J_{i + 1}"] for i in self._J_kept]
        if self.use_energy:
            cols += [g["energy"], self.energy_target]
        for u, tgt in zip(self.user, self.user_targets):
            cols += [g[u.name], tgt]
        if self.use_penalty:
            cols.append(g["penalty"])
        cols = [np.asarray(c, dtype=float) for c in cols]
        if all(c.ndim == 0 for c in cols):  # every gain and target common to the ensemble
            p = np.array(cols, dtype=float)
        else:  # per-member gains or targets: one row per member
            shape = np.broadcast_shapes(*(c.shape for c in cols))
            p = np.stack([np.broadcast_to(c, shape) for c in cols], -1)
        if gains is None:
            self._parameters = p
        return p

    def _check_data(self):
        """Retake what this integrator took at ``y0`` once the system's constants changed since it was built
        (:func:`liefi.integrator._ensemble.check_data`)."""
        _ensemble.check_data(self)

    def members(self, index=None):
        """The integrator restricted to some members of the ensemble (their own targets, gains and constants).

        ``index``: ``None``, the whole ensemble flattened to ``(B,)``; an int, that member alone; an integer
        array, those members (flat indices into :attr:`batch`).  It evaluates its system inside
        :meth:`selection` (:func:`liefi.integrator._ensemble.members`).
        """
        return _ensemble.members(self, index)

    def selection(self):
        """The context in which the system's per-member data (constants) are those of this integrator's members.

        A no-op for the whole integrator (:func:`liefi.integrator._ensemble.selection`).
        """
        return _ensemble.selection(self)

    def for_batch(self, batch):
        """The integrator for an ensemble of shape ``batch`` (from ``run(y0=...)``).

        Its per-member gains and targets must have that shape already (a
        ``ValueError`` says so); common ones are kept for every member.
        """
        batch = tuple(batch)
        if batch == self.batch:
            return self
        _ensemble.member_states(self.system, batch, "y0")
        if self.batch:
            raise ValueError(
                f"y0: this integrator holds the targets and gains of an ensemble of shape {self.batch} (from the "
                f"y0 it was built with); got states of shape {batch + (self.n,)}. Build the integrator from these "
                "states (each member keeps its own targets), or pass y0 of that shape"
            )
        import copy

        new = copy.copy(self)
        new.batch = batch
        return new

    def with_gains(self, gains):
        """A copy with other (fixed) gains; same system, invariants, targets and ``A``.

        ``gains`` as in the constructor (a number or ``{name: k}``; not ``"auto"``).
        Used by the adaptive runs (:mod:`liefi.integrator.policy`, :mod:`liefi.integrator.gains`), which change the gains
        along a run: the zero set of ``V`` -- the invariant set -- does not depend on them.
        """
        import copy

        new = copy.copy(self)
        new.gains_mode = "fixed"
        new._set_gains(self._parse_gains(gains))
        return new

    # --- bookkeeping ---------------------------------------------------------------
    @property
    def invariant_names(self):
        """Names of the penalized invariants, in the order of :meth:`invariant_values`."""
        names = []
        if self.use_penalty:
            names.append("penalty")
        if self.use_constraints:
            names += [f"J_{i + 1}" for i in self._J_kept]
        if self.use_energy:
            names.append("energy")
        names += [u.name for u in self.user]
        return tuple(names)

    def without(self, drops):
        """A copy whose ``V`` leaves out the invariants ``drops`` (``{name: reason}``); they stay monitored.

        Used by :func:`liefi.integrator.run.run_feedback` for the invariants the scheme keeps
        exactly (:func:`liefi.integrator.gains.exactly_kept`): their feedback term vanishes
        identically and only costs work.  The copy's :attr:`dropped` lists
        ``{"name", "reason"}``; its field (numpy and compiled) has no such term.
        The embedding penalty cannot be dropped.
        """
        import copy

        new = copy.copy(self)
        new.__dict__.pop("parameter_layout", None)
        new.user = list(self.user)
        new._dropped_user = list(self._dropped_user)
        kept_J = list(self._J_kept)
        for name in drops:
            if name.startswith("J_") and name[2:].isdigit() and int(name[2:]) - 1 in kept_J:
                kept_J.remove(int(name[2:]) - 1)
            elif name == "energy" and self.use_energy:
                new.use_energy = False
            elif name in [u.name for u in new.user]:
                i = [u.name for u in new.user].index(name)
                new._dropped_user.append(new.user.pop(i))
            else:
                raise ValueError(f"drops: {name!r} is not a penalized invariant that can be dropped; "
                                 f"choose among {[n for n in self.invariant_names if n != 'penalty']}")
        new._J_kept = tuple(kept_J)
        new.use_constraints = bool(kept_J)
        new.user_targets = [self.targets[u.name] for u in new.user]
        new.dropped = tuple(self.dropped) + tuple({"name": k, "reason": str(v)} for k, v in drops.items())
        new._set_gains({k: v for k, v in self.gains.items() if k in new.invariant_names})
        return new

    def split(self, y):
        """``y -> (g, z)`` (``g`` has zero length without configuration)."""
        return y[..., : self.nc], y[..., self.nc :]

    def invariant_values(self, y):
        """All monitored quantities at ``y``: ``J_i``, ``energy`` (as penalized),
        ``h``, ``h~``, user invariants, and the embedding penalty."""
        y = np.asarray(y, float)
        g, z = self.split(y)
        t = _core.evaluate(self.system, z, derivatives=False)
        out = {}
        if self.configuration:
            out["penalty"] = self.system.space.group.penalty(g)
        for i in range(self.system.K):
            out[f"J_{i + 1}"] = t.J[..., i]
        out["h"] = t.h
        out["h~"] = t.ht
        out["energy"] = t.ht if self.energy == "extended" else t.h
        for u in self.user + self._dropped_user:
            out[u.name] = np.asarray(u.fun(z))
        return out

    def invariant_gradients(self, y):
        """Residuals and gradients of the penalized invariants (all but the penalty) at ``y``.

        Returns an :class:`InvariantJet` with ``names`` (``m`` names, in the order
        of :attr:`invariant_names` without ``"penalty"``), ``residual``
        ``(..., m)`` = ``I_j(y) - I_j0``, ``grad`` ``(..., m, n)`` = ``dI_j/dy``
        (zero on the group block) and ``gains`` ``(..., m)``.  Then
        ``grad V = sum_j k_j r_j grad I_j + k0 grad P`` and, on the zero set of
        ``V``, ``Hess V = sum_j k_j grad I_j grad I_j^T + k0 Hess P``: its largest
        eigenvalue is that of the small Gram matrix
        ``G_ij = sqrt(k_i k_j) grad I_i . grad I_j`` (:mod:`liefi.integrator.stability`).
        """
        y = np.asarray(y, dtype=float)
        g, z = self.split(y)
        t = _core.evaluate(self.system, z)
        batch = y.shape[:-1]
        terms = self.invariant_terms(z, t, self.parameters())
        m = len(terms)
        r = np.zeros(batch + (m,))
        D = np.zeros(batch + (m, self.n))
        for j, (_, res, grad, _) in enumerate(terms):
            r[..., j] = np.broadcast_to(res, batch)
            D[..., j, self.nc :] = np.broadcast_to(grad, batch + (self.n - self.nc,))
        k = np.zeros(batch + (m,))
        for j, term in enumerate(terms):
            k[..., j] = np.broadcast_to(term[3], batch)
        return InvariantJet(tuple(term[0] for term in terms), r, D, k)

    def invariant_terms(self, z, t, params, data=_core.NUMPY_DATA):
        """``[(name, r_j, grad I_j, k_j), ...]``: the penalized invariants (all but the penalty) at ``z``.

        The one list of the terms of ``V = 1/2 sum_j k_j r_j^2 + k0 P``: ``r_j =
        I_j(z) - I_j0`` (shape ``(...)``), ``grad I_j = dI_j/dz`` (``(..., nz)``)
        and the gain ``k_j``, read from ``params`` (laid out by
        :attr:`parameter_layout`); ``t`` is :func:`liefi.reduction.core.evaluate`
        at ``z`` with the accessor ``data``.  :meth:`field_parts`,
        :meth:`invariant_gradients` and the split schemes' feedback step
        (:func:`liefi.schemes.split.feedback_step`) all read it.  With ``t`` evaluated
        without derivatives (``evaluate(..., derivatives=False)``) every ``grad I_j`` is
        ``None``: the residuals of :func:`liefi.integrator.drift.drift` need no Jacobian.
        """
        p, lay = params, self.parameter_layout
        out = []
        values_only = t.dh is None  # evaluate(..., derivatives=False): residuals only, every grad I_j None
        if self.use_constraints:
            kJ = p[..., lay.J]
            for c, i in enumerate(self._J_kept):
                out.append((f"J_{i + 1}", t.J[..., i], None if values_only else t.dJ[..., i, :], kJ[..., c]))
        if self.use_energy:
            E, dE = (t.ht, t.dht) if self.energy == "extended" else (t.h, t.dh)
            out.append(("energy", E - p[..., lay.energy_target], dE, p[..., lay.energy]))
        for u, ik, it in zip(self.user, lay.user, lay.user_target):
            val, grad = (np.asarray(u.fun(z)), None) if values_only else u.value_and_grad(z, data)
            out.append((u.name, val - p[..., it], grad, p[..., ik]))
        return out

    # --- V and its gradient -----------------------------------------------------------
    def field_parts(self, y, params=None, *, data=_core.NUMPY_DATA):
        """``(X(y), grad V(y), V(y))`` in one pass over the system's terms.

        ``X`` is the extended field (at the projection for ``field="projected"``)
        with the reconstruction of ``g``; ``V`` the Lyapunov function of the module
        docstring.  Every gain and target is read from ``params``
        (:meth:`parameters` by default, laid out by :attr:`parameter_layout`), and
        the data through the accessor ``data`` (:class:`liefi.reduction.core.NumpyData`):
        the compiled engine runs this very method on traced arrays.
        """
        y = _core.as_real(y)
        p = self.parameters() if params is None else params
        lay = self.parameter_layout
        g, z = self.split(y)
        sys = self.system
        # the field (at the projection for field="projected") and the terms at z for V
        zdot, xi, t = self._reduced_field(g, z, data)

        V = 0.0
        gz = 0.0
        for _, r, grad, k in self.invariant_terms(z, t, p, data):
            kr = k * r
            V = V + 0.5 * kr * r
            gz = _sparse.accumulate(gz, kr, grad)  # traced: the nonzero terms only
        gz = np.broadcast_to(gz, z.shape)

        if self.configuration:
            G = sys.space.group
            gdot = G.config_rate(g, xi)
            X = np.concatenate([np.broadcast_to(gdot, y.shape[:-1] + gdot.shape[-1:]), zdot], -1)
            if self.use_penalty:
                k0 = p[..., lay.penalty]
                V = V + k0 * G.penalty(g)
                gg = np.asarray(k0)[..., None] * G.penalty_grad(g)
            else:
                gg = np.zeros(g.shape)
            gradV = np.concatenate([np.broadcast_to(gg, y.shape[:-1] + (self.nc,)), gz], -1)
        else:
            X, gradV = zdot, gz
        return X, gradV, V

    def _reduced_field(self, g, z, data):
        """``(zdot, xi, t_z)`` of :func:`liefi.reduction.core.field_terms` (a forced integrator adds its force)."""
        return _core.field_terms(self.system, z, kind=self.field, data=data)

    def lyapunov(self, y):
        """``V(y)`` (shape ``(...)``); zero exactly on the target invariant set."""
        return self.field_parts(y)[2]

    def grad_lyapunov(self, y):
        """``grad V(y)`` (shape ``(..., n)``), exact to rounding."""
        return self.field_parts(y)[1]

    def unforced_vector_field(self, y, params=None, *, data=_core.NUMPY_DATA):
        """The extended field ``X(y)`` alone (the feedback integrator with zero gains).

        ``X`` reads no gain or target: without ``params`` it is evaluated with a
        zero parameter vector, so any batch of states ``y`` will do (an
        ensemble's per-member parameters need not match it).
        """
        if params is None:
            params = np.zeros(self.parameter_layout.size)
        return self.field_parts(y, params, data=data)[0]

    def vector_field(self, y, params=None, *, data=_core.NUMPY_DATA):
        """``X(y) - A grad V(y)``, batch-first: ``(..., n) -> (..., n)``.

        ``params`` and ``data`` as in :meth:`field_parts` (the compiled engine
        traces this method with symbolic ``y`` and ``params``).
        """
        X, gV, _ = self.field_parts(y, params, data=data)
        if self.A is not None:
            gV = np.einsum("ij,...j->...i", self.A, gV)
        return X - gV

    __call__ = vector_field

    def fun(self, t, y):
        """``fun(t, y)`` for ``scipy.integrate.solve_ivp`` (``y`` of shape ``(n,)`` or ``(n, k)``)."""
        y = np.asarray(y)
        if y.ndim == 2:  # vectorized solve_ivp: (n, k)
            return self.vector_field(y.T).T
        return self.vector_field(y)

    def jac(self, t, y):
        """``jac(t, y)`` for ``solve_ivp``'s implicit methods: ``d fun / d y`` at ``y`` (``(n,)`` -> ``(n, n)``).

        Exact to rounding: the field traced and differentiated symbolically
        (:func:`liefi.engine.jacobian.field_jacobian`), so ``Radau``, ``BDF`` and
        ``LSODA`` need no finite differences (``docs/getting-started.md`` has the
        counts).  A system whose data cannot be traced gets a ``ValueError``.
        """
        from ..engine.jacobian import field_jacobian

        return field_jacobian(self, y)

    # --- running ------------------------------------------------------------------
    @keywords
    def run(self, t_span=None, *more, dt=None, scheme=None, t_eval=None, events=None, dense_output=False, y0=None,
            save_every=None, check_every=1, backend=None, check_stability=True, adaptive=None, monitor_every=None,
            progress=None, drop_exact=True, errors="raise", rtol=None, atol=None, max_step=None, method=None,
            sensitivities=None, adjoint=None, **unknown):
        """Integrate from ``y0`` (default: the one given at construction) over ``t_span``, as ``solve_ivp``.

        The loop is :func:`liefi.integrator.run.run_feedback`.  The default method is the best one
        (:mod:`liefi.integrator.tolerance`): a split scheme, compiled, with the constructor's gains
        (``"auto"`` by default); without ``dt`` its order (``"imex-rk4"``, ``"imex-rk6"``
        or ``"imex-rk8"``, the fewest field evaluations) and its step are those
        :func:`liefi.integrator.tolerance.choose_step` picks for ``rtol`` and ``atol``; with a given
        ``dt`` it is ``"imex-rk4"``.  ``solution.method`` says which method ran and why.
        The old form ``run(dt, t_final, scheme)`` is retired (a ``TypeError`` names the new call).

        Parameters
        ----------
        t_span : float or (float, float)
            The final time (the run starts at 0) or ``(t0, t_final)``; two positional
            numbers ``fi.run(t0, t_final)`` are a span, as ``solve_ivp``'s users write it.
        dt : float, optional
            The step; default: chosen for ``rtol`` and ``atol``.  One that does not divide
            the span runs whole steps and a last one shortened to end at ``t_final``
            (``solution.method["last_step"]`` and ``["why"]`` say so).
        scheme : str, optional
            A tableau of :mod:`liefi.schemes` (``"euler"``, ``"rk4"``, ...) or a split scheme
            of :mod:`liefi.schemes.split` (``"imex-rk4"``, ...: the tableau on ``X``, then one
            linearly implicit feedback step, a Gauss--Newton step onto the invariant set with
            ``gains="auto"``); default: chosen with the step.
        method : str, optional
            ``solve_ivp``'s spelling of ``scheme`` (a liefi scheme; ``solve_ivp``'s adaptive
            methods run through :meth:`liefi.scenes.Scene.run`, ``scheme="scipy:RK45"``).
        t_eval : array_like, optional
            Times at which to store the solution, as in ``solve_ivp``: the state between two
            steps is a partial step of the scheme from the last step before it
            (:mod:`liefi.integrator.dense`: the scheme's order, the invariants kept as at the steps).
        events : callable or list of callables, optional
            Event functions ``event(t, y)``, as in ``solve_ivp``, located on those partial
            steps; a ``terminal`` one ends the run with ``status=1``; a single trajectory only.
        dense_output : bool, default False
            Give the solution a continuous ``sol(t)``, from the same partial steps.
        y0 : array_like, optional
            The start (default: the one given at construction).
        save_every : int, optional
            Keep every this many steps (default: every step, up to 256 MiB of output).
        check_every : int, default 1
            Steps between two checks for non-finite numbers.
        backend : {None, "numpy", "numba", "auto"}, optional
            ``None``: ``"auto"`` when numba is installed, else ``"numpy"`` (the reference
            path); compiled, the same field is generated as scalar code from the system's
            data (:mod:`liefi.engine`; agrees with numpy to 1e-12); where it cannot be, a
            :class:`liefi.engine.CompilationWarning` says so and numpy runs.
        check_stability : bool, default True
            Estimate ``dt * lambda_max(A Hess V)`` before the run against the scheme's bound
            (warn with the largest safe ``dt`` and gain at the limit, refuse 10x past it) and
            stop with :class:`liefi.integrator.stability.StabilityError` when the drift explodes; the
            report is ``solution.stability`` (:mod:`liefi.integrator.stability`).
        adaptive : bool, optional
            Rescale the gains along the run so that ``dt * lambda_max`` stays at the scheme's
            optimum (default: on for ``gains="auto"``; with fixed gains it only lowers them).
        monitor_every : int, optional
            Steps between two stability checks (default: adaptive).
        progress : bool, optional
            Progress on stderr (default: for runs of more than a few seconds, on a terminal).
        drop_exact : bool, default True
            Leave out of ``V`` an invariant that every Runge--Kutta step keeps to rounding
            (:func:`liefi.integrator.gains.exactly_kept`: a constant gradient no other term moves) and
            that starts on its target; ``solution.dropped`` lists them, still monitored.
        errors : {"raise", "return"}, default "raise"
            On non-finite numbers: raise :class:`~liefi.schemes.IntegrationError` naming the
            time and components, or return the run up to there with ``success=False``,
            ``status=-1`` and the error as ``message``.
        rtol, atol : float, optional
            The tolerance the step is chosen for (default ``1e-6`` and 0: relative to each
            component's size).
        max_step : float, optional
            As ``solve_ivp``'s: the largest step for a step chosen for the tolerance.
        sensitivities : sequence of str, optional
            Names to differentiate the saved states by: ``"y0"`` (``solution.sensitivities["y0"]``
            of shape ``(n, n, n_t)``, rows ``y``, columns ``y0``) and the system's parameters
            (the constants of :func:`liefi.mechanics.from_mechanics`; shape ``(n, n_t)``).  The
            exact derivatives of the numbers returned, by the tangents of the scheme's own
            steps with ``dt`` and the gains held (:mod:`liefi.integrator.sensitivity`).
        adjoint : bool or RecursiveCheckpointAdjoint, optional
            Keep what ``solution.vjp(W)`` needs: ``{name: dL/dname}`` for ``W = dL/dy`` at the saved
            states, by reverse mode, for ``"y0"`` and every parameter at once (as diffrax's
            ``adjoint=``; :mod:`liefi.integrator.adjoint` holds the design and ``checkpoints``).

        Returns
        -------
        Solution
            The run, in the layout of scipy's ``OdeResult`` (:class:`~liefi.schemes.Solution`:
            ``t``, ``y``, ``success``, ``status``, ``message``, ``nfev``, ``t_events``,
            ``y_events``, ``sol``; with ``cpu_seconds``, ``overhead_seconds`` and ``plan``).
        """
        from .._progress import compile_notice
        from .run import method_scheme, positional_span, run_feedback

        if unknown:
            raise unknown_keyword("run", unknown, FeedbackIntegrator.run, RUN_FOREIGN)
        self._check_data()  # targets taken at y0 with constants changed since: taken again
        t_span = positional_span(t_span, more, scheme=scheme)
        scheme = method_scheme(method, scheme)
        if t_span is None:
            raise TypeError("run: missing t_span, the final time or (t0, t_final); e.g. fi.run(10.0, dt=1e-3)")
        if sensitivities is not None:
            from .sensitivity import check

            sensitivities = check(self, sensitivities, t_eval=t_eval, events=events, dense_output=dense_output,
                                  y0=self.y0 if y0 is None else y0)
        if adjoint is not None:
            from .adjoint import check as check_adjoint

            adjoint = check_adjoint(self, adjoint, t_eval=t_eval, events=events, dense_output=dense_output, y0=y0)
        with compile_notice():  # a long first compile is announced on stderr
            return run_feedback(
                self, t_span, dt=dt, scheme=scheme, t_eval=t_eval, events=events, dense_output=dense_output,
                errors=errors, y0=y0, save_every=save_every, check_every=check_every, backend=backend,
                check_stability=check_stability, adaptive=adaptive, monitor_every=monitor_every, progress=progress,
                drop_exact=drop_exact, rtol=rtol, atol=atol, max_step=max_step, sensitivities=sensitivities,
                adjoint=adjoint,
            )
