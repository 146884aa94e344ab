"""Running compiled kernels: :class:`CompiledField` (fields and fixed-step loops) and :class:`CompiledDLA`.

A kernel's functions compile (or load from numba's on-disk cache) on their
first call; that call goes through :meth:`CompiledField._first_call`, which
times it and heals a cache entry that fails to load (:func:`liefi.engine.cache.heal`)
by compiling afresh once.  Ctrl-C (``SIGINT``) during that call is held until
the compile returns and then raised (:func:`interrupts_held`): numba's
compiler calls back into Python from LLVM, and a ``KeyboardInterrupt`` raised
in such a callback is printed ("Exception ignored ...") and dropped -- the run
then went on and exited 0 -- or leaves LLVM's state half-built.  A second
Ctrl-C raises at once.  The time paid to trace, load and compile is kept
apart from the run's ``cpu_seconds``: each :class:`~liefi.schemes.Solution`
carries ``overhead_seconds``, the part of it not reported by an earlier run.
"""

from __future__ import annotations

import signal
import threading
import time
from contextlib import contextmanager
from dataclasses import dataclass, field

import numpy as np

from .._progress import compiling
from . import cache as _cache
from .codegen import split_loop_name


class KernelLoadError(RuntimeError):
    """A generated kernel failed to compile or load even after its cache entry was rebuilt."""


@contextmanager
def interrupts_held():
    """Hold ``SIGINT`` (Ctrl-C), and ``SIGTERM`` where liefi raises it, inside the block; raise when it ends.

    Yields a list that holds the signals received.  The first signal is
    recorded, not raised where it lands (it could land in a callback from
    compiled code, where Python drops it); a second one raises at once.  Either
    way an interrupt leaves the block (:class:`liefi._signals.Terminated` for
    ``SIGTERM``) -- also when the block raised something else meanwhile.  A held
    signal also sets a deadline (:func:`liefi._signals.end_within_grace`, in the
    ``liefi`` process only): a compile that goes on for longer than
    :data:`liefi._signals.GRACE` seconds is not waited for, the process ends with
    the one line and ``128 + signum``.  Only
    in the main thread and with Python's own ``SIGINT`` handler installed;
    elsewhere the block runs unchanged.
    """
    from .. import _signals

    if threading.current_thread() is not threading.main_thread() \
            or signal.getsignal(signal.SIGINT) is not signal.default_int_handler:
        yield []
        return
    term = [s for s in _signals.TERMINATING if getattr(signal.getsignal(s), "liefi", False)]
    got = []

    def interrupt():
        s = got[0] if got else signal.SIGINT
        return _signals.Terminated(s) if s != signal.SIGINT else KeyboardInterrupt()

    def hold(signum, frame):
        got.append(signum)
        if len(got) > 1:
            raise interrupt()
        if signum != signal.SIGINT:
            _signals._received.append(signum)  # as if raised: a second SIGTERM in the clean-up is ignored
        _signals.end_within_grace(signum)

    def restore():
        signal.signal(signal.SIGINT, signal.default_int_handler)
        for s, h in previous_term.items():
            signal.signal(s, h)

    signal.signal(signal.SIGINT, hold)
    previous_term = {s: signal.signal(s, hold) for s in term}
    try:
        yield got
    except BaseException as exc:
        restore()
        if got and not isinstance(exc, KeyboardInterrupt):
            _signals.cancel_deadline()
            raise interrupt() from exc
        raise
    restore()
    if got:
        _signals.cancel_deadline()
        raise interrupt()


class _Overhead:
    """Bookkeeping of the one-off costs (trace, load, first-call compile) of a kernel."""

    def _first_call(self, key, fname, *args):
        """Call ``module.fname(*args)`` for the first time: compile (or load), timed; heal once on failure.

        Ctrl-C meanwhile raises ``KeyboardInterrupt`` when the compile returns (:func:`interrupts_held`).
        """
        if key in self.compile_seconds:
            return getattr(self.module, fname)(*args)
        with interrupts_held() as interrupted:
            return self._compile_call(key, fname, interrupted, *args)

    def _compile_call(self, key, fname, interrupted, *args):
        with compiling():  # a notice on stderr when it lasts (liefi._progress.compile_notice)
            return self._compile_call_timed(key, fname, interrupted, *args)

    def _compile_call_timed(self, key, fname, interrupted, *args):
        t = time.perf_counter()
        try:
            r = getattr(self.module, fname)(*args)
        except Exception as exc:  # noqa: BLE001 -- a kernel that does not load: rebuild it once
            if self.kernel.engine != "numba" or interrupted:
                raise
            try:
                _cache.heal(self.kernel)
                self.compile_seconds.clear()  # the module is new: its functions compile again
                r = getattr(self.module, fname)(*args)
            except Exception as again:  # noqa: BLE001
                raise KernelLoadError(
                    f"the generated kernel {self.kernel.name} failed to load ({type(exc).__name__}: {exc}) "
                    f"and again after its cache entry was rebuilt ({type(again).__name__}: {again})"
                ) from again
        self.compile_seconds[key] = time.perf_counter() - t
        return r

    @property
    def module(self):
        """The generated module (see :class:`liefi.engine.cache.Kernel`)."""
        return self.kernel.module

    @property
    def load_seconds(self):
        """Time spent writing/executing the generated module in this process (0 if another field loaded it)."""
        return self.kernel.load_seconds if self._owns_load else 0.0

    @property
    def overhead_seconds(self):
        """Everything paid once per process for this kernel so far: trace + load + first-call compiles."""
        return self.build_seconds + self.load_seconds + sum(self.compile_seconds.values())

    def take_overhead(self):
        """The part of :attr:`overhead_seconds` not yet reported by a run (and mark it reported)."""
        total = self.overhead_seconds
        new = max(0.0, total - self._reported)
        self._reported = total
        return new


def _loop_scheme(scheme):
    """The scheme object of a compiled loop: an explicit tableau or a split scheme (by name or object)."""
    from ..schemes import registry

    if isinstance(scheme, str):
        return registry.get(scheme, kind=("explicit", "split"))
    return getattr(scheme, "scheme", scheme)  # a split scheme bound to an integrator


def loop_name(sch):
    """The generated loop of a scheme: ``run_rk4``; a split scheme's ``run_imex_rk4`` (:mod:`.codegen`)."""
    if getattr(sch, "kind", None) == "split":
        return split_loop_name(sch)
    return f"run_{sch.name}"


@dataclass
class CompiledField(_Overhead):
    """A generated, compiled right-hand side ``rhs(y, p, out)`` and its fixed-step loops.

    :attr:`load_seconds` and :attr:`overhead_seconds` (build + load + compiles)
    are the one-off costs; :meth:`run` reports the unreported part of them as
    ``solution.overhead_seconds``.

    Attributes
    ----------
    kernel : liefi.engine.cache.Kernel
        The loaded generated module, ``kernel.module`` (also :attr:`module`):
        ``rhs``, ``run_<scheme>``, ``run_<scheme>_batch``, and with a projection
        ``resid``, ``project``, ``run_<scheme>_proj``.
    N : int
        State size.
    n_params : int
        Size of the parameter vector ``p`` (:attr:`liefi.FeedbackIntegrator.parameter_layout`).
    kind : str
        ``"feedback"``, ``"extended"`` (no feedback), ``"constrained"``.
    engine : str
        ``"numba"`` or ``"python"``.
    build_seconds : float
        Time spent tracing and generating the source.
    compile_seconds : dict
        Compile (first call, or numba cache load) time of each function used so far.
    projection : int
        Number of invariant residuals of the projection (0: none).
    nodes : int
        Size of the traced graph (a measure of the generated code).
    traced : bool
        False when the kernel was found by the fingerprint of the system's data, without a
        trace (:func:`liefi.engine.kernels.kernel_fingerprint`); :attr:`build_seconds` is then
        the time of that look-up.
    """

    kernel: object
    N: int
    n_params: int
    kind: str
    engine: str
    build_seconds: float
    compile_seconds: dict = field(default_factory=dict)
    projection: int = 0
    nodes: int = 0
    _owns_load: bool = True
    _reported: float = 0.0
    traced: bool = True

    def rhs(self, y, p):
        """The field at one state ``y`` (shape ``(N,)``) with parameters ``p``."""
        out = np.empty(self.N)
        self._first_call("rhs", "rhs", np.ascontiguousarray(y, dtype=float), np.ascontiguousarray(p, dtype=float), out)
        return out

    def fun(self, p):
        """``fun(t, y)`` for ``scipy.integrate.solve_ivp`` with the parameters ``p`` fixed."""
        p = np.ascontiguousarray(p, dtype=float)
        N = self.N
        self.rhs(np.zeros(N), p)  # compile outside the solver's timing
        f = self.module.rhs

        def fun(t, y):
            out = np.empty(N)
            f(np.ascontiguousarray(y, dtype=float), p, out)
            return out

        return fun

    def warmup(self, scheme="euler", *, batch=False, project=False):
        """Compile the loop of ``scheme`` now (the first call of a numba function compiles it)."""
        sch = _loop_scheme(scheme)
        fname = loop_name(sch) + ("_proj" if project else "")
        key = fname + ("_batch" if batch else "")
        if key in self.compile_seconds:
            return self.compile_seconds[key]
        N, npar = self.N, self.n_params
        pp = np.zeros(max(1, self.projection + 1))
        if batch:
            self._first_call(key, key,
                np.zeros((1, N)), np.zeros((1, npar)), 1.0, 0, 1, 1, np.zeros((1, N, 1)), np.zeros((1, N)),
                np.zeros((1, N)), np.zeros((1, pp.size)), 0, 0.0, np.zeros((1, 3), np.int64),
            )
        else:
            self._first_call(key, key, np.zeros(N), np.zeros(npar), 1.0, 0, 1, 1, np.zeros((N, 1)), np.zeros(N),
                             np.zeros(N), pp, 0, 0.0)
        return self.compile_seconds[key]

    def run(self, y0, p, dt, n_steps, scheme="euler", *, save_every=1, check_every=1, t0=0.0, names=(),
            project=None, maxit=3, tol=1e-14):
        """Step from ``y0`` (shape ``(N,)`` or ``(..., N)``: an ensemble) with a fixed-step scheme.

        Parameters as :func:`liefi.schemes.integrate`; ``p`` is ``(n_params,)`` or per
        trajectory ``(..., n_params)``.  ``project`` (parameters of the residuals,
        e.g. :func:`liefi.engine.projection_targets`) projects onto the invariant set after every
        step by Newton's method (at most ``maxit`` iterations, stop at ``max |r| <= tol``;
        ``tol < 0``: exactly ``maxit`` iterations and no check).

        Returns
        -------
        Solution
            As :func:`liefi.schemes.integrate`, with extra attributes
            ``wall_seconds`` (elapsed time of the loop; ``cpu_seconds`` is process
            time of the loop alone, summed over threads), ``compile_seconds``
            (first-call compile of the loop, 0 if it was compiled before),
            ``overhead_seconds`` (the one-off trace + load + compile time of this
            kernel not reported by an earlier run: paid once per process),
            ``backend`` and, with a projection, ``projection_evaluations``.
        """
        from ..schemes import Solution, _fail
        from ..schemes.core import _step_arguments

        sch = _loop_scheme(scheme)  # a run loop's object as it is; a name looked up here, once
        dt, n_steps, save_every = _step_arguments(dt, n_steps, save_every)
        check_every = max(1, int(check_every))
        if project is not None and not self.projection:
            raise ValueError("project: this compiled field has no invariant residuals (compile it with projection=True)")
        y0 = np.array(y0, dtype=float)
        if y0.shape[-1:] != (self.N,):
            raise ValueError(f"y0: expected shape (..., {self.N}), got {y0.shape}")
        if not np.all(np.isfinite(y0)):
            raise ValueError("y0: the initial state contains non-finite numbers")
        idx = np.arange(0, n_steps + 1, save_every)
        if idx[-1] != n_steps:
            idx = np.append(idx, n_steps)
        ns = idx.size
        batch = y0.shape[:-1]
        p = np.asarray(p, dtype=float)
        pp = np.atleast_1d(np.asarray(project if project is not None else [0.0], dtype=float))
        fname = loop_name(sch) + ("_proj" if project is not None else "")
        compile_s = 0.0
        if batch == ():
            if p.ndim != 1:
                raise ValueError(f"p: expected shape ({self.n_params},) for one trajectory, got {p.shape}")
            key = fname
            if key not in self.compile_seconds:
                compile_s = self.warmup(sch, project=project is not None)
            out = np.empty((self.N, ns))
            bad, last = np.empty(self.N), np.empty(self.N)
            c0, w0 = time.process_time(), time.perf_counter()
            failed, last_step, nproj = getattr(self.module, fname)(
                y0, np.ascontiguousarray(p), dt, n_steps, save_every, check_every, out, bad, last, pp, int(maxit), float(tol)
            )
            cpu, wall = time.process_time() - c0, time.perf_counter() - w0
        else:
            B = int(np.prod(batch))
            Y0 = np.ascontiguousarray(y0.reshape(B, self.N))
            P = np.ascontiguousarray(np.broadcast_to(p, batch + (self.n_params,)).reshape(B, self.n_params))
            PP = np.ascontiguousarray(np.broadcast_to(pp, batch + pp.shape[-1:]).reshape(B, -1))
            key = fname + "_batch"
            if key not in self.compile_seconds:
                compile_s = self.warmup(sch, batch=True, project=project is not None)
            OUT = np.empty((B, self.N, ns))
            BAD, LAST = np.empty((B, self.N)), np.empty((B, self.N))
            STATUS = np.zeros((B, 3), np.int64)
            c0, w0 = time.process_time(), time.perf_counter()
            getattr(self.module, key)(Y0, P, dt, n_steps, save_every, check_every, OUT, BAD, LAST, PP, int(maxit), float(tol), STATUS)
            cpu, wall = time.process_time() - c0, time.perf_counter() - w0
            failing = np.nonzero(STATUS[:, 0])[0]
            nproj = int(STATUS[:, 2].sum())
            if failing.size:
                first = failing[np.argmin(STATUS[failing, 0])]
                failed, last_step = int(STATUS[first, 0]), int(STATUS[first, 1])
                bad = BAD[first]
                last = LAST.reshape(batch + (self.N,))
            else:
                failed, last_step = 0, n_steps
            out = OUT.reshape(batch + (self.N, ns))
        if failed:
            _fail(bad, last, last_step, failed, t0, dt, sch, tuple(names), None)
        t = t0 + dt * idx.astype(float)
        sol = Solution(t, out, sch.name, dt, n_steps, n_steps * sch.stages, cpu, tuple(names))
        sol.wall_seconds = wall
        sol.compile_seconds = compile_s
        sol.overhead_seconds = self.take_overhead()
        sol.backend = self.engine
        if project is not None:
            sol.projection_evaluations = int(nproj)
        return sol


@dataclass
class CompiledDLA(_Overhead):
    """The DLA scheme compiled for a system on ``T*R^n`` with a constant metric (:func:`liefi.engine.compile_dla`)."""

    kernel: object
    n: int
    mass: np.ndarray
    engine: str
    build_seconds: float
    compile_seconds: dict = field(default_factory=dict)
    _owns_load: bool = True
    _reported: float = 0.0

    def run(self, q0, q1, h, n_steps, *, save_every=1, t0=0.0):
        """``(t, q, p, cpu_seconds, updates)`` with ``q, p`` of shape ``(n, n_saved)`` and
        ``p_k = M (q_k - q_{k-1}) / h`` (``p_0 = M (q_1 - q_0)/h``), as :meth:`liefi.schemes.dla_integrator.DLAIntegrator.run`."""
        from ..schemes.dla_integrator import DLANonFiniteError

        n_steps, save_every = int(n_steps), max(1, int(save_every))
        idx = list(range(0, n_steps + 1, save_every))
        if idx[-1] != n_steps:
            idx.append(n_steps)
        ns = len(idx)
        p = np.array([float(h)])
        self._first_call("dla_run", "dla_run", np.zeros(self.n), np.zeros(self.n), p, 0, 1, np.zeros((self.n, 2)),
                         np.zeros(self.n))
        out = np.empty((self.n, 2 * ns))
        bad = np.empty(self.n)
        c0 = time.process_time()
        failed = self.module.dla_run(np.array(q0, float), np.array(q1, float), p, n_steps, save_every, out, bad)
        cpu = time.process_time() - c0
        if failed:
            raise DLANonFiniteError("q", int(failed), t0 + (failed + 1) * h)
        q, qprev = out[:, :ns], out[:, ns:]
        mom = (self.mass @ (q - qprev)) / h
        mom[:, 0] = self.mass @ (np.asarray(q1, float) - np.asarray(q0, float)) / h
        return t0 + h * np.array(idx, float), q, mom, cpu, max(n_steps - 1, 0)


_KERNELS: dict = {}
