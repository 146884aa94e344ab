"""``liefi stability SCENE``: the pre-run estimate at a scene's settings and its measured map; the docs' report."""

from __future__ import annotations

import argparse
import math

from ..schemes import positive_int
from ..integrator.stability import estimate
from .battery import battery_table, plot_work_precision, run_battery, stiff_work_precision
from .stability_maps import plot_stability_map, stability_map


def _jobs(text):
    """``--jobs``: a whole number >= 1 (argparse names the flag in its error)."""
    try:
        return positive_int(int(text), "jobs")
    except ValueError:
        raise argparse.ArgumentTypeError(f"must be a whole number >= 1, got {text!r}") from None


def sweep_gains(text):
    """``--gains K1,K2,...`` -> the list of gains ``k`` (every gain equal to ``k``), or None; a ``ValueError``
    naming ``gains`` unless every entry is a finite positive number."""
    if text is None:
        return None
    try:
        gains = [float(x) for x in str(text).split(",")]
    except ValueError:
        raise ValueError(f"gains: expected a comma list of numbers K1,K2,... (every gain equal to k), "
                         f"got {text!r}") from None
    bad = [k for k in gains if not (math.isfinite(k) and k > 0)]
    if bad:
        raise ValueError(f"gains: every gain k must be a finite positive number, got {bad[0]!r} in {text!r}")
    return gains


def _estimate_at(fi, dt, scheme, T, k=None):
    """:func:`liefi.integrator.stability.estimate` at the scene's gains, or (``k``) at every gain equal to ``k``."""
    est = estimate(fi if k is None else fi.with_gains(k), dt, scheme, t_final=T)
    if k is not None and not (math.isfinite(est.lam) and est.lam < 1e300):
        raise ValueError(f"gains: at k = {k:g} the largest eigenvalue of Hess V is {est.lam:.3g}, past the ~1e300 "
                         "where a step's dt times the gains overflows; give a smaller gain")
    return est


def _estimate_dict(est):
    return {
        "scheme": est.scheme, "bound": est.bound, "dt": est.dt, "lambda_max": est.lam, "lambda_0": est.lam0,
        "t_max": est.t_max, "ratio": est.ratio, "verdict": est.verdict, "dt_safe": est.dt_safe,
        "gains": est.gains, "message": est.message()}


def add_arguments(parser):
    """Add the arguments of ``liefi stability`` to an ``argparse`` (sub)parser."""
    parser.add_argument("scene", help="scene name (see `liefi list`)")
    parser.add_argument("--variant", default=None)
    parser.add_argument("--scheme", default="euler", help="euler, heun, rk4, ... (default euler)")
    parser.add_argument("--gains", default=None, metavar="K1,K2,...",
                        help="the gains k of the sweep, every gain equal to k (default 1, 3.16, ..., 1e4); "
                             "with --estimate, the estimate at each k (default: at the scene's gains)")
    parser.add_argument("--t-final", type=float, default=None, help="horizon of each run (default min(scene's, 10))")
    parser.add_argument("--tol", type=float, default=0.02, help="relative tolerance of the boundaries in dt")
    parser.add_argument("--accurate", type=float, default=1e-2, help="drift (relative to scale) called accurate")
    parser.add_argument("--jobs", type=_jobs, default=1, help="worker processes (default 1: serial)")
    parser.add_argument("--backend", default="auto", choices=("auto", "numpy", "numba"))
    parser.add_argument("--out", default=None, metavar="FILE.png|DIR",
                        help="write the map to this file (a folder: SCENE-stability.png in it)")
    parser.add_argument("--plot", dest="out", help=argparse.SUPPRESS)  # deprecated spelling of --out
    parser.add_argument("--estimate", action="store_true",
                        help="only the pre-run estimate at the scene's settings (no sweep)")
    parser.add_argument("--json", action="store_true",
                        help="print strict JSON instead of a table; a number that is not finite is null: "
                             "\"bound\": null is a scheme with no real stability bound (stable on the whole "
                             "negative real axis), \"dt_safe\": null no step limit from the feedback's stiffness")
    return parser


def command(args, file=None):
    """Body of ``liefi stability SCENE`` (``args`` from :func:`add_arguments`); returns the exit code.

    Prints the estimate at the scene's settings and, unless ``--estimate``, the
    measured map (a table, or JSON with ``--json``); ``--out`` writes the figure.
    Errors in the arguments raise ``ValueError`` naming the argument.

    The JSON is strict (:func:`liefi._json.dumps`): a number that is not finite
    is ``null``.  In ``estimate``, ``"bound": null`` is a scheme with no real
    stability bound (a split ``imex-*`` scheme: stable on the whole negative real
    axis) and ``"dt_safe": null`` a step that the feedback's stiffness does not
    limit; in ``map``, ``"bound"``, ``"dt_estimate"``, ``"dt_estimate0"`` and the
    upper end of a ``"finite"`` or ``"accurate"`` interval read the same way (no
    limit: none was found).
    """
    import os
    import sys

    from .. import scenes as _scenes
    from .._json import dumps

    out = file or sys.stdout
    gains = sweep_gains(args.gains)  # checked before any work
    sc = _scenes.get(args.scene)
    if args.out and not args.estimate and not os.path.isdir(args.out):  # the figure's format, before any work
        from ..results.scene_figures import check_format

        check_format(args.out, "out")
    fi = sc.integrator(sc.variant(args.variant))
    T = float(args.t_final) if args.t_final is not None else float(sc.t_final)
    # --estimate --gains: the estimate at each k given (one k: "estimate" is its dict, several: a list)
    at = gains if args.estimate and gains else [None]
    ests = [_estimate_at(fi, sc.dt, args.scheme, T, k) for k in at]
    est = ests[0]
    result = {"scene": sc.name, "estimate": (_estimate_dict(est) if len(ests) == 1
                                              else [_estimate_dict(e) for e in ests])}
    if not args.estimate:
        ex = None
        if args.jobs and int(args.jobs) > 1:
            from concurrent.futures import ProcessPoolExecutor

            ex = ProcessPoolExecutor(int(args.jobs))
        try:
            smap = stability_map(sc.name, gains=gains, scheme=args.scheme, variant=args.variant,
                                 t_final=min(T, 10.0) if args.t_final is None else T, tol=args.tol,
                                 accurate=args.accurate, executor=ex, backend=args.backend)
        finally:
            if ex is not None:
                ex.shutdown()
        result["map"] = smap.to_dict()
        if args.out:
            plot_stability_map(smap, args.out)
            result["plot"] = args.out
    if args.json:
        out.write(dumps(result, indent=2, default=float) + "\n")
        return 0
    for k, e in zip(at, ests):
        where = f"gains {sc.gains}" if k is None else f"every gain {k:g}"
        what = "the scene's settings" if k is None else "the scene's step"
        out.write(f"{sc.name}: at {what} (dt = {sc.dt:g}, {where}, t in [0, {T:g}]):\n  " + e.message() + "\n")
    if not args.estimate:
        out.write(f"\nmeasured map ({smap.scheme}, runs of t in [0, {smap.t_final:g}], boundaries to "
                  f"{100 * smap.tol:g} % in dt):\n" + smap.table() + "\n")
        if args.out:
            out.write(f"map written to {args.out}\n")
    return 0


def write_report(out_dir="docs/stability", *, scenes=None, quick=False, executor=None, backend="auto"):
    """Regenerate the figures and tables of ``docs/stability.md``.

    Writes ``<out_dir>/map-<scene>.png`` for every scene, ``work-precision.png``
    and ``tables.md`` (the maps' tables, the battery's table and the
    work-precision rows).  Returns the markdown of ``tables.md``.
    """
    import os

    from .. import scenes as _scenes

    os.makedirs(out_dir, exist_ok=True)
    names = list(_scenes.names() if scenes is None else scenes)
    parts = ["# Stability: generated tables\n", "Generated by `liefi.experiments.stability_cli.write_report`.\n"]
    parts.append("## Stability maps (Euler, every gain equal to k)\n")
    gains = [1.0, 10.0, 100.0, 1000.0] if quick else None
    for nm in names:
        sc = _scenes.get(nm)
        v = sc.stability_variant
        smap = stability_map(nm, gains=gains, variant=v, t_final=2.0 if quick else None, executor=executor,
                             backend=backend)
        plot_stability_map(smap, os.path.join(out_dir, f"map-{nm}.png"))
        parts.append(f"### {nm} ({sc.variant(v).name}), t in [0, {smap.t_final:g}]\n\n![map](stability/map-{nm}.png)\n\n"
                     + smap.table() + "\n")
    res = run_battery(names, quick=quick, executor=executor, backend=backend)
    parts.append("## The extreme-case battery\n\n" + battery_table(res) + "\n")
    stiff = next((s for s in map(_scenes.get, _scenes.names()) if s.stiff_study), None)  # the scene's choice
    if stiff is not None:
        rows = stiff_work_precision(stiff, t_final=2.0 if quick else 5.0)
        plot_work_precision(rows, os.path.join(out_dir, "work-precision.png"),
                            f"{stiff.name}: explicit (auto gains), split imex and implicit solve_ivp")
        wp = ["| method | dt / rtol | outcome | max error | max drift | cpu s |",
              "| --- | --- | --- | --- | --- | --- |"]
        for r in rows:
            f = lambda x: "-" if not isinstance(x, float) or not math.isfinite(x) else f"{x:.2g}"  # noqa: E731
            wp.append(f"| {r['label']} | {r['dt'] if r['dt'] is not None else r['rtol']:g} | {r['outcome']} | "
                      f"{f(r['error'])} | {f(r['drift'])} | {f(r['cpu'])} |")
        parts.append(f"## Work-precision ({stiff.name})\n\n![wp](stability/work-precision.png)\n\n"
                     + "\n".join(wp) + "\n")
    text = "\n".join(parts)
    with open(os.path.join(out_dir, "tables.md"), "w") as fh:
        fh.write(text)
    return text


def main(argv=None):
    """``python -m liefi.experiments.stability_cli SCENE [...]`` (the same as ``liefi stability``); ``--report DIR`` regenerates the docs."""
    import argparse
    import sys

    if argv is None:
        argv = sys.argv[1:]
    if argv and argv[0] == "--report":
        write_report(argv[1] if len(argv) > 1 else "docs/stability", quick="--quick" in argv)
        return 0
    p = add_arguments(argparse.ArgumentParser(prog="liefi stability", description=command.__doc__.split("\n")[0]))
    args = p.parse_args(argv)
    try:
        return command(args)
    except ValueError as exc:
        print(f"liefi stability: error: {exc}", file=__import__("sys").stderr)
        return 2


if __name__ == "__main__":  # pragma: no cover -- ``python -m``: use the package's module (one set of classes)
    from liefi.experiments.stability_cli import main as _main

    raise SystemExit(_main())
