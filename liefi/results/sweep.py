"""Embarrassingly parallel sweeps that keep every result, over any :class:`concurrent.futures.Executor`.

Work-precision grids (:mod:`liefi.bench`), stability maps and ensembles are
lists of independent tasks.  :func:`run_sweep` maps a function over them:

* with no executor, in this process, one after the other (the default, and the
  reference: every other executor must give the same results);
* with any :class:`concurrent.futures.Executor` -- a
  :class:`~concurrent.futures.ProcessPoolExecutor` to use every core of this
  machine, or Dask's distributed scheduler (``Client.get_executor()``, the
  optional extra ``liefi[dask]``) to use a cluster.

Nothing is lost
---------------
* **Every task's outcome is a value.**  An exception raised by the function is
  caught where it was raised (in the worker) and comes back as a
  :class:`TaskError` -- its type name, message and traceback text, all plain
  strings, so it pickles whatever the exception was.  So does a result that
  cannot be sent back, a task whose worker died, or a Dask ``KilledWorker``.
  One failing task never costs the others.
* **A dead worker** (a :class:`~concurrent.futures.process.BrokenProcessPool`:
  a worker killed by a signal, ``os._exit``, the out-of-memory killer) breaks a
  process pool and every task in flight with it.  :func:`run_sweep` then starts
  a fresh pool, re-runs the tasks that were in flight *one at a time* (so that
  the one that kills its worker is found and marked ``TaskError("WorkerDied")``
  while the innocent ones finish), and goes on in parallel with the rest.
  Only ``max_in_flight`` tasks (the pool's worker count) are submitted at a
  time, so a break costs at most that many re-runs.
* **Results go to disk as they arrive** when a :class:`ResultStore` (SQLite,
  from the standard library) is given: one row per finished task, committed at
  once.  A rerun with the same store skips the tasks already done (a task is
  identified by its JSON text) and re-runs those that ended in a
  :class:`TaskError`.
* **Ctrl-C** (``SIGINT``), or ``SIGTERM`` where :func:`liefi._signals.terminate_as_interrupt`
  turns it into a ``KeyboardInterrupt`` (the ``liefi`` commands do), stops the
  sweep: the tasks not started are cancelled, the workers of a process pool are
  killed and joined, and :class:`SweepInterrupted` (a ``KeyboardInterrupt``) is
  raised carrying every result finished so far.  With a store, those results are
  read back from the store, so they are exactly what it holds (a task committed
  just before the signal is counted).  Workers of the pools made by
  :func:`open_executor` ignore ``SIGINT`` and ``SIGTERM``: the interrupt is the
  main process's to handle.
* **A store that cannot be written** (disk full, file size limit) or read
  (damaged, another program's file) raises :class:`StoreError`, an ``OSError``
  naming the file and what to do; in :func:`run_sweep` it stops the workers the
  same way and carries the results finished so far (``exc.results``).

The function must be picklable (a module-level function) and the tasks plain
data (scene names, numbers, dicts: JSON-serializable when a store is used),
because executors other than the default send them to other processes or
machines.  Results come back in the order of the tasks.

:func:`open_executor` turns a command-line ``--scheduler`` string into an
executor: ``serial``, ``processes[:N]``, ``threads[:N]``, ``dask[:N]`` (a Dask
``LocalCluster`` of N workers on this machine) or a Dask scheduler address
``tcp://host:8786``.

Querying a store
----------------
The store is one SQLite table ``results`` (``key``, ``sweep``, ``idx``,
``task``, ``status`` = ``done`` | ``error``, ``error_type``, ``message``,
``traceback``, ``value``, ``seconds``, ``finished_at``); ``task`` and ``value``
are JSON text, so for instance::

    sqlite3 results.sqlite "select json_extract(value, '$.method'), json_extract(value, '$.max_drift')
                            from results where status = 'done'"

Example
-------
>>> from liefi.results.sweep import run_sweep
>>> run_sweep(abs, [-1, 2, -3])
[1, 2, 3]
"""

from __future__ import annotations

import contextlib
import dataclasses
import json
import os
import signal
import sqlite3
import time
import traceback as _traceback
from concurrent.futures import FIRST_COMPLETED, Executor, wait

from .._json import plain as _plain
from .._progress import Progress
from .._signals import ignore_in_worker, shielded, signum_of

__all__ = ["run_sweep", "open_executor", "TaskError", "SweepInterrupted", "ResultStore", "StoreError", "task_key"]


@dataclasses.dataclass(frozen=True)
class TaskError:
    """A task that raised (or whose worker died): a value, never an exception.

    ``type`` is the exception's class name (``"WorkerDied"`` for a dead worker),
    ``message`` its text, ``traceback`` the formatted traceback (where the task
    raised; empty when the worker died).  Plain strings: it pickles, and it
    round-trips through a :class:`ResultStore`.
    """

    type: str
    message: str
    traceback: str = ""

    @classmethod
    def from_exception(cls, exc):
        tb = "".join(_traceback.format_exception(type(exc), exc, exc.__traceback__))
        return cls(type(exc).__name__, " ".join(str(exc).split()) or type(exc).__name__, tb)

    def __str__(self):
        return f"{self.type}: {self.message}"


class SweepInterrupted(KeyboardInterrupt):
    """Ctrl-C (or SIGTERM) during :func:`run_sweep`.  ``results`` holds, in task order, each
    finished task's value and ``None`` for the others; ``done`` counts the finished ones;
    ``signum`` is the signal (``SIGINT`` for Ctrl-C)."""

    def __init__(self, results, signum=signal.SIGINT):
        super().__init__("sweep interrupted")
        self.results = results
        self.done = sum(r is not None for r in results)
        self.signum = int(signum)


class StoreError(OSError):
    """A :class:`ResultStore` that cannot be used: not a results store, damaged, or not writable
    (disk full).  The message names the file and what to do.  Raised by :func:`run_sweep`, it
    carries ``results`` (as :class:`SweepInterrupted` does): what finished, all of it stored."""

    results = None


def _call(fn, task):
    """Run ``fn(task)`` in a worker; an exception becomes a :class:`TaskError` value here."""
    try:
        return fn(task)
    except Exception as exc:  # noqa: BLE001 -- every failure is a value of the sweep
        return TaskError.from_exception(exc)


def task_key(task):
    """The identity of a task in a store: its JSON text with sorted keys."""
    try:
        return json.dumps(_plain(task), sort_keys=True)
    except TypeError as exc:
        raise TypeError(f"tasks: a task stored in a ResultStore must be JSON-serializable ({exc})") from None


class ResultStore:
    """An append-only SQLite file of task results (see the module docstring).

    ``ResultStore(path)`` opens (or creates) the file.  :meth:`get` returns the
    finished value of a task (``None`` if not done); :meth:`put` records one
    outcome and commits at once, so a crash or an interrupt loses nothing that
    finished.  Values must be JSON-serializable (numpy arrays and scalars are
    converted); a :class:`TaskError` is stored in its own columns.
    ``sweep`` names a group of tasks within one file (for instance a scene).
    """

    SCHEMA = (
        "CREATE TABLE IF NOT EXISTS results (key TEXT PRIMARY KEY, sweep TEXT, idx INTEGER, task TEXT, "
        "status TEXT, error_type TEXT, message TEXT, traceback TEXT, value TEXT, seconds REAL, finished_at REAL)"
    )
    COLUMNS = ("key", "sweep", "idx", "task", "status", "error_type", "message", "traceback", "value", "seconds",
               "finished_at")

    def __init__(self, path, sweep=""):
        self.path = os.fspath(path)
        self.sweep = sweep
        self._db = None
        try:
            self._db = sqlite3.connect(self.path, timeout=30)
            tables = sorted(r[0] for r in self._db.execute("SELECT name FROM sqlite_master WHERE type = 'table'"))
            if "results" in tables:
                cols = tuple(r[1] for r in self._db.execute("PRAGMA table_info(results)"))
                if cols != self.COLUMNS:
                    raise self._foreign(f"its table 'results' has the columns {', '.join(cols)}")
            elif tables:  # another program's database: never add a table to it
                raise self._foreign(f"it holds the tables {', '.join(tables)}")
            else:
                self._db.execute(self.SCHEMA)
                self._db.commit()
        except sqlite3.Error as exc:
            self.close()
            raise self._error(exc, "open") from None
        except StoreError:
            self.close()
            raise

    def _foreign(self, what):
        return StoreError(f"store: {self.path} is not a liefi results store ({what}); liefi does not write into "
                          "another program's database: move the file away or choose another output folder (--out)")

    def _error(self, exc, doing):
        """``exc`` (an ``sqlite3.Error``) as a :class:`StoreError` naming the file and what to do."""
        name = getattr(exc, "sqlite_errorname", "") or ""
        text = " ".join(str(exc).split())
        if name.startswith(("SQLITE_FULL", "SQLITE_IOERR")) or "disk is full" in text or "disk I/O" in text:
            why = "its disk is full" if "full" in text else "its disk is full, a file size limit was reached or " \
                "the disk failed"
            return StoreError(f"store: cannot {doing} {self.path} ({text}): {why}; free space (or raise the limit) "
                              "and rerun to resume, or choose another output folder (--out); what finished before "
                              "is kept in it")
        if name.startswith(("SQLITE_BUSY", "SQLITE_LOCKED")):
            return StoreError(f"store: {self.path} is locked by another process ({text}); wait for it to finish or "
                              "choose another output folder (--out)")
        if name.startswith(("SQLITE_READONLY", "SQLITE_CANTOPEN", "SQLITE_PERM", "SQLITE_AUTH")):
            return StoreError(f"store: cannot {doing} {self.path} ({text}); make it writable or choose another "
                              "output folder (--out)")
        return StoreError(f"store: {self.path} is damaged or not a liefi results store ({text}); move it away "
                          "(or delete it: its runs are then run again) or choose another output folder (--out)")

    def _damaged_row(self, what, task):
        task = " ".join(str(task).split())
        task = task if len(task) <= 100 else task[:100] + "..."
        return StoreError(f"store: {self.path} holds a damaged row ({what} is not JSON; task {task}); move the "
                          "file away (or delete it: its runs are then run again) or choose another output folder "
                          "(--out)")

    def _value(self, task, status, etype, msg, tb, value):
        if status == "error":
            return TaskError(etype, msg, tb or "")
        try:
            return json.loads(value)
        except (TypeError, ValueError):
            raise self._damaged_row("its stored value" if value else "its stored value is empty, which", task) from None

    def close(self):
        if self._db is not None:
            self._db.close()

    def __enter__(self):
        return self

    def __exit__(self, *exc):
        self.close()

    def get(self, task, *, errors=False):
        """The stored value of ``task``; ``None`` if not there (or, unless ``errors``, if it failed)."""
        key = task_key(task)
        try:
            row = self._db.execute("SELECT status, error_type, message, traceback, value FROM results WHERE key = ?",
                                   (key,)).fetchone()
        except sqlite3.Error as exc:
            raise self._error(exc, "read") from None
        if row is None:
            return None
        if row[0] == "error" and not errors:
            return None
        return self._value(key, *row)

    def put(self, task, value, *, index=None, seconds=None):
        """Record ``value`` (or a :class:`TaskError`) for ``task`` and commit; returns the value as
        stored (non-finite numbers become ``None``: strict JSON), which is what :meth:`get` gives back."""
        key = task_key(task)
        if isinstance(value, TaskError):
            rec = ("error", value.type, value.message, value.traceback, None)
        else:
            value = _plain(value)
            rec = ("done", None, None, None, json.dumps(value, allow_nan=False))
        try:
            self._db.execute("INSERT OR REPLACE INTO results VALUES (?,?,?,?,?,?,?,?,?,?,?)",
                             (key, self.sweep, index, key, *rec, seconds, time.time()))
            self._db.commit()
        except sqlite3.Error as exc:
            with contextlib.suppress(sqlite3.Error):
                self._db.rollback()
            raise self._error(exc, "write") from None
        return value

    def rows(self, sweep=None):
        """Every stored outcome as ``(task, value_or_TaskError)``, in the order they finished."""
        q = "SELECT task, status, error_type, message, traceback, value FROM results"
        args = ()
        if sweep is not None:
            q += " WHERE sweep = ?"
            args = (sweep,)
        out = []
        try:
            found = self._db.execute(q + " ORDER BY finished_at", args).fetchall()
        except sqlite3.Error as exc:
            raise self._error(exc, "read") from None
        for task, *row in found:
            try:
                t = json.loads(task)
            except (TypeError, ValueError):
                raise self._damaged_row("its task", task) from None
            out.append((t, self._value(task, *row)))
        return out


def _workers(executor):
    n = getattr(executor, "_max_workers", None)
    if isinstance(n, int) and n > 0:
        return n
    client = getattr(executor, "_client", None)  # Dask's ClientExecutor
    if client is not None:
        try:
            return max(1, sum(client.nthreads().values()))
        except Exception:  # noqa: BLE001 -- a guess is enough here
            pass
    return os.cpu_count() or 1


def _fresh_pool(executor):
    """A new process pool like ``executor`` (which broke), or ``None`` if it is not a process pool."""
    from concurrent.futures import ProcessPoolExecutor

    if not isinstance(executor, ProcessPoolExecutor):
        return None
    return ProcessPoolExecutor(max_workers=_workers(executor), mp_context=getattr(executor, "_mp_context", None),
                               initializer=ignore_in_worker)


def _stop(executor):
    """Cancel what has not started and stop a process pool's workers (after Ctrl-C or SIGTERM).

    The workers ignore SIGTERM (:func:`~liefi._signals.ignore_in_worker`): they are killed and
    joined, so none is left running.  A Dask executor cancels its futures; its cluster is closed
    by :func:`open_executor`."""
    procs = list((getattr(executor, "_processes", None) or {}).values())  # no public way before Python 3.14;
    writer = getattr(getattr(executor, "_result_queue", None), "_writer", None)  # taken first: shutdown()
    manager = getattr(executor, "_executor_manager_thread", None)
    try:  # forgets them
        executor.shutdown(wait=False, cancel_futures=True)
    except TypeError:  # Dask's ClientExecutor: shutdown(wait) only
        with contextlib.suppress(Exception):
            executor.shutdown(wait=False)
    except Exception:  # noqa: BLE001 -- stopping must not raise
        pass
    for p in procs:
        with contextlib.suppress(Exception):
            p.kill()
    for p in procs:
        with contextlib.suppress(Exception):
            p.join(10)
    # A worker killed while it was sending a large result leaves half a message in the result pipe, and the
    # pool's manager thread would wait for the rest for ever (and the interpreter for that thread at exit).
    # With every worker dead, closing this process's write end gives that read an end of file: the manager
    # thread sees a broken pool and ends.
    if procs and writer is not None:
        with contextlib.suppress(Exception):
            writer.close()
    # concurrent.futures' exit hook would then wake that thread through a pipe the broken pool has
    # closed under it ("Exception ignored ... OSError: Bad file descriptor" at exit): the thread is
    # joined here and taken off the hook's list, so the interrupt stays one line.
    if procs and manager is not None:
        with contextlib.suppress(Exception):
            manager.join(10)
        with contextlib.suppress(Exception):
            from concurrent.futures import process as _cf_process

            if not manager.is_alive():
                _cf_process._threads_wakeups.pop(manager, None)


def run_sweep(fn, tasks, executor: Executor | None = None, *, store=None, convert=None, progress=None,
              label="", max_in_flight=None, expected=None):
    """``[fn(task) for task in tasks]``, computed by ``executor``, every outcome a value.

    Parameters
    ----------
    fn : callable
        A picklable (module-level) function of one task.
    tasks : iterable
        Picklable task descriptions (JSON-serializable with a ``store``).
    executor : concurrent.futures.Executor, optional
        Anything with ``submit(fn, *args) -> Future``.  ``None`` runs serially here.
    store : ResultStore, optional
        Where each outcome is written as it arrives; tasks already done there are
        not run again (their stored values are returned).
    convert : callable, optional
        ``convert(task, result) -> value``, applied in this process to each
        successful result as it arrives, before it is stored and returned (for
        instance to reduce a trajectory to a row of numbers).  An exception in
        it makes that task's value a :class:`TaskError`.
    progress : bool, optional
        Progress on stderr (done/total, rate, time left); default: live on a terminal,
        else a line every 5 % or 30 s (:class:`liefi._progress.Progress`, ``lines=True``).
    label : str
        Names the sweep in the progress line.
    max_in_flight : int, optional
        Tasks submitted at a time (default: the executor's worker count).
    expected : callable, optional
        ``expected(task) -> (kind, seconds)``: the kind of a task and its expected
        seconds (a prior, any common scale).  The time left is then weighted by
        them and learned per kind (:class:`liefi._progress.Progress`, ``costs``),
        not by the count of tasks left: a sweep of cheap tasks first and costly
        ones last is not promised to end early.

    Returns
    -------
    list
        In the order of ``tasks``: each task's (converted) result, or a
        :class:`TaskError` for a task that raised, whose result could not be
        returned, or whose worker died.

    Raises
    ------
    SweepInterrupted
        On Ctrl-C, with the results finished so far.
    """
    tasks = list(tasks)
    if executor is not None and not hasattr(executor, "submit"):
        raise TypeError(f"executor: expected a concurrent.futures.Executor, got {executor!r}")
    results = [None] * len(tasks)
    todo = []
    for i, t in enumerate(tasks):
        v = store.get(t) if store is not None else None
        if v is None:
            todo.append(i)
        else:
            results[i] = v
    kinds = costs = None
    if expected is not None:
        kinds, costs = zip(*(expected(t) for t in tasks)) if tasks else ((), ())
    bar = Progress(len(tasks), label or "sweep", progress, unit="task", lines=True, initial=len(tasks) - len(todo),
                   costs=costs, kinds=kinds, todo=todo)

    def record(i, value, seconds=None):
        if convert is not None and not isinstance(value, TaskError):
            try:
                value = convert(tasks[i], value)
            except Exception as exc:  # noqa: BLE001
                value = TaskError.from_exception(exc)
        if store is not None:
            value = store.put(tasks[i], value, index=i, seconds=seconds)
        results[i] = value
        bar.update(failed=isinstance(value, TaskError), index=i, seconds=seconds)

    owned = []  # pools started here after a break
    try:
        if executor is None:
            for i in todo:
                w = time.perf_counter()
                record(i, _call(fn, tasks[i]), time.perf_counter() - w)
            return results
        _parallel(fn, tasks, todo, executor, record, owned, max_in_flight)
        return results
    except KeyboardInterrupt as exc:
        with shielded():  # the workers stopped and the results read, whatever a second Ctrl-C says
            for ex in [executor, *owned]:
                if ex is not None:
                    _stop(ex)
            if store is not None:  # the store is the record: a task committed just before the signal counts
                _from_store(store, tasks, results)
        raise SweepInterrupted(results, signum_of(exc)) from None
    except StoreError as exc:  # the disk is full, or the store is damaged: stop as for Ctrl-C
        for ex in [executor, *owned]:
            if ex is not None:
                _stop(ex)
        exc.results = results
        raise
    finally:
        bar.close()
        for ex in owned:
            with contextlib.suppress(Exception):
                ex.shutdown(wait=True, cancel_futures=True)


def _from_store(store, tasks, results):
    """Fill the unfinished entries of ``results`` from ``store`` (after an interrupt)."""
    for i, t in enumerate(tasks):
        if results[i] is None:
            try:
                results[i] = store.get(t, errors=True)
            except StoreError:
                return


def _parallel(fn, tasks, todo, executor, record, owned, max_in_flight):
    from collections import deque
    from concurrent.futures import BrokenExecutor

    limit = max(1, int(max_in_flight or _workers(executor)))
    queue = deque(todo)
    isolate = deque()  # tasks in flight when a worker died: re-run one at a time
    inflight = {}  # future -> (index, start time, isolated)

    def broken(exc):
        nonlocal executor
        suspects = sorted(i for i, _, _ in inflight.values())
        alone = [i for i, _, iso in inflight.values() if iso]
        inflight.clear()
        fresh = _fresh_pool(executor)
        if fresh is None:  # not a process pool: nothing to restart; report, never lose silently
            for i in suspects + list(isolate) + list(queue):
                record(i, TaskError("ExecutorBroken", f"the executor broke ({exc}); the task was not run"))
            isolate.clear()
            queue.clear()
            return
        with contextlib.suppress(Exception):
            executor.shutdown(wait=False, cancel_futures=True)
        owned.append(fresh)
        executor = fresh
        for i in alone:  # it ran alone: it is the one that killed its worker
            record(i, TaskError("WorkerDied", f"the worker process died while running this task ({exc})"))
        isolate.extend(i for i in suspects if i not in alone)

    while queue or isolate or inflight:
        while isolate and not inflight:
            i = isolate.popleft()
            try:
                inflight[executor.submit(_call, fn, tasks[i])] = (i, time.perf_counter(), True)
            except BrokenExecutor as exc:
                isolate.appendleft(i)
                broken(exc)
        while queue and not isolate and len(inflight) < limit:
            i = queue.popleft()
            try:
                inflight[executor.submit(_call, fn, tasks[i])] = (i, time.perf_counter(), False)
            except BrokenExecutor as exc:
                queue.appendleft(i)
                broken(exc)
                break
        if not inflight:
            continue
        done, _ = wait(list(inflight), return_when=FIRST_COMPLETED)
        died = None
        for f in done:
            try:
                value = f.result()
            except BrokenExecutor as exc:
                died = exc
                continue
            except Exception as exc:  # noqa: BLE001 -- unpicklable result, Dask's KilledWorker, ...
                value = TaskError.from_exception(exc)
                if type(exc).__name__ == "KilledWorker":
                    value = TaskError("WorkerDied", value.message, value.traceback)
            i, start, _ = inflight.pop(f)
            record(i, value, time.perf_counter() - start)
        if died is not None:  # the finished ones are recorded; the rest in flight are suspects
            broken(died)


def _count(spec, default):
    if ":" in spec:
        n = spec.split(":", 1)[1]
        try:
            n = int(n)
        except ValueError:
            raise ValueError(f"scheduler: the number of workers in {spec!r} is not an integer") from None
        if n < 1:
            raise ValueError(f"scheduler: the number of workers in {spec!r} must be at least 1")
        return n
    return default


def default_scheduler():
    """``"processes"`` (one worker process per core) on a machine with more than one core, else
    ``"serial"``: what ``liefi bench`` runs on unless ``--scheduler`` says otherwise, as ``liefi
    reproduce`` runs its scenes on every core."""
    return "processes" if (os.cpu_count() or 1) > 1 else "serial"


@contextlib.contextmanager
def open_executor(scheduler: str | None = None):
    """An executor for ``scheduler`` (see the module docstring); closed on exit.

    Yields ``None`` for ``None``/``"serial"`` (run in this process).  The workers
    of a process pool ignore ``SIGINT`` and ``SIGTERM`` (the main process handles them).

    Raises
    ------
    ValueError
        For an unknown scheduler string.
    ImportError
        For a Dask scheduler when Dask is not installed (``pip install liefi[dask]``).
    """
    if scheduler is None or scheduler == "serial":
        yield None
        return
    cores = os.cpu_count() or 1
    if scheduler.startswith("processes"):
        from concurrent.futures import ProcessPoolExecutor

        with ProcessPoolExecutor(max_workers=_count(scheduler, cores), initializer=ignore_in_worker) as ex:
            yield ex
        return
    if scheduler.startswith("threads"):
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(max_workers=_count(scheduler, cores)) as ex:
            yield ex
        return
    is_address = "://" in scheduler
    if scheduler.startswith("dask") or is_address:
        try:
            from distributed import Client, LocalCluster
        except ImportError as exc:
            raise ImportError(
                f"scheduler: {scheduler!r} needs Dask's distributed scheduler; install it with "
                "`pip install liefi[dask]`"
            ) from exc
        if is_address:
            with Client(scheduler) as client:
                yield client.get_executor()
            return
        import logging

        n = _count(scheduler, cores)  # the workers' warnings (a task cancelled on Ctrl-C) would bury liefi's line
        with LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None,
                          silence_logs=logging.ERROR) as cluster:
            with Client(cluster) as client:
                yield client.get_executor()
        return
    raise ValueError(
        f"scheduler: unknown {scheduler!r}; use serial, processes[:N], threads[:N], dask[:N] "
        "or a Dask scheduler address such as tcp://host:8786"
    )

