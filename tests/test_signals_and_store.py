"""Stopping and failing cleanly: SIGTERM, interrupts counted from the store, a full disk, a damaged store, a lock.

* SIGTERM (``timeout``, ``kill``, Slurm, ``docker stop``) on ``liefi bench`` (a
  process pool, a Dask cluster) and ``liefi reproduce --jobs 2`` behaves as
  Ctrl-C: one line on stderr, exit code 143, a summary consistent with what
  finished, and no worker process left running (real signals, subprocesses);
* after an interrupt the message, the CSV and ``summary.json`` count exactly the
  runs in ``results.sqlite`` (a run committed just before the signal counts);
* a store that cannot be written (disk full, a file size limit) or read (damaged,
  another program's database, a row that is not JSON) is one line naming the
  file and what to do, after the summary of what finished; never a traceback,
  and another program's database is never written into;
* "File too large" names the file;
* two benches on one ``--out``: the second is refused at once.
"""

from __future__ import annotations

import importlib.util
import json
import os
import random
import resource
import signal
import sqlite3
import subprocess
import sys
import time

import pytest

from liefi import bench, cli, engine, sweep
from liefi.sweep import ResultStore, StoreError

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
pytestmark = pytest.mark.skipif(not engine.available(), reason="the work-precision harness runs compiled kernels")

#: a bench long enough to be interrupted: 45 runs to t = 100 (a second or so each)
LONG = ["suslov", "--t-final", "100", "--quick", "--methods", "FI,no-feedback", "--schemes", "euler,heun,rk4",
        "--no-progress"]
#: a bench of three short runs
TINY = ["suslov", "--quick", "--t-final", "1", "--methods", "FI", "--schemes", "euler", "--gains", "scene",
        "--no-progress"]


# --------------------------------------------------------------------------------------
# helpers
# --------------------------------------------------------------------------------------
def _start(argv, folder, **kw):
    """``python -m liefi ARGV`` in its own session (so its process group can be checked), output to files."""
    folder.mkdir(parents=True, exist_ok=True)
    out, err = open(folder / "stdout.txt", "w"), open(folder / "stderr.txt", "w")
    p = subprocess.Popen([sys.executable, "-m", "liefi", *argv], cwd=ROOT, stdout=out, stderr=err,
                         start_new_session=True, **kw)
    out.close()
    err.close()
    return p


def _as_from_a_terminal():
    """In the child before exec: the default actions of SIGINT, SIGTERM and SIGHUP, as from a terminal, even
    if the tests run under ``nohup`` or as a background job (then they start ignored, and liefi keeps them so)."""
    for s in (signal.SIGINT, signal.SIGTERM, getattr(signal, "SIGHUP", signal.SIGTERM)):
        signal.signal(s, signal.SIG_DFL)


def _group(pgid):
    """The live (not zombie) processes of the process group ``pgid``, from ``/proc``."""
    found = []
    for d in os.listdir("/proc"):
        if not d.isdigit():
            continue
        try:
            with open(f"/proc/{d}/stat") as fh:
                fields = fh.read().rsplit(")", 1)[1].split()
        except OSError:
            continue
        if int(fields[2]) == pgid and fields[0] not in "ZX":
            found.append(int(d))
    return found


def _stored(path):
    if not os.path.exists(path):
        return 0
    db = sqlite3.connect(path)
    try:
        return db.execute("select count(*) from results").fetchone()[0]
    except sqlite3.OperationalError:
        return 0
    finally:
        db.close()


def _wait_for(cond, p, seconds=180):
    deadline = time.time() + seconds
    while time.time() < deadline and p.poll() is None:
        if cond():
            return True
        time.sleep(0.05)
    return False


def _finish(p, logs, signum=None, seconds=120):
    """Send ``signum``, wait for the exit; returns ``(code, stdout, stderr, survivors)`` and kills survivors."""
    if signum is not None:
        os.kill(p.pid, signum)
    try:
        code = p.wait(timeout=seconds)
    except subprocess.TimeoutExpired:
        os.killpg(p.pid, signal.SIGKILL)
        p.wait()
        raise
    deadline = time.time() + 5  # the workers are joined before the exit; a grace for the kernel
    while _group(p.pid) and time.time() < deadline:
        time.sleep(0.1)
    survivors = _group(p.pid)
    for pid in survivors:  # do not leave them behind even when the test fails
        os.kill(pid, signal.SIGKILL)
    return code, (logs / "stdout.txt").read_text(), (logs / "stderr.txt").read_text(), survivors


def _csv_rows(path):
    return len(bench.read_csv(str(path))) if path.exists() else 0


needs_proc = pytest.mark.skipif(not os.path.isdir("/proc/self"), reason="checks worker processes in /proc")


# --------------------------------------------------------------------------------------
# SIGTERM (and SIGINT) on a running bench: real signals
# --------------------------------------------------------------------------------------
@needs_proc
@pytest.mark.parametrize("scheduler, signum", [
    ("processes:2", signal.SIGTERM),
    ("processes:2", signal.SIGINT),
    ("dask:2", signal.SIGTERM),  # about 10 s: kept in the default suite, the must-show
    ("processes:2", getattr(signal, "SIGHUP", signal.SIGTERM)),  # a closed terminal: handled as SIGTERM
])
def test_signal_on_a_parallel_bench_stops_cleanly(tmp_path, scheduler, signum):
    """Exit 128 + signal, one line, no worker left, and the message, the CSV and summary.json count
    exactly the runs in the store."""
    if scheduler.startswith("dask"):
        pytest.importorskip("distributed")
    out = tmp_path / "o"
    p = _start(["bench", *LONG, "--out", str(out), "--scheduler", scheduler], tmp_path,
               preexec_fn=_as_from_a_terminal)
    db = out / "results.sqlite"
    assert _wait_for(lambda: _stored(db) >= 2, p), (tmp_path / "stderr.txt").read_text()
    workers = [q for q in _group(p.pid) if q != p.pid]
    assert workers, "the bench should run in worker processes"
    code, stdout, stderr, survivors = _finish(p, tmp_path, signum)
    assert code == 128 + signum, stderr
    assert "Traceback" not in stderr and "Error" not in stderr, stderr
    lines = [ln for ln in stderr.splitlines() if ln.strip() and not ln.startswith("suslov: ")]
    word = "interrupted" if signum == signal.SIGINT else f"terminated by {signal.Signals(signum).name}"
    assert len(lines) == 1 and lines[0].startswith(f"liefi bench: {word}; "), stderr
    assert survivors == [], f"worker processes left running: {survivors}"
    stored = _stored(db)
    said = int(lines[0].split("; ")[1].split()[0])  # "N runs of this scene finished"
    s = json.loads((out / "summary.json").read_text())["scenes"]["suslov"]
    assert said == stored == s["runs"] == _csv_rows(out / "suslov-work-precision.csv") >= 2
    assert s["tasks"] == 45 and s["complete"] is False


@needs_proc
def test_sigterm_on_reproduce_with_two_jobs_stops_cleanly(tmp_path):
    """``liefi reproduce --jobs 2`` under SIGTERM: exit 143, one line, the summary marked interrupted,
    no worker left and no half-written file of a killed worker."""
    pytest.importorskip("matplotlib")
    d = tmp_path / "out"
    p = _start(["reproduce", "--out", str(d), "--t-final-scale", "0.02", "--jobs", "2",
                "--only", "suslov,chaplygin,knife-edge,heisenberg,vertical-disk"], tmp_path)
    assert _wait_for(lambda: (d / "summary.json").exists(), p), (tmp_path / "stderr.txt").read_text()
    assert [q for q in _group(p.pid) if q != p.pid], "reproduce --jobs 2 should run in worker processes"
    code, stdout, stderr, survivors = _finish(p, tmp_path, signal.SIGTERM)
    assert code == 143, stderr
    assert "Traceback" not in stderr and "BrokenPipe" not in stderr and "KeyboardInterrupt" not in stderr
    said = [ln for ln in stderr.splitlines() if "terminated" in ln or "interrupted" in ln]
    assert len(said) == 1 and said[0].startswith("liefi: terminated by SIGTERM (the summary of the "), stderr
    assert survivors == [], f"worker processes left running: {survivors}"
    summary = json.loads((d / "summary.json").read_text())
    assert summary["interrupted"] is True and summary["runs"] and summary["not_run"]
    assert f"the summary of the {len(summary['runs'])} finished runs" in said[0]
    assert not ({r["scene"] for r in summary["runs"]} & set(summary["not_run"]))
    assert all((d / f).exists() for f in summary["figures"])
    assert not [f for f in os.listdir(d) if ".tmp" in f]


def test_sigterm_during_liefi_run_is_one_line_and_143(capsys, monkeypatch):
    """The handler is the command's: SIGTERM to this very process during ``liefi run`` gives 143 and one
    line; outside the command the previous handler is back."""
    from liefi import scenes

    def run(self, **kw):
        os.kill(os.getpid(), signal.SIGTERM)
        time.sleep(5)  # the handler raises here
        raise AssertionError("SIGTERM was not handled")

    def unhandled(signum, frame):  # not the default action: that would end the test session
        raise AssertionError("SIGTERM reached the test's handler: the command did not handle it")

    monkeypatch.setattr(scenes.Scene, "run", run)
    previous = signal.signal(signal.SIGTERM, unhandled)
    try:
        code = cli.main(["run", "suslov"])
        after = signal.getsignal(signal.SIGTERM)
    finally:
        signal.signal(signal.SIGTERM, previous)
    err = capsys.readouterr().err
    assert code == 143 and err.strip().splitlines() == [
        "liefi: terminated by SIGTERM"]  # liefi run has no output folder: nothing more to say
    assert after is unhandled


# --------------------------------------------------------------------------------------
# an interrupt is counted from the store
# --------------------------------------------------------------------------------------
def test_interrupt_just_after_a_commit_counts_that_run(tmp_path, capsys, monkeypatch):
    """The signal lands after the store committed a run and before it was counted in memory: the
    message, the CSV and summary.json still equal the store."""
    real = ResultStore.put
    commits = []

    def put(self, *args, **kwargs):
        value = real(self, *args, **kwargs)
        commits.append(1)
        if len(commits) == 2:
            raise KeyboardInterrupt  # where a Ctrl-C can land: committed, not yet counted
        return value

    monkeypatch.setattr(ResultStore, "put", put)
    out = tmp_path / "o"
    code = bench.main([*TINY, "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 130 and "Traceback" not in err
    assert _stored(out / "results.sqlite") == 2
    assert "; 2 runs of this scene finished" in err
    assert _csv_rows(out / "suslov-work-precision.csv") == 2
    assert json.loads((out / "summary.json").read_text())["scenes"]["suslov"]["runs"] == 2


def test_sweep_interrupted_carries_the_signal_and_the_stored_results(tmp_path, monkeypatch):
    real = ResultStore.put

    def put(self, task, value, **kw):
        v = real(self, task, value, **kw)
        if task == -3:
            raise KeyboardInterrupt
        return v

    monkeypatch.setattr(ResultStore, "put", put)
    with ResultStore(tmp_path / "s.sqlite") as store:
        with pytest.raises(sweep.SweepInterrupted) as info:
            sweep.run_sweep(abs, [-1, -2, -3, -4], store=store)
    assert info.value.results == [1, 2, 3, None] and info.value.done == 3 and info.value.signum == signal.SIGINT


# --------------------------------------------------------------------------------------
# a full disk
# --------------------------------------------------------------------------------------
def test_full_disk_during_bench_is_one_line_after_the_summary(tmp_path, capsys, monkeypatch):
    """SQLite says "database or disk is full" at the third run: the summary of the two that finished,
    summary.json and the CSV from the store, then one line naming the store and what to do; exit 2."""
    connect = sqlite3.connect

    class FullDisk(sqlite3.Connection):
        inserts = 0

        def execute(self, sql, *args):
            if sql.startswith("INSERT"):
                FullDisk.inserts += 1
                if FullDisk.inserts > 2:
                    raise sqlite3.OperationalError("database or disk is full")
            return super().execute(sql, *args)

    monkeypatch.setattr(sweep.sqlite3, "connect", lambda *a, **k: connect(*a, factory=FullDisk, **k))
    out = tmp_path / "o"
    code = cli.main(["bench", *TINY, "--out", str(out)])
    o, err = capsys.readouterr()
    monkeypatch.setattr(sweep.sqlite3, "connect", connect)
    assert code == 2 and "Traceback" not in err
    lines = [ln for ln in err.splitlines() if ln.startswith("liefi")]
    assert len(lines) == 1, err
    store = str(out / "results.sqlite")
    assert lines[0].startswith(f"liefi: error: store: cannot write {store} (database or disk is full)")
    assert "free space" in lines[0] and "--out" in lines[0] and "summarized in" in lines[0]
    assert "stopped after 2 of 3 runs" in o and "cheapest" in o
    assert _stored(out / "results.sqlite") == 2 == _csv_rows(out / "suslov-work-precision.csv")
    assert json.loads((out / "summary.json").read_text())["scenes"]["suslov"]["runs"] == 2


def _limit_file_size(n):
    def pre():
        resource.setrlimit(resource.RLIMIT_FSIZE, (n, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))
    return pre


def test_store_past_a_file_size_limit_is_one_line_and_a_resume_finishes(tmp_path):
    """A real write failure (the store grows past RLIMIT_FSIZE, which SQLite reports as a disk I/O
    error): one line naming the store, exit 2; what finished is kept and a rerun completes it."""
    out = tmp_path / "o"
    grid = dict(t_final=1.0, quick=True, methods=["FI"], schemes=("euler", "rk4"), ivp_methods=(), gains=(None,))
    assert len(bench.work_precision("suslov", plots=False, **grid)) == 6  # kernels cached: the child writes its store
    argv = ["bench", "suslov", "--quick", "--t-final", "1", "--methods", "FI", "--schemes", "euler,rk4", "--gains",
            "scene", "--no-progress", "--out", str(out)]
    p = _start(argv, tmp_path, preexec_fn=_limit_file_size(20_000))  # about three runs fit
    code, stdout, stderr, _ = _finish(p, tmp_path)
    assert code == 2 and "Traceback" not in stderr, stderr
    lines = [ln for ln in stderr.splitlines() if ln.startswith("liefi")]
    assert len(lines) == 1 and f"store: cannot write {out / 'results.sqlite'}" in lines[0], stderr
    assert "file size limit" in lines[0]
    kept = _stored(out / "results.sqlite")
    assert 0 < kept < 6 and f"stopped after {kept} of 6 runs" in stdout
    assert len(bench.work_precision("suslov", out_dir=str(out), plots=False, **grid)) == 6
    assert _stored(out / "results.sqlite") == 6


def test_file_too_large_names_the_file(tmp_path):
    """EFBIG ("File too large", a file size limit) on the bench's CSV and summary.json, a figure and a
    reproduce summary: the message names the file and what to do (in a child: the limit is per process)."""
    code = (
        "import resource, sys\n"
        "from liefi import bench, plotting, reproduce\n"
        "from liefi.sweep import ResultStore\n"
        "d = sys.argv[1]\n"
        "with ResultStore(d + '/results.sqlite') as s:\n"
        "    for i in range(10):  # ten scenes: a summary.json of several kB\n"
        "        s.put({'i': i}, dict(scene=f's{i}', t_final=1.0, method='FI', status='ok'))\n"
        "out = reproduce.prepare_output(d + '/r')\n"
        "resource.setrlimit(resource.RLIMIT_FSIZE, (2000, resource.getrlimit(resource.RLIMIT_FSIZE)[1]))\n"
        "rows = [dict(scene='s', method='FI', status='ok', message='x' * 100)] * 100\n"
        "for write in (lambda: bench.write_csv(rows, d + '/w.csv'), lambda: bench.write_summary(d),\n"
        "              lambda: plotting.save(plotting.new_figure(6, 4), d + '/f.png'),\n"
        "              lambda: out.write_text('summary.md', 'x' * 5000)):\n"
        "    try:\n"
        "        write()\n"
        "    except OSError as exc:\n"
        "        print(exc)\n"
    )
    r = subprocess.run([sys.executable, "-c", code, str(tmp_path)], cwd=ROOT, capture_output=True, text=True,
                       timeout=120)
    lines = r.stdout.splitlines()
    names = [tmp_path / "w.csv", tmp_path / "summary.json", tmp_path / "f.png", tmp_path / "r" / "summary.md"]
    if importlib.util.find_spec("matplotlib") is None:
        names.remove(tmp_path / "f.png")
    assert len(lines) == len(names), r.stdout + r.stderr
    for line, name in zip(lines, names):
        assert line.startswith(f"cannot write {name} (File too large); free space on its disk"), line
    assert not [f for d in (tmp_path, tmp_path / "r") for f in os.listdir(d) if ".tmp" in f]  # no half files


# --------------------------------------------------------------------------------------
# a damaged or foreign store
# --------------------------------------------------------------------------------------
def _damaged_after_header(path):
    """A real store whose first page (the header and the schema) is kept and the rest is random bytes."""
    with ResultStore(path) as s:
        for i in range(200):
            s.put({"i": i}, {"payload": "x" * 500})
    data = open(path, "rb").read()
    rng = random.Random(15)
    open(path, "wb").write(data[:4096] + bytes(rng.getrandbits(8) for _ in range(len(data) - 4096)))


def _foreign(path):
    db = sqlite3.connect(path)
    db.execute("create table users (id integer, name text)")
    db.execute("insert into users values (1, 'ada')")
    db.commit()
    db.close()


def _foreign_results_table(path):
    db = sqlite3.connect(path)
    db.execute("create table results (id integer, score real)")
    db.commit()
    db.close()


def _empty_json_row(path):
    task = bench.build_tasks("suslov", 1.0, quick=True, methods=["FI"], schemes=("euler",), ivp_methods=(),
                             gains=(None,))[0]
    with ResultStore(path, sweep="suslov") as s:
        s.put(task, {"method": "FI"})
    db = sqlite3.connect(path)
    db.execute("update results set value = ''")
    db.commit()
    db.close()


@pytest.mark.parametrize("make, words", [
    (_damaged_after_header, "is damaged"),
    (_foreign, "is not a liefi results store (it holds the tables users)"),
    (_foreign_results_table, "is not a liefi results store (its table 'results' has the columns id, score)"),
    (_empty_json_row, "holds a damaged row"),
])
def test_damaged_or_foreign_store_is_one_clear_line(tmp_path, capsys, monkeypatch, make, words):
    """No traceback, no run, the file named with what to do; another program's database is left as it was."""
    def no_run(task):
        raise AssertionError("a run started on a store that cannot be used")

    monkeypatch.setattr(bench.core, "run_task", no_run)
    out = tmp_path / "o"
    # a folder an earlier bench owns (its manifest lists the store), whose store was damaged or replaced since
    from liefi.reproduce import prepare_output

    prepare_output(str(out), "bench", keep=True).claim_all(["results.sqlite"])
    store = out / "results.sqlite"
    make(str(store))
    before = store.read_bytes()
    code = cli.main(["bench", *TINY, "--out", str(out)])
    err = capsys.readouterr().err
    assert code == 2 and "Traceback" not in err and "Expecting value" not in err, err
    lines = [ln for ln in err.splitlines() if ln.startswith("liefi")]
    assert len(lines) == 1 and lines[0].startswith(f"liefi: error: store: {store} "), err
    assert words in lines[0] and "move" in lines[0] and "--out" in lines[0]
    assert store.read_bytes() == before  # never written into


def test_store_api_errors_are_store_errors(tmp_path):
    """The API raises StoreError (an OSError) naming the file, from open, get, put and rows."""
    p = tmp_path / "s.sqlite"
    _empty_json_row(str(p))
    with ResultStore(p) as s:
        with pytest.raises(StoreError, match="holds a damaged row"):
            s.rows()
    _foreign(str(tmp_path / "f.sqlite"))
    with pytest.raises(OSError, match="f.sqlite is not a liefi results store"):
        ResultStore(tmp_path / "f.sqlite")
    p = tmp_path / "ro.sqlite"
    ResultStore(p).close()
    os.chmod(p, 0o444)
    if os.access(p, os.W_OK):  # root writes anyway
        return
    with ResultStore(p) as s, pytest.raises(StoreError, match="cannot write .*ro.sqlite"):
        s.put({"a": 1}, 1)


# --------------------------------------------------------------------------------------
# two benches on one folder
# --------------------------------------------------------------------------------------
def test_second_bench_on_the_same_out_is_refused(tmp_path):
    """While one bench runs, a second on the same --out exits 2 at once, naming the folder and the
    process; the first is undisturbed; once it has ended, the folder is free again."""
    out = tmp_path / "o"
    first = _start(["bench", *LONG, "--out", str(out)], tmp_path / "first")
    assert _wait_for(lambda: _stored(out / "results.sqlite") >= 1, first), (tmp_path / "first/stderr.txt").read_text()
    second = _start(["bench", *LONG, "--out", str(out)], tmp_path / "second")
    stopped = (None,)
    try:
        code, _, err2, _ = _finish(second, tmp_path / "second", seconds=60)
    finally:
        if first.poll() is None:
            stopped = _finish(first, tmp_path / "first", signal.SIGTERM)
    assert code == 2, err2
    assert err2.strip() == (f"liefi: error: out: {out} is in use by another liefi bench (process {first.pid}); "
                            "two benches on one folder would compute the same runs twice: wait for it to finish "
                            "(a rerun then resumes from its results) or choose another --out")
    assert stopped[0] == 143
    lock = bench.cli.lock_folder(str(out))  # released when the first ended
    assert lock is not None
    lock.close()
