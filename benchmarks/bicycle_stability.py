"""The stability diagram of the benchmark bicycle from liefi's own linearization (``docs/bicycle.md``).

The Whipple bicycle as sympy's own test writes it (``tests/bicycle_model.py``), taken by
``liefi.from_mechanics`` and linearized on its constraint set at the upright straight run,
for forward speeds ``v`` in [0, 10] m/s: the real and imaginary parts of the four
eigenvalues of the lean-and-steer dynamics (Fig. 3 of Meijaard, Papadopoulos, Ruina &
Schwab, Proc. R. Soc. A 463 (2007) 1955), with the weave and capsize speeds found by
Brent's method and the published ones beside them.  Run from the repository root
(sympy and matplotlib needed; about two minutes)::

    python benchmarks/bicycle_stability.py            # writes docs/bicycle/stability_diagram.png
"""

from __future__ import annotations

import argparse
import pathlib
import sys
import time

import numpy as np

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path[:0] = [str(ROOT), str(ROOT / "tests")]

OUT = ROOT / "docs" / "bicycle" / "stability_diagram.png"


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", type=pathlib.Path, default=OUT)
    ap.add_argument("--points", type=int, default=101, help="speeds in [0, 10] m/s (default 101)")
    args = ap.parse_args(argv)

    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    import bicycle_model as bm
    from test_bicycle_liefi import eigenvalues, lateral, weave_and_capsize_speeds

    import liefi

    t0 = time.process_time()
    bike = bm.whipple_sympy_test()
    system = liefi.from_mechanics(bike.kane, bike.params)
    t1 = time.process_time()
    vs = np.linspace(0.0, 10.0, args.points)
    lam = np.array([np.sort_complex(lateral(bike, eigenvalues(bike, system, v))) for v in vs])
    t2 = time.process_time()

    vw, vc = weave_and_capsize_speeds(bike, system)
    print(f"weave speed {vw:.14f} (published {bm.WEAVE_SPEED:.14f}, relative error {abs(vw / bm.WEAVE_SPEED - 1):.1e})")
    print(f"capsize speed {vc:.14f} (published {bm.CAPSIZE_SPEED:.14f}, relative error {abs(vc / bm.CAPSIZE_SPEED - 1):.1e})")
    print(f"CPU s: sympy model and from_mechanics {t1 - t0:.1f}, {len(vs)} linearizations {t2 - t1:.1f}")

    fig, ax = plt.subplots(figsize=(8.0, 5.0), dpi=110)
    for k in range(4):
        ax.plot(vs, lam[:, k].real, ".", ms=3, color="C0", label="real part" if k == 0 else None)
        im = np.abs(lam[:, k].imag)
        ax.plot(vs[im > 0], im[im > 0], ".", ms=3, color="C1", label="|imaginary part|" if k == 0 else None)
    for v, name in ((vw, "weave"), (vc, "capsize")):
        ax.axvline(v, color="0.5", lw=0.8, ls="--")
        ax.text(v, 9.3, f" {name}\n {v:.5f} m/s", fontsize=9, va="top")
    ref = [(v, e) for v, es in bm.BENCHMARK_EIGENVALUES.items() for e in es]
    ax.plot([v for v, _ in ref], [e.real for _, e in ref], "o", mfc="none", color="k", ms=7,
            label="published (Meijaard et al. 2007, Table 2)")
    ax.plot([v for v, e in ref if e.imag], [abs(e.imag) for v, e in ref if e.imag], "o", mfc="none", color="k", ms=7)
    ax.axvspan(vw, vc, color="C2", alpha=0.12, label="self-stable")
    ax.set_xlim(0, 10)
    ax.set_ylim(-10, 10)
    ax.axhline(0, color="k", lw=0.6)
    ax.set_xlabel("forward speed v (m/s)")
    ax.set_ylabel("eigenvalue (1/s)")
    ax.set_title("Whipple bicycle: liefi.from_mechanics + linearize on the constraint set")
    ax.legend(loc="lower right", fontsize=9)
    fig.tight_layout()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    fig.savefig(args.out)
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
