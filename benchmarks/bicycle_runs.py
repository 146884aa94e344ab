"""Nonlinear runs of the benchmark bicycle (the scene ``bicycle``) and their figures, for ``docs/bicycle.md``.

The Whipple bicycle of Meijaard, Papadopoulos, Ruina & Schwab (2007) with Table 1's parameters,
built by ``liefi.from_mechanics`` from its Kane model (``liefi/scenes/bicycle.py``), uncontrolled,
from the upright straight run with a lean-rate kick: the scene's four variants at its settings
(``imex-rk8``, ``dt = 0.005``, gains 1000), over [0, 100] s for the stable ones and until before the
bicycle falls for the others.  Prints a Markdown table: the lean on [0, 2] s and at t = 10 s, the
model's own constraints and energy along the run (its sympy expressions, ``declared_residuals`` of
``tests/test_bicycle_liefi.py``), the CPU seconds; and the IFToMM run's difference from DOP853 at 1e-12 on
sympy's own equations of the model (``against_sympys_equations`` of ``tests/test_bicycle_scene.py``).
Writes into ``docs/bicycle/`` (``--out``):

* ``lean_steer.png``: lean and steer against time, and ``|lean|`` on a log axis;
* ``contact_paths.png``: both wheels' contact paths on the ground, one panel per run;
* ``bicycle.gif``: the IFToMM manoeuvre (4.6 m/s, 0.5 rad/s), seen from above and from behind.

Run from the repository root (sympy and matplotlib needed; Pillow for the GIF)::

    python benchmarks/bicycle_runs.py
    python benchmarks/bicycle_runs.py --frames 20 --png /tmp/frame.png --out /tmp/bike
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

#: variant -> horizon (s), as tests/test_bicycle_scene.py runs them
HORIZONS = {"self-stable": 100.0, "weave": 10.0, "capsize": 30.0, "iftomm": 100.0}


def runs(horizons=HORIZONS):
    """``(scene, {variant: RunResult}, {variant: row})`` of the scene's runs, with the measured rows."""
    from liefi import scenes
    from test_bicycle_liefi import declared_residuals

    sc = scenes.get("bicycle")
    t0 = time.process_time()
    sc.system
    build = time.process_time() - t0
    out, rows = {}, {}
    for name, T in horizons.items():
        t1 = time.process_time()
        r = sc.run(variant=name, t_final=T, save_every=2)  # every 0.01 s
        cpu = time.process_time() - t1
        velocity, f, energy = declared_residuals(sc.model, sc.system, r)
        t, lean = r.t, r["q4"]
        o = sc.variant(name).options
        rows[name] = {"v": o["speed"], "lean_rate": o["lean_rate"], "T": T, "cpu": cpu, "integrate": r.cpu_seconds,
                      "first": float(np.abs(lean[t <= 2.0]).max()), "at_10": float(lean[np.argmin(abs(t - 10.0))]),
                      "last": float(lean[-1]), "velocity": float(np.abs(velocity).max()),
                      "f": float(np.abs(f).max()), "energy": float(np.abs(energy - energy[0]).max() / abs(energy[0]))}
        out[name] = r
    return sc, out, rows, build


def table(rows, build):
    lines = [f"Build (sympy's kanes_equations and from_mechanics): {build:.1f} CPU s.", "",
             "| run | v (m/s) | lean rate (rad/s) | [0, T] s | max abs lean on [0, 2] s | lean at t = 10 s "
             "| lean at T | velocity constraints max (m/s) | front height max (m) | energy rel. "
             "| CPU s (integration) |",
             "|---|---|---|---|---|---|---|---|---|---|---|"]
    for name, x in rows.items():
        lines.append(f"| {name} | {x['v']:g} | {x['lean_rate']:g} | {x['T']:g} | {x['first']:.3g} | {x['at_10']:.3g} "
                     f"| {x['last']:.3g} | {x['velocity']:.1e} | {x['f']:.1e} | {x['energy']:.1e} "
                     f"| {x['cpu']:.1f} ({x['integrate']:.2f}) |")
    return "\n".join(lines)


def figures(sc, results, out):
    from liefi.scenes.bicycle import contacts_figure, lean_steer_figure
    from liefi.results import scene_figures as plotting

    short = {k: _until(r, 10.0 if k != "capsize" else 30.0) for k, r in results.items()}
    fig = lean_steer_figure({k: _until(r, 30.0) for k, r in results.items()})
    plotting.save(fig, out / "lean_steer.png")
    fig = contacts_figure(short)
    plotting.save(fig, out / "contact_paths.png")


def _until(r, T):
    """A view of the run ``r`` on ``[0, T]`` (its saved points)."""
    import copy

    k = r.t <= T + 1e-9
    v = copy.copy(r)
    v.t, v.y = r.t[k], r.y[:, k]
    return v


def gif(sc, r, path, frames=60, png=None, T=10.0):
    """The IFToMM run from above (both contacts' paths, the wheel base between them) and from behind (the lean)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.animation import PillowWriter

    from liefi.scenes.bicycle import contact_paths

    r = _until(r, T)
    p = contact_paths(sc.model, sc.system, r.y, r.names)
    (xr, yr), (xf, yf) = p["rear"], p["front"]
    lean, steer = r["q4"], r["q7"]
    idx = np.linspace(0, len(r.t) - 1, frames).astype(int)
    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(8.0, 3.6), dpi=72, gridspec_kw={"width_ratios": [1.7, 1]})
    ax0.set_xlim(xr.min() - 0.5, xf.max() + 0.5)
    pad = 0.1 + 0.1 * max(np.ptp(yr), np.ptp(yf))
    ax0.set_ylim(min(yr.min(), yf.min()) - pad, max(yr.max(), yf.max()) + pad)
    ax0.invert_yaxis()  # seen from above: the model's z points down, y to the right
    ax0.set_xlabel("x (m, forward)", fontsize=8)
    ax0.set_ylabel("y (m, to the right; not to scale)", fontsize=8)
    ax0.tick_params(labelsize=7)
    ax0.set_title("contact paths, seen from above", fontsize=9)
    rear, = ax0.plot([], [], lw=1.2, color="tab:blue", label="rear contact")
    front, = ax0.plot([], [], lw=0.9, ls="--", color="tab:orange", label="front contact")
    base, = ax0.plot([], [], lw=3, color="0.3", solid_capstyle="round")
    ax0.legend(fontsize=7, loc="upper right")
    ax1.set_xlim(-0.65, 0.65)
    ax1.set_ylim(-0.05, 1.3)
    ax1.set_aspect("equal")
    ax1.set_xticks([])
    ax1.set_yticks([])
    ax1.axhline(0.0, color="k", lw=0.8)
    frame, = ax1.plot([], [], lw=4, color="tab:red", solid_capstyle="round")
    bar, = ax1.plot([], [], lw=2, color="0.3")
    label = ax1.set_title("", fontsize=9)
    fig.suptitle("benchmark bicycle, 4.6 m/s, lean rate 0.5 rad/s (liefi, imex-rk8)", fontsize=9)
    fig.tight_layout()
    h = 1.1  # the height drawn for the frame (m), leaning about the ground line

    def draw(k):
        i = idx[k]
        rear.set_data(xr[:i + 1], yr[:i + 1])
        front.set_data(xf[:i + 1], yf[:i + 1])
        base.set_data([xr[i], xf[i]], [yr[i], yf[i]])
        top = (h * np.sin(lean[i]), h * np.cos(lean[i]))  # z down in the model: a positive lean is to the right
        frame.set_data([0.0, top[0]], [0.0, top[1]])
        half = 0.3 * np.cos(steer[i])  # the handlebar foreshortened by the steer
        bar.set_data([top[0] - half * np.cos(lean[i]), top[0] + half * np.cos(lean[i])],
                     [top[1] + half * np.sin(lean[i]), top[1] - half * np.sin(lean[i])])
        label.set_text(f"seen from behind: t = {r.t[i]:4.1f} s\nlean {np.degrees(lean[i]):+5.2f} deg, "
                       f"steer {np.degrees(steer[i]):+5.2f} deg")

    writer = PillowWriter(fps=10)
    with writer.saving(fig, str(path), dpi=fig.dpi):
        for k in range(frames):
            draw(k)
            writer.grab_frame()
    if png is not None:
        draw(int(frames * 0.06))
        fig.savefig(png, dpi=fig.dpi)
    plt.close(fig)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=pathlib.Path, default=ROOT / "docs" / "bicycle")
    ap.add_argument("--frames", type=int, default=60)
    ap.add_argument("--png", default=None, help="also save one frame of the GIF as PNG")
    args = ap.parse_args(argv)
    args.out.mkdir(parents=True, exist_ok=True)
    sc, results, rows, build = runs()
    print(table(rows, build), flush=True)
    from test_bicycle_scene import against_sympys_equations

    t0 = time.process_time()
    diff = against_sympys_equations(sc, _until(results["iftomm"], 10.0))
    print(f"\nIFToMM M2 on [0, 10] s against DOP853 at 1e-12 on sympy's own equations ({time.process_time() - t0:.1f} "
          "CPU s): max |difference| " + ", ".join(f"{n} {d:.1e} (size {m:.2g})" for n, (d, m) in diff.items()),
          flush=True)
    figures(sc, results, args.out)
    gif(sc, results["iftomm"], args.out / "bicycle.gif", args.frames, args.png)
    for name in ("lean_steer.png", "contact_paths.png", "bicycle.gif"):
        print(f"wrote {args.out / name}: {(args.out / name).stat().st_size / 1024:.0f} kB")
    return 0


if __name__ == "__main__":
    sys.exit(main())
