r"""The runs that measure a step chosen for a tolerance, on the compiled loop without a run's set-up.

The measured check of :mod:`liefi.integrator.tolerance_check` runs the scheme at several steps from one
start.  Through :meth:`liefi.FeedbackIntegrator.run` each of those runs pays the set-up of a user's run --
the gains chosen for its step, the invariants the scheme keeps exactly, the stability guard, the audit --
which on a short horizon costs far more than the steps (Suslov: 6 ms a run for 64 steps of microseconds;
the Chaplygin ball 20 ms).  :class:`CheckRuns` pays it once: the invariants left out and the gains are
those of the run at the first step asked, and at another step ``h`` the gains are the same rates,

.. math:: k(h) = k(h_1)\, h_1 / h

(``gains="auto"`` chooses a rate ``z = h k``, :func:`liefi.integrator.gains.rate_gains`, the same at every step
of a split scheme, whose feedback substep is stable at every rate); then each run is one call of the
compiled loop (:meth:`liefi.engine.CompiledField.run`).  Only for a split scheme, one trajectory and a
compiled backend; otherwise (and when the kernel cannot run) each run is :meth:`~liefi.FeedbackIntegrator.run`
as before.  A run made is kept (:data:`DENSE_BYTES`): an untrusted check's next try, at half the coarse
step, runs only its finest step anew.
"""

from __future__ import annotations

import warnings

import numpy as np

#: A run of the check keeps every step's state while they take at most this many bytes (a later try reuses it).
DENSE_BYTES = 2**26


class CheckRuns:
    """``runs(t0, tau, h, save_every) -> ys``: the states (``(n_saved, ..., n)``) of the scheme ``sch`` from
    ``y0`` at the step ``h`` over ``[t0, t0 + tau]``, every ``save_every`` steps (module docstring).

    Raises what a run raises (:class:`~liefi.schemes.IntegrationError`, ``ArithmeticError``, ...).
    """

    def __init__(self, fi, sch, y0, backend):
        self.fi, self.sch, self.y0, self.backend = fi, sch, np.asarray(y0, float), backend
        self._fast = backend != "numpy" and getattr(sch, "kind", None) == "split" and self.y0.ndim == 1
        self._set = None  # (run_fi, kernel, h1, gains at h1) once the first fast run is set up
        self._done = {}  # (t0, tau, h) -> (save_every, states): the runs made, for the check's next try
        self._scales = False  # the invariants' scales at the start, once (drift_scales)

    def drift_scales(self):
        """:func:`liefi.integrator.drift.drift_scales` at the start of every run, evaluated once (``None`` where
        they cannot be: each drift then evaluates, and fails, on its own)."""
        if self._scales is False:
            from .drift import drift_scales

            try:
                with np.errstate(all="ignore"):
                    self._scales = drift_scales(self.fi, self.y0)
            except Exception:  # noqa: BLE001 -- as _run_drift's: its own evaluation says what fails
                self._scales = None
        return self._scales

    def _setup(self, h, tau):
        from ..engine.kernels import prepare_feedback
        from .gains import exact_drops, exactly_kept, run_gains

        fi = self.fi.for_batch(())
        # the invariants the scheme keeps exactly, evaluated once: for the drops and for the gains (those of
        # the integrator without the drops are the others; kept(fi without d) = kept(fi) minus d)
        kept = exactly_kept(fi, self.sch, self.y0) if fi.invariant_names else ()
        drops = exact_drops(fi, self.sch, self.y0, kept=kept)
        if drops:
            fi = fi.without(drops)
        got = run_gains(fi, self.y0, h, self.sch, tau, kept=tuple(k for k in kept if k not in drops))
        if got.adaptive:  # gains re-chosen along the run: only the run loop does that
            return None
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            cf = prepare_feedback(got.fi, self.sch, self.y0, self.backend)
        if cf is None:
            return None
        return got.fi, cf, h, {k: np.asarray(v, float) for k, v in got.fi.gains.items()}

    def __call__(self, t0, tau, h, save_every):
        if self._fast and self._set is None:
            self._set = self._setup(h, tau) or False
        if self._fast and self._set:
            run_fi, cf, h1, g1 = self._set
            n = int(round(tau / h))
            key = (float(t0), float(tau), float(h))
            got = self._done.get(key)
            if got is not None and save_every % got[0] == 0:  # run before, saved as densely or more
                return got[1][:: save_every // got[0]]
            # saved at every step while the states take at most DENSE_BYTES: a later try of the check at half
            # the coarse step compares it at its own saved steps without running it again
            every = 1 if (n + 1) * self.y0.size * 8 <= DENSE_BYTES else save_every
            p = run_fi.parameters({k: v * (h1 / h) for k, v in g1.items()})
            with np.errstate(all="ignore"):
                sol = cf.run(self.y0, p, h, n, self.sch, save_every=every, names=run_fi.names)
            ys = np.moveaxis(np.asarray(sol.y), -1, 0)
            self._done[key] = (every, ys)
            return ys[:: save_every // every]
        kw = dict(scheme=self.sch, progress=False, check_stability=False, backend=self.backend, drop_exact=True)
        return np.moveaxis(np.asarray(self.fi.run((t0, t0 + tau), dt=h, save_every=save_every, y0=self.y0,
                                                  **kw).y), -1, 0)
