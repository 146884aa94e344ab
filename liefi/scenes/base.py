"""Scenes: the paper's experiments as data on top of the core library.

A :class:`Scene` holds a system's data (built lazily), the paper's settings
(step, horizon, scheme, gains, which invariants ``V`` penalizes), named
variants, and an exact or numerical reference solution.  :meth:`Scene.run`
integrates exactly what is asked -- the reduced state alone unless the
configuration is needed -- and returns a :class:`RunResult` with the error
against the reference and the drift of every invariant.  No scene writes an
equation of motion: the fields come from :mod:`liefi.reduction`.

A scene also owns what is particular to it, so that the plotting, the
``liefi`` command and ``liefi reproduce`` stay generic: its figures
(:meth:`Scene.figures`, drawn with the helpers of :mod:`liefi.results.scene_figures`),
whether they need the configuration (:attr:`Scene.figures_need_configuration`),
the runs ``liefi reproduce`` makes (:meth:`Scene.paper_runs`), its reference
solution and what it costs (:meth:`Scene.reference_solution`, computed once per
start; a run's reference values are kept on disk by :mod:`liefi.scenes.store`
and computed only when an error is asked for), and its extreme cases for the
stability battery (:attr:`Scene.stability_cases`).
"""

from __future__ import annotations

import hashlib
import time
from dataclasses import dataclass
from dataclasses import field as _field
from functools import cached_property

import numpy as np

from ..results import scene_figures as plotting
from .. import _fingerprint
from .._keywords import SCENE_FOREIGN, keywords, unknown_keyword
from ..integrator._ensemble import data_state
from ..integrator.feedback import FeedbackIntegrator
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


@dataclass(frozen=True)
class PaperRun:
    """One run of ``liefi reproduce`` (see :meth:`Scene.paper_runs`).

    ``label`` names the run among the variant's runs (it is the key of the mapping
    :meth:`Scene.figures` receives); ``scheme``, ``t_final``, ``save_every`` and
    ``configuration`` are passed to :meth:`Scene.run` (``None``: the scene's
    setting); ``experiment`` is recorded in the summary; a ``variant_independent``
    run does not depend on the variant (e.g. a scheme that ignores ``V``): it runs
    once and every variant reuses it.
    """

    label: str = "paper"
    scheme: str | None = None
    t_final: float | None = None
    save_every: int | None = None
    configuration: bool | None = None
    experiment: str = "paper"
    variant_independent: bool = False


@dataclass
class RunResult:
    """What one run of a scene produced.

    ``max_error`` maps each compared variable to its max absolute error over
    the saved points; ``max_drift`` maps each invariant to ``max |I(t) - I(0)|``
    (the constraint momenta ``J_i``, the energies ``h`` and ``h~``, the scene's
    other invariants, and ``orthogonality = ||R^T R - I||_F`` when the group
    element is integrated in an embedding with a penalty).

    The errors (``errors``, ``max_error``) are computed on first use: a run whose
    error is never asked for never computes the reference.  Its cost is then added
    to ``overhead_seconds`` and ``reference_seconds``.
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
    invariants: dict
    max_drift: dict
    #: CPU seconds of the whole :meth:`Scene.run` besides the integration itself
    #: (setup, stability estimate, compilation, reference solution, invariants)
    overhead_seconds: float = 0.0
    #: seconds spent computing the reference solution for this run (0 when cached)
    reference_seconds: float = 0.0
    #: the engine that stepped the run (``"numpy"``, ``"numba"``, ``"scipy"``)
    backend: str | None = None
    #: invariants left out of ``V`` (kept exactly by the scheme): ``[{"name", "reason"}]``
    dropped: list = _field(default_factory=list)
    #: which method ran and why (:func:`liefi.integrator.tolerance.describe`; ``None`` outside the fixed-step loop)
    method: dict = None
    #: ``() -> errors``: computes the errors against the reference (called once, on first use)
    _reference: object = _field(default=None, repr=False, compare=False)
    _errors: dict = _field(default=None, repr=False, compare=False)

    @property
    def errors(self):
        """``{name: array}``: the run minus the reference at the saved points (computed on first use)."""
        if self._errors is None:
            compute, self._reference = self._reference, None
            self._errors = {} if compute is None else compute(self)
        return self._errors

    @property
    def max_error(self):
        """``{name: max |error|}`` over the saved points (computes the reference on first use)."""
        return {k: float(np.max(np.abs(e))) for k, e in self.errors.items()}

    def __getstate__(self):  # the errors are computed before a result is pickled (the thunk is not)
        self.errors
        return dict(self.__dict__)

    def __getitem__(self, name):
        return self.y[self.names.index(name)]

    def to_dict(self):
        """The JSON-able summary (the keys of ``liefi run --json``)."""
        max_error = self.max_error  # first: computing the reference adds to the seconds below
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
            "max_error": max_error,
            "max_drift": {k: float(v) for k, v in self.max_drift.items()},
            "reference_seconds": self.reference_seconds,
            "backend": self.backend,
            "dropped": [dict(d) for d in self.dropped],
            "method": None if self.method is None else dict(self.method),
        }


def tolerance_method(scheme, dt, rtol, atol, choose_order=None, default=None):
    """``(scheme, choose_order)`` of a run asked for ``scheme`` (or None), ``dt`` and ``rtol``/``atol``.

    The one choice :meth:`Scene.run`, :meth:`liefi.FeedbackIntegrator.run` and ``liefi run`` make: a
    tolerance without ``dt`` and without ``scheme`` runs :data:`liefi.integrator.tolerance.DEFAULT_SCHEME`'s kind with
    the order chosen with the step; a named ``scheme`` is run as named (its order kept unless
    ``choose_order``); without a tolerance, ``default`` (the scene's scheme, for its own step).
    """
    from ..integrator.tolerance import DEFAULT_SCHEME

    for_tolerance = dt is None and (rtol is not None or atol is not None)
    if scheme is None:
        if for_tolerance:
            return DEFAULT_SCHEME, True if choose_order is None else bool(choose_order)
        scheme = default
    return scheme, bool(choose_order)


def _json_number(x):
    """numpy numbers and arrays as JSON (the step's ``info``)."""
    return x.tolist() if hasattr(x, "tolist") else float(x)


class Scene:
    """Base class of the scenes; a scene module subclasses it and fills in data.

    Class attributes to set: ``name``, ``title``, ``paper`` (section),
    ``reference`` (``"exact"`` or ``"numerical"``), ``dt``, ``t_final``,
    ``scheme``, ``gains`` (number or dict, see :class:`~liefi.FeedbackIntegrator`),
    ``variants`` (dict of :class:`Variant`), ``error_variables`` (names
    compared with the reference).  Methods to supply: :meth:`build_system`,
    :meth:`initial_state`; and :meth:`exact` when ``reference == "exact"``.

    What is particular to a scene and used by the generic tools: :meth:`figures`
    (default: one generic figure per run), :attr:`figures_need_configuration`,
    :meth:`paper_runs` (default: one run at the paper's settings),
    :meth:`reference_solution`, :attr:`stability_cases` and :attr:`stiff_study`.
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
    #: one of the paper's experiments: ``liefi reproduce`` runs it (others: ``--only`` or ``--all``)
    in_paper: bool = True
    #: the scene's figures need the group element integrated (e.g. ``||R^T R - I||``)
    figures_need_configuration: bool = False
    #: tolerances of the numerical reference (DOP853 on the constrained field)
    reference_rtol: float = 1e-12
    reference_atol: float = 1e-12
    #: the variant the stability experiments run (default: the first)
    stability_variant = None
    #: this scene's own extreme cases for the stability battery (see :meth:`stability_case`);
    #: each also runs with automatic gains as ``"<case> auto"``
    stability_cases: tuple = ()
    #: the stiff work-precision study of the stability report runs on this scene
    #: (:func:`liefi.experiments.battery.stiff_work_precision`: explicit, split and implicit schemes)
    stiff_study: bool = False

    def costly_build(self):
        """Why building this scene's system takes long (a phrase, e.g. sympy's derivation), or ``None``.

        ``liefi list -v`` builds every other scene to show the order of ``--gains``; it does not build one
        that says it is costly, and prints this instead.
        """
        return None

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
        system = self.build_system()
        self.__dict__["_built_data"] = data_state(system)  # its constants as built (_changed_data)
        if _fingerprint.of_system(system) is None:  # liefi's own scene: its data and liefi's code decide the system
            data = _fingerprint.object_data(self, skip=("system",))
            if data is not None:
                _fingerprint.stamp(system, "scene", type(self).__module__, type(self).__qualname__, data)
        return system

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
        """The :class:`~liefi.FeedbackIntegrator` of this scene and variant.

        Its gains are the scene's own (the paper's, fixed) unless ``gains`` is given.  A step chosen for a
        tolerance is chosen for the integrator that runs: :meth:`run` with ``rtol`` (and ``liefi run``) runs
        ``gains="auto"``, as ``FeedbackIntegrator(system, y0)`` does by default, so ``integrator(gains="auto")
        .run(rtol=...)`` chooses the same step as they do, while ``integrator().run(rtol=...)``, with the fixed
        paper gains, runs another feedback and may choose another step (the rattleback over ``[0, 20]`` at
        ``1e-6``: 7.7e-4 with ``"auto"``, 1.05e-3 with its ``k = 1``; at 1.05e-3 the ``"auto"`` run's error is
        1.2e-6, the ``k = 1`` run's 2.3e-7).
        """
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

    def numerical_reference(self, t, variant: Variant):
        """The constrained motion from the variant's start at the times ``t``: ``{name: array}``
        (configuration names, then the state names); see :meth:`reference_solution`."""
        t = np.asarray(t, float)
        return self.reference_solution(variant, float(t[-1]) if t.size else 0.0)(t)

    def monitored(self, variant):
        """First integrals the scene reports without penalizing them (:class:`~liefi.Invariant` of the
        reduced state): their drift is in ``RunResult.max_drift``, beside the invariants of ``V``.  None by
        default; a scene whose motion has integrals that ``V`` leaves out lists them here."""
        return ()

    def reference_values(self, t, variant):
        """The reference ``{name: array}`` at the times ``t``: :meth:`exact`, through the reference store.

        A numerical reference is kept on disk (:mod:`liefi.scenes.store`, signed, keyed by the scene's
        parameters, the variant, the start, ``t`` and liefi's code) and read back by any later run
        that asks for the same one; a closed-form reference is evaluated.
        """
        v = self.variant(variant) if not isinstance(variant, Variant) else variant
        t = np.asarray(t, float)
        if self.reference != "numerical":
            return self.exact(t, v)
        from . import store

        return store.reference(self, v, t, lambda: self.exact(t, v))

    def _changed_data(self):
        """A digest of the system's constants when they were changed since it was built (``scene.system.constants
        = ...``, a :func:`~liefi.from_mechanics` scene), else ``None``: a part of the key of everything the scene
        keeps (references, steps for a tolerance; in this process and in the store), which the old constants
        decided."""
        system = self.__dict__.get("system")
        now = None if system is None else data_state(system)
        if now is None or now == self.__dict__.get("_built_data"):
            return None
        return hashlib.sha256(repr(now).encode()).hexdigest()

    def _kept(self, key, make):
        """``make()``, computed once per scene and ``key`` in this process (a reference at given times)."""
        key = (key, self._changed_data())
        cache = self.__dict__.setdefault("_refcache", {})
        if key not in cache:
            cache[key] = make()
        return cache[key]

    def solve_reference(self, fun, y0, t_final, **kw):
        """``solve_ivp(fun, (0, t_final), y0)`` by DOP853 at the scene's ``reference_rtol``/``atol``: the one
        place a reference is solved (the liefi-derived constrained field here, or a scene's equations written
        by hand).  Its seconds are added to ``reference_seconds``; a failure raises ``RuntimeError``."""
        from scipy.integrate import solve_ivp

        start = time.perf_counter()
        sol = solve_ivp(fun, (0.0, float(t_final)), y0, method="DOP853", rtol=self.reference_rtol,
                        atol=self.reference_atol, **kw)
        self.reference_seconds = getattr(self, "reference_seconds", 0.0) + time.perf_counter() - start
        if not sol.success:
            raise RuntimeError(f"reference solution of {self.name!r} failed: {sol.message}")
        return sol

    def reference_solution(self, variant: Variant, t_final, *, backend=None):
        """The numerical reference on ``[0, t_final]``: a callable ``t -> {name: array}``.

        DOP853 (``reference_rtol``, ``reference_atol``) on the *constrained* field
        (:func:`~liefi.reduction.core.full_vector_field` with ``kind="constrained"``) from
        the full start ``(g, z)``, evaluated through its dense output -- the
        interpolant ``solve_ivp`` evaluates ``t_eval`` with, so the values are those
        of a ``t_eval`` run.  Its cost is paid once per start: the solution is cached
        on the scene by the start (variants that share a start, e.g. ones that only
        change ``V``, share it) and reused for every horizon up to the longest
        computed; ask for the longest horizon first to integrate once.  The field is
        the compiled one (:mod:`liefi.engine`) unless ``backend="numpy"`` or numba
        is missing; the seconds spent are added to ``reference_seconds``.
        """
        v = self.variant(variant) if not isinstance(variant, Variant) else variant
        y0 = np.asarray(self.initial_state(v), float)
        T = float(t_final)
        cache = self.__dict__.setdefault("_refcache", {})
        key = (y0.tobytes(), self._changed_data())
        hit = cache.get(key)
        if hit is None or hit[0] < T:
            sys = self.system
            names = tuple(sys.space.group.config_names) + sys.state_names
            sol = self.solve_reference(self._constrained_field(v, backend), y0, T, dense_output=True)
            hit = cache[key] = (T, sol.sol, names)
        _, dense, names = hit

        def at(t):
            t = np.asarray(t, float)
            if t.size and (t.min() < 0.0 or t.max() > T * (1 + 1e-12) + 1e-12):
                raise ValueError(f"t: the reference of {self.name!r} covers [0, {T:g}]; got t up to {t.max():g}")
            Y = dense(t) if t.size else np.zeros((len(names), 0))
            return {n: Y[i] for i, n in enumerate(names)}

        return at

    def _constrained_field(self, v, backend):
        """``fun(t, y)`` of the constrained field on the full state; compiled when possible."""
        sys = self.system

        def numpy_field(_t, y):
            return _core.full_vector_field(sys, y, kind="constrained")

        if backend == "numpy":
            return numpy_field
        import importlib.util

        if importlib.util.find_spec("numba") is None:
            return numpy_field
        try:
            from .. import engine

            fi = self.integrator(v, configuration=True)
            return engine.compile_constrained(fi).fun(np.zeros(0))
        except Exception as exc:  # noqa: BLE001 - the numpy field is the reference; say why it is used
            import warnings

            warnings.warn(
                f"reference of {self.name!r}: the compiled constrained field is not available "
                f"({type(exc).__name__}: {exc}); integrating the numpy field (slower)",
                RuntimeWarning, stacklevel=3,
            )
            return numpy_field

    def reference_method(self):
        """How the reference is computed, in words (``liefi run --json``: ``reference_method``)."""
        if self.reference == "numerical":
            return (f"DOP853 (scipy solve_ivp, rtol {self.reference_rtol:g}, atol {self.reference_atol:g}) "
                    "on the constrained field from the start")
        return "closed-form exact solution"

    # --- what the generic tools ask of a scene -----------------------------------------
    @staticmethod
    def as_runs(runs):
        """``runs`` as a mapping ``label -> RunResult`` (a single result is ``{"run": result}``)."""
        return {"run": runs} if isinstance(runs, RunResult) else dict(runs)

    def figures(self, runs, *, tag=""):
        """The figures of ``runs`` (a :class:`RunResult`, or the mapping ``label -> RunResult``
        of :meth:`paper_runs`): a list of :class:`liefi.results.scene_figures.FigureSpec`.

        The default is :func:`liefi.results.scene_figures.generic` (errors and drifts) for each run;
        a scene with figures in the paper overrides it.  ``tag`` is appended to titles.
        """
        return [
            plotting.FigureSpec("generic", lambda f, r=r: plotting.generic(r, f, title=self.title, tag=tag), 11, 4.0)
            for r in self.as_runs(runs).values()
        ]

    def paper_runs(self, variant: Variant):
        """The runs ``liefi reproduce`` makes for ``variant`` (a tuple of :class:`PaperRun`).

        Default: one run at the paper's settings, with the configuration when the
        figures need it.
        """
        return (PaperRun(configuration=True if self.figures_need_configuration else None),)

    # --- running ---------------------------------------------------------------------
    @keywords
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
        rtol=None,
        atol=None,
        choose_order=None,
        check_stability=True,
        adaptive=None,
        backend=None,
        **unknown,
    ) -> RunResult:
        """Run the scene at its settings unless told otherwise.

        ``scheme`` is a liefi scheme name (``euler``, ``heun``, ``rk4``...), a
        stiff-safe split scheme (``imex-euler``, ``imex-rk4``: :mod:`liefi.schemes.split`),
        ``"scipy:METHOD"`` (``solve_ivp`` with ``rtol``/``atol``, default 1e-9/1e-12), or one of the
        scene's ``extra_schemes`` (e.g. ``"dla"``).  ``gains="auto"``: chosen for accuracy
        from the scheme, ``dt`` and the horizon (:mod:`liefi.integrator.gains`; see
        :class:`~liefi.FeedbackIntegrator`).  ``RunResult.dropped``: the
        invariants left out of ``V`` because the scheme keeps them exactly.
        ``check_stability`` and ``adaptive`` are passed to
        :meth:`liefi.FeedbackIntegrator.run` (:mod:`liefi.integrator.stability`).
        ``backend``: ``"numpy"``, ``"numba"`` or ``"auto"`` (:mod:`liefi.engine`);
        default ``"auto"`` when numba is installed (``liefi[fast]``), else ``"numpy"``.
        ``rtol``/``atol`` without ``dt`` on a fixed-step scheme: the step is chosen for the
        tolerance (:func:`liefi.integrator.tolerance.choose_step`) instead of the scene's, the gains default to
        ``"auto"`` (as ``liefi run`` and :class:`~liefi.FeedbackIntegrator`'s default), and with
        ``choose_order=True`` also the order (``imex-rk4``/``6``/``8`` for a split ``scheme``).
        Without ``scheme`` a tolerance runs liefi's default method, the one
        :meth:`liefi.FeedbackIntegrator.run` and ``liefi run`` choose for it (:func:`tolerance_method`):
        a split scheme whose order is chosen with the step (``choose_order`` defaults to True then, and to
        False when ``scheme`` is named); the scene's own scheme goes with its own step ``dt``.
        ``RunResult.method`` says which method ran and why.
        """
        import importlib.util

        from .._progress import compile_notice

        if unknown:
            raise unknown_keyword("run", unknown, Scene.run, SCENE_FOREIGN)
        clock = (time.process_time(), getattr(self, "reference_seconds", 0.0))
        if backend is None:
            backend = "auto" if importlib.util.find_spec("numba") is not None else "numpy"
        from ..schemes import positive_number

        v = self.variant(variant) if not isinstance(variant, Variant) else variant
        T = positive_number(self.t_final if t_final is None else t_final, "t_final", "must be a positive number")
        scheme, choose_order = tolerance_method(scheme, dt, rtol, atol, choose_order, self.scheme)
        fixed_step = scheme not in self.extra_schemes and not str(scheme).lower().startswith("scipy:")
        if scheme in self.extra_schemes and dt is None and (rtol is not None or atol is not None):
            raise ValueError(
                f"rtol: the scheme {scheme!r} of scene {self.name!r} has no error control and liefi does not choose "
                f"its step for a tolerance; give dt (default the scene's {self.dt:g}), or use a liefi scheme "
                "(e.g. imex-rk4) for a step chosen for rtol/atol"
            )
        chosen = None
        if fixed_step and dt is None and (rtol is not None or atol is not None):
            # a step for a tolerance is liefi's method, as `liefi run` and FeedbackIntegrator run it: gains "auto"
            # unless given (the scene's paper gains go with its paper step)
            gains = "auto" if gains is None else gains
            with compile_notice():  # the step's check runs compile the kernels: a long compile is announced
                dt, chosen, fi = self._step_for_tolerance(v, scheme, gains, configuration, T, rtol, atol,
                                                          choose_order, backend)
            scheme = chosen["scheme"]
        dt = positive_number(self.dt if dt is None else dt, "dt", "the step must be a positive number")
        if T / dt > 1e10:
            raise ValueError(
                f"dt: {dt!r} with t_final = {T!r} means {T / dt:.3g} steps (more than 1e10); take a larger dt"
            )
        n_steps = int(round(T / dt))
        if save_every is None:
            save_every = max(1, n_steps // max_saved)
        if chosen is None:
            fi = self.integrator(v, gains=gains, configuration=configuration)
        self._check_start(fi, v)

        dropped = []  # invariants the fixed-step run left out of V
        if scheme in self.extra_schemes:
            t, Y, names, cpu, steps, nfev = self.run_extra(scheme, v, dt, T, save_every, fi)
            if check_stability:
                from ..integrator.run import check_result_drift

                check_result_drift(fi, t, Y, names, scheme, dt)  # e.g. DLA at a step that loses the motion
        elif str(scheme).lower().startswith("scipy:"):
            from ..integrator.run import IVP_MAX_EVALUATIONS
            from ..schemes import registry as _schemes
            from ..integrator.tolerance import check_tolerance

            ivp = _schemes.get(scheme, kind="scipy")
            rtol, atol = 1e-9 if rtol is None else rtol, 1e-12 if atol is None else atol
            check_tolerance(rtol, atol)  # before any work: scipy would refuse them after the set-up
            gains_mode = getattr(fi, "gains_mode", "fixed")
            if gains_mode == "auto":
                from ..integrator.gains import auto_gains

                fi = fi.with_gains(auto_gains(fi, dt, "euler"))
            if check_stability:
                from ..integrator.run import check_ivp

                check_ivp(fi, ivp, T)  # an explicit method on a stiff field would run for minutes
            t_eval = np.linspace(0.0, T, min(n_steps, max_saved) + 1)
            sol, cpu = ivp.solve(fi.fun, T, fi.y0, t_eval=t_eval, rtol=rtol, atol=atol,
                                 max_evaluations=IVP_MAX_EVALUATIONS)
            if not sol.success:
                raise RuntimeError(f"solve_ivp({ivp.method}) failed on {self.name!r}: {sol.message}")
            if not np.all(np.isfinite(sol.y)):
                raise FloatingPointError(f"solve_ivp({ivp.method}) returned non-finite values on {self.name!r}")
            t, Y, names, steps, nfev = sol.t, sol.y, fi.names, int(sol.t.size), int(sol.nfev)
            method = {"scheme": ivp.name, "dt": None, "gains": "auto" if gains_mode == "auto" else "fixed",
                      "backend": "scipy", "rtol": float(rtol), "atol": np.asarray(atol, float).tolist(),
                      "why": f"scheme {ivp.name} as asked (scipy solve_ivp, its own adaptive steps for rtol "
                             f"{float(rtol):g}); backend scipy"}
        else:
            from ..integrator.run import run_feedback

            # a step chosen for a tolerance brings the resolution limit its order and tolerance allow
            with compile_notice():
                sol = run_feedback(
                    fi, T, dt=dt, scheme=scheme, save_every=save_every, check_stability=check_stability,
                    adaptive=adaptive, backend=backend,
                    resolution_limit=None if chosen is None else chosen.get("resolution_limit"),
                )
            method = sol.method
            if chosen is not None:
                from ..integrator.tolerance import describe

                method = describe(method["scheme"], dt, fi.gains_mode, method["backend"], chosen=chosen,
                                  scheme_given=True)
            dropped = list(getattr(sol, "dropped", []))
            if getattr(sol, "stability", None) is not None and (sol.stability.gains or dropped):
                # report the gains the run started with (0 for the invariants left out of V)
                fi = fi.with_gains({**{d["name"]: 0.0 for d in dropped}, **sol.stability.gains})
            t, Y, names, cpu, steps, nfev = sol.t, sol.y, sol.names, sol.cpu_seconds, sol.steps, sol.rhs_evaluations
        ran = getattr(sol, "backend", None) if "sol" in locals() else None
        if str(scheme).startswith("scipy:"):
            ran = "scipy"
        elif ran is None:
            ran = "numba" if (backend != "numpy" and scheme in self.extra_schemes
                              and importlib.util.find_spec("numba") is not None) else "numpy"
        result = self._result(v, str(scheme), dt, T, fi, t, Y, names, cpu, steps, nfev, clock=clock)
        result.backend = ran
        result.dropped = dropped
        if "method" in locals():
            result.method = method
        return result

    def _step_for_tolerance(self, v, scheme, gains, configuration, T, rtol, atol, choose_order=False, backend=None):
        """``(dt, info, fi)``: the fixed step of ``scheme`` for ``rtol``/``atol`` (:meth:`step_for_tolerance`)."""
        dt, info = self.step_for_tolerance(v, scheme, T, rtol, atol, gains=gains, configuration=configuration,
                                           choose_order=choose_order, backend=backend)
        return dt, info, self.integrator(v, gains=gains, configuration=configuration)

    def step_for_tolerance(self, variant, scheme, t_final, rtol=None, atol=None, *, gains=None, configuration=None,
                           choose_order=False, backend=None):
        """``(dt, info)``: the step :meth:`run` takes for ``rtol``/``atol`` (:func:`liefi.integrator.tolerance.choose_step`;
        with ``choose_order``, ``info["scheme"]`` is the order chosen among ``scheme``'s kind).

        Known before the run (``liefi run`` refuses a run of too many steps with it); kept on the
        scene for the same arguments, so that the run that follows does not repeat the pilot.
        ``backend``: the run's (its check runs on it, as :meth:`liefi.FeedbackIntegrator.run`'s does).
        """
        from ..integrator.run import _fixed_step_scheme
        from ..integrator.tolerance import DEFAULT_RTOL, choose_step, default_backend

        v = self.variant(variant) if not isinstance(variant, Variant) else variant
        rtol = DEFAULT_RTOL if rtol is None else rtol
        backend = default_backend() if backend is None else backend
        other = () if backend == default_backend() else (backend,)  # the default's stored steps keep their key
        changed = self._changed_data()
        other += () if changed is None else (changed,)  # the system's constants changed since its build
        key = (v.name, str(scheme), repr(gains), configuration, float(t_final), repr(rtol), repr(atol),
               bool(choose_order)) + other
        cache = self.__dict__.setdefault("_stepcache", {})
        if key not in cache:
            import json

            from . import store

            def pilot():
                fi = self.integrator(v, gains=gains, configuration=configuration)
                dt, info = choose_step(fi, _fixed_step_scheme(scheme), fi.y0, 0.0, float(t_final), rtol, atol,
                                       choose_order=choose_order, backend=backend)
                return {"dt": np.array(dt), "info": np.array(json.dumps(info, default=_json_number))}

            # the pilot is deterministic: kept in the store like a reference, by everything it depends on
            got = store.remember(self, v, ("step", str(scheme), gains, configuration, float(t_final),
                                           np.asarray(rtol, float), None if atol is None else np.asarray(atol, float),
                                           bool(choose_order)) + other,
                                 pilot)
            cache[key] = float(got["dt"]), json.loads(str(got["info"]))
        return cache[key]

    def _check_start(self, fi, v, rtol=1e-9):
        """The reference solution is the *constrained* motion: the start must be on ``J = 0``."""
        if not self.system.K:
            return
        from ..integrator.stability import drift_scales

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

    def _errors(self, v, t, data):
        """``result -> errors`` against the reference, for :attr:`RunResult.errors` (called on first use)."""

        def compute(result):
            start, ref_before = time.process_time(), getattr(self, "reference_seconds", 0.0)
            ref = self.reference_values(t, v)
            errors = {k: data[k] - ref[k] for k in self.error_variables if k in data and k in ref}
            result.overhead_seconds += time.process_time() - start
            result.reference_seconds += getattr(self, "reference_seconds", 0.0) - ref_before
            return errors

        return compute

    def _result(self, v, scheme, dt, T, fi, t, Y, names, cpu, steps, nfev, clock=None):
        data = {n: Y[i] for i, n in enumerate(names)}
        data.update(self.observables(Y, names))
        # invariants along the run (the integrator's state layout)
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
        monitored = [inv for inv in self.monitored(v) if inv.name not in invariants]
        if monitored and all(n in data for n in self.system.state_names):
            z = np.stack([np.asarray(data[n], float) for n in self.system.state_names], -1)
            for inv in monitored:
                invariants[inv.name] = np.asarray(inv.fun(z), float)
        max_drift = {}
        for k, val in invariants.items():
            base = 0.0 if k.startswith("J_") or k == "orthogonality" else val[0]
            max_drift[k] = float(np.max(np.abs(val - base)))
        overhead = ref_seconds = 0.0
        if clock is not None:
            overhead = max(0.0, time.process_time() - clock[0] - float(cpu))
            ref_seconds = getattr(self, "reference_seconds", 0.0) - clock[1]
        return RunResult(
            self.name, v.name, scheme, dt, T, int(steps), float(cpu), int(nfev), self.reference,
            dict(fi.gains), t, Y, tuple(names), invariants, max_drift,
            overhead_seconds=overhead, reference_seconds=ref_seconds, _reference=self._errors(v, t, data),
        )
