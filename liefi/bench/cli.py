"""``liefi bench``: the command line of the work-precision harness.

Every run is appended to ``OUT/results.sqlite`` as it finishes (a rerun into
the same ``--out`` resumes, skipping the runs already there);
``OUT/summary.json`` is rebuilt from that store after each scene and on
Ctrl-C or SIGTERM.  It, the CSV and the console summary describe exactly this
invocation's task set (the store filtered to its tasks: runs of earlier
invocations with other arguments are kept in the store, not summarized), and
``complete`` says whether every task of this invocation has a stored result.

``OUT`` is a folder ``liefi bench`` owns (``liefi-manifest.json``, the mechanism
``liefi reproduce`` uses): a new or empty folder, or one an earlier ``liefi
bench`` wrote; every file an invocation writes is claimed before any work, and
one of that name that liefi did not write is never overwritten.

One bench at a time writes into a folder: it holds an exclusive lock on
``OUT/.liefi-bench.lock`` (``flock``, released when the process ends, however
it ends), and a second bench on the same ``--out`` is refused at once rather
than computing every run a second time.
"""

from __future__ import annotations

import os
import sys

from .. import _json
from .. import engine as _engine
from .. import scenes as _scenes
from .._files import replacing, writing
from .._signals import describe, exit_code, shielded, terminate_as_interrupt
from ..results.sweep import ResultStore, StoreError, SweepInterrupted, TaskError, task_key
from .core import (FI_GAINS, FIXED_SCHEMES, IVP_METHODS, METHODS, REPEATS, STORE, applicable_methods, build_tasks,
                   error_row, work_precision)
from .validate import positive, positive_int
from .verdict import ACCURATE_DRIFT, ACCURATE_ERROR, DRIFT, summarize, summary


def add_arguments(parser):
    """Add ``liefi bench``'s arguments to an ``argparse`` (sub)parser."""
    parser.add_argument("scene", metavar="SCENE", help="scene name, or 'all'")
    parser.add_argument("--t-final", type=float, default=None, dest="t_final",
                        help="horizon of every run (default: the scene's)")
    parser.add_argument("--out", default="./liefi-bench", metavar="DIR",
                        help="output directory; a rerun into the same DIR resumes (results.sqlite)")
    parser.add_argument("--variant", default=None, help="variant (default: the scene's first)")
    parser.add_argument("--scheduler", default=None, metavar="ADDR",
                        help="processes[:N] (default: one worker process per core, as `liefi reproduce`), serial, "
                        "threads[:N], dask[:N] or tcp://host:8786")
    parser.add_argument("--quick", action="store_true", help="a small grid (3 steps, 2 tolerances)")
    parser.add_argument("--long-horizon", type=float, default=None, dest="long_horizon", metavar="T",
                        help="also the drift against time up to T at matched cost (e.g. 1e4)")
    parser.add_argument("--no-configuration", action="store_true", dest="no_configuration",
                        help="integrate the reduced state only")
    parser.add_argument("--methods", default=None, metavar="M[,M]",
                        help=f"method families (default: all that apply): {','.join(METHODS)}")
    from ..schemes import names as _scheme_names

    parser.add_argument("--schemes", default=None, metavar="S[,S]",
                        help=f"schemes (default: {','.join(FIXED_SCHEMES + IVP_METHODS)}): any of "
                        f"{','.join(_scheme_names('explicit') + _scheme_names('split'))} (`liefi list --schemes`) "
                        "or a solve_ivp method "
                        f"({','.join(n.split(':', 1)[1] for n in _scheme_names('scipy'))})")
    parser.add_argument("--gains", default=None, metavar="K[,K]",
                        help="gains of the FI rows, 'scene' for the scene's own (default: scene,0.1,1,10)")
    parser.add_argument("--repeats", type=int, default=REPEATS, metavar="N",
                        help=f"time every run N times and keep the least CPU time; the spread of the N is the noise "
                        f"that decides a tie (default {REPEATS})")
    parser.add_argument("--max-steps", type=float, default=None, dest="max_steps", metavar="N",
                        help="refuse runs of more than N steps (t_final / dt) before any work, as `liefi run` "
                        "(default 1e8)")
    parser.add_argument("--progress", action=argparse_bool(), default=None,
                        help="progress on stderr: done/total, rate, time left (default: live on a terminal, "
                        "else a line every 5 %% or 30 s)")
    return parser


def argparse_bool():
    import argparse

    return argparse.BooleanOptionalAction


def _list(text, allowed, what):
    if text is None:
        return None
    items = [t.strip() for t in text.split(",") if t.strip()]
    bad = [t for t in items if t not in allowed]
    if bad or not items:
        raise ValueError(f"{what}: unknown {bad or text!r}; choose from {','.join(allowed)}")
    return items


def _schemes(text):
    """``--schemes`` -> ``(fixed-step tableaux, solve_ivp methods)``, names from the scheme registry
    (:func:`liefi.schemes.get`): any explicit tableau (the compiled engine unrolls any), a split
    ``imex-*`` scheme (feedback-integrator rows only, numpy path), and ``scipy:METHOD`` or ``METHOD``
    for solve_ivp."""
    if text is None:
        return FIXED_SCHEMES, IVP_METHODS
    from ..schemes import get, names

    fixed, ivp = [], []
    for t in (x.strip() for x in text.split(",") if x.strip()):
        fixed_names = names("explicit") + names("split")
        name = t if t.lower() in fixed_names or t.lower().startswith("scipy:") else f"scipy:{t}"
        try:
            sch = get(name, ("explicit", "split", "scipy"))
        except ValueError:
            raise ValueError(f"schemes: unknown scheme {t!r}; choose from "
                             f"{','.join(fixed_names + [n.split(':', 1)[1] for n in names('scipy')])}") from None
        (ivp if sch.kind == "scipy" else fixed).append(sch.method if sch.kind == "scipy" else sch.name)
    if not fixed and not ivp:
        raise ValueError("schemes: empty list")
    return tuple(fixed), tuple(ivp)


def _gains(text):
    if text is None:
        return FI_GAINS
    out = []
    for t in (x.strip() for x in text.split(",") if x.strip()):
        if t == "scene":
            out.append(None)
            continue
        try:
            out.append(float(t))
        except ValueError:
            raise ValueError(f"gains: {t!r} is not a number; give numbers > 0 or 'scene'") from None
    if not out:
        raise ValueError("gains: empty list; give numbers > 0 or 'scene'")
    return tuple(out)


def output_files(scene, long_horizon=False):
    """The files ``liefi bench`` writes into ``--out`` for ``scene`` (claimed before any work)."""
    names = [f"{scene}-work-precision.csv", f"{scene}-error.png", f"{scene}-drift.png"]
    if long_horizon:
        names += [f"{scene}-long-horizon.csv", f"{scene}-long-horizon.npz", f"{scene}-long-horizon.png"]
    return names


def write_summary(out_dir, tasks=None, arguments=None):
    """Rebuild ``out_dir/summary.json`` from ``out_dir/results.sqlite``: per scene, :func:`summarize`.

    ``tasks`` (``{scene: list of task dicts}``, :func:`build_tasks`) is the task set of one
    invocation: per scene, exactly the stored outcomes of these tasks are summarized (runs
    of other invocations, with other arguments, stay in the store but not in the summary;
    ``other_runs_in_store`` counts them), and ``complete`` says whether every one of them
    has a stored result.  ``None``: every stored run, by scene (``complete`` is then
    ``null``).  ``arguments`` (a dict) is recorded as given.  Strict JSON (a number that is
    not finite is ``null``); written to a temporary file and renamed, so a reader never
    sees half a file.  Returns the summary, or ``None`` if there is no store.
    """
    path = os.path.join(out_dir, STORE)
    if not os.path.exists(path):
        return None
    by, other = {}, 0
    with ResultStore(path) as store:
        stored = store.rows()
        if tasks is None:
            for task, value in stored:
                row = error_row(task, value) if isinstance(value, TaskError) else value
                if row.get("t_final") is None:
                    continue
                by.setdefault(row["scene"], []).append(row)
        else:
            keys = set()
            for name, ts in tasks.items():
                by[name] = []
                for task in ts:
                    keys.add(task_key(task))
                    value = store.get(task, errors=True)
                    if value is not None:
                        by[name].append(error_row(task, value) if isinstance(value, TaskError) else value)
            other = sum(task_key(task) not in keys for task, _ in stored)
    doc = {"criterion": f"every invariant's max drift <= {DRIFT:g} over [0, t_final]",
           "criterion_accurate": f"max state error <= {ACCURATE_ERROR:g} and every invariant's max drift <= "
                                 f"{ACCURATE_DRIFT:g} over [0, t_final]",
           "store": STORE}
    if arguments is not None:
        doc["arguments"] = arguments
    doc["scenes"] = {name: summarize(rows, DRIFT, tasks=None if tasks is None else len(tasks[name]))
                     for name, rows in sorted(by.items())}
    if tasks is not None:
        doc["other_runs_in_store"] = other
    out = os.path.join(out_dir, "summary.json")
    with replacing(out) as tmp, open(tmp, "w") as fh:  # half a file (a full disk, Ctrl-C): the old one stays
        fh.write(_json.dumps(doc, indent=1))
    return doc


def _arguments(args):
    keys = ("scene", "t_final", "variant", "quick", "no_configuration", "methods", "schemes", "gains", "long_horizon",
            "repeats")
    return {k: getattr(args, k, None) for k in keys}


def _check_steps(sc, tasks, args):
    """Refuse, before any work, runs longer than ``--max-steps``: :func:`liefi.integrator.run.check_step_count`,
    the check ``liefi run`` makes (on the grid's smallest step; the long horizon on the scene's
    step, where the feedback integrator's long run is made -- its peers run at matched cost)."""
    from ..integrator.run import check_step_count

    limit = getattr(args, "max_steps", None)
    dts = [t["dt"] for t in tasks if t["dt"] is not None]
    if dts:
        check_step_count(min(dts), tasks[0]["t_final"], limit, name="t-final",
                         advice=f"dt is the grid's smallest step for {sc.name}; take a shorter --t-final, "
                         "or raise --max-steps")
    if getattr(args, "long_horizon", None):
        check_step_count(sc.dt, args.long_horizon, limit, name="long-horizon",
                         advice=f"dt is {sc.name}'s step, the feedback integrator's long run; take a shorter "
                         "--long-horizon, or raise --max-steps")


#: the lock file of an output folder (see the module docstring)
LOCK = ".liefi-bench.lock"


def lock_folder(out_dir):
    """Take the exclusive lock of ``out_dir`` for this process; returns the open lock file (close it to release).

    Raises ``OSError`` naming the folder and the process holding it when another bench writes there.
    Where ``fcntl`` does not exist (Windows) nothing is locked.
    """
    try:
        import fcntl
    except ImportError:  # pragma: no cover - no flock: one bench at a time is the user's to keep
        return None
    path = os.path.join(out_dir, LOCK)
    with writing(path):
        fh = open(path, "a+")
    try:
        fcntl.flock(fh.fileno(), fcntl.LOCK_EX | fcntl.LOCK_NB)
    except OSError:
        fh.seek(0)
        holder = fh.read().strip()
        fh.close()
        raise OSError(f"out: {out_dir} is in use by another liefi bench{f' (process {holder})' if holder else ''}; "
                      "two benches on one folder would compute the same runs twice: wait for it to finish (a rerun "
                      "then resumes from its results) or choose another --out") from None
    fh.seek(0)
    fh.truncate()
    fh.write(str(os.getpid()))
    fh.flush()
    return fh


def _summarized(out_dir, expected, arguments=None):
    """Write ``summary.json`` after an interrupt or a store failure; returns the words that say where
    (or why it could not be written: the disk may be full)."""
    path = os.path.join(out_dir, "summary.json")
    try:
        write_summary(out_dir, expected, arguments)
    except OSError as exc:
        return f"{path} could not be rewritten ({' '.join(str(exc).split())})"
    return f"summarized in {path}"


def _unwritten(exc):
    why = getattr(exc, "unwritten", None)  # the CSV of what finished (liefi.bench.core.work_precision)
    return f"; the CSV could not be written ({why})" if why else ""


def run_from_args(args, log=None):
    """Run ``liefi bench`` from parsed arguments; prints the summary, returns the exit code.

    0: every task finished (some runs may have diverged: they are data); 1: some
    task raised or lost its worker (reported, every other result kept); 130 (Ctrl-C)
    or 143 (SIGTERM, when :func:`~liefi._signals.terminate_as_interrupt` is active,
    as in :func:`main`): interrupted, what finished is in the store and
    ``summary.json``, one line on stderr says so.

    Before any work: every argument, the length of every run (``--max-steps``,
    as ``liefi run``) and the output folder (:func:`liefi.reproduce.prepare_output`:
    a new or empty folder or one ``liefi bench`` owns; every file this invocation
    writes is claimed, and a file of that name that liefi did not write is refused),
    then the folder's lock (:func:`lock_folder`).

    Raises
    ------
    OSError
        The output folder is in use by another bench (:func:`lock_folder`) or
        cannot be written; or a :class:`~liefi.results.sweep.StoreError`: the store is
        damaged or another program's, or could not be written during the runs
        (disk full) -- then after printing the summary of what finished and
        rewriting ``summary.json`` where possible.
    """
    from ..reproduce import OutputError, prepare_output

    log = log or (lambda m: print(m, file=sys.stderr, flush=True))
    _scenes.check_name(args.scene, extra=("all",))
    if args.t_final is not None:
        positive("--t-final", args.t_final)
    if args.long_horizon is not None:
        positive("--long-horizon", args.long_horizon)
    if getattr(args, "max_steps", None) is not None:
        positive("--max-steps", args.max_steps)
    repeats = positive_int("--repeats", getattr(args, "repeats", REPEATS))
    names = _scenes.names() if args.scene == "all" else [args.scene]
    methods = _list(getattr(args, "methods", None), METHODS, "methods")
    schemes, ivp = _schemes(getattr(args, "schemes", None))
    gains = _gains(getattr(args, "gains", None))
    plan = []  # (scene, build_tasks keywords, tasks): this invocation's task set
    for name in names:
        try:
            sc = _scenes.get(name)
        except ImportError as exc:  # with 'all': a scene whose module is missing
            if args.scene != "all":
                raise
            log(f"{name}: skipped ({exc})")
            continue
        use = None if methods is None else [m for m in methods if m in applicable_methods(sc)]
        kw = dict(variant=args.variant, quick=args.quick, configuration=not args.no_configuration,
                  methods=use, schemes=schemes, ivp_methods=ivp, gains=gains, repeats=repeats)
        tasks = build_tasks(sc, sc.t_final if args.t_final is None else args.t_final, **kw)
        _check_steps(sc, tasks, args)
        plan.append((sc, kw, tasks))
    try:  # outputs checked before any work
        output = prepare_output(args.out, "bench", keep=True)
        output.claim_all([STORE, "summary.json", LOCK]
                         + [f for sc, _, _ in plan for f in output_files(sc.name, bool(args.long_horizon))])
    except OutputError as exc:
        raise ValueError(str(exc)) from None
    lock = lock_folder(args.out)
    try:
        ResultStore(os.path.join(args.out, STORE)).close()
        return _run(args, log, plan)
    finally:
        if lock is not None:
            lock.close()


def _run(args, log, plan):
    from ..results.sweep import default_scheduler, open_executor

    if not _engine.available():
        log(f"liefi bench: numba is not available ({_engine.NUMBA_ERROR}); the generated code runs as plain "
            "Python, orders of magnitude slower. Install it with `pip install liefi[fast]`.")
    expected, errors = {sc.name: tasks for sc, _, tasks in plan}, 0
    arguments = _arguments(args)
    try:
        with open_executor(args.scheduler or default_scheduler()) as ex:
            for sc, kw, _ in plan:
                rows = work_precision(sc, args.t_final, args.out, ex, log=log,
                                      progress=getattr(args, "progress", None), **kw)
                errors += sum(r["status"] == "error" for r in rows)
                write_summary(args.out, expected, arguments)
                print(f"{sc.name} (t_final = {rows[0]['t_final']:g}):")
                print("  " + summary(rows).replace("\n", "\n  "), flush=True)
                if args.long_horizon:
                    from .horizon import long_horizon

                    long_horizon(rows, args.out, ex, t_final=args.long_horizon, log=log)
    except KeyboardInterrupt as exc:
        with shielded():  # a second Ctrl-C does not cut the summary short (liefi._signals.shielded)
            where = _summarized(args.out, expected, arguments) + _unwritten(exc)
            done = f"{exc.done} runs of this scene finished, " if isinstance(exc, SweepInterrupted) else ""
            print(f"liefi bench: {describe(exc)}; {done}everything finished is kept in "
                  f"{os.path.join(args.out, STORE)} and {where}", file=sys.stderr, flush=True)
        return exit_code(exc)
    except StoreError as exc:  # disk full, or a damaged store: the summary of what finished, then the error
        if exc.results is None:  # found before any run (a damaged row): nothing new to summarize
            raise
        rows = getattr(exc, "rows", None) or []
        if rows:
            print(f"{rows[0]['scene']} (t_final = {rows[0]['t_final']:g}; stopped after {len(rows)} of "
                  f"{len(expected.get(rows[0]['scene'], ())) or '?'} runs):")
            print("  " + summary(rows).replace("\n", "\n  "), flush=True)
        where = _summarized(args.out, expected, arguments) + _unwritten(exc)
        raise StoreError(f"{' '.join(str(exc).split())}; {where}") from None
    print(f"written to {args.out}")
    if errors:
        log(f"liefi bench: {errors} runs raised or lost their worker; every other result is kept (see the CSV)")
        return 1
    return 0


def main(argv=None):
    """``python -m liefi.bench SCENE [--t-final T] [--out DIR] [--scheduler ADDR] ...``."""
    import argparse

    p = argparse.ArgumentParser(prog="liefi bench", description="work-precision diagrams of a scene")
    add_arguments(p)
    args = p.parse_args(argv)
    try:
        with terminate_as_interrupt():
            return run_from_args(args)
    except KeyboardInterrupt as exc:
        print(f"liefi bench: {describe(exc)}", file=sys.stderr)
        return exit_code(exc)
    except (ValueError, OSError, ImportError) as exc:
        print(f"liefi bench: error: {' '.join(str(exc).split())}", file=sys.stderr)
        return 2
