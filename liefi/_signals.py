"""SIGTERM handled as SIGINT: one way to stop liefi's long commands cleanly.

``timeout``, ``kill``, Slurm and ``docker stop`` send ``SIGTERM``.  Inside
:func:`terminate_as_interrupt` it raises :class:`Terminated`, a
``KeyboardInterrupt``, so every path that handles Ctrl-C (stopping a worker
pool, writing the summary of what finished) handles it the same way; the
command then exits with ``128 + signal number`` (130 for SIGINT, 143 for
SIGTERM), the shell's convention.

Worker processes ignore both signals (:func:`ignore_in_worker`, their pool's
initializer): the main process receives them, stops its workers itself and
reports; a signal sent to the whole process group (Slurm does) does not kill a
worker in the middle of handing back a result.
"""

from __future__ import annotations

import contextlib
import signal
import threading


class Terminated(KeyboardInterrupt):
    """``SIGTERM`` (or another terminating signal) received: handled as Ctrl-C.  ``signum`` is the signal."""

    def __init__(self, signum=signal.SIGTERM):
        super().__init__(f"terminated by {signal_name(signum)}")
        self.signum = int(signum)


def signal_name(signum):
    """``"SIGTERM"`` for 15, ..."""
    try:
        return signal.Signals(signum).name
    except ValueError:
        return f"signal {signum}"


def signum_of(exc):
    """The signal behind a ``KeyboardInterrupt``: its ``signum`` (SIGINT for a plain Ctrl-C)."""
    return int(getattr(exc, "signum", None) or signal.SIGINT)


def exit_code(exc):
    """The exit code after the interrupt ``exc``: ``128 + signal number`` (130: SIGINT, 143: SIGTERM)."""
    return 128 + signum_of(exc)


def describe(exc):
    """``"interrupted"`` (Ctrl-C) or ``"terminated by SIGTERM"``: the first words of the one line printed."""
    s = signum_of(exc)
    return "interrupted" if s == signal.SIGINT else f"terminated by {signal_name(s)}"


@contextlib.contextmanager
def terminate_as_interrupt():
    """Within the block, ``SIGTERM`` raises :class:`Terminated` in the main thread (once: a second
    SIGTERM during the clean-up is ignored, ``SIGKILL`` still ends the process).  Outside the main
    thread, or where signals cannot be set, the block runs unchanged."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    received = []

    def handler(signum, frame):
        if received:  # already stopping: let the clean-up finish
            return
        received.append(signum)
        raise Terminated(signum)

    try:
        previous = signal.signal(signal.SIGTERM, handler)
    except (ValueError, OSError):  # pragma: no cover - not settable here
        yield
        return
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)


def ignore_in_worker():
    """Initializer of worker processes: ignore ``SIGINT`` and ``SIGTERM`` (the main process stops them)."""
    signal.signal(signal.SIGINT, signal.SIG_IGN)
    signal.signal(signal.SIGTERM, signal.SIG_IGN)
