"""The rolling disk's upright rolling: its eigenvalues against the spin, with the critical spin marked.

A uniform thin disk (``m = a = g = 1``) is built from its data by
``liefi.rolling.rolling_body``, set rolling upright in a straight line at the spin
``omega`` (``liefi.rolling.rolling_start``), and linearized there with
``system.linearize(z)``: six minimal coordinates on the constraint set, four trivial
zeros (the energy, the heading, the disk's own axis, the family of steady motions)
and two nontrivial eigenvalues ``+-sqrt(-sigma^2)``.  The upright rolling is stable
for ``omega^2 > m g a A / (C (C + m a^2)) = g / (3a)`` (Routh, *Advanced Rigid
Dynamics*, sec. 244); the critical spin is found by root finding on
``-trace(A^2) / 2 = sigma^2`` (the trivial modes are zeros, the pair is ``+-lambda``).

Run ``python examples/linearize_disk.py [out.png]``: it prints the critical spin
against ``sqrt(g / (3a))`` and saves the figure (default ``liefi-out/disk_eigenvalues.png``; the docs'
figure is ``docs/linearize/disk_eigenvalues.png``).
"""

import sys

import numpy as np
from scipy.optimize import brentq

from liefi.groups import SO3
from liefi.rolling import disk, rolling_body, rolling_start


def main(out="liefi-out/disk_eigenvalues.png", speeds=np.linspace(0.05, 1.5, 59)):
    """Sweep the spin, find the critical one, draw the eigenvalues; returns ``(speeds, eigenvalues, omega_c)``."""
    m = a = g = 1.0
    system = rolling_body(m, m * a * a * np.array([0.25, 0.25, 0.5]), disk(a), gravity=g,
                          sample=SO3().exp([np.pi / 2, 0.0, 0.0]))
    R = SO3().exp([np.pi / 2, 0.0, 0.0])  # the disk's axis (body e_3) horizontal: upright

    def eigenvalues(w):
        return system.linearize(rolling_start(system, R, [0.0, 0.0, w])).nontrivial_eigenvalues

    ev = np.array([np.sort_complex(eigenvalues(w)) for w in speeds])
    def sigma2(w):  # the trivial modes are zeros, so trace(A^2) = 2 lambda^2 = -2 sigma^2 (no eigensolver)
        A = system.linearize(rolling_start(system, R, [0.0, 0.0, w])).A
        return -0.5 * float(np.trace(A @ A))

    wc = brentq(sigma2, 0.1, 1.5, xtol=1e-15, rtol=1e-15)
    print(f"critical spin {wc:.15f}; Routh's sqrt(g / (3a)) = {np.sqrt(g / (3 * a)):.15f}; "
          f"relative difference {abs(wc / np.sqrt(g / (3 * a)) - 1):.1e}")
    if out:
        import matplotlib

        matplotlib.use("Agg")
        import matplotlib.pyplot as plt

        fig, ax = plt.subplots(figsize=(6.4, 3.8))
        ax.plot(speeds, ev.real, "C0.", ms=4)
        ax.plot(speeds, ev.imag, "C1.", ms=3)
        ax.plot([], [], "C0.", label="real parts")
        ax.plot([], [], "C1.", label="imaginary parts")
        ax.axvline(wc, color="k", lw=0.8, ls="--", label=rf"$\omega_c = \sqrt{{g/3a}}$ = {wc:.4f}")
        ax.axhline(0.0, color="0.6", lw=0.5)
        ax.set_xlabel(r"spin $\omega$ (rad/s), $m = a = g = 1$")
        ax.set_ylabel("nontrivial eigenvalues")
        ax.set_title("Upright rolling disk: unstable below $\\omega_c$, stable above")
        ax.legend(loc="upper left", fontsize=8)
        fig.tight_layout()
        import pathlib

        pathlib.Path(out).parent.mkdir(parents=True, exist_ok=True)
        fig.savefig(out, dpi=110)
        plt.close(fig)
        print(f"saved {out}")
    return speeds, ev, wc


if __name__ == "__main__":
    main(*sys.argv[1:2])
