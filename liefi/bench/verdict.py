r"""The verdict of a work-precision sweep: the cheapest run under each criterion, ties, and tolerance runs.

Reads the rows of :func:`liefi.bench.work_precision` (dicts, or a CSV read back by
:func:`liefi.bench.read_csv`); runs nothing.

Two criteria
------------
* **drift** (:data:`DRIFT`): every invariant's max drift over ``[0, t_final]``
  at most ``1e-8``, whatever the state error.  This is the criterion
  ``fi_over_best`` has always used.  It can be won by a run that is not
  accurate: a method that holds the invariants but not the motion (projected
  Euler at a large step, a first-order FI) qualifies with a state error of
  order one.
* **accurate** (:data:`ACCURATE_ERROR`, :data:`ACCURATE_DRIFT`): the max state
  error against the scene's exact or reference solution at most ``1e-6`` *and*
  every invariant's max drift at most ``1e-8``.  ``fi_over_best_accurate`` is
  the ratio for this criterion.

For each criterion, among the successful runs (``status = "ok"``) that meet it:
the cheapest run of any method (``cheapest_overall`` / ``cheapest_accurate``),
the cheapest feedback-integrator run (:data:`FI_METHODS`), and the cheapest run
of the other methods.  ``fi_over_best`` is CPU(cheapest FI) / CPU(cheapest of
all): 1 when an FI run is the cheapest, ``None`` with a reason when no FI run
or no run meets the criterion.

Ties
----
Each run is timed ``repeats`` times (:data:`liefi.bench.core.REPEATS`) and keeps
the least CPU time; ``cpu_spread = (second least - least) / least`` of its
repeats is the run's measured noise (:func:`liefi.bench.core.best_of`: the
second least, so that one repeat slowed by another process does not make
every comparison a tie).  The noise of a comparison is the larger of the two
runs' spreads and the median spread of the scene's runs (a floor: three
repeats that happen to agree say little).  The verdict compares the cheapest
FI run with the cheapest run of the other methods, ``r = CPU(FI) / CPU(other)``:
``"tie"`` when ``max(r, 1/r) - 1 <= noise``, else ``"win"`` (``r < 1``) or
``"loss"`` (``r > 1``); ``"win"`` when only an FI run meets the criterion,
``"loss"`` when only others do, ``None`` when none does or when the timings
were not repeated (no noise measured).

Tolerance runs
--------------
:func:`rtol_vs_best` compares each ``FI-rtol`` run (``FeedbackIntegrator.run``
with only ``rtol`` given: liefi's default method at the step it chooses) with
the other runs of the grid at the error it achieved.
"""

from __future__ import annotations

import math

import numpy as np

#: the drift criterion: every invariant's max drift over ``[0, t_final]`` at most this
DRIFT = 1e-8
#: the accurate criterion: the max state error at most this ...
ACCURATE_ERROR = 1e-6
#: ... and every invariant's max drift at most this
ACCURATE_DRIFT = 1e-8
#: the harness's family of runs driven by a tolerance (``fi.run(t_span, rtol=r)``)
RTOL_METHOD = "FI-rtol"
#: the methods that count as a feedback integrator in :func:`summarize`
FI_METHODS = ("FI", "FI-tuned", "FI-accurate", "FI/solve_ivp", RTOL_METHOD)


def _finite(x):
    return x is not None and isinstance(x, (int, float)) and math.isfinite(x)


def _meets(r, drift, error):
    if r.get("status") != "ok" or not _finite(r.get("max_drift")) or not _finite(r.get("cpu_seconds")):
        return False
    if error is not None and not (_finite(r.get("max_error")) and r["max_error"] <= error):
        return False
    return r["max_drift"] <= drift


def cheapest(rows, *, drift=DRIFT, error=None, methods=None, exclude=()):
    """The row of least ``cpu_seconds`` among successful runs with ``max_drift <= drift``
    (and ``max_error <= error`` when given), optionally among ``methods`` only and never
    among the methods of ``exclude``; ``None`` if no run qualifies."""
    ok = [r for r in rows if _meets(r, drift, error) and (methods is None or r["method"] in methods)
          and r["method"] not in exclude]
    return min(ok, key=lambda r: r["cpu_seconds"]) if ok else None


def label(r):
    """``"method scheme (dt=..., k=...)"``: one run in words."""
    if r.get("method") == RTOL_METHOD:
        p = f"rtol={r['rtol']:.0e}" + (f", dt={r['dt']:.3g}" if r.get("dt") else "")
    else:
        p = f"dt={r['dt']:.3g}" if r.get("dt") else f"rtol={r['rtol']:.0e}"
    k = f", k={r['gain']:g}" if r.get("gain") is not None else ""
    return f"{r['method']} {r['scheme']} ({p}{k})"


def brief(r):
    """The fields of a run that ``summary.json`` keeps (``None`` stays ``None``)."""
    if r is None:
        return None
    keys = ("method", "scheme", "dt", "rtol", "gain", "cpu_seconds", "cpu_spread", "rhs_evaluations", "max_drift",
            "max_error")
    return {k: r.get(k) for k in keys}


def _spread(r):
    s = r.get("cpu_spread") if r is not None else None
    return float(s) if _finite(s) else math.nan


def scene_noise(rows):
    """The median ``cpu_spread`` over the successful runs (``nan`` when no run was repeated)."""
    s = [_spread(r) for r in rows if r.get("status") == "ok"]
    s = [x for x in s if math.isfinite(x)]
    return float(np.median(s)) if s else math.nan


def compare(fi, other, floor=math.nan):
    """``(verdict, ratio, noise)`` of the cheapest FI run ``fi`` against the cheapest other run ``other``
    (either may be ``None``); ``floor``: the scene's noise (:func:`scene_noise`).  See the module docstring."""
    if fi is None and other is None:
        return None, None, None
    if other is None:
        return "win", None, None
    if fi is None:
        return "loss", None, None
    ratio = fi["cpu_seconds"] / max(other["cpu_seconds"], 1e-12)
    noise = max((x for x in (_spread(fi), _spread(other), floor) if math.isfinite(x)), default=math.nan)
    if not math.isfinite(noise):
        return None, ratio, None
    if max(ratio, 1.0 / max(ratio, 1e-300)) - 1.0 <= noise:
        return "tie", ratio, noise
    return ("win" if ratio < 1.0 else "loss"), ratio, noise


def criterion(rows, *, drift, error=None, floor=math.nan):
    """One criterion's part of the summary (suffix-free keys; :func:`summarize` names them)."""
    best = cheapest(rows, drift=drift, error=error)
    fi = cheapest(rows, drift=drift, error=error, methods=FI_METHODS)
    other = cheapest(rows, drift=drift, error=error, exclude=FI_METHODS)
    ratio, reason = None, None
    if best is not None and fi is not None:
        ratio = fi["cpu_seconds"] / max(best["cpu_seconds"], 1e-12)
    elif not any(r.get("status") == "ok" for r in rows):
        reason = "no successful run"
    elif error is not None and not any(r.get("status") == "ok" and _finite(r.get("max_error")) for r in rows):
        reason = "the state error is not measured (no exact or reference solution)"
    elif best is None:
        floor_err = min((r["max_error"] for r in rows if r.get("status") == "ok" and _finite(r.get("max_error"))
                         and _finite(r.get("max_drift")) and r["max_drift"] <= drift), default=None)
        reason = "no run of the grid meets the criterion" + (
            f" (least error among the runs within the drift: {floor_err:.2g})" if floor_err is not None else "")
    else:
        reason = f"no feedback-integrator run meets it (the cheapest run: {label(best)})"
    verdict, r_other, noise = compare(fi, other, floor)
    return {"best": brief(best), "fi": brief(fi), "other": brief(other), "ratio": ratio, "reason": reason,
            "verdict": verdict, "fi_over_other": r_other, "noise": noise}


def summarize(rows, drift=DRIFT, tasks=None):
    """The verdict of one scene's sweep, for ``summary.json``.

    Drift criterion (``max_drift <= drift``, each invariant's max over the run):
    ``cheapest_overall``, ``cheapest_fi`` (:data:`FI_METHODS`: every gain nonzero
    -- zero gains are ``no-feedback``), ``cheapest_other``, ``fi_over_best`` (their
    CPU ratio, ``None`` with ``fi_over_best_reason`` when either is missing),
    ``verdict``, ``fi_over_other`` and ``noise`` (:func:`compare`).  Accurate
    criterion (:data:`ACCURATE_ERROR`, :data:`ACCURATE_DRIFT`): the same keys with
    ``accurate`` -- ``cheapest_accurate``, ``cheapest_fi_accurate``,
    ``cheapest_other_accurate``, ``fi_over_best_accurate`` (and its ``_reason``),
    ``verdict_accurate``, ``fi_over_other_accurate``, ``noise_accurate``.  Each run
    holds ``method``, ``scheme``, ``dt`` or ``rtol``, ``gain``, ``cpu_seconds``,
    ``cpu_spread``, ``max_drift`` and ``max_error``.  ``rtol_vs_best``:
    :func:`rtol_vs_best`.

    Only runs with ``status = "ok"`` count; ``runs``, ``failed`` (diverged or
    solver failures), ``not_applicable`` and ``errors`` (raised, worker died)
    count the rest.  ``rows`` are the stored outcomes of the grid's tasks, at
    most one per task; ``complete`` says whether every one of the ``tasks`` (their
    number; ``None`` when not given) has a stored result: a finished run, whatever
    its status, not a task that raised or lost its worker (a rerun retries those).
    """
    floor = scene_noise(rows)
    d = criterion(rows, drift=drift, floor=floor)
    a = criterion(rows, drift=ACCURATE_DRIFT, error=ACCURATE_ERROR, floor=floor)
    return {
        "criterion": f"every invariant's max drift <= {drift:g}",
        "criterion_accurate": f"max state error <= {ACCURATE_ERROR:g} and every invariant's max drift <= "
                              f"{ACCURATE_DRIFT:g}",
        "t_final": rows[0]["t_final"] if rows else None,
        "runs": len(rows),
        "tasks": None if tasks is None else int(tasks),
        "complete": None if tasks is None else len(rows) - sum(r["status"] == "error" for r in rows) == tasks,
        "failed": sum(r["status"] in ("diverged", "failed") for r in rows),
        "not_applicable": sum(r["status"] == "not-applicable" for r in rows),
        "errors": sum(r["status"] == "error" for r in rows),
        "scene_noise": None if not math.isfinite(floor) else floor,
        "cheapest_overall": d["best"],
        "cheapest_fi": d["fi"],
        "cheapest_other": d["other"],
        "fi_over_best": d["ratio"],
        "fi_over_best_reason": d["reason"],
        "verdict": d["verdict"],
        "fi_over_other": d["fi_over_other"],
        "noise": d["noise"],
        "cheapest_accurate": a["best"],
        "cheapest_fi_accurate": a["fi"],
        "cheapest_other_accurate": a["other"],
        "fi_over_best_accurate": a["ratio"],
        "fi_over_best_accurate_reason": a["reason"],
        "verdict_accurate": a["verdict"],
        "fi_over_other_accurate": a["fi_over_other"],
        "noise_accurate": a["noise"],
        "rtol_vs_best": rtol_vs_best(rows),
    }


def _verdict_words(verdict, ratio, noise):
    if verdict is None:
        return "no verdict" if ratio is None else f"FI/other = {ratio:.3g} (timings not repeated: no noise measured)"
    if ratio is None:
        return verdict + (" (only feedback integrators meet it)" if verdict == "win" else " (no FI meets it)")
    return f"{verdict}: FI/other = {ratio:.3g}, noise {noise:.2g}"


def summary(rows, drift=DRIFT):
    """A few lines of text: per criterion the cheapest run, the cheapest FI run, the ratio and the verdict."""
    s = summarize(rows, drift)
    lines = []
    for name, sfx in ((f"max drift <= {drift:g}", ""),
                      (f"error <= {ACCURATE_ERROR:g} and drift <= {ACCURATE_DRIFT:g}", "_accurate")):
        best = s["cheapest_overall" if not sfx else "cheapest_accurate"]
        fi = s["cheapest_fi" + sfx]
        lines.append(f"cheapest with {name}: " + (f"{label(best)}, {best['cpu_seconds']:.3g} s" if best else "none"))
        lines.append("  cheapest feedback integrator reaching it: "
                     + (f"{label(fi)}, {fi['cpu_seconds']:.3g} s" if fi else "none in the grid"))
        ratio = s["fi_over_best" + sfx]
        lines.append(f"  fi_over_best{sfx} = " + (f"{ratio:.3g}" if ratio is not None else f"null ({s['fi_over_best' + sfx + '_reason']})")
                     + "; " + _verdict_words(s["verdict" + sfx], s["fi_over_other" + sfx], s["noise" + sfx]))
    for x in s["rtol_vs_best"]:
        if x["status"] != "ok":
            lines.append(f"FI-rtol rtol={x['rtol']:.0e}: {x['status']}")
            continue
        c = x["cpu_over_cheapest"]
        lines.append(f"FI-rtol rtol={x['rtol']:.0e}: error {x['max_error']:.2g} ({x['error_over_rtol']:.2g} x rtol), "
                     f"{x['cpu_seconds']:.3g} s, " + (f"{c:.3g} x the cheapest run at that error" if c is not None
                                                      else "no other run reaches that error"))
    if s["failed"] or s["errors"]:
        lines.append(f"{s['failed']} runs diverged or failed, {s['errors']} raised or lost their worker (see the CSV)")
    return "\n".join(lines)


# ======================================================================================
# tolerance runs against the grid
# ======================================================================================


def _usable(r):
    return (r.get("status") == "ok" and r.get("method") != RTOL_METHOD and _finite(r.get("max_error"))
            and _finite(r.get("cpu_seconds")) and r["cpu_seconds"] > 0)


def interpolated_cpu(rows, error):
    """The least CPU time at which a method of the grid reaches ``error``, interpolated.

    Per series (method, scheme, gain) the runs are ordered by CPU time; between
    two consecutive runs whose errors bracket ``error`` (the cheaper one above
    it, the dearer one at or below it) ``log cpu`` is interpolated linearly in
    ``log error``.  ``FI-rtol`` runs are not part of the grid here.  ``None`` if
    no series brackets ``error``.
    """
    if not (_finite(error) and error > 0):
        return None
    series = {}
    for r in rows:
        if _usable(r) and r["max_error"] > 0:
            series.setdefault((r["method"], r["scheme"], r.get("gain")), []).append(r)
    best = None
    le = math.log(error)
    for rs in series.values():
        rs.sort(key=lambda r: r["cpu_seconds"])
        for a, b in zip(rs, rs[1:]):
            ea, eb = a["max_error"], b["max_error"]
            if not (ea > error >= eb) or ea == eb:
                continue
            la, lb = math.log(a["cpu_seconds"]), math.log(b["cpu_seconds"])
            c = math.exp(la + (le - math.log(ea)) * (lb - la) / (math.log(eb) - math.log(ea)))
            best = c if best is None else min(best, c)
    return best


def rtol_vs_best(rows):
    """Per ``FI-rtol`` run (by ``rtol``): its achieved error and CPU against the grid's cheapest at that error.

    Each entry: ``rtol``, ``status``, ``dt`` (the step the run chose), ``max_error``,
    ``error_over_rtol``, ``max_drift``, ``cpu_seconds`` (the integration, best of the
    repeats, as every run of the grid), ``setup_seconds`` (the rest of the call:
    choosing the step, the stability guard), ``cheapest_at_error`` (the cheapest
    other run of the grid with ``max_error`` at most this run's, whatever its
    drift), ``interpolated_cpu`` (:func:`interpolated_cpu` at this run's error),
    ``reference_cpu`` (the smaller of the two), ``cpu_over_cheapest`` (CPU /
    reference), ``total_over_cheapest`` ((CPU + setup) / reference),
    ``cheapest_kept_at_error`` (the same with every invariant within :data:`DRIFT`)
    and ``cpu_over_cheapest_kept``.
    """
    out = []
    for r in sorted((r for r in rows if r.get("method") == RTOL_METHOD), key=lambda r: -(r.get("rtol") or 0)):
        e = {"rtol": r.get("rtol"), "status": r.get("status"), "dt": r.get("dt"), "max_error": r.get("max_error"),
             "max_drift": r.get("max_drift"), "cpu_seconds": r.get("cpu_seconds"),
             "cpu_spread": r.get("cpu_spread"), "setup_seconds": r.get("setup_seconds"), "error_over_rtol": None,
             "cheapest_at_error": None, "interpolated_cpu": None, "reference_cpu": None, "cpu_over_cheapest": None,
             "total_over_cheapest": None, "cheapest_kept_at_error": None, "cpu_over_cheapest_kept": None}
        out.append(e)
        if r.get("status") != "ok" or not _finite(r.get("max_error")) or not _finite(r.get("cpu_seconds")):
            continue
        err = r["max_error"]
        e["error_over_rtol"] = err / r["rtol"] if r.get("rtol") else None
        at = [x for x in rows if _usable(x) and x["max_error"] <= err]
        real = min(at, key=lambda x: x["cpu_seconds"]) if at else None
        kept = [x for x in at if _finite(x.get("max_drift")) and x["max_drift"] <= DRIFT]
        real_kept = min(kept, key=lambda x: x["cpu_seconds"]) if kept else None
        interp = interpolated_cpu(rows, err)
        ref = min([c for c in (real["cpu_seconds"] if real else None, interp) if c is not None], default=None)
        setup = r.get("setup_seconds") if _finite(r.get("setup_seconds")) else 0.0
        e.update(cheapest_at_error=brief(real), interpolated_cpu=interp, reference_cpu=ref,
                 cpu_over_cheapest=None if ref is None else r["cpu_seconds"] / ref,
                 total_over_cheapest=None if ref is None else (r["cpu_seconds"] + setup) / ref,
                 cheapest_kept_at_error=brief(real_kept),
                 cpu_over_cheapest_kept=None if real_kept is None else r["cpu_seconds"] / real_kept["cpu_seconds"])
    return out
