"""Scenes: the paper's experiments as data on top of the core library.

A :class:`Scene` holds a system's data (built lazily), the paper's settings
(step, horizon, scheme, gains, which invariants ``V`` penalizes), named
variants, and an exact or numerical reference solution.  :meth:`Scene.run`
integrates exactly what is asked -- the reduced state alone unless the
configuration is needed -- and returns a :class:`RunResult` with the error
against the reference and the drift of every invariant.  No scene writes an
equation of motion: the fields come from :mod:`liefi.reduction`.
"""

from __future__ import annotations

import time
from dataclasses import dataclass
from dataclasses import field as _field
from functools import cached_property

import numpy as np

from ..feedback import FeedbackIntegrator
from ..reduction import core as _core


@dataclass(frozen=True)
class Variant:
    """A named way to run a scene.

    Attributes
    ----------
    name, description : str
    energy : {"extended", "original"}
        Whether ``V`` penalizes ``h~`` or ``h``.
    field : {"extended", "projected"}
        Which extension of the constrained field is integrated.
    options : dict
        Scene-specific settings (e.g. the start of the Heisenberg system).
    """

    name: str
    description: str
    energy: str = "extended"
    field: str = "extended"
    options: dict = _field(default_factory=dict)


@dataclass
class RunResult:
    """What one run of a scene produced.

    ``max_error`` maps each compared variable to its max absolute error over
    the saved points; ``max_drift`` maps each invariant to ``max |I(t) - I(0)|``
    (the constraint momenta ``J_i``, the energies ``h`` and ``h~``, the scene's
    other invariants, and ``orthogonality = ||R^T R - I||_F`` when the group
    element is integrated in an embedding with a penalty).
    """

    scene: str
    variant: str
    scheme: str
    dt: float
    t_final: float
    steps: int
    cpu_seconds: float
    rhs_evaluations: int
    reference: str
    gains: dict
    t: np.ndarray
    y: np.ndarray
    names: tuple
    errors: dict
    invariants: dict
    max_error: dict
    max_drift: dict
    #: seconds spent besides the integration (estimate, guard, kernel loading)
    overhead_seconds: float = 0.0
    #: invariants left out of ``V`` (kept exactly by the scheme): ``[{"name", "reason"}]``
    dropped: list = _field(default_factory=list)

    def __getitem__(self, name):
        return self.y[self.names.index(name)]

    def to_dict(self):
        """The JSON-able summary (the keys of ``liefi run --json``)."""
        return {
            "scene": self.scene,
            "variant": self.variant,
            "scheme": self.scheme,
            "dt": self.dt,
            "t_final": self.t_final,
            "steps": self.steps,
            "cpu_seconds": self.cpu_seconds,
            "overhead_seconds": self.overhead_seconds,
            "rhs_evaluations": self.rhs_evaluations,
            "reference": self.reference,
            "gains": self.gains,
            "max_error": {k: float(v) for k, v in self.max_error.items()},
            "max_drift": {k: float(v) for k, v in self.max_drift.items()},
            "dropped": [dict(d) for d in self.dropped],
        }


class Scene:
    """Base class of the scenes; a scene module subclasses it and fills in data.

    Class attributes to set: ``name``, ``title``, ``paper`` (section),
    ``reference`` (``"exact"`` or ``"numerical"``), ``dt``, ``t_final``,
    ``scheme``, ``gains`` (number or dict, see :class:`~liefi.FeedbackIntegrator`),
    ``variants`` (dict of :class:`Variant`), ``error_variables`` (names
    compared with the reference).  Methods to supply: :meth:`build_system`,
    :meth:`initial_state`; and :meth:`exact` when ``reference == "exact"``.
    """

    name = ""
    title = ""
    paper = ""
    reference = "exact"
    dt = 1e-3
    t_final = 10.0
    scheme = "euler"
    gains = 1.0
    variants: dict = {}
    error_variables: tuple = ()
    #: schemes besides liefi's RK tableaux and ``scipy:METHOD`` this scene supports
    extra_schemes: tuple = ()
    #: the variant the stability experiments run (default: the first)
    stability_variant = None
    #: this scene's own extreme cases for the stability battery (see :meth:`stability_case`);
    #: each also runs with automatic gains as ``"<case> auto"``
    stability_cases: tuple = ()

    def stability_case(self, case):
        """``(scene, variant, has_reference)`` of one of :attr:`stability_cases` (a modified copy of the scene)."""
        raise ValueError(f"case: scene {self.name!r} has no stability case {case!r}")

    # --- data (to supply) --------------------------------------------------------
    def build_system(self):
        raise NotImplementedError

    def initial_state(self, variant: Variant):
        """The full initial state ``(g, z)`` (group element in its embedding, then z)."""
        raise NotImplementedError

    def invariants(self, variant: Variant):
        """Invariants ``V`` penalizes (default: constraints and energy)."""
        return ("constraints", "energy")

    def exact(self, t, variant: Variant):
        """Reference values ``{name: array(len(t))}`` of the constrained motion."""
        if self.reference == "numerical":
            return self.numerical_reference(t, variant)
        raise NotImplementedError

    def observables(self, y, names):
        """Derived quantities (e.g. the heading from a rotation matrix); default none."""
        return {}

    # --- derived -------------------------------------------------------------------
    @cached_property
    def system(self):
        return self.build_system()

    def variant(self, name=None) -> Variant:
        if name is None:
            return next(iter(self.variants.values()))
        try:
            return self.variants[name]
        except KeyError:
            raise ValueError(
                f"variant: scene {self.name!r} has variants {list(self.variants)}, not {name!r}"
            ) from None

    def needs_configuration(self):
        """True when a compared variable is not a reduced-state name (a configuration
        number, or an observable computed from the configuration)."""
        reduced = set(self.system.state_names)
        return any(v not in reduced for v in self.error_variables)

    def integrator(self, variant=None, *, gains=None, configuration=None, y0=None):
        """The :class:`~liefi.FeedbackIntegrator` of this scene and variant."""
        v = self.variant(variant) if not isinstance(variant, Variant) else variant
        cfg = self.needs_configuration() if configuration is None else configuration
        full = np.asarray(self.initial_state(v) if y0 is None else y0, float)
        nc = self.system.space.group.config_dim
        start = full if cfg else full[nc:]
        return FeedbackIntegrator(
            self.system,
            start,
            invariants=self.invariants(v),
            gains=self.gains if gains is None else gains,
            energy=v.energy,
            configuration=cfg,
            field=v.field,
        )

    def numerical_reference(self, t, variant: Variant, rtol=1e-12, atol=1e-12):
        """High-accuracy integration (DOP853) of the *constrained* field from the start."""
        from scipy.integrate import solve_ivp

        key = (variant.name, float(t[-1]), len(t))
        cache = self.__dict__.setdefault("_refcache", {})
        if key not in cache:
            y0 = np.asarray(self.initial_state(variant), float)
            sys = self.system

            def f(_t, y):
                return _core.full_vector_field(sys, y, kind="constrained")

            sol = solve_ivp(f, (0.0, float(t[-1])), y0, method="DOP853", rtol=rtol, atol=atol, t_eval=t)
            if not sol.success:
                raise RuntimeError(f"reference solution of {self.name!r} failed: {sol.message}")
            names = tuple(sys.space.group.config_names) + sys.state_names
            cache[key] = {n: sol.y[i] for i, n in enumerate(names)}
        return cache[key]

    # --- running ---------------------------------------------------------------------
    def run(
        self,
        *,
        dt=None,
        t_final=None,
        scheme=None,
        gains=None,
        variant=None,
        configuration=None,
        save_every=None,
        max_saved=20000,
        rtol=1e-9,
        atol=1e-12,
        check_stability=True,
        adaptive=None,
        backend=None,
    ) -> RunResult:
        """Run the scene at its settings unless told otherwise.

        ``scheme`` is a liefi scheme name (``euler``, ``heun``, ``rk4``...), a
        stiff-safe split scheme (``imex-euler``, ``imex-rk4``: :mod:`liefi.schemes.split`),
        ``"scipy:METHOD"`` (``solve_ivp`` with ``rtol``/``atol``), or one of the
        scene's ``extra_schemes`` (e.g. ``"dla"``).  ``gains="auto"``: chosen for accuracy
        from the scheme, ``dt`` and the horizon (:mod:`liefi.gains`; see
        :class:`~liefi.FeedbackIntegrator`).  ``RunResult.dropped``: the
        invariants left out of ``V`` because the scheme keeps them exactly.
        ``check_stability`` and ``adaptive`` are passed to
        :meth:`liefi.FeedbackIntegrator.run` (:mod:`liefi.stability`).
        ``backend``: ``"numpy"``, ``"numba"`` or ``"auto"`` (:mod:`liefi.compiled`);
        default ``"auto"`` when numba is installed (``liefi[fast]``), else ``"numpy"``.
        """
        if backend is None:
            import importlib.util

            backend = "auto" if importlib.util.find_spec("numba") is not None else "numpy"
        from ..stability import positive_number

        v = self.variant(variant) if not isinstance(variant, Variant) else variant
        dt = positive_number(self.dt if dt is None else dt, "dt", "the step must be a positive number")
        T = positive_number(self.t_final if t_final is None else t_final, "t_final", "must be a positive number")
        scheme = self.scheme if scheme is None else scheme
        if T / dt > 1e10:
            raise ValueError(
                f"dt: {dt!r} with t_final = {T!r} means {T / dt:.3g} steps (more than 1e10); take a larger dt"
            )
        n_steps = int(round(T / dt))
        if save_every is None:
            save_every = max(1, n_steps // max_saved)
        fi = self.integrator(v, gains=gains, configuration=configuration)
        self._check_start(fi, v)

        overhead = 0.0
        if scheme in self.extra_schemes:
            t, Y, names, cpu, steps, nfev = self.run_extra(scheme, v, dt, T, save_every, fi)
            if check_stability:
                from ..run import check_result_drift

                check_result_drift(fi, t, Y, names, scheme, dt)  # e.g. DLA at a step that loses the motion
        elif str(scheme).lower().startswith("scipy:"):
            from ..schemes import registry as _schemes

            ivp = _schemes.get(scheme, kind="scipy")
            method = ivp.method
            if getattr(fi, "gains_mode", "fixed") == "auto":
                from ..stability import auto_gains

                fi = fi.with_gains(auto_gains(fi, dt, "euler"))
            if check_stability:
                from ..run import check_ivp

                check_ivp(fi, ivp, T)  # an explicit method on a stiff field would run for minutes
            t_eval = np.linspace(0.0, T, min(n_steps, max_saved) + 1)
            sol, cpu = ivp.solve(fi.fun, T, fi.y0, t_eval=t_eval, rtol=rtol, atol=atol)
            if not sol.success:
                raise RuntimeError(f"solve_ivp({method}) failed on {self.name!r}: {sol.message}")
            if not np.all(np.isfinite(sol.y)):
                raise FloatingPointError(f"solve_ivp({method}) returned non-finite values on {self.name!r}")
            t, Y, names, steps, nfev = sol.t, sol.y, fi.names, int(sol.t.size), int(sol.nfev)
        else:
            sol = fi.run(
                dt, T, scheme, save_every=save_every, check_stability=check_stability, adaptive=adaptive,
                backend=backend,
            )
            dropped = list(getattr(sol, "dropped", []))
            if getattr(sol, "stability", None) is not None and (sol.stability.gains or dropped):
                # report the gains the run started with (0 for the invariants left out of V)
                fi = fi.with_gains({**{d["name"]: 0.0 for d in dropped}, **sol.stability.gains})
            t, Y, names, cpu, steps, nfev = sol.t, sol.y, sol.names, sol.cpu_seconds, sol.steps, sol.rhs_evaluations
            overhead = getattr(sol, "overhead_seconds", 0.0)
        res = self._result(v, str(scheme), dt, T, fi, t, Y, names, cpu, steps, nfev)
        res.overhead_seconds = float(overhead)
        if scheme not in self.extra_schemes and not str(scheme).lower().startswith("scipy:"):
            res.dropped = dropped
        return res

    def _check_start(self, fi, v, rtol=1e-9):
        """The reference solution is the *constrained* motion: the start must be on ``J = 0``."""
        if not self.system.K:
            return
        from ..stability import drift_scales

        J = np.atleast_1d(np.asarray(self.system.constraint_momenta(fi.split(fi.y0)[1]), float))
        sc = drift_scales(fi)
        rel = max(abs(float(J[i])) / sc.get(f"J_{i + 1}", 1.0) for i in range(self.system.K))
        if not rel <= rtol:
            raise ValueError(
                f"initial state: the start of {self.name!r} (variant {v.name!r}) is off the constraint set "
                f"(J = {np.round(J, 12).tolist()}), but the scene compares with the constrained motion from it; "
                "put it on the set, e.g. z = scene.system.project(z), or solve the constraints for some momenta"
            )

    def run_extra(self, scheme, variant, dt, T, save_every, fi):
        """Run a scene-specific scheme; returns ``(t, Y, names, cpu, steps, nfev)``."""
        raise ValueError(f"scheme: {scheme!r} is not available for scene {self.name!r}")

    def _result(self, v, scheme, dt, T, fi, t, Y, names, cpu, steps, nfev):
        data = {n: Y[i] for i, n in enumerate(names)}
        data.update(self.observables(Y, names))
        ref = self.exact(t, v)
        errors = {k: data[k] - ref[k] for k in self.error_variables if k in data and k in ref}
        # invariants along the run (the integrator's state layout)
        nc_fi = fi.nc
        full_names = fi.names
        Yfi = np.stack([data[n] for n in full_names], -1) if all(n in data for n in full_names) else None
        invariants = {}
        if Yfi is not None:
            vals = fi.invariant_values(Yfi)
            for k, val in vals.items():
                if k == "energy":
                    continue
                if k == "penalty":
                    if fi.use_penalty:
                        invariants["orthogonality"] = 2.0 * np.sqrt(np.maximum(val, 0.0))
                else:
                    invariants[k] = np.asarray(val)
        max_drift = {}
        for k, val in invariants.items():
            base = 0.0 if k.startswith("J_") or k == "orthogonality" else val[0]
            max_drift[k] = float(np.max(np.abs(val - base)))
        max_error = {k: float(np.max(np.abs(e))) for k, e in errors.items()}
        return RunResult(
            self.name, v.name, scheme, dt, T, int(steps), float(cpu), int(nfev), self.reference,
            dict(fi.gains), t, Y, tuple(names), errors, invariants, max_error, max_drift,
        )
