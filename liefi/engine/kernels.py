"""The compiled kernels of liefi: the library's own functions, traced and generated.

Each kernel is the trace of one library function on symbolic arrays, nothing
more:

* :func:`compile_feedback` -- :meth:`liefi.FeedbackIntegrator.vector_field`
  (``X - A grad V``, or :meth:`~liefi.FeedbackIntegrator.unforced_vector_field`)
  with the gains and targets as the run-time parameter vector ``p``
  (:meth:`~liefi.FeedbackIntegrator.parameters`), so one kernel serves every gain;
* :func:`compile_constrained` -- :func:`liefi.reduction.core.full_vector_field`
  (or :func:`~liefi.reduction.core.field_terms`) with ``kind="constrained"``,
  plus the residuals of the invariant set for a projection after every step;
* :func:`compile_dla` -- :meth:`liefi.schemes.dla_integrator.DLAIntegrator.update`.

A user datum, invariant or group method that cannot be traced raises
:class:`~liefi.engine.trace.NotCompilable` naming it; :func:`run_feedback`
(the hook of ``FeedbackIntegrator.run(backend=...)``) then runs the numpy path
after a :class:`~liefi.engine.trace.CompilationWarning`, as it does for any
failure to build, load or compile a kernel.
"""

from __future__ import annotations

import time
import warnings
import weakref

import numpy as np

from .._progress import compiling
from . import cache as _cache
from .codegen import NJIT, dla_loop_source, function_source, loops_source, project_source, scalar_function_source
from .split_loops import split_loops_source
from .runners import CompiledDLA, CompiledField
from .trace import TRACED_DATA, CompilationWarning, NotCompilable, as_sym, jacobian, trace, traced_call

_KERNELS: dict = {}


def _engine(engine):
    if engine is None:
        return "numba" if _cache.available() else "python"
    return engine


def _fi_key(fi, kind):
    return (
        kind, fi.nc, fi.configuration, fi.field, fi.energy, fi.use_constraints, getattr(fi, "_J_kept", None),
        fi.use_energy,
        tuple((u.name, id(u.fun), id(u.grad)) for u in fi.user), fi.use_penalty,
        None if fi.A is None else fi.A.tobytes(),
    )


def _cached(system, key, engine, build):
    """The kernel of ``(system, key, engine)``: from this process's table, or ``build()`` and keep it
    (weakly per system; the generated module itself is shared by the hash of its text).  A system whose
    data can change in place (the constants of :class:`liefi.systems.mechanics.MechanicsSystem`) names its current
    data by ``data_key``, which is part of the key."""
    full = (id(system), getattr(system, "data_key", None)) + key + (engine,)
    with _cache._LOCK:
        got = _KERNELS.get(full)
        if got is not None and got[0]() is system:
            return got[1]
    made = build()
    with _cache._LOCK:
        _KERNELS[full] = (weakref.ref(system), made)
    return made


def kernel_fingerprint(fi, kind, engine):
    """The fingerprint naming the kernel ``kind`` of ``fi`` without a trace, or ``None`` (the safe path: trace).

    SHA-256 (:func:`liefi._fingerprint.digest`) of liefi's sources, numba's and numpy's
    versions, the system's stamp (given by the builders that make a system from pure data:
    :func:`liefi.from_sympy`, :func:`liefi.from_mechanics`, :func:`liefi.systems.rolling.rolling_body`
    with liefi's contact functions), its constants (``data_key``) and every setting of ``fi``
    the trace reads (those of the per-process key ``_fi_key``), the invariants by their
    fingerprints.  ``None`` for a system built from a user's callables, a user's invariant, or
    a stamped system whose attributes were replaced since.
    """
    from .. import _fingerprint as _fp

    if engine != "numba":
        return None
    system_fp = _fp.of_system(fi.system)
    if system_fp is None:
        return None
    # the system's own parts a function of liefi's may close over (the invariants f_j of its configuration
    # constraints): named, their data being in the system's stamp
    own = {"system": fi.system, "system.holonomic": getattr(fi.system, "holonomic", None)}
    users = []
    for u in fi.user:
        fun, grad = _fp.of(u.fun, own), None if u.grad is None else _fp.of(u.grad, own)
        if fun is None or (u.grad is not None and grad is None):
            return None
        users.append((u.name, fun, grad))
    nb = _cache.numba_module()
    return _fp.digest(
        "liefi kernel", kind, _fp.sources(), nb.__version__ if nb else "", np.__version__, system_fp,
        getattr(fi.system, "data_key", None), fi.n, fi.nc, fi.configuration, fi.field, fi.energy,
        fi.use_constraints, getattr(fi, "_J_kept", None), fi.use_energy, users, fi.use_penalty, fi.A,
        fi.parameter_layout.size,
    )


def _field_kernel(fi, key, engine, make):
    """The kernel found by its fingerprint (:func:`kernel_fingerprint`, no trace), else traced with
    ``make(tr) -> (source, n_params, kind, projection)`` and loaded (and its fingerprint recorded)."""
    engine = _engine(engine)

    def build():
        t = time.perf_counter()
        fingerprint = kernel_fingerprint(fi, key, engine)
        found = None if fingerprint is None else _cache.find(fingerprint, engine)
        if found is not None:
            kernel, meta = found
            return CompiledField(kernel, fi.n, meta["n_params"], meta["kind"], engine, time.perf_counter() - t, {},
                                 meta["projection"], meta["nodes"], _owns_load=kernel.claim(), traced=False)
        with compiling(), trace() as tr:
            source, n_params, kind, projection = make(tr)
            nodes = tr.size
        build_s = time.perf_counter() - t
        with compiling():
            kernel = _cache.load(source, engine)
        if fingerprint is not None:
            _cache.remember(fingerprint, kernel, {"n_params": n_params, "kind": kind, "projection": projection,
                                                  "nodes": nodes})
        return CompiledField(kernel, fi.n, n_params, kind, engine, build_s, {}, projection, nodes,
                             _owns_load=kernel.claim())

    return _cached(fi.system, _fi_key(fi, key), engine, build)


def compile_feedback(fi, *, feedback=True, engine=None):
    """The compiled field ``X - A grad V`` of a :class:`~liefi.FeedbackIntegrator` (or ``X`` alone).

    The trace of :meth:`~liefi.FeedbackIntegrator.vector_field` (or, with
    ``feedback=False``, of :meth:`~liefi.FeedbackIntegrator.unforced_vector_field`:
    no ``grad V`` computed at all) at a symbolic state and parameter vector.

    Parameters
    ----------
    fi : FeedbackIntegrator
    feedback : bool
    engine : {"numba", "python"}, optional
        Default numba when importable.

    Returns
    -------
    CompiledField
        Call ``run(y0, fi.parameters(), dt, n_steps, scheme)``.

    Raises
    ------
    NotCompilable
        Naming what cannot be traced.
    """

    def make(tr):
        y = tr.symbols("y", fi.n)
        size = fi.parameter_layout.size
        p = tr.symbols("p", size)
        if feedback:
            f = traced_call("the feedback field", fi.vector_field, y, p, data=TRACED_DATA)
        else:
            f = traced_call("the extended field", fi.unforced_vector_field, y, p, data=TRACED_DATA)
        src = (scalar_function_source("rhs_s", f, [("y", fi.n), ("p", size)], wrapper=("rhs", ("y", "p", "out")))
               + "\n\n" + loops_source(fi.n, n_params=size))
        return src, size, "feedback" if feedback else "extended", 0

    return _field_kernel(fi, "feedback" if feedback else "extended", engine, make)


def compile_split(fi, *, engine=None):
    """The compiled split schemes (``imex-*``, :mod:`liefi.schemes.split`) of a :class:`~liefi.FeedbackIntegrator`.

    The module holds ``xrhs``, the trace of
    :meth:`~liefi.FeedbackIntegrator.unforced_vector_field` (``X`` alone, no
    ``grad V``), ``fstep``, the trace of :func:`liefi.schemes.split.feedback_step`
    at a symbolic state, parameter vector and step, and one loop per split scheme:
    the tableau on ``xrhs``, then ``fstep`` once per step.  Run with
    ``run(y0, fi.parameters(), dt, n_steps, "imex-rk4")``.
    """
    from ..schemes.split import feedback_step

    def make(tr):
        y = tr.symbols("y", fi.n)
        size = fi.parameter_layout.size
        p = tr.symbols("p", size)
        h = tr.symbols("hh", 1)[0]
        x = traced_call("the extended field", fi.unforced_vector_field, y, p, data=TRACED_DATA)
        yn = traced_call("the feedback step", feedback_step, fi, y, h, p, data=TRACED_DATA)
        src = (scalar_function_source("xrhs_s", x, [("y", fi.n), ("p", size)], wrapper=("xrhs", ("y", "p", "out")))
               + "\n\n" + scalar_function_source("fstep_s", yn, [("y", fi.n), ("p", size), ("hh", 1)],
                                                  wrapper=("fstep", ("y", "p", "hh", "out")), inline=True)
               + "\n\n" + split_loops_source(fi.n, size))
        return src, size, "split", 0

    return _field_kernel(fi, "split", engine, make)


def _constrained_field(fi, y):
    from ..reduction import core

    if fi.configuration:
        return core.full_vector_field(fi.system, y, kind="constrained", data=TRACED_DATA)
    return core.field_terms(fi.system, y, kind="constrained", data=TRACED_DATA)[0]


# --- the invariant set, for a projection after every step (the ManifoldProjection peer) --------


def orthogonal_matrices(group, g):
    """The ``k x k`` blocks of the configuration ``g`` that must stay orthogonal, as the group declares
    them (:meth:`liefi.groups.LieGroup.orthogonal_matrices`, traced like every group method)."""
    return list(group.orthogonal_matrices(g))


def projection_targets(fi):
    """Parameters of the residuals of :func:`invariant_residuals`: ``[h0, user targets...]`` from ``fi.y0``."""
    vals = fi.invariant_values(fi.y0)
    return np.array(
        [float(np.asarray(vals["h"]).reshape(-1)[0])] + [float(np.asarray(t).reshape(-1)[0]) for t in fi.user_targets]
    )


def invariant_residuals(fi, y, targets, data):
    """Residuals ``r(y)`` whose zero set is the invariant set.

    ``r`` = the upper triangle of ``R^T R - I`` for every orthogonal block the
    group declares (:func:`orthogonal_matrices`), every ``J_i``, ``h - h0`` (the
    original energy: the peer integrates the original constrained equations) and
    every user invariant minus its target (``targets = [h0, user targets...]``).
    """
    from ..reduction import core

    g, z = fi.split(y)
    res = []
    if fi.configuration:
        for R in orthogonal_matrices(fi.system.space.group, g):
            k = R.shape[-1]
            S = np.swapaxes(R, -1, -2) @ R - np.eye(k)
            res += [S[..., i, j] for i in range(k) for j in range(i, k)]
    t = core.evaluate(fi.system, z, data=data)
    res += [t.J[..., i] for i in range(fi.system.K)]
    res.append(t.h - targets[..., 0])
    for j, u in enumerate(fi.user):
        res.append(u.value_and_grad(z, data)[0] - targets[..., 1 + j])
    return res


def compile_constrained(fi, *, projection=False, engine=None):
    """The original constrained field on ``fi``'s state layout, with the Newton projection.

    The state is ``fi``'s ``(g, z)`` (or ``z``); the field is the trace of
    :func:`~liefi.reduction.core.full_vector_field` with ``kind="constrained"``
    (multipliers ``lambda = C^{-1} {h, J}``, ``(lambda:general)``).  The module
    also holds ``resid`` (:func:`invariant_residuals` and their Jacobian) and
    ``project`` (Newton's method along ``G^T``, the Euclidean orthogonal
    projection used by DifferentialEquations.jl's ``ManifoldProjection``); run
    with ``project=projection_targets(fi)``.  They are generated when possible
    (numba compiles a function on its first call only, so one module serves
    ``solve_ivp`` and the projected schemes); ``projection=True`` raises
    :class:`NotCompilable` when they cannot be.
    """

    def make(tr):
        y = tr.symbols("y", fi.n)
        f = traced_call("the constrained field", _constrained_field, fi, y)
        src = NJIT + function_source("rhs", f)
        m = 0
        try:
            pp = tr.symbols("pp", 1 + len(fi.user))
            res = traced_call("the invariant residuals", invariant_residuals, fi, y, pp, TRACED_DATA)
            r = np.empty(len(res), dtype=object)
            r[:] = [as_sym(v.item() if isinstance(v, np.ndarray) else v) for v in res]
            G = jacobian(r, list(y)).T  # (m, N)
            m = r.size
            src += project_source(fi.n, m) + "\n" + NJIT + function_source(
                "resid", np.concatenate([r, G.reshape(-1)]), ("y", "pp", "out"))
        except NotCompilable:
            if projection:
                raise
        src += "\n\n" + loops_source(fi.n, projection=m > 0)
        return src, 0, "constrained", m

    cf = _field_kernel(fi, "constrained", engine, make)
    if projection and not cf.projection:
        raise NotCompilable("projection: the invariant residuals of this system could not be generated")
    return cf


def dla_applies(system):
    """Whether :mod:`liefi.schemes.dla_integrator` applies: a system on ``T*R^n`` (no group) with a constant metric
    and no vector potential."""
    return (
        system.space.d == 0 and system.metric.constant and system.space.n > 0
        and system.vector_potential is None
    )


def compile_dla(system, *, engine=None):
    """The DLA scheme of :mod:`liefi.schemes.dla_integrator` compiled for ``system``: the trace of
    :meth:`~liefi.schemes.dla_integrator.DLAIntegrator.update` of :meth:`~liefi.schemes.dla_integrator.DLAIntegrator.from_system`."""
    from ..schemes.dla_integrator import DLAIntegrator

    if not dla_applies(system):
        raise NotCompilable("dla: the DLA integrator applies to systems on T*R^n with a constant metric")
    engine = _engine(engine)
    n = system.space.n

    def build():
        try:
            dla = DLAIntegrator.from_system(system, data=TRACED_DATA)
        except ValueError as exc:
            raise NotCompilable(f"dla: {exc}") from exc
        t = time.perf_counter()
        with trace() as tr:
            qp, qc = tr.symbols("qp", n), tr.symbols("qc", n)
            h = tr.symbols("p", 1)[0]
            qn = traced_call("the DLA step", lambda: dla.update(qp, qc, h)[0])
            src = NJIT + function_source("dla_update", qn, ("qp", "qc", "p", "out"))
        src += dla_loop_source(n)
        build_s = time.perf_counter() - t
        kernel = _cache.load(src, engine)
        return CompiledDLA(kernel, n, np.array(dla.mass), engine, build_s, {}, _owns_load=kernel.claim())

    return _cached(system, ("dla",), engine, build)


def parameters(fi, gains=None):
    """``fi.parameters(gains)``: the run-time parameters (gains, targets) of :func:`compile_feedback`'s kernel."""
    return fi.parameters(gains)


# ======================================================================================
# the hook used by FeedbackIntegrator.run(backend=...)
# ======================================================================================

_WARNED: set = set()


def _say(msg, key):
    if key not in _WARNED:
        _WARNED.add(key)
        warnings.warn(msg, CompilationWarning, stacklevel=4)


def prepare_feedback(fi, scheme, y0, backend):
    """The :class:`CompiledField` of ``fi`` for ``scheme``, its loop compiled (or loaded); ``None`` to use numpy.

    The first half of :func:`run_feedback` (same warnings, once per system and
    reason): :func:`liefi.integrator.run.run_feedback` calls it before its progress starts,
    so that the bar counts steps, not the compile.  ``scheme`` is the scheme object the run
    loop resolved (an explicit tableau or a split scheme), never a name: it is not looked up here.
    """
    if backend not in ("numba", "auto"):
        raise ValueError(f"backend: expected 'numpy', 'numba' or 'auto', got {backend!r}")
    if _cache.numba_module() is None:
        _say(f"liefi: numba is not available ({_cache.NUMBA_ERROR}); running the numpy path. "
             "Install it with `pip install liefi[fast]`.", "nonumba")
        return None
    try:
        sch = scheme
        cf = compile_split(fi) if getattr(sch, "kind", None) == "split" else compile_feedback(fi)
        cf.warmup(sch, batch=np.ndim(fi.y0 if y0 is None else y0) > 1)
    except NotCompilable as exc:
        _say(f"liefi: the compiled engine cannot run this system ({exc}); running the numpy path.",
             ("nc", id(fi.system)))
        return None
    except Exception as exc:  # noqa: BLE001 -- cache, load or compile failure: the numpy path still works
        _say(f"liefi: the compiled kernel could not be built or loaded ({type(exc).__name__}: {exc}); "
             "running the numpy path.", ("load", id(fi.system), type(exc).__name__))
        return None
    return cf


def run_feedback(fi, dt, n_steps, scheme, y0, save_every, check_every, backend):
    """Run ``fi`` with the compiled engine; ``None`` (after a :class:`CompilationWarning`) to use numpy.

    ``backend``: ``"numba"`` (asked for explicitly) or ``"auto"``; in both cases a
    missing numba, an untraceable datum or group method, and any failure to build,
    load or compile the kernel give the warning (once per system and reason) and
    ``None``.  (A read-only, unsafe or full cache directory is not one: the kernel
    is then compiled in memory, :mod:`liefi.engine.cache`.)  Errors
    of the run itself (:class:`~liefi.schemes.IntegrationError`) propagate.
    ``scheme``: the run loop's scheme object, as :func:`prepare_feedback`'s.

    The returned :class:`~liefi.schemes.Solution` has ``cpu_seconds`` of the loop
    alone and ``overhead_seconds``: the one-off cost of tracing, loading and
    compiling the kernel, paid by the first run in the process that needs it.
    """
    y0 = fi.y0 if y0 is None else y0
    cf = prepare_feedback(fi, scheme, y0, backend)
    if cf is None:
        return None
    return cf.run(y0, fi.parameters(), dt, n_steps, scheme, save_every=save_every,
                  check_every=check_every, names=fi.names)
