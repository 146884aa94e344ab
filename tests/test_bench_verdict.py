"""The harness's verdict: both criteria, best-of-n timings, ties, and the tolerance runs.

Synthetic rows (no run) except one short ``FI-rtol`` run; no test asserts a time.
"""

from __future__ import annotations

import json
import math

import pytest

from liefi import bench, engine
from liefi.bench import verdict


def _row(method, cpu, error, drift, *, scheme="rk4", dt=1e-2, rtol=None, gain=None, spread=0.05, status="ok",
         **extra):
    return dict(scene="s", variant="v", method=method, scheme=scheme, dt=dt, rtol=rtol, gain=gain, t_final=1e3,
                status=status, cpu_seconds=cpu, cpu_spread=spread, max_error=error, max_drift=drift,
                rhs_evaluations=1, **extra)


def test_the_criteria_are_named_constants():
    assert bench.ACCURATE_ERROR == 1e-6 and bench.ACCURATE_DRIFT == 1e-8 and bench.DRIFT == 1e-8
    s = bench.summarize([_row("FI", 1.0, 1e-7, 1e-9)])
    assert "1e-06" in s["criterion_accurate"] and "1e-08" in s["criterion_accurate"]


def test_accurate_criterion_selects_the_accurate_runs_only():
    """A cheap inaccurate FI wins the drift criterion; the accurate one counts only runs with both bounds."""
    rows = [
        _row("FI-accurate", 1.0, 1e-2, 1e-11, scheme="imex-euler"),   # keeps the invariants, not the motion
        _row("no-feedback", 1.5, 4e-8, 4e-11),                        # accurate, the cheapest such run
        _row("projection", 1.2, 5e-7, 2e-8),                          # accurate state, drift over the bar
        _row("FI", 2.0, 8e-9, 4e-9, gain=10.0),                       # the cheapest accurate FI
        _row("FI", 1.8, 2e-6, 1e-9, gain=1.0),                        # error just over the bar
        _row("FI", 0.5, 1e-9, 1e-9, status="diverged"),               # not a success: never counts
    ]
    s = bench.summarize(rows)
    assert s["cheapest_overall"]["method"] == "FI-accurate" and s["fi_over_best"] == 1.0
    assert s["cheapest_accurate"]["method"] == "no-feedback"
    assert s["cheapest_fi_accurate"]["gain"] == 10.0
    assert s["fi_over_best_accurate"] == pytest.approx(2.0 / 1.5)
    assert s["fi_over_best_accurate_reason"] is None
    assert s["cheapest_other_accurate"]["method"] == "no-feedback"


def test_accurate_criterion_is_null_with_a_reason():
    inaccurate = [_row("FI", 1.0, 1e-3, 1e-10), _row("no-feedback", 0.8, 1e-4, 1e-9)]
    s = bench.summarize(inaccurate)
    assert s["fi_over_best_accurate"] is None and s["cheapest_accurate"] is None
    assert "no run of the grid" in s["fi_over_best_accurate_reason"] and "0.0001" in s["fi_over_best_accurate_reason"]
    assert s["verdict_accurate"] is None
    # only another method is accurate: no FI meets it, and the verdict is a loss
    s = bench.summarize(inaccurate + [_row("projection", 3.0, 1e-8, 1e-12)])
    assert s["fi_over_best_accurate"] is None and "no feedback-integrator run" in s["fi_over_best_accurate_reason"]
    assert s["verdict_accurate"] == "loss"
    # no error measured (no reference): said so
    s = bench.summarize([_row("FI", 1.0, math.nan, 1e-10)])
    assert s["fi_over_best"] == 1.0 and s["fi_over_best_accurate"] is None
    assert "not measured" in s["fi_over_best_accurate_reason"]
    assert bench.summarize([_row("FI", 1.0, 1e-9, 1e-10, status="failed")])["fi_over_best_reason"] == "no successful run"


def test_best_of_keeps_the_least_time_and_measures_the_spread():
    times = iter([0.30, 0.20, 0.25])
    calls = []

    def timed():
        t = next(times)
        calls.append(t)
        return f"run {t}", t

    result, cpu, spread = bench.best_of(3, timed)
    assert calls == [0.30, 0.20, 0.25] and cpu == 0.20 and result == "run 0.2"
    assert spread == pytest.approx(0.25)  # the next-best repeat, 0.25 against 0.20
    assert bench.best_of(2, iter([(1, 2.0), (2, 1.0)]).__next__)[1:] == (1.0, 1.0)
    assert math.isnan(bench.best_of(1, lambda: ("x", 1.0))[2])


def test_a_ratio_within_the_noise_is_a_tie():
    fi, other = _row("FI", 1.05, 1e-8, 1e-12, spread=0.08), _row("projection", 1.0, 1e-8, 1e-12, spread=0.02)
    assert verdict.compare(fi, other) == ("tie", pytest.approx(1.05), 0.08)
    fi["cpu_spread"] = 0.01
    v, r, noise = verdict.compare(fi, other)
    assert v == "loss" and noise == 0.02
    assert verdict.compare(fi, other, floor=0.1)[0] == "tie"  # the scene's median spread is a floor
    fast = _row("FI", 0.5, 1e-8, 1e-12, spread=0.01)
    assert verdict.compare(fast, other)[0] == "win"
    assert verdict.compare(fast, None) == ("win", None, None)
    assert verdict.compare(None, other) == ("loss", None, None)
    # timings not repeated: no noise, no verdict (the ratio is still given)
    single = [_row("FI", 1.0, 1e-8, 1e-12, spread=math.nan), _row("projection", 2.0, 1e-8, 1e-12, spread=math.nan)]
    assert verdict.compare(*single) == (None, 0.5, None)
    s = bench.summarize(single)
    assert s["verdict"] is None and s["fi_over_other"] == 0.5 and s["scene_noise"] is None


def test_summary_verdict_in_json_and_text():
    rows = [_row("FI", 1.0, 1e-8, 1e-12, spread=0.03), _row("projection", 1.02, 1e-8, 1e-12, spread=0.04),
            _row("projection", 0.4, 1e-2, 1e-12, scheme="euler", spread=0.05)]
    s = bench.summarize(rows)
    assert s["verdict"] == "loss" and s["fi_over_best"] == pytest.approx(2.5)
    assert s["verdict_accurate"] == "tie" and s["noise_accurate"] == pytest.approx(0.04)
    assert s["scene_noise"] == pytest.approx(0.04)
    json.dumps(s)  # plain JSON
    text = bench.summary(rows)
    assert "fi_over_best = 2.5" in text and "fi_over_best_accurate = 1" in text and "tie" in text


def _rtol_row(rtol, cpu, error, **kw):
    return _row("FI-rtol", cpu, error, 1e-15, scheme="imex-rk4", rtol=rtol, dt=kw.pop("dt", 1e-2), **kw)


def test_rtol_vs_best_compares_with_the_cheapest_run_at_that_error():
    grid = [_row("no-feedback", 1.0, 1e-4, 1e-7, dt=8e-3), _row("no-feedback", 2.0, 1e-6, 1e-9, dt=4e-3),
            _row("no-feedback", 4.0, 1e-8, 1e-11, dt=2e-3), _row("projection", 3.0, 1e-6, 1e-14)]
    rows = grid + [_rtol_row(1e-5, 1.5, 1e-5, setup_seconds=0.5), _rtol_row(1e-9, 5.0, 1e-10),
                   _rtol_row(1e-7, math.nan, math.nan, status="diverged")]
    out = bench.rtol_vs_best(rows)
    assert [e["rtol"] for e in out] == [1e-5, 1e-7, 1e-9]
    a, bad, c = out
    assert a["error_over_rtol"] == pytest.approx(1.0)
    # the cheapest real run with error <= 1e-5: no-feedback at 2 s; interpolated between 1 s (1e-4) and 2 s (1e-6)
    assert a["cheapest_at_error"]["cpu_seconds"] == 2.0
    assert a["interpolated_cpu"] == pytest.approx(math.sqrt(2.0))
    assert a["reference_cpu"] == pytest.approx(math.sqrt(2.0))
    assert a["cpu_over_cheapest"] == pytest.approx(1.5 / math.sqrt(2.0))
    assert a["total_over_cheapest"] == pytest.approx(2.0 / math.sqrt(2.0))
    # with every invariant within 1e-8 too: the 2 s run (the 1 s one drifts 1e-7)
    assert a["cheapest_kept_at_error"]["cpu_seconds"] == 2.0 and a["cpu_over_cheapest_kept"] == 0.75
    assert bad["status"] == "diverged" and bad["cpu_over_cheapest"] is None
    # nothing of the grid reaches 1e-10: no reference, said as None
    assert c["cheapest_at_error"] is None and c["interpolated_cpu"] is None and c["cpu_over_cheapest"] is None
    # FI-rtol rows never serve as their own reference, and count as feedback integrators
    assert verdict.interpolated_cpu(rows, 1e-5) == pytest.approx(math.sqrt(2.0))
    assert "FI-rtol" in bench.FI_METHODS
    s = bench.summarize(rows)
    assert s["rtol_vs_best"] == out and s["cheapest_fi"]["method"] == "FI-rtol"
    assert "FI-rtol rtol=1e-05" in bench.summary(rows)


def test_rtol_runs_are_a_method_family_of_the_grid():
    tasks = bench.build_tasks("suslov", 1e3)
    rt = [t for t in tasks if t["method"] == "FI-rtol"]
    assert [t["rtol"] for t in rt] == [1e-4, 1e-5, 1e-6, 1e-7, 1e-8, 1e-9, 1e-10] == list(bench.FI_RTOLS)
    assert all(t["dt"] is None and t["repeats"] == bench.REPEATS == 3 for t in rt)
    assert [t["rtol"] for t in bench.build_tasks("suslov", 1.0, quick=True) if t["method"] == "FI-rtol"] == \
        [1e-4, 1e-7, 1e-10]
    assert all(t["repeats"] == 1 for t in bench.build_tasks("suslov", 1.0, quick=True, repeats=1))
    with pytest.raises(ValueError, match="repeats"):
        bench.build_tasks("suslov", 1.0, repeats=0)
    with pytest.raises(ValueError, match="rtol"):
        bench.build_tasks("suslov", 1.0, fi_rtols=[-1e-6])


@pytest.mark.skipif(not engine.available(), reason="the harness runs compiled kernels")
def test_an_rtol_run_is_recorded_like_the_others(tmp_path):
    """FI-rtol runs liefi's default (imex-rk4/6/8, gains auto) at the order and step it chooses, timed best of 2."""
    rows = bench.work_precision("rigid-body", t_final=2.0, methods=("FI-rtol", "no-feedback"), schemes=("rk4",),
                                dts=[1e-2], fi_rtols=[1e-6], repeats=2, n_save=10, out_dir=str(tmp_path),
                                plots=False)
    r = next(r for r in rows if r["method"] == "FI-rtol")
    assert r["status"] == "ok", r["message"]
    assert r["scheme"] in ("imex-rk4", "imex-rk6", "imex-rk8") and r["rtol"] == 1e-6 and r["dt"] > 0 and r["repeats"] == 2
    assert r["cpu_seconds"] > 0 and math.isfinite(r["cpu_spread"]) and r["setup_seconds"] >= 0
    assert r["max_drift"] < 1e-12 and r["max_error"] < 1e-4
    back = bench.read_csv(str(tmp_path / "rigid-body-work-precision.csv"))
    assert {"cpu_spread", "repeats", "setup_seconds"} <= set(back[0])
    s = bench.summarize(back)
    assert [e["rtol"] for e in s["rtol_vs_best"]] == [1e-6]


def test_bench_refuses_a_bad_repeat_count(tmp_path, capsys):
    assert bench.main(["suslov", "--quick", "--repeats", "0", "--out", str(tmp_path / "o")]) == 2
    assert "--repeats" in capsys.readouterr().err
