"""An interrupt (Ctrl-C, SIGTERM) in the middle of writing an output leaves no half-written file.

Every output of ``liefi run --out``, ``reproduce`` and ``bench`` (figures, CSV, ``summary.json``, the long-horizon
curves' ``.npz``) is written whole or not at all (:func:`liefi._files.replacing`): the interrupt is simulated
inside the writer (deterministic, no timing), after part of the file is written.  The file as it was before
stays (or none), and no temporary file is left behind; a later write works.
"""

from __future__ import annotations

import csv
import json
import os

import numpy as np
import pytest


def _half_then_interrupt(path, *args, **kwargs):
    """A writer cut short: part of the bytes in ``path``, then Ctrl-C."""
    with open(path, "wb") as fh:
        fh.write(b"\x89PNG half")
    raise KeyboardInterrupt


def _figure():
    pytest.importorskip("matplotlib")
    from matplotlib.figure import Figure

    fig = Figure()
    fig.add_subplot().plot([0, 1], [1, 0])
    return fig


def _save_figure(path, monkeypatch, cut):
    from liefi.results import scene_figures

    fig = _figure()
    if cut:
        monkeypatch.setattr(fig, "savefig", _half_then_interrupt)
    scene_figures.save(fig, str(path))


def _write_csv(path, monkeypatch, cut):
    from liefi.bench.core import write_csv

    if cut:
        real = csv.DictWriter.writerow

        def writerow(self, row):
            real(self, row)
            self.writerow = None  # the second row is never written
            raise KeyboardInterrupt

        monkeypatch.setattr(csv.DictWriter, "writerow", writerow)
    write_csv([{"scene": "a", "status": "ok"}, {"scene": "b", "status": "ok"}], str(path))


def _save_curves(path, monkeypatch, cut):
    from liefi.bench import plots

    if cut:
        monkeypatch.setattr(np, "savez_compressed", _half_then_interrupt)
    plots.save_curves({"FI": (np.arange(3.0), {"h": np.ones(3)}, 0.1, "FI", "rk4")}, str(path))


def _write_summary(path, monkeypatch, cut):
    from liefi import _json
    from liefi.reproduce import Output

    if cut:
        def dumps(*a, **k):
            raise KeyboardInterrupt

        monkeypatch.setattr(_json, "dumps", dumps)
    out = Output(str(path.parent), command="bench")
    out._atomic(path.name, lambda f: (f.write('{"half": '), f.write(_json.dumps({"runs": 2})), f.write("}")))


@pytest.mark.parametrize("write, name", [(_save_figure, "fig.png"), (_write_csv, "rows.csv"),
                                         (_save_curves, "curves.npz"), (_write_summary, "summary.json")])
def test_an_interrupt_while_writing_leaves_the_old_file_whole_and_no_temporary(tmp_path, monkeypatch, write, name):
    path = tmp_path / name
    old = b"the previous, complete file"
    path.write_bytes(old)
    with monkeypatch.context() as m, pytest.raises(KeyboardInterrupt):
        write(path, m, cut=True)
    assert path.read_bytes() == old  # before: the file cut to its first bytes
    assert sorted(os.listdir(tmp_path)) == [name]  # no temporary file left
    write(path, monkeypatch, cut=False)  # and the next write replaces it
    assert path.read_bytes() != old and path.stat().st_size > 0
    assert sorted(os.listdir(tmp_path)) == [name]
    assert oct(path.stat().st_mode & 0o777) == oct(0o666 & ~_umask())  # the usual mode, not mkstemp's 0600


def _umask():
    m = os.umask(0)
    os.umask(m)
    return m


# --- a run interrupted in a script keeps what it finished ------------------------------------------------------
def _suslov():
    from liefi.scenes import get

    return get("suslov").integrator()


RUN = dict(dt=1e-3, scheme="rk4", backend="numpy", progress=True, save_every=10)


def test_a_run_interrupted_keeps_its_finished_steps_on_the_interrupt_and_continues_from_them(monkeypatch):
    """Ctrl-C landing in ``FeedbackIntegrator.run``'s stepping loop (simulated at the third segment) propagates
    as the ``KeyboardInterrupt`` itself, which carries the saved states so far (``.solution``, status -1),
    the last finished state (``.t``, ``.y``) and says so; the states are those of the uninterrupted run, and a
    run continued from ``.y`` ends where the uninterrupted run ends (before: a bare KeyboardInterrupt, the
    finished part lost)."""
    from liefi.integrator import run as run_module

    fi, T = _suslov(), 2.0
    full = fi.run(T, **RUN)
    real = run_module.Progress
    calls = []

    class Cut(real):
        def update(self, n=1, **kw):
            super().update(n, **kw)
            calls.append(n)
            if len(calls) == 3:
                raise KeyboardInterrupt

    monkeypatch.setattr(run_module, "Progress", Cut)
    monkeypatch.setattr(run_module, "PROGRESS_SECONDS", 0.0)  # a run in segments of 1 % (as a long one is)
    with pytest.raises(KeyboardInterrupt) as info:
        fi.run(T, **RUN)
    monkeypatch.setattr(run_module, "Progress", real)
    exc = info.value
    assert type(exc) is KeyboardInterrupt  # not a subclass: an uncaught one still ends a script as SIGINT does
    part = exc.solution
    assert part.status == -1 and not part.success and "interrupted at t = " in part.message
    assert 0 < exc.t < T and exc.t_final == T and exc.t == pytest.approx(sum(calls) * RUN["dt"], rel=1e-12)
    assert part.t[-1] <= exc.t and part.t.size == int(exc.t / RUN["dt"]) // RUN["save_every"] + 1
    np.testing.assert_array_equal(part.t, full.t[: part.t.size])
    np.testing.assert_allclose(part.y, full.y[..., : part.t.size], rtol=1e-12, atol=1e-15)
    assert f"continue with fi.run(({exc.t:.17g}, 2), y0=exc.y" in str(exc) and ".solution" in str(exc)
    rest = fi.run((exc.t, T), y0=exc.y, **RUN)
    assert rest.t[-1] == pytest.approx(T, rel=1e-14)
    np.testing.assert_allclose(rest.y[..., -1], full.y[..., -1], rtol=1e-10, atol=1e-13)


SCRIPT = r"""
import json, signal, sys, time
signal.signal(signal.SIGINT, signal.default_int_handler)  # as from a terminal, even if the tests run with it ignored
import liefi._progress as progress
import liefi.integrator.run as run_module
from liefi.scenes import get

run_module.PROGRESS_SECONDS = 0.0  # a run in segments of 1 % of its steps, as a long one is

real = progress.Progress.update
def update(self, n=1, **kw):  # for the test: a marker file once the first segment of steps is done, then wait
    real(self, n, **kw)
    if not getattr(self, "marked", False):
        self.marked = True
        open(sys.argv[1], "w").close()
        time.sleep(120)  # the test's SIGINT lands here, inside the run's loop
progress.Progress.update = update
fi = get("suslov").integrator()
try:
    fi.run(20.0, dt=1e-3, scheme="rk4", backend="numpy", progress=True, save_every=100)
except KeyboardInterrupt as exc:
    print(json.dumps({"t": exc.t, "last": float(exc.solution.t[-1]), "n": int(exc.solution.t.size),
                      "status": exc.solution.status}), flush=True)
    raise
print("not interrupted")
"""


def test_ctrl_c_on_a_script_running_a_long_run_keeps_the_finished_part_and_ends_as_sigint(tmp_path, monkeypatch):
    """A real SIGINT on a script in the middle of a long run (sent once its first segment is done: a marker file,
    no timing): the script's ``except KeyboardInterrupt`` finds the finished part on the exception, and the
    uncaught interrupt ends the process as SIGINT does (return code -2, 130 in a shell), with the message that
    says where the run stopped as the traceback's last line."""
    import signal
    import subprocess
    import sys
    import time

    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    marker = tmp_path / "segment-done"
    p = subprocess.Popen([sys.executable, "-c", SCRIPT, str(marker)], cwd=root, stdout=subprocess.PIPE,
                         stderr=subprocess.PIPE, text=True,
                         env=dict(os.environ, PYTHONPATH=root))
    try:
        deadline = time.monotonic() + 300
        while not marker.exists() and p.poll() is None and time.monotonic() < deadline:
            time.sleep(0.1)
        assert marker.exists(), p.communicate(timeout=60)
        p.send_signal(signal.SIGINT)
        out, err = p.communicate(timeout=120)
    finally:
        p.kill()
        p.wait(timeout=60)
    got = json.loads(out.strip().splitlines()[-1])
    assert got["status"] == -1 and 0 < got["last"] <= got["t"] < 20.0 and got["n"] >= 1
    assert p.returncode == -signal.SIGINT
    assert err.strip().splitlines()[-1].startswith("KeyboardInterrupt: run interrupted at t = ")


def test_liefi_run_interrupted_in_its_steps_says_how_far_it_got_and_no_output_folder(capsys, monkeypatch):
    """``liefi run`` (no --out) stopped by Ctrl-C in its steps: 130 and one line saying where the run was, not
    "what finished is kept; see the command's output folder" (it has none)."""
    from liefi import cli
    from liefi.integrator import run as run_module

    real = run_module.Progress

    class Cut(real):
        def update(self, n=1, **kw):
            super().update(n, **kw)
            raise KeyboardInterrupt

    monkeypatch.setattr(run_module, "Progress", Cut)
    monkeypatch.setattr(run_module, "PROGRESS_SECONDS", 0.0)
    code = cli.main(["run", "suslov", "--t-final", "50", "--dt", "1e-3", "--scheme", "rk4", "--backend", "numpy"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 130 and len(err) == 1, err
    assert err[0].startswith("liefi: interrupted (the run had reached t = 0.5 of 50; nothing was written)"), err


def test_the_temporaries_of_a_killed_writer_are_found_and_removed(tmp_path):
    """A worker killed inside :func:`liefi._files.replacing` cannot remove its temporary file; its main process
    removes those of the killed pids (``reproduce``), and only those."""
    import subprocess
    import sys

    from liefi._files import remove_temporaries

    code = ("import os, sys; from liefi._files import replacing\n"
            "with replacing(os.path.join(sys.argv[1], 'fig.png')) as tmp:\n"
            "    open(tmp, 'wb').write(b'half'); print(os.getpid(), flush=True); os._exit(0)\n")
    root = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))
    p = subprocess.run([sys.executable, "-c", code, str(tmp_path)], cwd=root, timeout=120, capture_output=True,
                       text=True, env=dict(os.environ, PYTHONPATH=root))
    assert p.returncode == 0, p.stderr
    killed = int(p.stdout)
    (tmp_path / ".keep.json").write_text("{}")
    left = [f for f in os.listdir(tmp_path) if f != ".keep.json"]
    assert len(left) == 1 and left[0].startswith(".fig.png.") and left[0].endswith(".png")
    remove_temporaries(str(tmp_path), [os.getpid()])  # not the killed one's: kept
    assert len(os.listdir(tmp_path)) == 2
    remove_temporaries(str(tmp_path), [killed])
    assert os.listdir(tmp_path) == [".keep.json"]


def test_a_second_ctrl_c_during_the_clean_up_does_not_lose_the_summary(capsys, tmp_path, monkeypatch):
    """Ctrl-C pressed twice: the second lands while ``reproduce`` writes the summary of what finished (a real
    SIGINT to this process, sent from inside the clean-up: no timing).  The summary is still written and the
    one line says where (before: the second KeyboardInterrupt cut the clean-up short, the summary was lost and
    the line said only "see the command's output folder")."""
    import signal

    pytest.importorskip("matplotlib")
    from liefi import cli, reproduce

    def job(task):
        raise KeyboardInterrupt

    real = reproduce._write_summary
    sent = []

    def write_summary(*a, **k):
        if not sent:
            sent.append(True)
            os.kill(os.getpid(), signal.SIGINT)  # Python runs the handler at once, here
        return real(*a, **k)

    monkeypatch.setattr(reproduce, "_scene_job", job)
    monkeypatch.setattr(reproduce, "_write_summary", write_summary)
    d = tmp_path / "out"
    previous = signal.signal(signal.SIGINT, signal.default_int_handler)  # also when the tests run with it ignored
    try:
        code = cli.main(["reproduce", "--only", "knife-edge", "--out", str(d), "--jobs", "1"])
        after = signal.getsignal(signal.SIGINT)
    finally:
        signal.signal(signal.SIGINT, previous)
    err = capsys.readouterr().err.strip().splitlines()
    assert sent and code == 130
    assert err[-1] == f"liefi: interrupted (the summary of the 0 finished runs is in {d})", err
    assert json.loads((d / "summary.json").read_text())["interrupted"] is True
    assert after is signal.default_int_handler  # the handler is Python's again


def test_a_writable_file_in_a_folder_without_room_for_a_temporary_is_written_in_place(tmp_path, monkeypatch):
    """Where no new file may be created in the folder (but the output may be written: what ``probe_writable``
    checks before the work), the output is written in place as before, not refused after the work."""
    from liefi import _files

    path = tmp_path / "fig.png"
    path.write_bytes(b"old")
    real = os.open

    def no_new_files(name, flags, *a):
        if ".tmp" in os.path.basename(name):
            raise PermissionError(13, "Permission denied", name)
        return real(name, flags, *a)

    monkeypatch.setattr(os, "open", no_new_files)
    with _files.replacing(str(path)) as tmp:
        assert tmp == str(path)
        with open(tmp, "wb") as fh:
            fh.write(b"new")
    assert path.read_bytes() == b"new" and os.listdir(tmp_path) == ["fig.png"]
