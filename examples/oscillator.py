"""Nonholonomic oscillator: feedback integrator vs. discrete Lagrange--d'Alembert (paper Sec. 3).

Both integrators are built from the same data -- metric ``I``, potential
``|q|^2/2``, constraint vector ``e = (1, 0, y)/sqrt(1 + y^2)`` -- the feedback
integrator by :class:`liefi.FeedbackIntegrator` (through the scene), the DLA
integrator by :meth:`liefi.dla.DLAIntegrator.from_system`.  The script prints
the largest excursions of the three quantities of Figure
``figure:oscillator`` (``Delta H``, ``Delta H_y``, ``J``) for each, and the
Poincaré snapshots of Figure ``figure:Poincare:FI`` (``y`` crossing 0 upward).

Run ``python examples/oscillator.py`` for the paper's horizon ``[0, 200]``
(Euler, ``dt = 1e-3``, gains ``k_1 = 500``, ``k_2 = k_3 = 300``; about half a
minute); ``python examples/oscillator.py --plot`` also draws the two figures
(needs matplotlib; the scene draws them, ``scene.figures``).
"""

import sys

from liefi import scenes
from liefi.scenes.oscillator import poincare_section


def main(t_final=200.0, dt=1e-3, plot=False):
    """Run FI (Euler) and DLA; print drifts and Poincaré snapshots.

    Returns
    -------
    dict
        ``{"fi": RunResult, "dla": RunResult, "sections": {"fi": ..., "dla": ...}}``.
    """
    scene = scenes.get("oscillator")
    runs = {
        "fi": scene.run(t_final=t_final, dt=dt, save_every=1),
        "dla": scene.run(t_final=t_final, dt=dt, save_every=1, scheme="dla"),
    }
    print(f"nonholonomic oscillator, dt={dt:g}, t in [0, {t_final:g}], FI gains {scene.gains}")
    print(f"{'':>5} {'max|dH|':>10} {'max|dH_y|':>10} {'max|J|':>10} {'max err':>10} {'cpu s':>7}")
    for k, r in runs.items():
        d = r.max_drift
        print(f"{k:>5} {d['h']:10.2e} {d['H_y']:10.2e} {d['J_1']:10.2e} "
              f"{max(r.max_error.values()):10.2e} {r.cpu_seconds:7.2f}")
    sections = {k: poincare_section(r) for k, r in runs.items()}
    for k, s in sections.items():
        print(f"{k:>5} Poincaré snapshots (t, x, z, p_z):")
        for row in zip(s["t"][:5], s["x"][:5], s["z"][:5], s["p_z"][:5]):
            print("       " + "  ".join(f"{v:9.5f}" for v in row))
    if plot:
        from liefi import plotting

        for spec in scene.figures(runs):  # figure:oscillator and figure:Poincare:FI, FI and DLA side by side
            path = spec.key.replace(":", "_") + ".png"
            plotting.save(spec.draw(None), path)
            print(f"wrote {path}")
    return {**runs, "sections": sections}


if __name__ == "__main__":
    main(plot="--plot" in sys.argv[1:])
