"""One progress display for runs, sweeps, reproduce and the stability maps (liefi._progress)."""

from __future__ import annotations

import io
import sys

import pytest

from liefi import _progress
from liefi._progress import Progress


class _Tty(io.StringIO):
    def isatty(self):
        return True


@pytest.fixture
def no_tqdm(monkeypatch):
    monkeypatch.setitem(sys.modules, "tqdm", None)  # import tqdm -> ImportError: the plain line


def test_quiet_when_stderr_is_not_a_terminal(monkeypatch):
    err = io.StringIO()
    monkeypatch.setattr(sys, "stderr", err)
    with Progress(10, "sweep", unit="task") as bar:
        for _ in range(10):
            bar.update()
    assert bar.done == 10 and not bar.enabled
    assert err.getvalue() == ""


def test_plain_line_on_a_terminal_without_tqdm(monkeypatch, no_tqdm):
    err = _Tty()
    monkeypatch.setattr(sys, "stderr", err)
    assert _progress.stderr_is_terminal()
    with Progress(3, "reproduce", unit="scene") as bar:
        bar.update()
        bar.update(failed=True)
        bar.update()
    text = err.getvalue()
    assert "reproduce: 3/3 scenes (100 %), 1 failed" in text
    assert text.endswith("\n")


def test_forced_on_and_off(monkeypatch, no_tqdm):
    err = io.StringIO()
    monkeypatch.setattr(sys, "stderr", err)
    Progress(2, "liefi rk4", enabled=True).update(2)
    assert "liefi rk4: 2/2 steps" in err.getvalue()
    err2 = _Tty()
    monkeypatch.setattr(sys, "stderr", err2)
    Progress(2, "liefi rk4", enabled=False).update(2)
    assert err2.getvalue() == ""
