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
as before.
"""

from __future__ import annotations

import warnings

import numpy as np


class CheckRuns:
    """``runs(t0, tau, h, save_every) -> ys``: the states (``(n_saved, ..., n)``) of the scheme ``sch`` from
    ``y0`` at the step ``h`` over ``[t0, t0 + tau]``, every ``save_every`` steps (module docstring).

    Raises what a run raises (:class:`~liefi.schemes.IntegrationError`, ``ArithmeticError``, ...).
    """

    def __init__(self, fi, sch, y0, backend):
        self.fi, self.sch, self.y0, self.backend = fi, sch, np.asarray(y0, float), backend
        self._fast = backend != "numpy" and getattr(sch, "kind", None) == "split" and self.y0.ndim == 1
        self._set = None  # (run_fi, kernel, h1, gains at h1) once the first fast run is set up

    def _setup(self, h, tau):
        from ..engine.kernels import prepare_feedback
        from .gains import exact_drops, run_gains

        fi = self.fi.for_batch(())
        drops = exact_drops(fi, self.sch, self.y0)
        if drops:
            fi = fi.without(drops)
        got = run_gains(fi, self.y0, h, self.sch, tau)
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
            p = run_fi.parameters({k: v * (h1 / h) for k, v in g1.items()})
            with np.errstate(all="ignore"):
                sol = cf.run(self.y0, p, h, n, self.sch, save_every=save_every, names=run_fi.names)
            return np.moveaxis(np.asarray(sol.y), -1, 0)
        kw = dict(scheme=self.sch, progress=False, check_stability=False, backend=self.backend, drop_exact=True)
        return np.moveaxis(np.asarray(self.fi.run((t0, t0 + tau), dt=h, save_every=save_every, y0=self.y0,
                                                  **kw).y), -1, 0)
