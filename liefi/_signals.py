"""SIGTERM handled as SIGINT: one way to stop liefi's long commands cleanly.

``timeout``, ``kill``, Slurm and ``docker stop`` send ``SIGTERM``.  Inside
:func:`terminate_as_interrupt` it raises :class:`Terminated`, a
``KeyboardInterrupt``, so every path that handles Ctrl-C (stopping a worker
pool, writing the summary of what finished) handles it the same way; the
command then exits with ``128 + signal number`` (130 for SIGINT, 143 for
SIGTERM), the shell's convention.

``SIGHUP`` (the terminal or the ssh session closed) is handled as ``SIGTERM``
(:data:`TERMINATING`; exit code 129): what finished is kept and summarized, as
for ``SIGTERM``.  Under ``nohup`` (``SIGHUP`` ignored from the start) it stays ignored.

Worker processes ignore these signals (:func:`ignore_in_worker`, their pool's
initializer): the main process receives them, stops its workers itself and
reports; a signal sent to the whole process group (Slurm does, a closed terminal
does) does not kill a worker in the middle of handing back a result.  A worker
whose main process has gone anyway (``kill -9``, the OOM killer) ends itself
within a second (:func:`ignore_in_worker`'s watch), rather than running on, or
waiting for ever, without it.

The clean-up after an interrupt (stopping the workers, writing the summary of
what finished) runs under :func:`shielded`: Ctrl-C pressed twice does not cut it
short and lose the summary; the second signal is noted, and the process ends
:data:`GRACE` seconds later if the clean-up still runs.

An interrupt must end the process wherever it lands:

* **before and after the command** (``liefi`` still importing numpy and scipy, or the
  output already written): :func:`install_for_command`, called first thing in
  ``liefi/__init__.py`` in the ``liefi`` process only, makes SIGINT and SIGTERM end the
  process at once with one line and 130 / 143 (standard output flushed: what was
  printed is kept);
* **in a callback from C** (numba's compiler calls back into Python from LLVM): Python
  drops an exception raised there ("Exception ignored on calling ctypes callback
  function") and the run went on and exited 0.  Inside :func:`terminate_as_interrupt`
  such a dropped interrupt is caught by ``sys.unraisablehook``: it is raised again in
  the main thread, and if the process still runs :data:`GRACE` seconds later it ends
  there with the one line and its code (:func:`end_within_grace`), as ``kill -9`` would,
  which the kernel cache and the result store survive.  A compile holds the signal
  instead (:func:`liefi.engine.runners.interrupts_held`), under the same deadline.
"""

from __future__ import annotations

import contextlib
import os
import signal
import sys
import threading

#: the signals handled as ``SIGTERM`` (:class:`Terminated`): ``SIGTERM`` and, where it exists, ``SIGHUP``
TERMINATING = tuple(getattr(signal, n) for n in ("SIGTERM", "SIGHUP") if hasattr(signal, n))

#: seconds an interrupt that could not be raised (held during a compile, or dropped in a callback from
#: C) leaves the process to stop cleanly before it is ended anyway (:func:`end_within_grace`)
GRACE = 2.0


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


def _say(signum, detail=""):
    """Write ``liefi: interrupted`` / ``liefi: terminated by SIGTERM`` (and ``detail``) on stderr, unbuffered."""
    words = "interrupted" if signum == signal.SIGINT else f"terminated by {signal_name(signum)}"
    try:
        os.write(2, f"liefi: {words}{detail}\n".encode())
    except OSError:  # pragma: no cover - stderr closed
        pass


def exit_now(signum, frame=None):
    """End the process at once: standard output flushed, one line on stderr, ``128 + signum``.

    The handler of SIGINT and SIGTERM in the ``liefi`` process outside the command (while
    it imports, after it returned): nothing is running that a clean-up could save."""
    try:
        sys.stdout.flush()
    except BaseException:  # noqa: BLE001 -- e.g. the signal landed inside a write to stdout
        pass
    _say(signum)
    os._exit(128 + int(signum))


def is_command_process(argv=None, orig_argv=None):
    """True in the ``liefi`` command's process: its console script (``sys.argv[0]`` named
    ``liefi``) or ``python [options] -m liefi`` (``sys.orig_argv``)."""
    argv = sys.argv if argv is None else argv
    if argv and os.path.splitext(os.path.basename(str(argv[0])))[0] in ("liefi", "liefi-script"):
        return True
    orig = list(getattr(sys, "orig_argv", ()) if orig_argv is None else orig_argv)
    i = 1
    while i < len(orig):
        a = orig[i]
        if a == "-m":
            return orig[i + 1:i + 2] == ["liefi"]
        if a.startswith("-m"):
            return a[2:] == "liefi"
        if a in ("-W", "-X"):
            i += 2
            continue
        if a == "-c" or not a.startswith("-"):
            return False
        i += 1
    return False


def install_for_command():
    """In the ``liefi`` process (:func:`is_command_process`): SIGINT and SIGTERM end it at once
    (:func:`exit_now`) until the command installs its own handling.  Called first thing in
    ``liefi/__init__.py``, before numpy and scipy are imported; a signal the process was started
    to ignore (``nohup``, a background job) stays ignored.  Elsewhere (a library user's process)
    nothing is changed."""
    if not is_command_process() or threading.current_thread() is not threading.main_thread():
        return
    mp = sys.modules.get("multiprocessing")
    if mp is not None and mp.parent_process() is not None:  # a worker (spawned with the command's argv)
        return
    try:
        if signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            signal.signal(signal.SIGINT, exit_now)
        for s in TERMINATING:
            if signal.getsignal(s) == signal.SIG_DFL:
                signal.signal(s, exit_now)
    except (ValueError, OSError):  # pragma: no cover - not settable here
        return
    import atexit

    atexit.register(_end_with_status)  # registered first: runs after every other exit handler
    _Deadline.allowed = True


#: the exit status the ``liefi`` command returned (:func:`command_returned`), ``None`` while it runs
_status = []


def command_returned(code):
    """Note the command's exit status ``code`` (returned by :func:`liefi.cli.main`); returns it."""
    _status[:] = [code]
    return code


def _end_with_status():
    """The last exit handler of the ``liefi`` process: once the command has returned, flush the
    standard streams and leave with its status, without the interpreter's finalization, during
    which Python resets the signal handlers and a Ctrl-C would kill the process with no word
    (``-2``) after its output was complete."""
    if not _status or not isinstance(_status[0], int):
        return
    for f in (sys.stdout, sys.stderr):
        try:
            f.flush()
        except BaseException:  # noqa: BLE001 -- a closed pipe: the status still stands
            pass
    os._exit(_status[0])


class _Deadline:
    """The one pending deadline of an interrupt that could not be raised (:func:`end_within_grace`);
    ``allowed`` in the ``liefi`` process only (:func:`install_for_command`): a notebook or a test
    session calling liefi is never ended by it."""

    timer = None
    signum = None
    allowed = False


def end_within_grace(signum, grace=None):
    """End the process ``grace`` seconds (:data:`GRACE`) from now with the one line and
    ``128 + signum`` unless it has ended by then or :func:`cancel_deadline` is called.

    For an interrupt that could not be raised where it landed (held during a compile, dropped
    in a callback from C): the clean path gets the grace, the deadline holds either way.  Only in
    the ``liefi`` process (elsewhere nothing happens: the interrupt is raised when it can be)."""
    if _Deadline.timer is not None or not _Deadline.allowed:
        return
    _Deadline.signum = int(signum)

    def end():
        _say(signum, f" (the run did not stop within {GRACE if grace is None else grace:g} s: ended)")
        os._exit(128 + int(signum))

    t = threading.Timer(GRACE if grace is None else grace, end)
    t.daemon = True
    _Deadline.timer = t
    t.start()


def cancel_deadline():
    """Cancel the deadline of :func:`end_within_grace` (the interrupt was raised after all)."""
    t, _Deadline.timer = _Deadline.timer, None
    if t is not None:
        t.cancel()


def _reraise_later(signum):
    """Raise the interrupt ``signum`` again in the main thread, from another thread (not from
    inside the hook that saw it dropped)."""
    import _thread

    def again():
        try:
            _thread.interrupt_main(signum)
        except (ValueError, OSError, TypeError):  # pragma: no cover - not handled by Python
            pass

    t = threading.Timer(0.01, again)
    t.daemon = True
    t.start()


#: the SIGTERMs received under :func:`terminate_as_interrupt` (shared by nested blocks); emptied when an
#: interrupt is found dropped, so that it is raised again
_received = []


def _handler(signum, frame):
    if _received:  # already stopping: let the clean-up finish
        return
    _received.append(signum)
    raise Terminated(signum)


_handler.liefi = True  # recognised by interrupts_held


def _dropped_interrupts(previous):
    """A ``sys.unraisablehook`` that raises a dropped ``KeyboardInterrupt`` again (and sets its deadline)
    instead of printing "Exception ignored ..."; anything else goes to ``previous``."""

    def hook(unraisable):
        signum = None
        for _ in range(3):  # the interrupt raised again can land in this very hook: caught here too
            try:
                if signum is None:
                    exc = unraisable.exc_value
                    if not isinstance(exc, KeyboardInterrupt):
                        break
                    signum = signum_of(exc)
                _received.clear()
                end_within_grace(signum)
                _reraise_later(signum)
                return
            except KeyboardInterrupt as again:
                signum = signum_of(again)
        if signum is None:
            previous(unraisable)

    return hook


@contextlib.contextmanager
def terminate_as_interrupt():
    """Within the block, ``SIGTERM`` (and ``SIGHUP``: :data:`TERMINATING`, unless ignored from the start)
    raises :class:`Terminated` in the main thread (once: a second one during the clean-up is ignored,
    ``SIGKILL`` still ends the process), and an interrupt
    dropped in a callback from C is raised again, the process ended :data:`GRACE` seconds later if
    it still runs.  In the ``liefi`` process SIGINT raises ``KeyboardInterrupt`` within the block
    (:func:`install_for_command` made it end the process at once before).  Outside the main
    thread, or where signals cannot be set, the block runs unchanged."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    try:
        previous = signal.signal(signal.SIGTERM, _handler)
        others = {s: signal.getsignal(s) for s in TERMINATING if s != signal.SIGTERM}
        for s, h in others.items():
            if h != signal.SIG_IGN:  # nohup: stays ignored
                signal.signal(s, _handler)
    except (ValueError, OSError):  # pragma: no cover - not settable here
        yield
        return
    outer = previous is not _handler
    previous_int = signal.getsignal(signal.SIGINT)
    if previous_int is exit_now:
        signal.signal(signal.SIGINT, signal.default_int_handler)
    previous_hook = sys.unraisablehook
    sys.unraisablehook = _dropped_interrupts(previous_hook)
    try:
        yield
    except KeyboardInterrupt:
        if outer:
            cancel_deadline()  # raised after all: its handlers report it
        raise
    finally:
        sys.unraisablehook = previous_hook
        if previous_int is exit_now:
            signal.signal(signal.SIGINT, exit_now)
        signal.signal(signal.SIGTERM, signal.SIG_DFL if previous is None else previous)
        for s, h in others.items():
            signal.signal(s, signal.SIG_DFL if h is None else h)
        if outer:
            _received.clear()
    if outer and _Deadline.timer is not None:  # dropped and never raised again (swallowed twice): now
        signum = _Deadline.signum
        cancel_deadline()
        raise Terminated(signum) if signum != signal.SIGINT else KeyboardInterrupt()


@contextlib.contextmanager
def shielded():
    """The clean-up after an interrupt (stopping the workers, writing the summary of what finished): within
    the block, a further Ctrl-C, ``SIGTERM`` or ``SIGHUP`` does not raise -- it would cut the clean-up short
    and lose the summary -- but is noted (the list yielded), and in the ``liefi`` process the process ends
    :data:`GRACE` seconds after it if the block still runs (:func:`end_within_grace`): a second Ctrl-C still
    ends a clean-up that hangs.  Main thread only; elsewhere the block runs unchanged."""
    got = []
    if threading.current_thread() is not threading.main_thread():
        yield got
        return
    mine = []

    def note(signum, frame):
        got.append(signum)
        if _Deadline.timer is None and _Deadline.allowed:
            mine.append(signum)
            end_within_grace(signum)

    saved = {}
    try:
        for s in (signal.SIGINT,) + TERMINATING:
            h = signal.getsignal(s)
            if h not in (signal.SIG_IGN, None):
                saved[s] = signal.signal(s, note)
    except (ValueError, OSError):  # pragma: no cover - not settable here
        pass
    try:
        yield got
    finally:
        for s, h in saved.items():
            signal.signal(s, h)
        if mine:
            cancel_deadline()


def ignore_in_worker(parent=None):
    """Initializer of worker processes: ignore ``SIGINT``, ``SIGTERM`` and ``SIGHUP`` (the main process stops
    them), and end this worker within :data:`WATCH` seconds once its main process ``parent`` (a pid; default
    the parent at start) is gone: killed with ``SIGKILL``, it cannot stop its workers, which ignore the
    signals that would end them and would run on (writing into its output folder) or wait for tasks for ever.
    The watch is a daemon thread reading ``os.getppid()``; compiled code that holds the GIL delays it to the
    end of its segment of steps."""
    parent = os.getppid() if parent is None else int(parent)
    for s in (signal.SIGINT,) + TERMINATING:
        signal.signal(s, signal.SIG_IGN)

    def watch():
        import time

        while os.getppid() == parent:
            time.sleep(WATCH)
        os._exit(128 + int(getattr(signal, "SIGHUP", 1)))  # the main process has gone: nobody to report to

    threading.Thread(target=watch, name="liefi-parent-watch", daemon=True).start()


#: seconds between two looks of a worker at its main process (:func:`ignore_in_worker`)
WATCH = 0.5
