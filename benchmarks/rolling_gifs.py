"""Animations (GIF) of two rolling scenes, for ``docs/rolling_bodies.md``.

* ``rattleback.gif``: Kane & Levinson's rattleback seen from above -- its long
  axis (the ellipsoid's ``a`` axis, horizontal projection) turning, with the
  trace of its tip, beside the long axis' heading rate against time; the
  sense of rotation (counter-clockwise / clockwise) is written and coloured.
* ``chaplygin_ball.gif``: the Chaplygin ball's contact point tracing its path
  on the plane, the ball's outline and a body-fixed diameter drawn at it.

Both from liefi's runs (``imex-rk4 --gains auto``, the scenes' steps, with the
configuration).  Run from the repository root (matplotlib and Pillow needed)::

    python benchmarks/rolling_gifs.py                 # writes docs/rolling_bodies/*.gif
    python benchmarks/rolling_gifs.py --out /tmp/gifs --frames 20 --png /tmp/gifs/frame.png
"""

from __future__ import annotations

import argparse
import pathlib
import sys

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))


def _run(name, t_final):
    from liefi import scenes

    sc = scenes.get(name)
    r = sc.run(t_final=t_final, scheme="imex-rk4", gains="auto", configuration=True, max_saved=4000)
    return sc, r, {n: r.y[i] for i, n in enumerate(r.names)}


def rattleback_gif(path, frames=60, png=None, t_final=5.0):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from liefi.scenes.rattleback import SEMI_AXES, heading_rate

    sc, r, d = _run("rattleback", t_final)
    W, G = sc.body_rates(r.y, list(r.names))
    rate = heading_rate(W, G)
    a = SEMI_AXES[0]
    ex, ey = a * d["R11"], a * d["R21"]  # the long axis' horizontal projection (R e_1)
    idx = np.linspace(0, len(r.t) - 1, frames).astype(int)

    fig, (ax0, ax1) = plt.subplots(1, 2, figsize=(6.4, 3.0), dpi=64, gridspec_kw={"width_ratios": [1, 1.5]})
    ax0.set_xlim(-1.15 * a, 1.15 * a)
    ax0.set_ylim(-1.15 * a, 1.15 * a)
    ax0.set_aspect("equal")
    ax0.set_xticks([])
    ax0.set_yticks([])
    ax0.set_title("seen from above", fontsize=9)
    trail, = ax0.plot([], [], lw=0.6, color="0.6")
    axis, = ax0.plot([], [], lw=4, solid_capstyle="round")
    tip, = ax0.plot([], [], "o", ms=5)
    label = ax0.text(0.5, 0.04, "", transform=ax0.transAxes, ha="center", fontsize=9)
    ax1.plot(r.t, rate, lw=0.5, color="0.5")
    ax1.axhline(0.0, color="k", lw=0.4)
    ax1.set_xlabel("t (s)", fontsize=8)
    ax1.set_ylabel("heading rate of the long axis (rad/s)", fontsize=8)
    ax1.tick_params(labelsize=7)
    ax1.set_title("the rattleback reverses (liefi, imex-rk4)", fontsize=9)
    marker, = ax1.plot([], [], "o", ms=5)
    fig.tight_layout()

    def draw(k):
        i = idx[k]
        ccw = rate[i] > 0
        col = "tab:blue" if ccw else "tab:red"
        lo = max(0, i - 400)
        trail.set_data(ex[lo:i + 1], ey[lo:i + 1])
        axis.set_data([-ex[i], ex[i]], [-ey[i], ey[i]])
        axis.set_color(col)
        tip.set_data([ex[i]], [ey[i]])
        tip.set_color(col)
        label.set_text(f"t = {r.t[i]:.2f} s  " + ("counter-clockwise" if ccw else "clockwise"))
        label.set_color(col)
        marker.set_data([r.t[i]], [rate[i]])
        marker.set_color(col)

    _write(fig, draw, frames, path, png, fps=12)
    plt.close(fig)
    return r


def ball_gif(path, frames=60, png=None, t_final=30.0):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    sc, r, d = _run("chaplygin-ball", t_final)
    x, y = d["r_1"], d["r_2"]  # the centre; the contact point is below it
    a = sc.radius
    idx = np.linspace(0, len(r.t) - 1, frames).astype(int)
    pad = 1.2 * a
    w, h = np.ptp(x) + 2 * pad, np.ptp(y) + 2 * pad
    fig, ax = plt.subplots(figsize=(1.0 + 3.6 * min(1.0, w / h), 0.6 + 3.6 * min(1.0, h / w)), dpi=64)
    ax.set_xlim(x.min() - pad, x.max() + pad)
    ax.set_ylim(y.min() - pad, y.max() + pad)
    ax.set_aspect("equal")
    path_line, = ax.plot([], [], lw=1.0, color="tab:blue")
    ball = plt.Circle((x[0], y[0]), a, fill=False, lw=1.0, color="0.3")
    ax.add_patch(ball)
    diam, = ax.plot([], [], lw=1.5, color="tab:orange")
    dot, = ax.plot([], [], "o", ms=4, color="tab:blue")
    title = ax.set_title("Chaplygin ball: contact path, t = 00.0", fontsize=9)
    ax.set_xlabel("x", fontsize=8)
    ax.set_ylabel("y", fontsize=8)
    ax.tick_params(labelsize=7)
    fig.tight_layout()

    def draw(k):
        i = idx[k]
        path_line.set_data(x[:i + 1], y[:i + 1])
        dot.set_data([x[i]], [y[i]])
        ball.center = (x[i], y[i])
        ux, uy = a * d["R11"][i], a * d["R21"][i]  # body axis e_1, seen from above
        diam.set_data([x[i] - ux, x[i] + ux], [y[i] - uy, y[i] + uy])
        title.set_text(f"Chaplygin ball: contact path, t = {r.t[i]:.1f}")

    _write(fig, draw, frames, path, png, fps=10)
    plt.close(fig)
    return r


def _write(fig, draw, frames, path, png, fps):
    from matplotlib.animation import PillowWriter

    writer = PillowWriter(fps=fps)
    with writer.saving(fig, str(path), dpi=fig.dpi):
        for k in range(frames):
            draw(k)
            writer.grab_frame()
    if png is not None:
        draw(int(frames * 0.7))
        fig.savefig(png, dpi=fig.dpi)


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", default=str(ROOT / "docs" / "rolling_bodies"))
    p.add_argument("--frames", type=int, default=60)
    p.add_argument("--only", choices=("rattleback", "chaplygin_ball"), default=None)
    p.add_argument("--png", default=None, help="also save one frame of each as PNG (prefix)")
    args = p.parse_args(argv)
    out = pathlib.Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    png = None if args.png is None else pathlib.Path(args.png)
    for name, make in (("rattleback", rattleback_gif), ("chaplygin_ball", ball_gif)):
        if args.only not in (None, name):
            continue
        target = out / f"{name}.gif"
        make(target, args.frames, None if png is None else png.with_name(f"{png.stem}-{name}.png"))
        print(f"{target}: {target.stat().st_size / 1024:.0f} kB")


if __name__ == "__main__":
    main()
