"""``liefi bench`` that a person can wait for: every core, progress off a terminal, legible figures."""

from __future__ import annotations

import io
import os
import re
import subprocess
import sys

import pytest

from liefi import _progress, cli, sweep
from liefi._progress import Progress

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


# --------------------------------------------------------------------------------------
# every core by default
# --------------------------------------------------------------------------------------
def test_default_scheduler_is_every_core(monkeypatch):
    monkeypatch.setattr(os, "cpu_count", lambda: 4)
    assert sweep.default_scheduler() == "processes"
    monkeypatch.setattr(os, "cpu_count", lambda: 1)
    assert sweep.default_scheduler() == "serial"


class _Stop(Exception):
    pass


@pytest.mark.parametrize("extra, expected", [((), "processes"), (("--scheduler", "serial"), "serial"),
                                             (("--scheduler", "processes:1"), "processes:1")])
def test_bench_opens_a_process_pool_unless_told(tmp_path, monkeypatch, extra, expected):
    seen = []

    def spy(scheduler=None):
        seen.append(scheduler)
        raise _Stop

    monkeypatch.setattr(os, "cpu_count", lambda: 2)
    monkeypatch.setattr(sweep, "open_executor", spy)
    with pytest.raises(_Stop):
        cli._main(cli.build_parser(), ["bench", "suslov", "--quick", "--t-final", "0.01", "--out",
                                       str(tmp_path / "o"), *extra])
    assert seen == [expected]


# --------------------------------------------------------------------------------------
# progress: done/total, rate, time left; whole lines when stderr is not a terminal
# --------------------------------------------------------------------------------------
class _Clock:
    def __init__(self):
        self.t = 1000.0

    def __call__(self):
        return self.t


def test_lines_off_a_terminal_every_5_percent_or_30_s(monkeypatch):
    err, clock = io.StringIO(), _Clock()
    monkeypatch.setattr(sys, "stderr", err)
    monkeypatch.setattr(_progress.time, "monotonic", clock)
    bar = Progress(200, "suslov", unit="task", lines=True, initial=20)  # 20 resumed from a store
    assert bar.enabled and bar.lines
    for _ in range(9):  # 4.5 % more in 9 s: no line yet
        clock.t += 1.0
        bar.update()
    assert err.getvalue() == ""
    clock.t += 1.0
    bar.update()  # 5 % more: a line; rate from this session's 10 tasks in 10 s, not the resumed ones
    (line,) = err.getvalue().splitlines()
    assert line == "suslov: 30/200 tasks (15 %), 1 tasks/s, about 2 min 50 s left"
    clock.t += 31.0
    bar.update()  # slow: after 30 s a line although less than 5 % more is done
    assert len(err.getvalue().splitlines()) == 2
    clock.t += 31.0
    bar.update(169)  # the end: always a line
    bar.close()
    last = err.getvalue().splitlines()[-1]
    assert last.startswith("suslov: 200/200 tasks (100 %), ") and last.endswith("in all")
    assert "\r" not in err.getvalue()


def test_without_lines_off_a_terminal_stays_quiet(monkeypatch):
    err = io.StringIO()
    monkeypatch.setattr(sys, "stderr", err)
    with Progress(10, "run", unit="step") as bar:
        bar.update(10)
    assert err.getvalue() == "" and not bar.enabled


def test_terminal_line_has_rate_and_time_left(monkeypatch):
    class Tty(io.StringIO):
        def isatty(self):
            return True

    err, clock = Tty(), _Clock()
    monkeypatch.setattr(sys, "stderr", err)
    monkeypatch.setattr(_progress.time, "monotonic", clock)
    monkeypatch.setitem(sys.modules, "tqdm", None)
    bar = Progress(100, "suslov", unit="task", lines=True)
    assert not bar.lines  # a terminal: the live line
    clock.t += 5.0
    bar.update(10)
    assert "\rsuslov: 10/100 tasks (10 %), 2 tasks/s, about 45 s left" in err.getvalue()


def test_duration_reads_like_a_person():
    assert [_progress.duration(s) for s in (4.4, 65, 3 * 3600 + 125)] == ["4 s", "1 min 5 s", "3 h 2 min"]


def test_bench_prints_progress_lines_into_a_pipe(tmp_path):
    """A real ``liefi bench`` whose stderr is a pipe (a log, CI): a whole progress line, not silence."""
    env = dict(os.environ)
    cmd = [sys.executable, "-m", "liefi", "bench", "suslov", "--t-final", "0.05", "--quick", "--methods", "FI",
           "--schemes", "euler", "--gains", "scene", "--scheduler", "serial", "--out", str(tmp_path / "o")]
    p = subprocess.run(cmd, cwd=ROOT, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                       timeout=300)
    assert p.returncode == 0, p.stderr
    lines = [ln for ln in p.stderr.splitlines() if re.match(r"suslov: \d+/3 tasks", ln)]
    assert lines and re.fullmatch(r"suslov: 3/3 tasks \(100 %\), [\d.e+]+ (tasks/s|s/task), .+ in all", lines[-1])
    assert "\r" not in p.stderr


# --------------------------------------------------------------------------------------
# legible figures: grouped legends inside the figure
# --------------------------------------------------------------------------------------
def _rows():
    rows = []
    for m in ("FI", "FI-tuned", "FI-accurate", "no-feedback", "projection"):
        for s in ("euler", "heun", "rk4", "imex-euler", "imex-heun", "imex-rk4"):
            for k in ((None, 0.1, 1.0, 10.0) if m == "FI" else (None,)):
                for i, dt in enumerate((1e-2, 1e-3, 1e-4)):
                    rows.append({"method": m, "scheme": s, "gain": k, "dt": dt, "status": "ok", "t_final": 10.0,
                                 "cpu_seconds": 10.0 ** (i - 3), "rhs_evaluations": 10 ** (i + 3),
                                 "max_error": 10.0 ** (-3 * i), "drift_J_1": 10.0 ** (-4 * i),
                                 "drift_h": 10.0 ** (-2 * i)})
    for s in ("RK45", "DOP853", "LSODA"):
        rows.append({"method": "constrained", "scheme": s, "gain": None, "rtol": 1e-6, "dt": None, "status": "ok",
                     "t_final": 10.0, "cpu_seconds": 0.1, "rhs_evaluations": 1e4, "max_error": 1e-6,
                     "drift_J_1": 0.0, "drift_h": 1e-7})
    return rows


def test_work_precision_legends_are_grouped_and_fit_in_the_figure(tmp_path, monkeypatch):
    pytest.importorskip("matplotlib")
    from matplotlib.figure import Figure

    from liefi.bench.plots import plot

    figs, real = [], Figure.savefig

    def keep(self, *a, **k):
        figs.append(self)
        return real(self, *a, **k)

    monkeypatch.setattr(Figure, "savefig", keep)
    rows = _rows()
    series = len({(r["method"], r["scheme"], r["gain"]) for r in rows})
    assert series > 40  # the case of the issue: more series than a legend can list
    paths = plot(rows, str(tmp_path), "x")
    assert len(paths) == 2 and len(figs) == 2
    for fig in figs:
        fig.canvas.draw()
        box = fig.bbox
        entries = 0
        for leg in fig.legends:
            b = leg.get_window_extent()
            assert box.x0 - 1 <= b.x0 and b.x1 <= box.x1 + 1 and box.y0 - 1 <= b.y0 and b.y1 <= box.y1 + 1, b
            entries += len(leg.get_texts())
        # one entry per family (6), scheme (9) and FI gain (4), not one per series
        assert entries == 6 + 9 + 4, entries
        for ax in fig.axes:  # the legends do not cover a panel
            a = ax.get_window_extent()
            assert all(not a.overlaps(leg.get_window_extent()) for leg in fig.legends)
