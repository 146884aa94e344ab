r"""Progress on stderr for long work: one implementation for runs, sweeps, reproduce and maps.

``tqdm`` draws the bar when it is installed (the ``liefi[progress]`` extra); without
it one line is rewritten in place at most once a second.  Both show done/total, the
rate and an estimate of the time left.  Progress is shown only when stderr is a
terminal, unless forced with ``enabled=True``: output redirected to a file
(``liefi run --json > out.json``, CI logs) stays quiet -- except for work that
asks for ``lines=True`` (sweeps, ``liefi bench``): off a terminal it writes a
whole line (done/total, rate, time left) each time another 5 % is done (at most
once a second) or at least every 30 s while something finishes, and one at the end.

The time left is ``(total - done) / rate`` when every unit costs about the same
(the steps of a run).  Units of unequal cost (the tasks of ``liefi bench``: a
coarse compiled run takes milliseconds, a ``solve_ivp`` run at a tight tolerance
a minute) are given ``costs`` -- the expected seconds of each, a prior -- and
``kinds``.  The time left is then

.. math::  T_{left} = \frac{E}{S} \sum_{j\ \mathrm{open}} c_j r_{k(j)}, \qquad
           r_k = \frac{\sum_{i\ \mathrm{done},\ k(i) = k} s_i}{\sum_{i\ \mathrm{done},\ k(i) = k} c_i},

with ``s_i`` the measured seconds of the finished unit ``i``, ``c_i`` its prior,
``E`` the wall time elapsed and ``S = sum s_i`` (``E / S`` corrects for workers
in parallel and for the time between units); a kind with no finished unit yet
takes the rate of all finished units, and the line says that the estimate is a
guess until a unit of each kind has finished.  Nothing is estimated before the
first unit has finished.

**The first compile.**  The compiled engine traces and compiles a system's
kernels the first time they are needed (tens of seconds; later runs load them
from the cache).  The engine marks that work (:func:`compiling`); while a run
is prepared (:func:`compile_notice`, in :meth:`liefi.FeedbackIntegrator.run` and
:meth:`liefi.scenes.Scene.run`) a
compile that has lasted :data:`NOTICE_SECONDS` is announced by one line on
stderr, on a terminal or in a notebook; a run's progress starts after it.
"""

from __future__ import annotations

import contextlib
import math
import sys
import threading
import time

#: ``lines`` mode: a line when this fraction more is done, or after this many seconds
LINE_FRACTION, LINE_SECONDS, LINE_MIN_SECONDS = 0.05, 30.0, 1.0


#: A compile that lasts this long is announced (:func:`compile_notice`).
NOTICE_SECONDS = 1.0
#: The line that announces it.
COMPILE_MESSAGE = ("liefi: compiling the kernels for this system (first run only: later runs load them from the "
                   "cache; about 20 s)...")


def stderr_is_terminal():
    """Whether stderr is an interactive terminal (progress is shown only there by default)."""
    return sys.stderr is not None and hasattr(sys.stderr, "isatty") and sys.stderr.isatty()


def in_notebook():
    """Whether stderr is a Jupyter kernel's stream (a notebook shows what is written to it)."""
    return "ipykernel" in sys.modules and type(sys.stderr).__module__.startswith("ipykernel")


_COMPILE = {"depth": 0, "since": None, "watching": False}
_COMPILE_LOCK = threading.Lock()


@contextlib.contextmanager
def compiling():
    """Mark a block of the engine that traces or compiles a kernel (nested blocks count as one)."""
    with _COMPILE_LOCK:
        _COMPILE["depth"] += 1
        if _COMPILE["depth"] == 1:
            _COMPILE["since"] = time.monotonic()
    try:
        yield
    finally:
        with _COMPILE_LOCK:
            _COMPILE["depth"] -= 1
            if not _COMPILE["depth"]:
                _COMPILE["since"] = None


@contextlib.contextmanager
def compile_notice(message=COMPILE_MESSAGE, *, after=None, enabled=None):
    """While the block runs, say ``message`` once on stderr when a compile (:func:`compiling`) has lasted ``after`` s.

    ``after=None``: :data:`NOTICE_SECONDS`.  ``enabled=None``: when stderr is a terminal or a notebook's.  Nested blocks
    (the runs a run makes to choose its step) leave it to the outermost.  A
    watcher thread looks every 0.1 s; nothing is written when no compile
    happens, or when it is short (kernels loaded from the cache).
    """
    on = (stderr_is_terminal() or in_notebook()) if enabled is None else bool(enabled)
    after = NOTICE_SECONDS if after is None else float(after)
    with _COMPILE_LOCK:
        mine = on and not _COMPILE["watching"]
        if mine:
            _COMPILE["watching"] = True
    if not mine:
        yield
        return
    stop = threading.Event()

    def watch():
        while not stop.wait(0.1):
            since = _COMPILE["since"]
            if since is not None and time.monotonic() - since >= after:
                if sys.stderr is not None:
                    sys.stderr.write(message + "\n")
                    sys.stderr.flush()
                return

    watcher = threading.Thread(target=watch, name="liefi-compile-notice", daemon=True)
    watcher.start()
    try:
        yield
    finally:
        stop.set()
        with _COMPILE_LOCK:
            _COMPILE["watching"] = False


class Progress:
    """A progress display over ``total`` units of work.

    Parameters
    ----------
    total : int
    desc : str
        What is being done (``"liefi rk4"``, ``"sweep suslov"``).
    enabled : bool or None
        ``None``: shown when stderr is a terminal and there is more than one unit.
    unit : str
        The unit counted (``"step"``, ``"task"``, ``"run"``).
    lines : bool
        With ``enabled=None`` and stderr not a terminal: periodic whole lines
        instead of silence (see the module docstring).
    initial : int
        Units already done before this display started (a resumed sweep): counted
        in done/total, not in the rate.
    costs : sequence of float, optional
        The expected seconds of each unit (any common scale): the time left is
        weighted by them (module docstring); :meth:`update` then names the unit
        done (``index``) and its measured ``seconds``.
    kinds : sequence, optional
        With ``costs``: the kind of each unit (e.g. a method); the rate of a kind
        is learned from its own finished units.
    todo : iterable of int, optional
        With ``costs``: the indices of the units still to do (default: all).
    """

    def __init__(self, total, desc, enabled=None, unit="step", *, lines=False, initial=0, costs=None, kinds=None,
                 todo=None):
        self.lines = False
        if enabled is None:
            enabled = total > 1 and stderr_is_terminal()
            self.lines = bool(lines) and total > 0 and not enabled
        self.total, self.desc, self.unit, self.enabled = int(total), desc, unit, bool(enabled) or self.lines
        self.done, self.failed, self.bar, self._last = int(initial), 0, None, 0.0
        self._start, self._initial, self._line_done = time.monotonic(), int(initial), int(initial)
        if self.lines:
            self._last = self._start  # the first line after 5 % or 30 s, not at the first unit
        self.costs = None if costs is None else [float(c) for c in costs]
        if self.costs is not None:
            self.kinds = [None] * len(self.costs) if kinds is None else list(kinds)
            self._open = set(range(len(self.costs)) if todo is None else todo)
            self._spent = {}  # kind -> [measured seconds, prior seconds] of its finished units
        if not self.enabled or self.lines or self.costs is not None:  # tqdm's estimate is by count
            return
        try:
            from tqdm import tqdm

            self.bar = tqdm(total=self.total, desc=desc, unit=unit, unit_scale=unit == "step", leave=False,
                            file=sys.stderr, initial=int(initial))
        except ImportError:
            pass

    def status(self):
        """``"DESC: done/total units (P %)[, F failed], R units/s, about T left"``: the line shown."""
        fail = f", {self.failed} failed" if self.failed else ""
        pct = 100 * self.done / max(self.total, 1)
        text = f"{self.desc}: {self.done}/{self.total} {self.unit}s ({pct:.0f} %){fail}"
        elapsed = time.monotonic() - self._start
        new = self.done - self._initial
        if new > 0 and elapsed > 0:
            rate = new / elapsed
            text += f", {rate:.3g} {self.unit}s/s" if rate >= 1 else f", {1 / rate:.3g} s/{self.unit}"
            if self.done >= self.total:
                text += f", {duration(elapsed)} in all"
            elif self.costs is None:
                text += f", about {duration(max(self.total - self.done, 0) / rate)} left"
            else:
                left = self.time_left(elapsed)
                if left is not None:
                    text += f", about {duration(left[0])} left"
                    if left[1]:
                        text += f" (a guess: {left[1]} {self.unit}s of kinds not timed yet)"
        return text

    def time_left(self, elapsed=None):
        """``(seconds, n_unseen)``: the time left weighted by ``costs`` (module docstring), or ``None``.

        ``n_unseen``: open units of a kind none of whose units has finished (their rate is the overall
        one).  ``None`` without ``costs`` or before a unit with a measured time has finished.
        """
        if self.costs is None:
            return None
        elapsed = time.monotonic() - self._start if elapsed is None else elapsed
        spent = sum(s for s, _ in self._spent.values())
        prior = sum(c for _, c in self._spent.values())
        if not (spent > 0 and prior > 0):
            return None
        overall, total, unseen = spent / prior, 0.0, 0
        for j in self._open:
            s, c = self._spent.get(self.kinds[j], (0.0, 0.0))
            if c > 0:
                total += self.costs[j] * s / c
            else:
                total += self.costs[j] * overall
                unseen += 1
        return total * elapsed / spent, unseen

    def update(self, n=1, *, failed=False, index=None, seconds=None):
        """``n`` more units done (``failed``: one of them failed, counted in the line).

        With ``costs``: ``index`` names the unit done and ``seconds`` its measured time.
        """
        self.done += n
        self.failed += bool(failed)
        if self.costs is not None and index is not None and index in self._open:
            self._open.discard(index)
            if seconds is not None and math.isfinite(seconds):
                got = self._spent.setdefault(self.kinds[index], [0.0, 0.0])
                got[0] += max(float(seconds), 0.0)
                got[1] += self.costs[index]
        if not self.enabled:
            return
        if self.bar is not None:
            self.bar.update(n)
            if failed:
                self.bar.set_postfix(failed=self.failed)
        elif self.lines:
            now = time.monotonic()
            more = (self.done - self._line_done) / max(self.total, 1)
            if self.done >= self.total or (more >= LINE_FRACTION and now - self._last >= LINE_MIN_SECONDS) \
                    or (self.done > self._line_done and now - self._last >= LINE_SECONDS):
                self._last, self._line_done = now, self.done
                sys.stderr.write(self.status() + "\n")
                sys.stderr.flush()
        elif time.monotonic() - self._last > 1.0 or self.done >= self.total:
            self._last = time.monotonic()
            sys.stderr.write(f"\r{self.status()}\033[K")
            sys.stderr.flush()

    def close(self):
        if not self.enabled:
            return
        if self.bar is not None:
            self.bar.close()
        elif self.done and not self.lines:
            sys.stderr.write("\n")
            sys.stderr.flush()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()


def duration(seconds):
    """``"42 s"``, ``"3 min 5 s"``, ``"1 h 20 min"``: a time for a person."""
    s = int(round(seconds))
    if s < 60:
        return f"{max(s, 0)} s"
    if s < 3600:
        return f"{s // 60} min {s % 60} s"
    return f"{s // 3600} h {s % 3600 // 60} min"
