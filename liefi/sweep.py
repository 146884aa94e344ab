"""Embarrassingly parallel sweeps over any :class:`concurrent.futures.Executor`.

Work-precision grids (:mod:`liefi.bench`), stability maps and ensembles are
lists of independent tasks.  :func:`run_sweep` maps a function over them:

* with no executor, in this process, one after the other (the default, and the
  reference: every other executor must give the same results);
* with any :class:`concurrent.futures.Executor` -- a
  :class:`~concurrent.futures.ProcessPoolExecutor` to use every core of this
  machine, or Dask's distributed scheduler (``Client.get_executor()``, the
  optional extra ``liefi[dask]``) to use a cluster.

The function and the tasks must be picklable (a module-level function and
plain data: scene names, numbers, dicts), because executors other than the
default send them to other processes or machines.  Results come back in the
order of the tasks.

:func:`open_executor` turns a command-line ``--scheduler`` string into an
executor: ``serial``, ``processes[:N]``, ``threads[:N]``, ``dask[:N]`` (a Dask
``LocalCluster`` of N workers on this machine) or a Dask scheduler address
``tcp://host:8786``.

Example
-------
>>> from liefi.sweep import run_sweep
>>> run_sweep(abs, [-1, 2, -3])
[1, 2, 3]
"""

from __future__ import annotations

import contextlib
import os
from concurrent.futures import Executor

__all__ = ["run_sweep", "open_executor"]


def run_sweep(fn, tasks, executor: Executor | None = None):
    """``[fn(task) for task in tasks]``, computed by ``executor`` (default: in this process).

    Parameters
    ----------
    fn : callable
        A picklable (module-level) function of one task.
    tasks : iterable
        Picklable task descriptions.
    executor : concurrent.futures.Executor, optional
        Anything with ``submit(fn, arg) -> Future``.  ``None`` runs serially here.

    Returns
    -------
    list
        The results, in the order of ``tasks``.  An exception raised by ``fn``
        is re-raised here (the first one, in task order); a task that should
        not stop the sweep must catch its own errors and return them.
    """
    tasks = list(tasks)
    if executor is None:
        return [fn(t) for t in tasks]
    if not hasattr(executor, "submit"):
        raise TypeError(f"executor: expected a concurrent.futures.Executor, got {executor!r}")
    futures = [executor.submit(fn, t) for t in tasks]
    return [f.result() for f in futures]


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


@contextlib.contextmanager
def open_executor(scheduler: str | None = None):
    """An executor for ``scheduler`` (see the module docstring); closed on exit.

    Yields ``None`` for ``None``/``"serial"`` (run in this process).

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

        with ProcessPoolExecutor(max_workers=_count(scheduler, cores)) as ex:
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
        n = _count(scheduler, cores)
        with LocalCluster(n_workers=n, threads_per_worker=1, processes=True, dashboard_address=None) as cluster:
            with Client(cluster) as client:
                yield client.get_executor()
        return
    raise ValueError(
        f"scheduler: unknown {scheduler!r}; use serial, processes[:N], threads[:N], dask[:N] "
        "or a Dask scheduler address such as tcp://host:8786"
    )
