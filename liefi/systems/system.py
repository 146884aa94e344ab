"""Nonholonomic mechanical systems given by their data only.

A system is a phase space (:mod:`liefi.phase_space`) and three data:

* ``metric`` ``m(x)``: the symmetric positive definite (reduced, locked) mass
  tensor on ``P = (mu, p_x)``, shape ``(D, D)``; the kinetic energy is
  ``1/2 <P, m(x)^{-1} P>``;
* ``constraints`` ``e(x)``: ``K`` independent vectors (rows, shape ``(K, D)``)
  defining the constraint set ``C = {<P, e_i(x)> = 0}``; they need *not* be
  orthonormal for ``m`` (Remark ``(remark:nonhol:general)``);
* ``potential`` ``U(x)`` (default 0);
* ``vector_potential`` ``A(x)`` (default 0), shape ``(D,)``: the Hamiltonian is
  ``h = 1/2 <P - A(x), m(x)^{-1} (P - A(x))> + U(x)``, the velocities are
  ``v = m^{-1} (P - A)`` and the constraints ``<e_i^flat, v> = 0`` read
  ``J_i = <P - A(x), e_i(x)> = 0`` (a gauge shift ``A = grad S``, a gyrostat's
  rotor momentum ``A = l``, a charged particle's ``q A``).

With an advected vector (a phase space built with ``advected=`` and ``a0``,
:mod:`liefi.phase_space`) every callable datum takes ``(x, Gamma)`` instead of
``x``, ``Gamma = g^{-1} . a_0`` (e.g. ``potential=lambda x, Gamma: m g l
Gamma @ chi`` for a heavy top; ``x`` has ``n = 0`` columns on a Lie group), and
analytic derivatives are taken in ``(x, Gamma)`` together (axis of length
``n + k``).

Everything else -- ``H~``, ``lambda``, ``lambda~``, the constrained, extended
and reduced vector fields, the reconstruction -- is derived in
:mod:`liefi.reduction`.  Each datum is a constant array or a batch-first
function of ``x`` (``(..., n) -> (..., *shape)``) that accepts complex input;
derivatives in ``x`` are taken by complex step (exact to rounding) unless an
analytic one is passed.
"""

from __future__ import annotations

import numpy as np

from .._data import DataFunction, as_float_array, as_state, check_real
from .. import reduction as _red
from ..phase_space import PhaseSpace


#: what to do about a datum that is not finite at the checked configuration (the end of check's messages)
_NON_FINITE = ("; the datum divides by a function that vanishes there (or is undefined there). If that "
               "configuration is a singularity of your coordinates, pass sample= an ordinary configuration to be "
               "checked instead; if it is an ordinary one, write the datum without that division (e.g. clear the "
               "denominators of a constraint row, or keep a kinematic map unsolved), since a run through it fails")


class NonholonomicSystem:
    """A mechanical system with linear nonholonomic constraints on a phase space.

    Parameters
    ----------
    space : PhaseSpace
        ``CotangentBundle(n)``, ``LieGroupPhaseSpace(G)`` or ``TrivialPrincipalBundle(G, n)``.
    metric : array_like (D, D) or callable
        Mass tensor ``m(x)`` (symmetric positive definite).
    constraints : array_like (K, D) or callable, optional
        Constraint vectors ``e_i(x)`` as rows (a 1-D array is one constraint).
    potential : callable, optional
        ``U(x)`` (``(..., n) -> (...)``).
    vector_potential : array_like (D,) or callable, optional
        ``A(x)`` (``(..., n) -> (..., D)``), the momentum shift in
        ``h = 1/2 <P - A, m^{-1} (P - A)> + U``; the constraint set is then
        ``C = {<P - A(x), e_i(x)> = 0}`` (zero velocity along ``e_i^flat``).
        Default none (no cost).  On a Lie group (no shape variables) it is a
        constant ``l in g*``, e.g. a gyrostat's rotor momentum.
    metric_derivative, constraints_derivative, potential_gradient, vector_potential_derivative : callable, optional
        Analytic ``d/dx`` of the data, shape ``(..., n, *shape)``; by default the
        complex step is used.
    sample : array_like (n,), optional
        A shape point at which the data are checked (default ``x = 0``).
    orthonormalize : bool
        Replace the constraint rows by the orthonormal ones spanning the same
        constraint set, ``e' = L^{-1} e`` with ``C = L L^T`` the Gram matrix
        (Cholesky, derived from the data, exact to rounding).  The constraint set
        is unchanged; the extension is then the paper's main-text one, for which
        ``h`` is a first integral everywhere.  Without it (the general form of
        Remark ``(remark:nonhol:general)``), ``h~`` and every ``J_i`` are first
        integrals everywhere but ``h = h~ + 1/2 J^T C^{-1} J`` is one only where
        the Gram matrix ``C(x)`` is constant or on the constraint set.
    check : bool
        Check the data at ``sample`` (symmetry, positive definiteness,
        independence, complex-step safety).  Default True.
    holonomic : callable, optional
        ``f(x)`` (``(..., n) -> (..., H)``, batch-first, accepting complex input): holonomic
        constraints ``f(x) = 0`` on the shape variables.  Their differentials join the
        constraint rows (``df_j . x' = 0``, unit-scaled, after the rows of ``constraints``:
        ``J_{K-H+1} ... J_K``) and their values join ``V`` (invariants ``f_1 ... f_H``,
        target 0).  The dependent coordinates stay in the state; the maths, and the
        gains for which the feedback is locally exponentially stable, are in
        :mod:`liefi.systems.holonomic`.
    holonomic_derivative : callable, optional
        ``df(x)``, shape ``(..., n, H)``.  Without it ``df`` is taken by complex step and
        its own derivative (read by the extended field through the rows) by differences,
        to about 1e-10, on the numpy path only; with it both are exact and the field compiles.
    start_check : callable, optional
        ``start_check(y0, configuration)``: called by :class:`~liefi.FeedbackIntegrator`
        with its start (``(g, z)``, or ``z`` when ``configuration`` is False; any
        batch shape); raises ``ValueError`` naming what makes ``y0`` no state of
        this system.  :func:`liefi.systems.rolling.rolling_body` sets it (orthonormal
        attitude rows, no slip at the contact).  Default none.

    Attributes
    ----------
    metric_inverse : ndarray (D, D) or None
        ``m^{-1}`` when the metric is constant (cached; ``None`` otherwise).
    flat_constraints : ndarray (K, D) or None
        The rows ``e_i^flat = m e_i`` when metric and constraints are constant.
    gram_inverse : ndarray (K, K) or None
        ``C^{-1}``, ``C^{li} = <e_l^flat, e_i>``, when metric and constraints are constant.

    Raises
    ------
    ValueError
        Naming the datum and the fix, for a non-symmetric or indefinite metric,
        dependent constraints, wrong shapes or non-finite numbers.
    """

    def __init__(
        self,
        space: PhaseSpace,
        metric,
        constraints=None,
        potential=None,
        *,
        metric_derivative=None,
        constraints_derivative=None,
        potential_gradient=None,
        vector_potential=None,
        vector_potential_derivative=None,
        sample=None,
        orthonormalize: bool = False,
        check: bool = True,
        start_check=None,
        holonomic=None,
        holonomic_derivative=None,
    ):
        if not isinstance(space, PhaseSpace):
            raise TypeError(f"space: expected a liefi PhaseSpace, got {space!r}")
        #: the constructor's arguments as given (for :meth:`replace`)
        self._arguments = dict(
            space=space, metric=metric, constraints=constraints, potential=potential,
            metric_derivative=metric_derivative, constraints_derivative=constraints_derivative,
            potential_gradient=potential_gradient, vector_potential=vector_potential,
            vector_potential_derivative=vector_potential_derivative, sample=sample, orthonormalize=orthonormalize,
            check=check, start_check=start_check, holonomic=holonomic, holonomic_derivative=holonomic_derivative,
        )
        if start_check is not None and not callable(start_check):
            raise TypeError(f"start_check: expected a function start_check(y0, configuration), got {start_check!r}")
        #: ``start_check(y0, configuration)`` or None (the constructor's ``start_check=``)
        self.start_check = start_check
        self.space = space
        # The data are functions of the data point y = (x, Gamma) (n + k numbers): of
        # the shape x alone without an advected vector; with one, the user writes
        # f(x, Gamma) and liefi sees f(y), so x- and Gamma-derivatives come from the
        # same complex step (or the same traced derivative in the compiled engine).
        n, D = space.data_dim, space.D
        if space.k:
            metric, constraints, potential, vector_potential = (
                _at_data_point(f, space.n) for f in (metric, constraints, potential, vector_potential))
            metric_derivative, constraints_derivative, potential_gradient, vector_potential_derivative = (
                _at_data_point(f, space.n) for f in (
                    metric_derivative, constraints_derivative, potential_gradient, vector_potential_derivative))
        if n == 0:
            for name, val in (
                ("metric", metric), ("constraints", constraints), ("potential", potential),
                ("vector_potential", vector_potential),
            ):
                if callable(val):
                    raise ValueError(
                        f"{name}: a system on a Lie group has no shape variables, so its "
                        "data must be constant arrays (a G-invariant Hamiltonian has constant "
                        "locked inertia and no potential; data that depend on the attitude "
                        "through Gamma = g^-1 . a0 need advected= on the phase space)"
                    )
        if sample is None and space.k:
            sample = np.concatenate([np.zeros(space.n), space.a0])  # x = 0 at the identity
        if sample is not None:
            sample = as_float_array(sample, "sample")
            if sample.shape != (n,) or not np.all(np.isfinite(sample)):
                what = "a data point (x, Gamma)" if space.k else "a shape point (x)"
                raise ValueError(
                    f"sample: expected {what} of {n} finite numbers, got {sample.tolist()!r}"
                )
        if constraints is None:
            constraints = np.zeros((0, D))
        elif not callable(constraints):
            constraints = np.atleast_2d(as_float_array(constraints, "constraints"))
        K = constraints.shape[0] if not callable(constraints) else None
        if K is None:
            x_probe = np.zeros(n) if sample is None else sample
            try:
                probe = np.asarray(constraints(x_probe))
            except Exception as exc:  # noqa: BLE001 -- user code: say which datum failed
                raise ValueError(f"constraints: calling it at x = {x_probe} failed: {exc!r}") from exc
            if probe.ndim == 0:
                raise ValueError(
                    f"constraints: expected the constraint vectors as rows, shape (K, {D}), got a scalar"
                )
            if probe.ndim == 1:  # one constraint returned as (..., D): make it (..., 1, D)
                one = constraints
                constraints = lambda x: np.asarray(one(x))[..., None, :]  # noqa: E731
                probe = probe[None, :]
            K = probe.shape[-2]
        #: the holonomic constraints f(x) = 0 (:class:`liefi.systems.holonomic.HolonomicData`) or None
        self.holonomic = None
        if holonomic is not None or holonomic_derivative is not None:
            constraints, K = self._with_holonomic(holonomic, holonomic_derivative, constraints, metric, K, sample)
        self.K = K
        self.orthonormalized = bool(orthonormalize)
        if orthonormalize and K:
            if constraints_derivative is not None:
                raise ValueError(
                    "constraints_derivative: not supported with orthonormalize=True (the "
                    "orthonormal rows are differentiated by complex step); pass orthonormal "
                    "constraints and their derivative instead"
                )
            constraints = _orthonormalized(constraints, metric, n, K, D)
        self.metric = DataFunction(metric, (D, D), n, "metric", metric_derivative, sample)
        self.constraints = DataFunction(constraints, (K, D), n, "constraints", constraints_derivative, sample)
        self.potential = DataFunction(
            0.0 if potential is None else potential, (), n, "potential", potential_gradient, sample
        )
        #: ``A(x)`` as a :class:`DataFunction` of shape ``(D,)``, or None (no vector potential)
        self.vector_potential = None
        if vector_potential is not None:
            self.vector_potential = DataFunction(
                vector_potential, (D,), n, "vector_potential", vector_potential_derivative, sample
            )
        elif vector_potential_derivative is not None:
            raise ValueError("vector_potential_derivative: given without a vector_potential")
        self.constant = self.metric.constant and self.constraints.constant
        #: ``m^{-1}`` of a constant metric (``None`` if the metric depends on ``x``)
        self.metric_inverse = None
        #: rows ``e_i^flat = m e_i`` (``(K, D)``) and the inverse Gram matrix ``C^{-1}``
        #: (``(K, K)``, ``C = E m E^T``) when metric and constraints are constant, else ``None``
        self.flat_constraints = self.gram_inverse = None
        if self.metric.constant:
            self.metric_inverse = _checked_inverse(self.metric.value, "metric")
        if self.constant:
            E, m = self.constraints.value, self.metric.value
            with np.errstate(over="ignore", invalid="ignore"):  # an overflow is named by _gram_inverse
                self.flat_constraints = E @ m
                C = self.flat_constraints @ E.T
            self.gram_inverse = _gram_inverse(C)
        if check:
            space.group.check()  # the group's differentiated methods (liefi.groups.LieGroup.check)
            if self.holonomic is not None:  # first: dependent differentials are named as such
                self.holonomic.check(np.zeros(n) if sample is None else sample)
            self.check(np.zeros(n) if sample is None else sample)

    def _with_holonomic(self, f, df, constraints, metric, K, sample):
        """The constraint rows with the rows of ``df`` appended (:mod:`liefi.systems.holonomic`)."""
        from .holonomic import HolonomicData

        sp = self.space
        if f is None:
            raise ValueError("holonomic_derivative: given without holonomic (the values f(x))")
        if self._arguments["constraints_derivative"] is not None:
            raise ValueError("constraints_derivative: not supported with holonomic= (the rows of df are appended "
                             "to the constraints and differentiated with them); leave it out")
        if sp.k or sp.data_dim == 0:
            raise ValueError("holonomic: constraints f(x) = 0 on the shape variables x need a space with shape "
                             "variables and no advected vector (CotangentBundle(n) or TrivialPrincipalBundle(G, n))")
        hol = HolonomicData(f, df, sp.n, sp.D, sample)
        rows = hol.rows(metric)
        user = constraints

        def combined(x):
            e = rows(x)
            if K == 0:
                return e
            u = user(x) if callable(user) else np.broadcast_to(user, e.shape[:-2] + user.shape)
            return np.concatenate([np.asarray(u), e], -2)

        combined.liefi_data_point = True
        self.holonomic = hol
        return combined, K + hol.H

    @property
    def holonomic_invariants(self):
        """``(Invariant("f_1", ...), ...)``: the holonomic values, which ``V`` penalizes with the ``J_i`` (target 0)."""
        return () if self.holonomic is None else self.holonomic.invariants()

    # --- constraints as people write them ----------------------------------
    @classmethod
    def from_velocity_constraints(cls, space, metric, A, potential=None, *, scaling="unit", **kw):
        """A system from Pfaffian constraints on velocities, ``A(x) v = 0``.

        Parameters
        ----------
        space : PhaseSpace
        metric : array_like (D, D) or callable
            Mass tensor ``m(x)``: the kinetic energy is ``1/2 <v, m v>``.
        A : array_like (K, D) or callable
            Rows ``a_i(x)`` with ``<a_i, v> = 0`` on the velocities ``v = (xi, x')``
            (body velocity for the group part, ``x'`` for the shape part), as
            written in textbooks and by sympy.physics.mechanics (``A(q) q' = 0``).
            Batch-first ``(..., n) -> (..., K, D)`` and complex-step safe if callable
            (a 1-D array or ``(..., D)`` function is one constraint).
        potential : callable, optional
            ``U(x)``.
        scaling : {"unit", "orthonormal", None}
            How the constraint vectors ``e_i`` are scaled (the constraint set and,
            on it, the motion do not depend on it; the gains do):

            * ``"unit"`` (default): ``e_i = m^{-1} a_i / sqrt(<a_i, m^{-1} a_i>)``, so
              the Gram matrix ``C = E m E^T`` has unit diagonal at every ``x``.
              ``J_i = <e_i^flat, v>`` is then the velocity along the ``i``-th
              forbidden direction in the kinetic-energy norm, ``J_i^2 <= 2 T``
              whatever the units or the scale the user wrote ``a_i`` in, so a gain
              on ``J_i`` is a rate in the same units as the gain on the energy,
              and each ``J_i`` still belongs to the user's row ``i``.
            * ``"orthonormal"``: ``C = I`` (``orthonormalize=True``): the paper's
              main-text extension, for which ``h`` is a first integral everywhere;
              ``J_i`` mixes rows ``1..i``.
            * ``None``: ``e_i = m^{-1} a_i`` as given (the row scaling then sets the
              stiffness of ``J_i``).
        **kw
            Passed to :class:`NonholonomicSystem` (``vector_potential``, ``sample``,
            ``check`` ...).

        Notes
        -----
        With ``v = m^{-1}(P - A_vec)`` (``A_vec`` the ``vector_potential``, default 0)
        the constraint ``<a_i, v> = 0`` is ``<P - A_vec, e_i> = 0`` with ``e_i =
        m^{-1} a_i``, i.e. ``e_i^flat = a_i``: the constraint forces act along the
        rows ``a_i`` (Lagrange--d'Alembert).  A scaling by a constant leaves the
        extended field unchanged; the ``x``-dependent normalisation of
        ``"unit"`` changes it off ``C`` only (by a term proportional to ``J``),
        and ``h~`` and every ``J_i`` are first integrals either way.
        """
        if scaling not in ("unit", "orthonormal", None):
            raise ValueError(f"scaling: expected 'unit', 'orthonormal' or None, got {scaling!r}")
        if "constraints" in kw or "orthonormalize" in kw:
            raise TypeError("from_velocity_constraints: give the constraints as A (rows a_i); "
                            "the scaling is chosen with scaling=")
        if not isinstance(space, PhaseSpace):
            raise TypeError(f"space: expected a liefi PhaseSpace, got {space!r}")
        n, D = space.data_dim, space.D
        if space.k:  # rows and metric of (x, Gamma): seen as functions of y = (x, Gamma)
            A, metric = _at_data_point(A, space.n), _at_data_point(metric, space.n)
        x0 = np.zeros(n) if kw.get("sample") is None else np.asarray(kw["sample"], float)
        if kw.get("sample") is None and space.k:
            x0 = np.concatenate([np.zeros(space.n), space.a0])
        if callable(A):
            try:
                probe = np.asarray(A(x0))
            except Exception as exc:  # noqa: BLE001 -- user code: say which datum failed
                raise ValueError(f"A: calling it at x = {x0} failed: {exc!r}") from exc
            check_real(probe, "A", x0)  # before any arithmetic on it: complex rows are not "non-finite"
            fun = A
            if probe.ndim == 1:
                fun = lambda x, f=A: np.asarray(f(x))[..., None, :]  # noqa: E731
                probe = probe[None, :]
        else:
            probe = np.atleast_2d(as_float_array(A, "A"))
            fun = None
        if probe.ndim != 2 or probe.shape[-1] != D:
            raise ValueError(f"A: expected constraint rows of shape (K, {D}) (one row per constraint, "
                             f"one column per velocity {space.momentum_names}), got {probe.shape}")
        norms = np.linalg.norm(np.asarray(probe, complex), axis=-1)
        if np.any(norms == 0):
            raise ValueError(f"A: row(s) {np.flatnonzero(norms == 0).tolist()} are zero at x = {x0}; "
                             "drop them or fix the constraint")

        def rows(x):
            a = fun(x) if fun is not None else probe
            m = metric(x) if callable(metric) else np.asarray(metric, float)
            e = np.swapaxes(np.linalg.solve(m, np.swapaxes(a, -1, -2)), -1, -2)  # e_i = m^{-1} a_i
            if scaling == "unit":
                e = e / np.sqrt(np.sum(a * e, -1))[..., None]
            return e

        rows.liefi_data_point = True  # already a function of y = (x, Gamma)
        constraints = rows if (fun is not None or callable(metric)) else rows(x0)
        return cls(space, metric, constraints, potential, orthonormalize=scaling == "orthonormal", **kw)

    # --- names and sizes ---------------------------------------------------
    def replace(self, **changes):
        """A new system with the same data except ``changes`` (constructor arguments), every other datum kept.

        E.g. ``system.replace(sample=x0)``.  The data are those given to the
        constructor (callables, derivatives, the vector potential, ``orthonormalize``...).
        """
        unknown = sorted(set(changes) - set(self._arguments))
        if unknown:
            raise ValueError(f"changes: unknown argument(s) {unknown}; the data are {sorted(self._arguments)}")
        return NonholonomicSystem(**{**self._arguments, **changes})

    def with_scaled_metric(self, S, **changes):
        """A copy whose metric is ``S m(x) S^T`` (``S``: a constant ``(D, D)`` matrix), every other datum kept.

        The kinetic energy in other units of momentum (or a mass/inertia ratio);
        a given ``metric_derivative`` is scaled the same way.  ``changes``: other
        constructor arguments to replace (e.g. ``sample``).
        """
        from .._data import as_float_array

        D = self.space.D
        S = as_float_array(S, "S")
        if S.shape != (D, D) or not np.all(np.isfinite(S)):
            raise ValueError(f"S: expected a finite ({D}, {D}) matrix, got shape {S.shape}")
        m, dm = self._arguments["metric"], self._arguments["metric_derivative"]
        if callable(m):
            metric = lambda *x, f=m: S @ np.asarray(f(*x)) @ S.T  # noqa: E731 -- (x) or (x, Gamma)
        else:
            metric = S @ as_float_array(m, "metric") @ S.T
        deriv = None if dm is None else (lambda *x, f=dm: S @ np.asarray(f(*x)) @ S.T)
        return self.replace(metric=metric, metric_derivative=deriv, **changes)

    @property
    def state_names(self):
        return self.space.state_names

    def __repr__(self):
        return f"NonholonomicSystem({self.space!r}, K={self.K})"

    # --- validation -----------------------------------------------------------
    def check(self, x):
        """Check the data at the data point(s) ``x`` (``(x, Gamma)`` with an advected vector); raise a named ``ValueError`` if wrong."""
        x = np.asarray(x, dtype=float)
        if x.shape[-1:] != (self.space.data_dim,):
            what = "data points (x, Gamma)" if self.space.k else "shape points"
            raise ValueError(f"x: expected {what} of shape (..., {self.space.data_dim}), got {x.shape}")
        if not np.all(np.isfinite(x)):
            raise ValueError("x: contains non-finite numbers")
        data = [self.metric, self.constraints, self.potential]
        if self.vector_potential is not None:
            data.append(self.vector_potential)
        for datum in data:  # first: a complex value is named, not cast to real with a ComplexWarning
            datum.check_real(x)
        m = np.asarray(self.metric(x), float)
        if not np.all(np.isfinite(m)):
            raise ValueError(f"metric: non-finite values at x = {x}" + _NON_FINITE)
        asym = np.max(np.abs(m - np.swapaxes(m, -1, -2)), initial=0.0)
        if asym > 1e-12 * max(1.0, np.max(np.abs(m), initial=0.0)):
            raise ValueError(
                f"metric: not symmetric (max |m - m^T| = {asym:.3g}); the mass tensor must be "
                "symmetric positive definite, e.g. pass (m + m.T) / 2 if that is what you meant"
            )
        eig = np.linalg.eigvalsh(m)
        if np.any(eig <= 0):
            raise ValueError(
                f"metric: not positive definite (smallest eigenvalue {eig.min():.3g}); every "
                "inertia/mass must be positive"
            )
        if self.K:
            E = np.asarray(self.constraints(x), float)
            if not np.all(np.isfinite(E)):
                raise ValueError(f"constraints: non-finite values at x = {x}" + _NON_FINITE)
            with np.errstate(over="ignore", invalid="ignore"):  # an overflow is named by _gram_inverse
                C = E @ m @ np.swapaxes(E, -1, -2)
            _gram_inverse(C)
        U = np.asarray(self.potential(x), float)
        if not np.all(np.isfinite(U)):
            raise ValueError(f"potential: non-finite value at x = {x}" + _NON_FINITE)
        if self.vector_potential is not None:
            if not np.all(np.isfinite(np.asarray(self.vector_potential(x), float))):
                raise ValueError(f"vector_potential: non-finite values at x = {x}" + _NON_FINITE)
        if self.space.data_dim:
            for datum in data:
                datum.check_differentiable(x)

    # --- the derived quantities (formulas in liefi.reduction.core) -----------
    def hamiltonian(self, z):
        """``h(z)``, see :func:`liefi.reduction.hamiltonian`."""
        return _red.hamiltonian(self, z)

    def extended_hamiltonian(self, z):
        """``h~(z)``, see :func:`liefi.reduction.extended_hamiltonian`."""
        return _red.extended_hamiltonian(self, z)

    def constraint_momenta(self, z):
        """``J_i(z) = <P, e_i>``, see :func:`liefi.reduction.constraint_momenta`."""
        return _red.constraint_momenta(self, z)

    def gram_matrix(self, x):
        """``C^{li} = <e_l^flat, e_i>``, see :func:`liefi.reduction.gram_matrix`."""
        return _red.gram_matrix(self, x)

    def multipliers(self, z):
        """``lambda(z)``, see :func:`liefi.reduction.multipliers`."""
        return _red.multipliers(self, z)

    def extended_multipliers(self, z):
        """``lambda~(z)``, see :func:`liefi.reduction.extended_multipliers`."""
        return _red.extended_multipliers(self, z)

    def constrained_vector_field(self, z):
        """Constrained field, see :func:`liefi.reduction.constrained_vector_field`."""
        return _red.constrained_vector_field(self, z)

    def extended_vector_field(self, z):
        """Extended field, see :func:`liefi.reduction.extended_vector_field`."""
        return _red.extended_vector_field(self, z)

    def projected_vector_field(self, z):
        """Extended field at the projection, see :func:`liefi.reduction.projected_vector_field`."""
        return _red.projected_vector_field(self, z)

    def complete_momenta(self, x, known):
        """The reduced state on the constraint set with the given momentum components.

        ``known`` maps ``D - K`` momentum names (``space.momentum_names``) to values;
        the other ``K`` components are solved from the ``K`` linear constraints
        ``E(x) (P - A(x)) = 0``.  Returns ``z = (x, P)`` with ``J(z) = 0``; with an
        advected vector ``x`` is the data point ``(x, Gamma)`` and ``z = (x, Gamma, P)``.
        """
        names = self.space.momentum_names
        unknown = [i for i, s in enumerate(names) if s not in known]
        if len(unknown) != self.K or set(known) - set(names):
            raise ValueError(
                f"known: give {self.space.D - self.K} of the momenta {names}; the other "
                f"{self.K} are solved from the constraints"
            )
        x = np.asarray(x, float)
        E = np.asarray(self.constraints(x), float)
        P = np.array([known.get(s, 0.0) for s in names], float)
        A = E[:, unknown]
        if np.linalg.cond(A) > 1e12:
            raise ValueError(
                f"known: the constraints do not determine {[names[i] for i in unknown]} at "
                f"x = {x}; give other components"
            )
        rhs = -E @ P
        if self.vector_potential is not None:  # J = E (P - A(x))
            rhs = rhs + E @ np.asarray(self.vector_potential(x), float)
        P[unknown] = np.linalg.solve(A, rhs)
        return np.concatenate([x, P])

    def project(self, z):
        """Projection onto ``J = 0``, see :func:`liefi.reduction.project`.

        ``z``: real states ``(..., nz)``; a string, a wrong length or a non-finite
        entry is a ``ValueError`` naming ``z`` (complex ``z``, a complex step, passes).
        """
        if not np.iscomplexobj(z):
            z = as_state(z, "z", self.state_names)
        return _red.project(self, z)

    def reconstruction(self, g, z, *, extended=True):
        """``g'`` in the group's embedding, see :func:`liefi.reduction.reconstruction`."""
        return _red.reconstruction(self, g, z, extended=extended)


def _at_data_point(fun, n):
    """A datum ``fun(x, Gamma)`` as a function of the data point ``y = (x, Gamma)``: ``f(y) = fun(y[:n], y[n:])``.

    Constants, ``None`` and functions already of ``y`` (marked ``liefi_data_point``)
    are returned unchanged.  Slicing keeps complex and traced entries, so the
    complex step (and the engine's tracing) differentiate in ``x`` and ``Gamma`` at once.
    """
    if not callable(fun) or getattr(fun, "liefi_data_point", False):
        return fun

    def at(y):
        y = np.asarray(y)
        return fun(y[..., :n], y[..., n:])

    at.liefi_data_point = True
    at.__name__ = getattr(fun, "__name__", "datum")
    return at


def _cholesky(C):
    """Lower-triangular ``L`` with ``L L^T = C`` by plain arithmetic (complex-step safe:
    ``np.linalg.cholesky`` conjugates complex input, which breaks the complex step)."""
    K = C.shape[-1]
    L = [[None] * K for _ in range(K)]
    for i in range(K):
        for j in range(i + 1):
            s = C[..., i, j] - sum((L[i][k] * L[j][k] for k in range(j)), 0.0)
            L[i][j] = np.sqrt(s) if i == j else s / L[j][j]
    zero = np.zeros_like(C[..., 0, 0])
    return np.stack([np.stack([L[i][j] if j <= i else zero for j in range(K)], -1) for i in range(K)], -2)


def _orthonormalized(constraints, metric, n, K, D):
    """Constraint rows made orthonormal for the metric: ``e' = L^{-1} e``, ``L L^T = E m E^T``."""

    def rows(x):
        E = constraints(x) if callable(constraints) else np.asarray(constraints, float)
        E = np.broadcast_to(E, np.shape(x)[:-1] + (K, D)) if n else E
        m = metric(x) if callable(metric) else np.asarray(metric, float)
        C = E @ m @ np.swapaxes(E, -1, -2)
        return np.linalg.solve(_cholesky(C), E)

    if not callable(constraints) and not callable(metric):
        return rows(np.zeros(n))
    return rows


def _checked_inverse(m, name):
    try:
        np.linalg.cholesky(m)
    except np.linalg.LinAlgError:
        raise ValueError(
            f"{name}: not symmetric positive definite; every inertia/mass must be positive"
        ) from None
    if np.max(np.abs(m - m.T), initial=0) > 1e-12 * max(1.0, np.abs(m).max()):
        raise ValueError(f"{name}: not symmetric; pass (m + m.T) / 2 if that is what you meant")
    cond = np.linalg.cond(m)
    if not np.isfinite(cond) or cond > 1e14:
        raise ValueError(
            f"{name}: numerically singular (condition number {cond:.3g}); every inertia/mass "
            "must be positive and of comparable scale to machine precision"
        )
    return np.linalg.inv(m)


def _gram_inverse(C):
    """Inverse of the Gram matrix ``C^{li} = <e_l^flat, e_i>``; error if the constraints are dependent."""
    K = C.shape[-1]
    if K == 0:
        return C
    if not np.all(np.isfinite(C)):
        raise ValueError(
            "constraints: the Gram matrix E m E^T of the constraint vectors is not finite "
            "(overflow or NaN in the metric or the constraints); rescale the constraint rows"
        )
    cond = np.linalg.cond(C)
    if not np.all(np.isfinite(cond)) or np.any(cond > 1e12):
        raise ValueError(
            f"constraints: the constraint vectors are (nearly) linearly dependent (condition "
            f"number of their Gram matrix {np.max(cond):.3g}); drop redundant constraints"
        )
    return np.linalg.inv(C)
