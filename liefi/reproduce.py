"""``liefi reproduce``: every experiment of the paper's Section 3, its figures and a summary.

What runs (each at the scene's own ``dt``, ``t_final``, scheme and gains, i.e. the paper's):

* every scene and every variant of :data:`liefi.scenes.REGISTRY`;
* the nonholonomic oscillator also with the DLA scheme on the same horizon
  ``[0, 200]`` (``figure:oscillator``: left column FI, right column DLA), and
  both the feedback integrator (Euler) and DLA on ``[0, 400]`` (every step
  saved) for the Poincaré sections (``figure:Poincare:FI``); the DLA runs do
  not depend on the variant (it only changes ``V``), so they run once and each
  variant's figures reuse them;
* the Suslov runs integrate the rotation matrix (``figure:Suslov_integrals``
  plots ``||R^T R - I||``).

What is written to ``out``:

* the paper's figures as PNG, named after their labels
  (``figure_Suslov_Pi_exact.png``, ``figure_Suslov_integrals.png``,
  ``figure_knife_cycloid.png``, ``figure_knife_exact.png``,
  ``figure_knife_integrals.png``, ``figure_oscillator.png``,
  ``figure_Poincare_FI.png``); a variant other than a scene's first gets a
  ``-VARIANT`` suffix; scenes without a paper figure get ``SCENE-VARIANT.png``
  (errors and drifts vs ``t``, semilogy);
* ``summary.json`` (every run: settings, steps, CPU time, max errors, max drifts,
  figures, status) and ``summary.md`` (the same as a markdown table).

``t_final_scale`` (``--t-final-scale``, for tests) multiplies every horizon,
rounded to a whole number of steps.  A failing experiment is recorded (status
``failed`` and its error) and the others still run.
"""

from __future__ import annotations

import json
import os
import sys
import time
import traceback
import warnings

from . import scenes as _scenes

#: the Poincaré sections of the oscillator run over [0, 400] (paper, "Comparisons")
POINCARE_T_FINAL = 400.0


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


def _row(result, experiment, wall):
    d = result.to_dict()
    d.update(experiment=experiment, status="ok", wall_seconds=wall, figures=[])
    return d


def _failed_row(scene, variant, scheme, t_final, experiment, exc):
    return {
        "scene": scene,
        "variant": variant,
        "scheme": scheme,
        "t_final": t_final,
        "experiment": experiment,
        "status": "failed",
        "error": f"{type(exc).__name__}: {' '.join(str(exc).split())}",
        "figures": [],
    }


class _Runner:
    def __init__(self, out, t_final_scale):
        self.out = out
        self.scale = float(t_final_scale)
        self.rows = []
        self.failures = []
        self.figures = []
        self.count = 0

    def run(self, scene, variant, *, scheme=None, t_final=None, configuration=None, experiment="paper",
            save_every=None):
        """Run one experiment; returns the result or None (failure recorded)."""
        scheme = scheme or scene.scheme
        T = _horizon(scene.t_final if t_final is None else t_final, scene.dt, self.scale)
        self.count += 1
        tag = f"[{self.count}] {scene.name} / {variant} / {scheme} / t in [0, {T:g}]"
        _log(f"{tag} ...")
        start = time.perf_counter()
        try:
            with warnings.catch_warnings(record=True) as caught:
                warnings.simplefilter("always")
                result = scene.run(
                    scheme=scheme, t_final=T, variant=variant, configuration=configuration, save_every=save_every
                )
        except Exception as exc:  # noqa: BLE001 - record and go on with the other experiments
            row = _failed_row(scene.name, variant, scheme, T, experiment, exc)
            self.rows.append(row)
            self.failures.append(row)
            _log(f"{tag} FAILED: {row['error']}")
            return None
        wall = time.perf_counter() - start
        row = _row(result, experiment, wall)
        msgs = list(dict.fromkeys(f"{w.category.__name__}: {' '.join(str(w.message).split())}" for w in caught))
        if msgs:
            row["warnings"] = msgs
            for m in msgs:
                _log(f"  warning: {m}")
        self.rows.append(row)
        worst = max(result.max_error.values(), default=float("nan"))
        _log(f"{tag} done: CPU {result.cpu_seconds:.2f} s, wall {wall:.2f} s, max |error| {worst:.3e}")
        result._row = row
        return result

    def figure(self, key, draw, filename, rows):
        """Draw one figure into ``out/filename``; record it on ``rows``."""
        from . import plotting

        path = os.path.join(self.out, filename)
        try:
            fig = draw(None)
            plotting.save(fig, path)
        except Exception as exc:  # noqa: BLE001
            msg = f"figure {filename} ({key}): {type(exc).__name__}: {' '.join(str(exc).split())}"
            _log("  " + msg)
            self.failures.append({"figure": filename, "status": "failed", "error": msg})
            if os.environ.get("LIEFI_DEBUG"):
                traceback.print_exc()
            return None
        for r in rows:
            r["figures"].append(filename)
        self.figures.append(filename)
        _log(f"  wrote {path}")
        return path


def _oscillator(runner, scene, variant, default_variant, dla_cache):
    """``figure:oscillator`` (FI and DLA on the paper's horizon) and ``figure:Poincare:FI``
    (both on [0, 400], every step saved).  The DLA does not depend on the variant (which
    only changes ``V``): it runs once per start and horizon and is reused."""
    import importlib

    import numpy as np

    from . import plotting

    has_dla = "dla" in scene.extra_schemes
    start_key = tuple(np.asarray(scene.initial_state(scene.variant(variant)), float).round(15))

    def dla_run(t_final, experiment, save_every=None):
        key = (start_key, t_final)
        if key not in dla_cache:
            dla_cache[key] = runner.run(scene, variant, scheme="dla", t_final=t_final, experiment=experiment,
                                        save_every=save_every)
        return dla_cache[key]

    fi = runner.run(scene, variant, scheme="euler", experiment="figure:oscillator")
    dla = dla_run(None, "figure:oscillator") if has_dla else None
    runs = [r for r in (fi, dla) if r is not None]
    if runs:
        runner.figure(
            "figure:oscillator",
            lambda f: plotting.oscillator_integrals(fi, dla, f, tag=_tag(variant, default_variant)),
            _figure_file("figure:oscillator", scene.name, variant, default_variant),
            [r._row for r in runs],
        )

    long = []
    # every step saved: the crossings y = 0 are interpolated between saved points
    fi_long = runner.run(scene, variant, scheme="euler", t_final=POINCARE_T_FINAL,
                         experiment="figure:Poincare:FI", save_every=1)
    dla_long = dla_run(POINCARE_T_FINAL, "figure:Poincare:FI", save_every=1) if has_dla else None
    for r in (fi_long, dla_long):
        if r is None:
            continue
        try:
            sec, ref = oscillator_sections(r)
        except Exception as exc:  # noqa: BLE001
            sec = ref = None
            msg = f"poincare_section({r.scheme}): {type(exc).__name__}: {exc}"
            _log("  " + msg)
            runner.failures.append({"figure": "figure:Poincare:FI", "status": "failed", "error": msg})
        long.append((r, sec, ref))
    if long:
        runner.figure(
            "figure:Poincare:FI",
            lambda f: plotting.oscillator_poincare(long, f, tag=_tag(variant, default_variant)),
            _figure_file("figure:Poincare:FI", scene.name, variant, default_variant),
            [r._row for r, _, _ in long],
        )


def oscillator_sections(result):
    """``(sections, reference_sections)`` of an oscillator run (``figure:Poincare:FI``).

    ``sections`` is ``liefi.scenes.oscillator.poincare_section(result)``; the reference
    sections apply the same function to the reference solution at the saved times
    (``data - error``: no extra integration), or are ``None`` when the run lacks errors.
    """
    import importlib
    from types import SimpleNamespace

    import numpy as np

    section = getattr(importlib.import_module("liefi.scenes.oscillator"), "poincare_section", None)
    if section is None:
        return None, None
    sec = section(result)
    if not all(n in result.errors for n in result.names):
        return sec, None
    Y = np.stack([np.asarray(result[n]) - np.asarray(result.errors[n]) for n in result.names])
    ref = section(SimpleNamespace(t=result.t, y=Y, names=result.names))
    return sec, ref


def _tag(variant, default_variant):
    return "" if variant == default_variant else f" [variant {variant}]"


def reproduce(out="./liefi-out", *, only=None, t_final_scale=1.0):
    """Run the paper's experiments, write figures and ``summary.{md,json}`` to ``out``.

    Returns the summary dict (``runs``, ``failures``, ``figures``, ``wall_seconds``, ...).
    """
    from . import plotting

    os.makedirs(out, exist_ok=True)
    runner = _Runner(out, t_final_scale)
    start = time.perf_counter()
    cpu0 = time.process_time()
    for name in only or _scenes.names():
        try:
            scene = _scenes.get(name)
        except Exception as exc:  # noqa: BLE001 - e.g. the scene module is missing
            row = _failed_row(name, None, None, None, "paper", exc)
            runner.rows.append(row)
            runner.failures.append(row)
            _log(f"{name}: FAILED to load: {row['error']}")
            continue
        variants = list(scene.variants) or [None]
        default_variant = variants[0]
        dla_cache = {}
        for variant in variants:
            if name == "oscillator":
                _oscillator(runner, scene, variant, default_variant, dla_cache)
                continue
            cfg = True if plotting.needs_configuration(name) else None
            r = runner.run(scene, variant, configuration=cfg)
            if r is None:
                continue
            tag = _tag(variant, default_variant)
            for key, _ in plotting.scene_figures(r, title=scene.title):
                draw = _drawer(key, r, scene.title, tag)
                runner.figure(key, draw, _figure_file(key, name, variant, default_variant), [r._row])
    summary = {
        "out": os.path.abspath(out),
        "t_final_scale": runner.scale,
        "wall_seconds": time.perf_counter() - start,
        "cpu_seconds": time.process_time() - cpu0,
        "runs": runner.rows,
        "figures": runner.figures,
        "failures": runner.failures,
    }
    with open(os.path.join(out, "summary.json"), "w") as f:
        json.dump(summary, f, indent=1, default=_json_default)
    with open(os.path.join(out, "summary.md"), "w") as f:
        f.write(markdown_table(summary) + "\n")
    _log(
        f"reproduce: {len(runner.rows)} runs, {len(runner.figures)} figures, {len(runner.failures)} failures, "
        f"{summary['wall_seconds']:.1f} s wall; written to {summary['out']}"
    )
    return summary


def _drawer(key, result, title, tag):
    from . import plotting

    table = {
        "figure:Suslov_Pi_exact": plotting.suslov_momentum_error,
        "figure:Suslov_integrals": plotting.suslov_integrals,
        "figure:knife_cycloid": plotting.knife_cycloid,
        "figure:knife_exact": plotting.knife_errors,
        "figure:knife_integrals": plotting.knife_integrals,
    }
    if key in table:
        return lambda f: table[key](result, f, tag=tag)
    return lambda f: plotting.generic(result, f, title=title, tag=tag)


def _json_default(o):
    try:
        return float(o)
    except (TypeError, ValueError):
        return str(o)


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
            f"| {r['cpu_seconds']:.2f} | {r['reference']} | {_fmt_map(r['max_error'])} | {_fmt_map(r['max_drift'])} |"
        )
    lines.append("")
    lines.append(
        f"{len(summary['runs'])} runs, {len(summary['figures'])} figures, total wall time "
        f"{summary['wall_seconds']:.1f} s (CPU {summary['cpu_seconds']:.1f} s)"
        + (f", t_final scaled by {summary['t_final_scale']:g}" if summary["t_final_scale"] != 1 else "")
        + "."
    )
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
