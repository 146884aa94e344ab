"""Steering a roller racer: the steering torque that drives it furthest, by gradients of liefi's own runs.

The roller racer (``liefi.scenes.roller_racer``) starts at rest with its steering
angle at 45 degrees.  A torque ``tau(t)`` on the steering joint, piecewise constant
over ``N`` intervals of ``[0, T]``, makes it wriggle forward (its wheels' rolling
constraints turn the joint's oscillation into travel).  We choose the ``N`` values to

    maximize  x(T) - eps * (T / N) * sum_j tau_j^2

(the distance along the start heading, less a small torque-effort penalty) with
``scipy.optimize.minimize(method="L-BFGS-B", jac=...)``, the gradient from the
forced run's sensitivities ``sol.sensitivities["tau"]`` (``d y(t) / d tau_j``, exact
derivatives of the states liefi returned: ``liefi.integrator._forced_sensitivity``),
and compare with ``minimize``'s own finite-difference gradient (``jac=None``).

On every iterate the run's constraint drift (``max |J_1|, |J_2|``) and its energy balance
``h~ - W`` are recorded (a callback): they stay at rounding.

Run:  python examples/steering.py [--write] [--no-compare]
      (--write: docs/steering/path.png, docs/steering/racer.gif)
"""

from __future__ import annotations

import argparse
import pathlib
import time

import numpy as np
from scipy.optimize import minimize

import liefi
from liefi.scenes.roller_racer import RollerRacer
from liefi.systems.forcing import ForceLaw, piecewise_constant, spline

ROOT = pathlib.Path(__file__).resolve().parent.parent


def steering_torque(t, q, v, u):
    """The generalized force: ``u`` on the steering joint ``phi`` (the last velocity), nothing on the body."""
    F = np.zeros(np.broadcast_shapes(v.shape, u.shape[:-1] + (4,)), np.result_type(v, u, float))
    F[..., 3] = u[..., 0]
    return F


class Racer:
    """The roller racer at rest, driven by a piecewise-constant torque over ``n`` intervals of ``[0, T]``."""

    def __init__(self, T=3.0, n=10, dt=0.03, eps=0.01, bound=1.0, kind="piecewise", gains=1e8):
        self.gains = gains
        self.T, self.n, self.dt, self.eps, self.bound, self.kind = T, n, dt, eps, bound, kind
        scene = RollerRacer()
        self.system = scene.build_system(analytic_derivatives=True)  # so the complex step through a run is exact
        self.y0 = np.concatenate([np.zeros(3), self.system.complete_momenta([scene.phi0], {"Pi_theta": 0.0,
                                                                                         "p_phi": 0.0})])
        # piecewise constant: n intervals of [0, T], each a whole number of steps (a forced run holds such an
        # input over each step, so its switches at step ends are exact); spline: through n nodes spanning [0, T]
        self.grid = np.linspace(0.0, T, n + 1) if kind == "piecewise" else np.linspace(0.0, T, n)
        self.law = ForceLaw(steering_torque, inputs=("tau",))
        self._cache = {}
        self.runs = 0
        self.drift = []  # per iterate: max |J_i| and |h~ - W - 0| over the run

    def run(self, tau, sensitivities=True):
        key = (np.asarray(tau, float).tobytes(), sensitivities)
        if key not in self._cache:
            fi = liefi.FeedbackIntegrator(self.system, self.y0, force=self.law, configuration=True, gains=self.gains,
                                          inputs={"tau": self.signal(tau)})
            sol = fi.run(self.T, dt=self.dt, scheme="imex-rk4", sensitivities=("tau",) if sensitivities else None)
            self.runs += 1
            self._cache = {key: (fi, sol)}  # the last run only: fun and jac ask for the same x
        return self._cache[key]

    def signal(self, tau):
        return piecewise_constant(self.grid, tau) if self.kind == "piecewise" else spline(self.grid, tau)

    def loss(self, tau, sensitivities=True):
        fi, sol = self.run(tau, sensitivities)
        return -sol.y[fi.names.index("x"), -1] + self.eps * (self.T / self.n) * np.sum(np.square(tau))

    def distance(self, tau):
        fi, sol = self.run(tau)
        return sol.y[fi.names.index("x"), -1]

    def gradient(self, tau):
        fi, sol = self.run(tau)
        return -sol.sensitivities["tau"][fi.names.index("x"), :, -1] + 2 * self.eps * (self.T / self.n) * tau

    def record(self, tau, sensitivities=True):
        """The callback: the constraint drift and the balance of this iterate's run."""
        fi, sol = self.run(tau, sensitivities)
        inv = fi.invariant_values(sol.y.T)
        self.drift.append(max(np.abs(inv["J_1"]).max(), np.abs(inv["J_2"]).max(), np.abs(inv["energy"]).max()))


def optimize(racer, exact=True, maxiter=30):
    """``minimize`` the loss from a small wiggle; ``exact``: liefi's gradient, else minimize's finite differences."""
    tau0 = 0.2 * np.sin(4 * np.pi * np.arange(racer.n) / racer.n)
    racer.drift, racer.runs = [], 0
    racer.record(tau0, exact)
    fun = (lambda x: racer.loss(x, True)) if exact else (lambda x: racer.loss(x, False))
    start = time.perf_counter()
    res = minimize(fun, tau0, jac=racer.gradient if exact else None, method="L-BFGS-B",
                   bounds=[(-racer.bound, racer.bound)] * racer.n, options={"maxiter": maxiter},
                   callback=lambda x: racer.record(x, exact))
    res.seconds = time.perf_counter() - start
    res.runs, res.drift = racer.runs, list(racer.drift)
    return res


def draw(racer, tau, png=None, gif=None, frames=40):
    """The path of the optimum (and of the start's wiggle) and the racer driving it."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fi, sol = racer.run(tau)
    x, y, th, phi = (sol.y[fi.names.index(s)] for s in ("x", "y", "theta", "phi"))
    fig, (ax, bx) = plt.subplots(1, 2, figsize=(8, 3.2), dpi=90)
    ax.plot(x, y, "C0", label="optimal torque")
    ax.set_aspect("equal")
    ax.set_xlabel("x")
    ax.set_ylabel("y")
    ax.set_title(f"roller racer, T = {racer.T}: x(T) = {x[-1]:.3f}")
    torque = np.broadcast_to(racer.signal(tau)(sol.t), sol.t.shape)
    bx.plot(sol.t, torque, "C0", drawstyle="steps-post" if racer.kind == "piecewise" else "default")
    bx.plot(racer.grid[: racer.n], tau, "C0.")
    bx.set_xlabel("t")
    bx.set_ylabel("steering torque")
    fig.tight_layout()
    if png:
        fig.savefig(png)
    if gif:
        from matplotlib.animation import PillowWriter

        d1, d2 = RollerRacer.d1, RollerRacer.d2
        (body,) = ax.plot([], [], "k-", lw=3)
        (rear,) = ax.plot([], [], "C3-", lw=3)
        (dot,) = bx.plot([], [], "C3o")
        pad = 0.6
        ax.set_xlim(min(x.min(), -d1) - pad, max(x.max(), 0) + pad)
        ax.set_ylim(min(y.min(), 0) - pad, max(y.max(), 0) + pad)
        writer = PillowWriter(fps=12)
        with writer.saving(fig, str(gif), dpi=fig.dpi):
            for k in np.linspace(0, sol.t.size - 1, frames).astype(int):
                joint = np.array([x[k], y[k]]) - d1 * np.array([np.cos(th[k]), np.sin(th[k])])
                back = joint - d2 * np.array([np.cos(th[k] + phi[k]), np.sin(th[k] + phi[k])])
                body.set_data([x[k], joint[0]], [y[k], joint[1]])
                rear.set_data([joint[0], back[0]], [joint[1], back[1]])
                dot.set_data([sol.t[k]], [torque[k]])
                writer.grab_frame()
    plt.close(fig)


def main(T=3.0, n=10, dt=0.03, maxiter=20, compare=True, write=False):
    racer = Racer(T=T, n=n, dt=dt)
    exact = optimize(racer, True, maxiter)
    print(f"liefi gradient : x(T) = {racer.distance(exact.x):.6f} (loss {exact.fun:.6f}), {exact.nit} iterations, "
          f"{exact.nfev} loss+gradient evaluations ({exact.runs} runs with sensitivities), {exact.seconds:.1f} s; "
          f"max drift over every iterate {max(exact.drift):.2e}")
    out = {"exact": exact, "racer": racer}
    if compare:
        fd = optimize(Racer(T=T, n=n, dt=dt), False, maxiter)
        print(f"finite diffs   : x(T) = {Racer(T=T, n=n, dt=dt).distance(fd.x):.6f} (loss {fd.fun:.6f}), {fd.nit} iterations, {fd.nfev} loss "
              f"evaluations ({fd.runs} runs), {fd.seconds:.1f} s; max drift over every iterate {max(fd.drift):.2e}")
        out["fd"] = fd
    if write:
        d = ROOT / "docs" / "steering"
        d.mkdir(exist_ok=True)
        draw(racer, exact.x, png=d / "path.png", gif=d / "racer.gif")
        print(f"wrote {d / 'path.png'} and {d / 'racer.gif'}")
    return out


if __name__ == "__main__":
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--write", action="store_true", help="write docs/steering/path.png and racer.gif")
    ap.add_argument("--maxiter", type=int, default=20)
    ap.add_argument("--no-compare", action="store_true", help="skip the finite-difference optimization (4 min)")
    a = ap.parse_args()
    main(maxiter=a.maxiter, write=a.write, compare=not a.no_compare)
