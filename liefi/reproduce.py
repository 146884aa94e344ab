"""``liefi reproduce``: every experiment of the paper's Section 3, its figures and a summary.

What runs: every scene of the paper (``Scene.in_paper``; ``all_scenes``: every
scene of :data:`liefi.scenes.REGISTRY`) and every variant, each
with the runs the scene asks for (:meth:`liefi.scenes.Scene.paper_runs`: by
default one run at the paper's ``dt``, ``t_final``, scheme and gains, the
configuration included when the scene's figures need it).  A run that does not
depend on the variant (``PaperRun.variant_independent``) runs once and is
reused.  A scene with a numerical reference computes it once, for the longest
horizon it needs, before its runs (:meth:`~liefi.scenes.Scene.reference_solution`).
Independent scenes run in parallel (``jobs`` worker processes).

What is written to ``out``:

* the figures of each scene and variant (:meth:`~liefi.scenes.Scene.figures`)
  as PNG, named after the paper's figure labels (``figure_Suslov_Pi_exact.png``);
  a variant other than a scene's first gets a ``-VARIANT`` suffix; a scene's
  generic figure is ``SCENE-VARIANT.png``;
* ``summary.json`` (every run: settings, steps, CPU time, max errors, max drifts,
  figures, status; strict JSON, a number that is not finite written as ``null``) and ``summary.md`` (the same as a markdown table), rewritten
  after every scene, so an interrupted or killed reproduction leaves a
  consistent summary of what finished (a scene cut short contributes the runs
  and figures it finished and is listed in ``unfinished``);
* ``liefi-manifest.json``: the files liefi wrote there.

The output folder is checked before any work (:func:`prepare_output`): liefi
writes only into a new or empty folder or into one it owns (one holding its
manifest); the files of an earlier reproduction listed in the manifest are
removed first, so nothing stale is mixed in, and a file liefi did not write is
never overwritten.  ``liefi bench`` uses the same mechanism (its manifest names
the command): neither command writes into the other's folder.

``t_final_scale`` (``--t-final-scale``, for tests) multiplies every horizon,
rounded to a whole number of steps.  A failing experiment is recorded (status
``failed`` and its error) and the others still run.  ``KeyboardInterrupt``
(SIGINT, or SIGTERM under :func:`liefi._signals.terminate_as_interrupt`, as in
the ``liefi`` command) stops the work: the worker processes (which ignore both
signals) are killed and joined, the summary of everything finished is written
(with ``"interrupted": true``), and the interrupt is raised again with
``detail`` saying where that summary is.
"""

from __future__ import annotations

import json
import os
import sys
import time
import traceback
import warnings

from . import __version__
from . import _json
from ._files import replacing
from ._progress import Progress
from ._signals import ignore_in_worker, shielded
from . import scenes as _scenes

#: the file that marks a folder as liefi's and lists what liefi wrote there
MANIFEST = "liefi-manifest.json"


class OutputError(OSError):
    """The output folder cannot be used (not writable, or it holds files liefi did not write)."""


def _log(msg):
    print(msg, file=sys.stderr, flush=True)


def _horizon(T, dt, scale):
    """``T * scale`` rounded to a whole number (>= 1) of steps ``dt``."""
    n = max(1, int(round(T * scale / dt)))
    return n * dt


def _figure_file(key, scene, variant, default_variant):
    if key == "generic":
        return f"{scene}-{variant}.png"
    base = key.replace(":", "_")
    return base + ("" if variant == default_variant else f"-{variant}") + ".png"


def _tag(variant, default_variant):
    return "" if variant == default_variant else f" [variant {variant}]"


def _one_line(exc):
    return f"{type(exc).__name__}: {' '.join(str(exc).split())}"


# --------------------------------------------------------------------------------------
# the output folder
# --------------------------------------------------------------------------------------
class Output:
    """A folder liefi owns: every file is listed in its manifest before it is written.

    The manifest is read and rewritten under an exclusive lock (``fcntl`` where
    available), so worker processes writing into the same folder keep it whole.
    ``command`` (``"reproduce"``, ``"bench"``) is the command that owns the folder,
    recorded in the manifest: one command never writes into another's folder.
    """

    def __init__(self, path, command="reproduce"):
        self.path = os.path.abspath(path)
        self.command = command

    def _atomic(self, name, write):
        final = os.path.join(self.path, name)
        with replacing(final) as tmp, open(tmp, "w") as f:  # half a file (a full disk, Ctrl-C): the old one stays
            write(f)
        return final

    def files(self):
        """The names the manifest lists."""
        try:
            with open(os.path.join(self.path, MANIFEST)) as f:
                return [str(n) for n in json.load(f).get("files", [])]
        except FileNotFoundError:
            return []

    def _update(self, add=(), reset=False, refuse_foreign=False):
        lock = os.open(self.path, os.O_RDONLY)  # the folder itself is the lock
        try:
            try:
                import fcntl

                fcntl.flock(lock, fcntl.LOCK_EX)
            except (ImportError, OSError):  # pragma: no cover - no flock here: a single writer
                pass
            files = [] if reset else self.files()
            new = [n for n in add if n not in files]
            if refuse_foreign:
                for n in new:
                    if os.path.lexists(os.path.join(self.path, n)):
                        raise OutputError(
                            f"out: {os.path.join(self.path, n)} exists and was not written by liefi; not overwriting it"
                        )
            if new or reset or not os.path.exists(os.path.join(self.path, MANIFEST)):
                data = {"written_by": f"liefi {__version__}", "command": self.command, "files": files + new}
                self._atomic(MANIFEST, lambda f: json.dump(data, f, indent=1))
            return files
        finally:
            os.close(lock)

    def claim(self, name):
        """The path of ``name`` in the folder, recorded in the manifest before it is written.

        Raises :class:`OutputError` if a file of that name exists that liefi did not write.
        """
        return self.claim_all([name])[0]

    def claim_all(self, names):
        """The paths of ``names``, all recorded in the manifest at once before any is written; raises
        :class:`OutputError` (and claims none) if one of them exists that liefi did not write."""
        self._update(add=list(names), refuse_foreign=True)
        return [os.path.join(self.path, n) for n in names]

    def write_text(self, name, text):
        self.claim(name)
        return self._atomic(name, lambda f: f.write(text))


def prepare_output(out, command="reproduce", *, keep=False):
    """Check the output folder ``out`` before any work and take it over for ``command``; returns an
    :class:`Output`.  ``liefi reproduce`` and ``liefi bench`` share it.

    * missing: created (with its parents);
    * empty, or holding liefi's manifest of the same ``command``: used; the files the
      manifest lists (an earlier reproduction's figures and summaries) are removed
      first, unless ``keep`` (``liefi bench``: its results store is resumed; each
      file it writes is claimed with :meth:`Output.claim`, which refuses a file liefi
      did not write);
    * holding another command's manifest, other files and no manifest, not a folder,
      or not writable: :class:`OutputError` naming ``out`` and what to do.
    """
    path = os.path.abspath(out)
    if os.path.lexists(path) and not os.path.isdir(path):
        raise OutputError(f"out: {out!r} exists and is not a folder; give a folder (it is created if missing)")
    try:
        os.makedirs(path, exist_ok=True)
    except OSError as exc:
        raise OutputError(f"out: cannot create the folder {out!r} ({exc.strerror or exc}); choose another --out") from None
    entries = set(os.listdir(path))
    old = []
    if MANIFEST in entries:
        try:
            with open(os.path.join(path, MANIFEST)) as f:
                data = json.load(f)
            old = [str(n) for n in data.get("files", [])]
            owner = str(data.get("command", "reproduce"))
        except (OSError, ValueError, AttributeError) as exc:
            raise OutputError(
                f"out: {os.path.join(path, MANIFEST)} is unreadable ({_one_line(exc)}); remove it or choose another --out"
            ) from None
        if owner != command:
            raise OutputError(
                f"out: the folder {out!r} holds the output of `liefi {owner}` ({MANIFEST}); `liefi {command}` "
                "does not write into it: choose another --out"
            )
    elif entries:
        shown = ", ".join(sorted(entries)[:3]) + (", ..." if len(entries) > 3 else "")
        raise OutputError(
            f"out: the folder {out!r} is not empty ({shown}) and was not created by liefi (no {MANIFEST}); "
            "liefi writes only into a new or empty folder or one it owns: choose another --out, or empty it"
        )
    if not os.access(path, os.W_OK | os.X_OK):
        raise OutputError(f"out: the folder {out!r} is not writable; choose another --out")
    output = Output(path, command)
    try:
        output._update(reset=not keep)  # proves the folder writable before any work
    except OSError as exc:
        raise OutputError(f"out: cannot write into {out!r} ({exc.strerror or exc}); choose another --out") from None
    if keep:
        return output
    for name in old:  # an earlier reproduction: nothing stale stays beside the new figures
        p = os.path.join(path, os.path.basename(name))
        if os.path.isfile(p) or os.path.islink(p):
            os.remove(p)
    return output


# --------------------------------------------------------------------------------------
# one scene
# --------------------------------------------------------------------------------------
def _failed_row(scene, variant, scheme, t_final, experiment, exc, status="failed"):
    return {
        "scene": scene,
        "variant": variant,
        "scheme": scheme,
        "t_final": t_final,
        "experiment": experiment,
        "status": status,
        "error": _one_line(exc) if isinstance(exc, BaseException) else str(exc),
        "figures": [],
    }


def _run_one(scene, variant, spec, scale, count):
    """One :class:`~liefi.scenes.PaperRun`; returns ``(result or None, row)``."""
    scheme = spec.scheme or scene.scheme
    T = _horizon(scene.t_final if spec.t_final is None else spec.t_final, scene.dt, scale)
    tag = f"[{count}] {scene.name} / {variant} / {scheme} / t in [0, {T:g}]"
    _log(f"{tag} ...")
    start = time.perf_counter()
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            result = scene.run(scheme=scheme, t_final=T, variant=variant, configuration=spec.configuration,
                               save_every=spec.save_every)
            result.errors  # the errors against the reference (computed on first use): their failures are this run's
    except Exception as exc:  # noqa: BLE001 - record and go on with the other experiments
        row = _failed_row(scene.name, variant, scheme, T, spec.experiment, exc)
        _log(f"{tag} FAILED: {row['error']}")
        return None, row
    wall = time.perf_counter() - start
    row = result.to_dict()
    row.update(experiment=spec.experiment, status="ok", wall_seconds=wall, figures=[])
    msgs = list(dict.fromkeys(f"{w.category.__name__}: {' '.join(str(w.message).split())}" for w in caught))
    if msgs:
        row["warnings"] = msgs
        for m in msgs:
            _log(f"  warning: {m}")
    worst = max(result.max_error.values(), default=float("nan"))
    _log(f"{tag} done: CPU {_seconds(result.cpu_seconds)} s, wall {wall:.2f} s, max |error| {worst:.3e}")
    return result, row


def _scene_job(task):
    """Every run and figure of one scene: ``(name, out, scale, first_count)`` -> a dict of rows,
    figure names and failures.  Never raises (but ``KeyboardInterrupt``); module level, so a
    process pool can run it."""
    name, out_path, scale, count = task
    rows, failures, figures, references = [], [], [], []
    done = {"rows": rows, "failures": failures, "figures": figures, "scene": name, "references": references}
    try:
        scene = _scenes.get(name)
    except Exception as exc:  # noqa: BLE001 - e.g. the scene module is missing
        row = _failed_row(name, None, None, None, "paper", exc)
        rows.append(row)
        failures.append(row)
        _log(f"{name}: FAILED to load: {row['error']}")
        return done
    output = Output(out_path)

    def snapshot():  # what finished so far, for a summary written while this scene is cut short
        output.write_text(_partial_name(name), _json.dumps(done, default=_json_default))

    variants = list(scene.variants) or [None]
    default_variant = variants[0]
    plans = {v: scene.paper_runs(scene.variant(v)) for v in variants}
    shared = {}  # label -> (result, row) of the variant-independent runs
    for variant in variants:
        plan = plans[variant]
        if scene.reference == "numerical":  # once, for the longest horizon of the plan
            T = max(_horizon(scene.t_final if s.t_final is None else s.t_final, scene.dt, scale) for s in plan)
            before = getattr(scene, "reference_seconds", 0.0)
            try:
                scene.reference_solution(scene.variant(variant), T)
            except Exception as exc:  # noqa: BLE001 - the runs will report it
                _log(f"{name} / {variant}: reference failed: {_one_line(exc)}")
            else:
                spent = getattr(scene, "reference_seconds", 0.0) - before
                references.append({"scene": name, "variant": variant, "t_final": T, "seconds": spent,
                                   "method": scene.reference_method(), "reused": spent == 0.0})
                _log(f"{name} / {variant}: reference on [0, {T:g}] "
                     + (f"computed in {spent:.2f} s" if spent else "reused (same start)"))
        results, used_rows = {}, []
        for spec in plan:
            if spec.variant_independent and spec.label in shared:
                result, row = shared[spec.label]
            else:
                count += 1
                result, row = _run_one(scene, variant, spec, scale, count)
                rows.append(row)
                if result is None:
                    failures.append(row)
                snapshot()
                if spec.variant_independent:
                    shared[spec.label] = (result, row)
            if result is not None:
                results[spec.label] = result
                used_rows.append(row)
        if not results:
            continue
        try:
            specs = scene.figures(results, tag=_tag(variant, default_variant))
        except Exception as exc:  # noqa: BLE001
            specs = []
            msg = f"figures of {name} / {variant}: {_one_line(exc)}"
            _log("  " + msg)
            failures.append({"figure": name, "status": "failed", "error": msg})
        for spec in specs:
            filename = _figure_file(spec.key, name, variant, default_variant)
            if _draw(output, spec, filename, failures):
                figures.append(filename)
                for r in used_rows:
                    if filename not in r["figures"]:
                        r["figures"].append(filename)
                snapshot()
    return done


def _draw(output, spec, filename, failures):
    from .results import scene_figures as plotting

    try:
        path = output.claim(filename)
        fig = spec.draw(None)
        plotting.save(fig, path)
    except Exception as exc:  # noqa: BLE001
        msg = f"figure {filename} ({spec.key}): {_one_line(exc)}"
        _log("  " + msg)
        failures.append({"figure": filename, "status": "failed", "error": msg})
        if os.environ.get("LIEFI_DEBUG"):
            traceback.print_exc()
        return False
    _log(f"  wrote {path}")
    return True


# --------------------------------------------------------------------------------------
# everything
# --------------------------------------------------------------------------------------
def paper_scenes():
    """The names of the scenes that are the paper's experiments (``Scene.in_paper``), in order."""
    out = []
    for n in _scenes.names():
        try:
            if not getattr(_scenes.get(n), "in_paper", True):
                continue
        except Exception:  # noqa: BLE001 - a scene that does not load is reported by its job
            pass
        out.append(n)
    return out


def reproduce(out="./liefi-out", *, only=None, t_final_scale=1.0, jobs=None, all_scenes=False):
    """Run the paper's experiments, write figures and ``summary.{md,json}`` to ``out``.

    The scenes are ``only``, else the paper's (:func:`paper_scenes`; every registered
    scene with ``all_scenes``).  ``out`` is checked first (:func:`prepare_output`).  ``jobs``: worker processes
    for independent scenes (default: the number of CPUs, at most the number of
    scenes; 1 runs everything in this process).  Returns the summary dict
    (``runs``, ``failures``, ``figures``, ``wall_seconds``, ``interrupted``, ...).
    """
    names = list(only or (_scenes.names() if all_scenes else paper_scenes()))
    jobs = _jobs(jobs, len(names))
    output = prepare_output(out)
    scale = float(t_final_scale)
    state = {"results": {}, "start": time.perf_counter(), "cpu0": _cpu_all(), "interrupted": False}

    bar = Progress(len(names), "reproduce", unit="scene")

    def finished(done):
        state["results"][done["scene"]] = done
        _drop_partial(output, done["scene"])
        _write_summary(output, names, state, scale)
        bar.update(failed=bool(done["failures"]))

    # the longest scenes first, so that the workers finish together
    order = sorted(names, key=lambda n: -_weight(n))
    tasks = [(n, output.path, scale, 0) for n in order]
    try:
        if jobs == 1:
            for task in tasks:
                finished(_scene_job(task))
        else:
            _parallel(tasks, jobs, finished)
    except KeyboardInterrupt as exc:
        with shielded():  # a second Ctrl-C does not cut the summary short (liefi._signals.shielded)
            bar.close()
            state["interrupted"] = True
            try:
                summary = _write_summary(output, names, state, scale)
            except OSError as err:  # e.g. the disk is full: say so in the one line
                exc.detail = f"the summary could not be written: {' '.join(str(err).split())}"
            else:
                exc.detail = f"the summary of the {len(summary['runs'])} finished runs is in {output.path}"
        raise
    bar.close()
    summary = _write_summary(output, names, state, scale)
    _log(
        f"reproduce: {len(summary['runs'])} runs, {len(summary['figures'])} figures, {len(summary['failures'])} "
        f"failures, {summary['wall_seconds']:.1f} s wall; written to {summary['out']}"
    )
    return summary


def _jobs(jobs, n_tasks):
    if jobs is None:
        jobs = os.cpu_count() or 1
    if isinstance(jobs, bool) or not isinstance(jobs, int) or jobs < 1:
        raise ValueError(f"jobs: must be a whole number >= 1, got {jobs!r}")
    return max(1, min(jobs, n_tasks))


def _weight(name):
    """A rough cost of a scene's experiments (its longest horizon in steps times its runs)."""
    try:
        sc = _scenes.get(name)
        plan = sc.paper_runs(sc.variant())
        return len(plan) * max((s.t_final or sc.t_final) / sc.dt for s in plan) * (2 if sc.reference == "numerical" else 1)
    except Exception:  # noqa: BLE001 - the job will report it
        return 0.0


def _cpu_all():
    """CPU seconds of this process and its finished children."""
    t = os.times()
    return t.user + t.system + t.children_user + t.children_system


def _parallel(tasks, jobs, finished):
    """Run ``_scene_job`` over ``tasks`` in ``jobs`` processes; ``finished(done)`` as each ends.

    The workers ignore SIGINT and SIGTERM: the parent receives them, kills and joins
    its workers (none is left running), removes the temporary files they were
    writing, and reports what finished."""
    import multiprocessing as mp
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait

    from .results.sweep import _stop

    methods = mp.get_all_start_methods()
    ctx = mp.get_context("fork" if "fork" in methods else None)
    pool = ProcessPoolExecutor(jobs, mp_context=ctx, initializer=ignore_in_worker)
    pending = {pool.submit(_scene_job, t) for t in tasks}
    try:
        while pending:
            done, pending = wait(pending, return_when=FIRST_COMPLETED)
            for f in done:
                finished(f.result())
    except BaseException:
        with shielded():  # the workers stopped and their files removed, whatever a second Ctrl-C says
            pids = [p.pid for p in (getattr(pool, "_processes", None) or {}).values()]
            _stop(pool)
            _remove_partial_files(tasks[0][1], pids)
        raise
    finally:
        pool.shutdown(wait=True, cancel_futures=True)


def _remove_partial_files(path, pids):
    """Remove the temporary files that the killed workers ``pids`` left in ``path`` (:func:`liefi._files.replacing`)."""
    from ._files import remove_temporaries

    remove_temporaries(path, pids)


def _partial_name(scene):
    """The file where a scene's job keeps what it finished so far (removed when the scene ends)."""
    return f".{scene}.partial.json"


def _read_partial(output, scene):
    """What a scene's job that has not returned (still running, interrupted or killed) had finished."""
    try:
        with open(os.path.join(output.path, _partial_name(scene))) as f:
            return json.load(f)
    except (OSError, ValueError):
        return None


def _drop_partial(output, scene):
    try:
        os.remove(os.path.join(output.path, _partial_name(scene)))
    except OSError:
        pass


def _write_summary(output, names, state, scale):
    """``summary.json`` and ``summary.md``: the scenes that finished, and the runs and figures that
    finished in a scene that did not (its job's partial record, :func:`_partial_name`), which stays
    listed in ``unfinished`` (a scene with nothing finished is in ``not_run``)."""
    rows, failures, figures, references, unfinished = [], [], [], [], []
    for n in names:
        done = state["results"].get(n)
        if done is None:
            done = _read_partial(output, n)
            if done is None:
                continue
            unfinished.append(n)
        rows += done["rows"]
        failures += done["failures"]
        figures += done["figures"]
        references += done.get("references", [])
    pending = [n for n in names if n not in state["results"] and n not in unfinished]
    summary = {
        "liefi_version": __version__,
        "out": output.path,
        "t_final_scale": scale,
        "wall_seconds": time.perf_counter() - state["start"],
        "cpu_seconds": _cpu_all() - state["cpu0"],
        "interrupted": state["interrupted"],
        "scenes": names,
        "not_run": pending if (state["interrupted"] or pending) else [],
        "unfinished": unfinished,
        "runs": rows,
        "references": references,
        "figures": figures,
        "failures": failures,
    }
    output.write_text("summary.json", _json.dumps(summary, indent=1, default=_json_default))
    output.write_text("summary.md", markdown_table(summary) + "\n")
    return summary


def _json_default(o):
    try:
        return float(o)
    except (TypeError, ValueError):
        return str(o)


def _seconds(x):
    """A time in seconds with three significant digits (``0.00123``, ``12.3``): a run of a few ms is not ``0.00``."""
    return f"{x:.3g}" if x >= 1e-4 else f"{x:.1e}"


def _fmt_map(d):
    return ", ".join(f"{k} {v:.2e}" for k, v in d.items()) if d else "-"


def markdown_table(summary):
    """The summary as a markdown table (one row per run), then the failures."""
    lines = [
        "| scene | variant | experiment | scheme | dt | t_final | steps | CPU [s] | reference | max abs error | max drift |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
    ]
    for r in summary["runs"]:
        if r.get("status") != "ok":
            lines.append(
                f"| {r['scene']} | {r.get('variant') or '-'} | {r.get('experiment', '')} | {r.get('scheme') or '-'} "
                f"| - | {r.get('t_final') if r.get('t_final') is not None else '-'} | - | - | - | **FAILED** | "
                f"{r['error'][:200]} |"
            )
            continue
        exp = r.get("experiment", "paper")
        lines.append(
            f"| {r['scene']} | {r['variant']} | {exp} | {r['scheme']} | {r['dt']:g} | {r['t_final']:g} | {r['steps']} "
            f"| {_seconds(r['cpu_seconds'])} | {r['reference']} | {_fmt_map(r['max_error'])} | {_fmt_map(r['max_drift'])} |"
        )
    lines.append("")
    lines.append(
        f"{len(summary['runs'])} runs, {len(summary['figures'])} figures, total wall time "
        f"{summary['wall_seconds']:.1f} s (CPU {summary['cpu_seconds']:.1f} s)"
        + (f", t_final scaled by {summary['t_final_scale']:g}" if summary["t_final_scale"] != 1 else "")
        + "."
    )
    if summary.get("interrupted") or summary.get("not_run") or summary.get("unfinished"):
        lines.append("")
        lines.append(
            ("**Interrupted**: " if summary.get("interrupted") else "")
            + "not run (or nothing finished): " + (", ".join(summary.get("not_run", ())) or "-") + "."
            + (f" Cut short (the runs and figures that finished are listed): {', '.join(summary['unfinished'])}."
               if summary.get("unfinished") else "")
        )
    refs = summary.get("references") or []
    if refs:
        lines.append("")
        lines.append("Numerical references (computed once per start, before the runs):")
        for r in refs:
            how = "reused (same start)" if r["reused"] else f"{r['seconds']:.2f} s"
            lines.append(f"- {r['scene']} / {r['variant']}: {r['method']}, t in [0, {r['t_final']:g}]: {how}")
    warned = [r for r in summary["runs"] if r.get("warnings")]
    if warned:
        lines.append("")
        lines.append("Warnings:")
        for r in warned:
            for w in r["warnings"]:
                lines.append(f"- {r['scene']} / {r['variant']} / {r['scheme']}: {w[:300]}{'...' if len(w) > 300 else ''}")
    figs = [f for f in summary["failures"] if "figure" in f]
    if figs:
        lines.append("")
        lines.append("Figure failures:")
        lines += [f"- {f['error']}" for f in figs]
    return "\n".join(lines)
