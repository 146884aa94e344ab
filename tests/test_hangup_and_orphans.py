"""SIGHUP (a closed terminal or ssh session) and a main process killed outright, on commands with workers.

* ``SIGHUP`` to the whole process group (what a closed terminal sends) on ``liefi reproduce --jobs 2`` is
  handled as ``SIGTERM``: exit 129, one line, the summary of what finished, no worker left (before: the
  main process died at once with no summary, its workers died or ran on);
* ``kill -9`` of the main process: its workers, which ignore the signals that would end them, end
  themselves within seconds (before: they ran on, writing into the output folder, then waited for ever).

Real processes, each step waited for by a marker (a file, a line), every wait bounded.
"""

from __future__ import annotations

import json
import os
import signal
import time

import pytest

from test_signals_and_store import _finish, _group, _start, _wait_for, needs_proc

def _as_from_a_terminal():
    """In the child before exec: the default actions of the signals a terminal sends, even if the tests run
    under ``nohup`` or as a background job (which start with them ignored, and liefi keeps them so)."""
    for s in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
        signal.signal(s, signal.SIG_DFL)


ONLY = ["--t-final-scale", "0.02", "--jobs", "2", "--only", "suslov,chaplygin,knife-edge,heisenberg,vertical-disk"]


@needs_proc
@pytest.mark.skipif(not hasattr(signal, "SIGHUP"), reason="no SIGHUP here")
def test_sighup_to_the_group_on_reproduce_is_handled_as_sigterm(tmp_path):
    pytest.importorskip("matplotlib")
    d = tmp_path / "out"
    p = _start(["reproduce", "--out", str(d), *ONLY], tmp_path, preexec_fn=_as_from_a_terminal)
    assert _wait_for(lambda: (d / "summary.json").exists(), p), (tmp_path / "stderr.txt").read_text()
    assert [q for q in _group(p.pid) if q != p.pid], "reproduce --jobs 2 should run in worker processes"
    os.killpg(p.pid, signal.SIGHUP)  # the terminal closed: every process of the group gets it
    code, stdout, stderr, survivors = _finish(p, tmp_path)
    assert code == 128 + signal.SIGHUP, stderr
    assert "Traceback" not in stderr and "KeyboardInterrupt" not in stderr, stderr
    said = [ln for ln in stderr.splitlines() if "terminated" in ln or "interrupted" in ln]
    assert len(said) == 1 and said[0].startswith("liefi: terminated by SIGHUP (the summary of the "), stderr
    assert survivors == [], f"worker processes left running: {survivors}"
    summary = json.loads((d / "summary.json").read_text())
    assert summary["interrupted"] is True and summary["not_run"]
    assert f"the summary of the {len(summary['runs'])} finished runs" in said[0]
    assert all((d / f).exists() for f in summary["figures"])


@needs_proc
def test_workers_end_when_their_main_process_is_killed(tmp_path):
    d = tmp_path / "out"
    p = _start(["reproduce", "--out", str(d), *ONLY], tmp_path)
    err = tmp_path / "stderr.txt"
    assert _wait_for(lambda: " ..." in err.read_text() and len(_group(p.pid)) >= 3, p), err.read_text()
    os.kill(p.pid, signal.SIGKILL)  # no clean-up possible: only the workers themselves can notice
    p.wait(timeout=60)
    deadline = time.time() + 60
    while _group(p.pid) and time.time() < deadline:
        time.sleep(0.2)
    survivors = _group(p.pid)
    for pid in survivors:  # do not leave them behind even when the test fails
        os.kill(pid, signal.SIGKILL)
    assert survivors == [], f"worker processes left running after their main process was killed: {survivors}"
