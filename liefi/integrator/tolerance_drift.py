r"""The drift rule of a step chosen for a tolerance: the invariants kept at rounding.

Part of step 5 of :mod:`liefi.integrator.tolerance`: the split step leaves ``K e^2`` of the tableau's per-step
defect ``e`` of the invariants; a run whose drift (:func:`liefi.integrator.drift.drift`) is above :data:`DRIFT_LEVEL`
and more than :data:`DRIFT_FLOOR_RATIO` times the drift of a shorter run is the step's, and the step is cut
to where ``K e^2 ~ dt^{2(p+1)}`` reaches :data:`DRIFT_AIM` of the level (:func:`_drift_cap`).
Re-exported by :mod:`liefi.integrator.tolerance`.
"""

from __future__ import annotations

import math

import numpy as np

from .._members import MembersError

#: The invariants' relative drift (:func:`liefi.integrator.drift.drift`, against their scales at the start) that counts as
#: rounding: ``1e4 u`` (``2.2e-12``), ten times the highest floor of evaluating the invariants in floating point
#: that no step lowers (the non-reversible knife edge: ``1.5e-13 = 700 u`` whatever the step).  Below it the
#: drift need not follow the step: the roller racer's stays at ``1.2e-12`` from ``dt = 0.92`` to ``1.01``.
DRIFT_LEVEL = 1e4 * np.finfo(float).eps
#: A run's drift above :data:`DRIFT_LEVEL` is the step's when it is more than this many times the drift of the
#: run at a shorter step it was compared with (the Gauss--Newton residual falls like ``dt^{2(p+1)}``; a floor
#: that a shorter step does not lower is the evaluation's rounding, not the step's).
DRIFT_FLOOR_RATIO = 4.0
#: The step a drift above the level is cut to aims at this fraction of :data:`DRIFT_LEVEL`: the measured drift
#: falls a little slower than ``dt^{2(p+1)}`` (Kepler at order 8: ``dt^{16.8}``, not ``dt^{18}``).
DRIFT_AIM = 0.25


#: The drift of a run is evaluated at most at this many of its saved states (evenly spread, the first and the last
#: among them): the values of the invariants in numpy cost 10--100 us a state, and a check's runs save up to
#: millions (the rattleback's step choice spent a third of its time there).
DRIFT_SAMPLES = 512


def _run_drift(fi, ys, scales=None):
    """The largest relative drift of the invariants over a run's saved states ``ys`` (:func:`liefi.integrator.drift.drift`,
    scales at the start; at :data:`DRIFT_SAMPLES` of them at most); ``0`` where it cannot be evaluated (no
    invariant: nothing to keep).  ``scales``: :func:`liefi.integrator.drift.drift_scales` at ``ys[0]`` when the
    caller has them (every run of a step choice starts from the same state: they are evaluated once)."""
    from .drift import drift, drift_scales

    if len(ys) > DRIFT_SAMPLES:
        ys = np.asarray(ys)[np.unique(np.linspace(0, len(ys) - 1, DRIFT_SAMPLES).astype(int))]
    try:
        with np.errstate(all="ignore"):
            d = drift(fi, np.asarray(ys, float), drift_scales(fi, ys[0]) if scales is None else scales)[0]
    except MembersError:
        raise
    except (ArithmeticError, np.linalg.LinAlgError, ValueError, TypeError, KeyError, IndexError):
        return 0.0
    return float(d) if math.isfinite(d) else math.inf


def _drift_pair(fi, coarse, fine, scales=None):
    """``(drift, floor)``: the drift of the run ``coarse`` (:func:`_run_drift`) and, only where it is above
    :data:`DRIFT_LEVEL`, of the run at a shorter step ``fine`` (else ``0.0``: :func:`_drift_cap` is ``inf``
    whatever the floor, so the values of the invariants at ``fine``'s states are not needed)."""
    d = _run_drift(fi, coarse, scales)
    return d, (_run_drift(fi, fine, scales) if d > DRIFT_LEVEL else 0.0)


def _drift_cap(dt, drift, floor, p):
    r"""The longest step whose run keeps the invariants at rounding, from the drift ``drift`` measured at ``dt``.

    One Gauss--Newton step onto the invariant set leaves ``K e^2`` of the tableau's per-step defect
    ``e = c dt^{p+1}`` (measured: ``K`` 0.2 to 1.1 on the Chaplygin sleighs, Suslov, the oscillator, the roller
    racer), so the drift scales like ``dt^{2(p+1)}`` and the cap is ``dt (a L / drift)^{1 / (2(p+1))}``, ``L`` =
    :data:`DRIFT_LEVEL`, ``a`` = :data:`DRIFT_AIM`.  ``inf`` when the drift is at rounding: below ``L``, or within
    :data:`DRIFT_FLOOR_RATIO` of ``floor``, the drift of a run at a shorter step (rounding that no step lowers).
    """
    if not drift > max(DRIFT_LEVEL, DRIFT_FLOOR_RATIO * floor):
        return math.inf
    if not math.isfinite(drift):
        return 0.0
    return dt * (DRIFT_AIM * DRIFT_LEVEL / drift) ** (1.0 / (2.0 * (p + 1)))
