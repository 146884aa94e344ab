"""The fair peer of liefi's split step: hand-written numba kernels of ``imex-rk4`` at ``gains="auto"``.

What a competent person writes for one system without liefi, for exactly
the step liefi takes (:func:`liefi.schemes.split.feedback_step` after an RK4
step of the extended field ``X``):

1. RK4 on ``X`` (the free rigid body; Suslov's extended field), the state in
   local variables, ``y + dt/6 (k1 + 2 k2 + 2 k3 + k4)``;
2. one linearly implicit step of ``-grad V`` on the momentum: with the rows
   ``W = (grad I_1; grad I_2)`` of the invariants at the new state, their
   residuals ``r`` and ``a_j = dt k_j``, solve the 2 x 2 system
   ``(I + diag(a) W W^T) s = diag(a) r`` by Cramer's rule and take
   ``Pi -= W^T s``.  At ``gains="auto"`` ``a_j = w_j z*`` with ``z* = 1/sqrt(u)``
   (:data:`liefi.gains.SPLIT_RATE_MAX`): one Gauss--Newton step onto the
   invariant set;
3. on ``R`` the penalty's step ``R -= c R (R^T R - I)`` with
   ``c = a_0 / (1 + 2 a_0)`` (``-> 1/2`` as ``a_0`` grows: the Newton--Schulz
   step ``R (3 I - R^T R) / 2``).

Every constant -- the inertia, ``e``, the targets, the ``a_j`` and ``c`` -- is
folded into the compiled code (the kernels are built by :func:`make_kernels`
from the values liefi's run uses, captured as closure constants).  The state is
saved every ``save_every`` steps into ``out`` of shape ``(12, n_saved)``, as
liefi's loop does; nothing is checked.

The script times liefi's run as a user calls it -- ``cpu_seconds`` of
``fi.run(T, dt=h, scheme="imex-rk4", backend="numba")`` with ``gains="auto"``,
with the default stability guard and with ``check_stability=False`` -- against
the hand kernel, saving every step (``save_every=None``, the default) and the
last state only; process CPU time, best of ``--repeat``, the runs interleaved.
Both write into a fresh buffer allocated before their clock starts (:func:`hand_run`),
so both pay the first touch of its pages when every step is saved.
It checks first that both take the same step (the largest difference of the
states over 1000 steps and at the end).  Suslov has two peers: ``suslov``, the
formulas as written above with the numbers folded (``I^{-1} Pi`` with the
full matrix), and ``suslov-simplified``, the algebra done by hand for the
scene's inertia (``xi = (Pi_1, Pi_2, 0)``).  Then the explicit Euler engine
against ``hand_kernels.py`` with its constants folded.

Run::

    python benchmarks/split_peer.py                 # h = 1e-2, t in [0, 1000], best of 3, interleaved
    python benchmarks/split_peer.py --quick         # t in [0, 100], a smoke test
    python benchmarks/split_peer.py --json docs/work_precision/split_peer.json --markdown docs/work_precision/split_peer.md
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import warnings

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))
sys.path.insert(0, os.path.dirname(HERE))

from numba import njit  # noqa: E402

from liefi import gains as _gains  # noqa: E402
from liefi import scenes  # noqa: E402
from _machine import cpu_model  # noqa: E402 -- benchmarks/_machine.py

SCHEME = "imex-rk4"


# --------------------------------------------------------------------------------------
# the two extended fields and invariants, scalar code (constants folded by closure)
# --------------------------------------------------------------------------------------


def _rigid_body(inertia):
    i1, i2, i3 = (1.0 / float(v) for v in (np.diag(inertia) if np.ndim(inertia) == 2 else inertia))

    @njit(inline="always")
    def X(R11, R12, R13, R21, R22, R23, R31, R32, R33, P1, P2, P3):
        """``R' = R hat(Omega)``, ``Pi' = Pi x Omega``, ``Omega = I^{-1} Pi``."""
        w1, w2, w3 = P1 * i1, P2 * i2, P3 * i3
        return (R12 * w3 - R13 * w2, R13 * w1 - R11 * w3, R11 * w2 - R12 * w1,
                R22 * w3 - R23 * w2, R23 * w1 - R21 * w3, R21 * w2 - R22 * w1,
                R32 * w3 - R33 * w2, R33 * w1 - R31 * w3, R31 * w2 - R32 * w1,
                P2 * w3 - P3 * w2, P3 * w1 - P1 * w3, P1 * w2 - P2 * w1)

    @njit(inline="always")
    def invariants(P1, P2, P3):
        """``(I_1, grad I_1, I_2, grad I_2)``: the energy ``Pi . Omega / 2`` and the Casimir ``|Pi|^2 / 2``."""
        w1, w2, w3 = P1 * i1, P2 * i2, P3 * i3
        return (0.5 * (P1 * w1 + P2 * w2 + P3 * w3), w1, w2, w3,
                0.5 * (P1 * P1 + P2 * P2 + P3 * P3), P1, P2, P3)

    return X, invariants


def _suslov(inertia, e):
    Ii = np.linalg.inv(inertia)
    a11, a12, a13, a21, a22, a23, a31, a32, a33 = (float(v) for v in Ii.ravel())
    e1, e2, e3 = (float(v) for v in e)
    f1, f2, f3 = (float(v) for v in inertia @ e)  # e^flat = I e

    @njit(inline="always")
    def X(R11, R12, R13, R21, R22, R23, R31, R32, R33, P1, P2, P3):
        """``Pi' = Pi x xi + lam~ I e``, ``R' = R hat(xi)``; ``xi = I^{-1} Pi - J e``, ``lam~ = -Pi . (xi x e)``."""
        J = P1 * e1 + P2 * e2 + P3 * e3
        x1 = a11 * P1 + a12 * P2 + a13 * P3 - J * e1
        x2 = a21 * P1 + a22 * P2 + a23 * P3 - J * e2
        x3 = a31 * P1 + a32 * P2 + a33 * P3 - J * e3
        lam = -(P1 * (x2 * e3 - x3 * e2) + P2 * (x3 * e1 - x1 * e3) + P3 * (x1 * e2 - x2 * e1))
        return (R12 * x3 - R13 * x2, R13 * x1 - R11 * x3, R11 * x2 - R12 * x1,
                R22 * x3 - R23 * x2, R23 * x1 - R21 * x3, R21 * x2 - R22 * x1,
                R32 * x3 - R33 * x2, R33 * x1 - R31 * x3, R31 * x2 - R32 * x1,
                P2 * x3 - P3 * x2 + lam * f1, P3 * x1 - P1 * x3 + lam * f2, P1 * x2 - P2 * x1 + lam * f3)

    @njit(inline="always")
    def invariants(P1, P2, P3):
        """``(J, e, h~, xi)``: the constraint ``<Pi, e>`` and the energy ``Pi . I^{-1} Pi / 2 - J^2 / 2``."""
        J = P1 * e1 + P2 * e2 + P3 * e3
        x1 = a11 * P1 + a12 * P2 + a13 * P3 - J * e1
        x2 = a21 * P1 + a22 * P2 + a23 * P3 - J * e2
        x3 = a31 * P1 + a32 * P2 + a33 * P3 - J * e3
        h = 0.5 * (P1 * (a11 * P1 + a12 * P2 + a13 * P3) + P2 * (a21 * P1 + a22 * P2 + a23 * P3)
                   + P3 * (a31 * P1 + a32 * P2 + a33 * P3)) - 0.5 * J * J
        return J, e1, e2, e3, h, x1, x2, x3

    return X, invariants


def _suslov_simplified(inertia, e):
    """Suslov with the algebra done by hand for the scene's ``I = [[1,0,0],[0,1,1],[0,1,2]]``, ``a = e_3``:
    ``e = (0, -1, 1)``, ``I e = e_3``, ``J = Pi_3 - Pi_2``, ``xi = (Pi_1, Pi_2, 0)``, ``lam~ = Pi_1 Pi_3``,
    ``h~ = (Pi_1^2 + Pi_2^2)/2``: the strongest peer (the same maths, other rounding)."""
    if not (np.allclose(inertia, [[1, 0, 0], [0, 1, 1], [0, 1, 2]], rtol=0, atol=0) and np.allclose(e, [0, -1, 1])):
        raise ValueError("the simplified Suslov kernel holds for the scene's inertia and a = e_3 only")

    @njit(inline="always")
    def X(R11, R12, R13, R21, R22, R23, R31, R32, R33, P1, P2, P3):
        q = P1 * P3
        return (-R13 * P2, R13 * P1, R11 * P2 - R12 * P1,
                -R23 * P2, R23 * P1, R21 * P2 - R22 * P1,
                -R33 * P2, R33 * P1, R31 * P2 - R32 * P1,
                -P3 * P2, q, q)

    @njit(inline="always")
    def invariants(P1, P2, P3):
        return P3 - P2, 0.0, -1.0, 1.0, 0.5 * (P1 * P1 + P2 * P2), P1, P2, 0.0

    return X, invariants


def make_kernels(X, invariants, targets, a, c):
    """``run(y0, dt, n_steps, save_every, out)``: the hand-written ``imex-rk4`` loop.

    ``targets = (I_1^0, I_2^0)``, ``a = (dt k_1, dt k_2)`` of the invariants,
    ``c = dt k_0 / (1 + 2 dt k_0)`` of the penalty: folded constants.
    """
    t1, t2 = float(targets[0]), float(targets[1])
    a1, a2 = float(a[0]), float(a[1])
    c = float(c)

    @njit(cache=False, error_model="numpy")
    def run(y0, dt, n_steps, save_every, out):
        h2, h6 = 0.5 * dt, dt / 6.0
        R11, R12, R13, R21, R22, R23, R31, R32, R33, P1, P2, P3 = (
            y0[0], y0[1], y0[2], y0[3], y0[4], y0[5], y0[6], y0[7], y0[8], y0[9], y0[10], y0[11])
        for i in range(12):
            out[i, 0] = y0[i]
        j = 1
        until_save = save_every
        for step in range(1, n_steps + 1):
            k1 = X(R11, R12, R13, R21, R22, R23, R31, R32, R33, P1, P2, P3)
            k2 = X(R11 + h2 * k1[0], R12 + h2 * k1[1], R13 + h2 * k1[2], R21 + h2 * k1[3], R22 + h2 * k1[4],
                   R23 + h2 * k1[5], R31 + h2 * k1[6], R32 + h2 * k1[7], R33 + h2 * k1[8], P1 + h2 * k1[9],
                   P2 + h2 * k1[10], P3 + h2 * k1[11])
            k3 = X(R11 + h2 * k2[0], R12 + h2 * k2[1], R13 + h2 * k2[2], R21 + h2 * k2[3], R22 + h2 * k2[4],
                   R23 + h2 * k2[5], R31 + h2 * k2[6], R32 + h2 * k2[7], R33 + h2 * k2[8], P1 + h2 * k2[9],
                   P2 + h2 * k2[10], P3 + h2 * k2[11])
            k4 = X(R11 + dt * k3[0], R12 + dt * k3[1], R13 + dt * k3[2], R21 + dt * k3[3], R22 + dt * k3[4],
                   R23 + dt * k3[5], R31 + dt * k3[6], R32 + dt * k3[7], R33 + dt * k3[8], P1 + dt * k3[9],
                   P2 + dt * k3[10], P3 + dt * k3[11])
            R11 += h6 * (k1[0] + 2.0 * (k2[0] + k3[0]) + k4[0])
            R12 += h6 * (k1[1] + 2.0 * (k2[1] + k3[1]) + k4[1])
            R13 += h6 * (k1[2] + 2.0 * (k2[2] + k3[2]) + k4[2])
            R21 += h6 * (k1[3] + 2.0 * (k2[3] + k3[3]) + k4[3])
            R22 += h6 * (k1[4] + 2.0 * (k2[4] + k3[4]) + k4[4])
            R23 += h6 * (k1[5] + 2.0 * (k2[5] + k3[5]) + k4[5])
            R31 += h6 * (k1[6] + 2.0 * (k2[6] + k3[6]) + k4[6])
            R32 += h6 * (k1[7] + 2.0 * (k2[7] + k3[7]) + k4[7])
            R33 += h6 * (k1[8] + 2.0 * (k2[8] + k3[8]) + k4[8])
            P1 += h6 * (k1[9] + 2.0 * (k2[9] + k3[9]) + k4[9])
            P2 += h6 * (k1[10] + 2.0 * (k2[10] + k3[10]) + k4[10])
            P3 += h6 * (k1[11] + 2.0 * (k2[11] + k3[11]) + k4[11])
            # Gauss--Newton on the invariants: (I + diag(a) W W^T) s = diag(a) r, Cramer's rule; Pi -= W^T s
            I1, u1, u2, u3, I2, v1, v2, v3 = invariants(P1, P2, P3)
            uv = u1 * v1 + u2 * v2 + u3 * v3
            m11 = 1.0 + a1 * (u1 * u1 + u2 * u2 + u3 * u3)
            m12 = a1 * uv
            m21 = a2 * uv
            m22 = 1.0 + a2 * (v1 * v1 + v2 * v2 + v3 * v3)
            b1 = a1 * (I1 - t1)
            b2 = a2 * (I2 - t2)
            det = m11 * m22 - m12 * m21
            s1 = (b1 * m22 - m12 * b2) / det
            s2 = (m11 * b2 - m21 * b1) / det
            P1 -= s1 * u1 + s2 * v1
            P2 -= s1 * u2 + s2 * v2
            P3 -= s1 * u3 + s2 * v3
            # the penalty's step on R: R -= c R (R^T R - I)
            S11 = R11 * R11 + R21 * R21 + R31 * R31 - 1.0
            S22 = R12 * R12 + R22 * R22 + R32 * R32 - 1.0
            S33 = R13 * R13 + R23 * R23 + R33 * R33 - 1.0
            S12 = R11 * R12 + R21 * R22 + R31 * R32
            S13 = R11 * R13 + R21 * R23 + R31 * R33
            S23 = R12 * R13 + R22 * R23 + R32 * R33
            R11, R12, R13 = (R11 - c * (R11 * S11 + R12 * S12 + R13 * S13), R12 - c * (R11 * S12 + R12 * S22 + R13 * S23),
                             R13 - c * (R11 * S13 + R12 * S23 + R13 * S33))
            R21, R22, R23 = (R21 - c * (R21 * S11 + R22 * S12 + R23 * S13), R22 - c * (R21 * S12 + R22 * S22 + R23 * S23),
                             R23 - c * (R21 * S13 + R22 * S23 + R23 * S33))
            R31, R32, R33 = (R31 - c * (R31 * S11 + R32 * S12 + R33 * S13), R32 - c * (R31 * S12 + R32 * S22 + R33 * S23),
                             R33 - c * (R31 * S13 + R32 * S23 + R33 * S33))
            until_save -= 1
            if until_save == 0 or step == n_steps:
                until_save = save_every
                out[0, j], out[1, j], out[2, j], out[3, j], out[4, j], out[5, j] = R11, R12, R13, R21, R22, R23
                out[6, j], out[7, j], out[8, j], out[9, j], out[10, j], out[11, j] = R31, R32, R33, P1, P2, P3
                j += 1
        return j

    return run


def liefi_setting(sc, fi, dt, t_final):
    """The values liefi's run takes at ``gains="auto"``: ``(targets, a, c)`` of :func:`make_kernels`."""
    _, g = _gains.accurate_setting(fi, dt, SCHEME, t_final)
    names = [n for n in fi.invariant_names if n != "penalty"]
    tg = [float(np.ravel(fi.targets.get(n, 0.0))[0]) for n in names]
    a = [dt * g[n] for n in names]
    a0 = dt * g["penalty"]
    return tg, a, a0 / (1.0 + 2.0 * a0), names


def hand_kernel(name, fi, dt, t_final):
    """``(run, invariant names)``: the hand kernel of ``name`` (``"rigid-body"``, ``"suslov"``,
    ``"suslov-simplified"``) at the setting liefi's run of ``fi`` takes."""
    sc = scenes.get(name.replace("-simplified", ""))
    if name == "rigid-body":
        X, inv = _rigid_body(sc.inertia)
    elif name in ("suslov", "suslov-simplified"):
        Iinv_a = np.linalg.solve(sc.inertia, sc.a)
        make = _suslov if name == "suslov" else _suslov_simplified
        X, inv = make(sc.inertia, Iinv_a / np.sqrt(sc.a @ Iinv_a))
    else:
        raise KeyError(name)
    tg, a, c, names = liefi_setting(sc, fi, dt, t_final)
    return make_kernels(X, inv, tg, a, c), names


def liefi_run(fi, t_final, dt, save_every, guard):
    """``cpu_seconds`` and the states of liefi's compiled split run, as a user calls it."""
    sol = fi.run(t_final, dt=dt, scheme=SCHEME, backend="numba", check_stability=guard, save_every=save_every)
    return sol.cpu_seconds, sol.y


#: the hand kernel's outputs of one :func:`measure`, kept alive so that the allocator cannot hand their
#: pages back (up to ``2 repeat + 2`` buffers)
_KEPT = []


def hand_run(run, y0, dt, n, save_every):
    """CPU seconds of the hand kernel's loop, its output allocated as liefi's runner allocates its own.

    liefi's loop writes into a fresh ``np.empty`` buffer allocated just before its clock starts, so a run
    that saves every step pays the first touch of every page of it (about 10 ns per step of 12 numbers);
    the hand kernel gets the same: a fresh, untouched buffer (the earlier ones kept alive, so that it is
    not memory already touched by an earlier repeat).  Both clocks then time the same work.
    """
    ns = n // save_every + 1 + (1 if n % save_every else 0)
    out = np.empty((12, ns))
    _KEPT.append(out)
    c = time.process_time()
    run(y0, dt, n, save_every, out)
    return time.process_time() - c, out


def measure(scene, name, dt, t_final, save_every, repeat):
    """Best-of-``repeat`` CPU seconds of liefi (guard on and off) and the hand kernel, interleaved."""
    sc = scenes.get(scene)
    fi = sc.integrator(None, gains="auto", configuration=True)
    n = int(round(t_final / dt))
    se = n if save_every is None else save_every
    run, names = hand_kernel(name, fi, dt, t_final)
    _KEPT.clear()
    # warm up both (compile / load), and check they take the same step
    short = min(n, 1000)
    _, yl = liefi_run(fi, short * dt, dt, 1, False)
    _, yh = hand_run(run, fi.y0, dt, short, 1)
    agree = float(np.max(np.abs(yl - yh)))
    best = {"liefi": np.inf, "liefi_no_guard": np.inf, "hand": np.inf}
    for _ in range(repeat):
        best["hand"] = min(best["hand"], hand_run(run, fi.y0, dt, n, se)[0])
        best["liefi_no_guard"] = min(best["liefi_no_guard"], liefi_run(fi, t_final, dt, se, False)[0])
        best["liefi"] = min(best["liefi"], liefi_run(fi, t_final, dt, se, True)[0])
        best["hand"] = min(best["hand"], hand_run(run, fi.y0, dt, n, se)[0])
    _, yl = liefi_run(fi, t_final, dt, se, False)
    _, yh = hand_run(run, fi.y0, dt, n, se)
    _KEPT.clear()
    return {
        "scene": scene, "peer": name, "invariants": names, "dt": dt, "t_final": t_final, "steps": n, "save_every": se,
        "hand_ns_per_step": 1e9 * best["hand"] / n,
        "liefi_ns_per_step": 1e9 * best["liefi"] / n,
        "liefi_no_guard_ns_per_step": 1e9 * best["liefi_no_guard"] / n,
        "ratio": best["liefi"] / best["hand"],
        "ratio_no_guard": best["liefi_no_guard"] / best["hand"],
        "max_abs_diff_1000_steps": agree,
        "max_abs_diff_final": float(np.max(np.abs(yl[:, -1] - yh[:, -1]))),
    }


def euler_rows(n_steps, repeat):
    """The explicit Euler engine against the hand kernels of ``hand_kernels.py`` with their constants
    folded (:func:`hand_kernels.folded_euler`): CPU seconds of the loop, best of ``repeat``, interleaved."""
    sys.path.insert(0, HERE)
    import hand_kernels
    from liefi import engine

    rows = []
    for name, cfg in (("suslov", True), ("knife-edge", False), ("roller-racer", False)):
        sc = scenes.get(name)
        fi = sc.integrator(None, configuration=cfg)
        _, euler, c = hand_kernels.for_scene(sc, fi, folded=True)
        cf = engine.compile_feedback(fi)
        cf.warmup("euler")
        p = engine.parameters(fi)
        euler(fi.y0, c, sc.dt, 1)
        n = min(n_steps, int(round(250.0 / sc.dt))) if name == "suslov" else n_steps  # Suslov: no subnormals
        hand = liefi = np.inf
        for _ in range(repeat):
            t = time.process_time()
            yh = euler(fi.y0, c, sc.dt, n)
            hand = min(hand, time.process_time() - t)
            sol = cf.run(fi.y0, p, sc.dt, n, "euler", save_every=n)
            liefi = min(liefi, sol.cpu_seconds)
        rows.append({"scene": name, "steps": n, "hand_ns_per_step": 1e9 * hand / n,
                     "engine_ns_per_step": 1e9 * liefi / n, "ratio": liefi / hand,
                     "max_abs_diff_final": float(np.max(np.abs(sol.y[:, -1] - yh)))})
    return rows


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--dt", type=float, default=1e-2)
    ap.add_argument("--t-final", type=float, default=1000.0,
                    help="horizon of the rigid body; Suslov runs to a quarter of it (its Pi_2 Pi_3 = sech(t)^2 reaches "
                         "subnormal numbers near t = 354, which slow every step, liefi's and the hand kernel's alike)")
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--quick", action="store_true", help="t in [0, 100], 1e5 Euler steps")
    ap.add_argument("--euler-steps", type=float, default=1e6, help="explicit Euler comparison (0: skip)")
    ap.add_argument("--json", default=None, metavar="FILE")
    ap.add_argument("--markdown", default=None, metavar="FILE")
    a = ap.parse_args(argv)
    if a.quick:
        a.t_final, a.euler_steps = 100.0, 1e5
    warnings.filterwarnings("ignore", category=DeprecationWarning)
    n = int(round(a.t_final / a.dt))
    rows = []
    for scene, name in (("rigid-body", "rigid-body"), ("suslov", "suslov"), ("suslov", "suslov-simplified")):
        for se in (None, 1):
            rows.append(measure(scene, name, a.dt, a.t_final / (4 if scene == "suslov" else 1), se, a.repeat))
    cpu = cpu_model()
    lines = [f"CPU: {cpu}; {SCHEME} at gains='auto', h = {a.dt:g}, t in [0, {a.t_final:g}] ({n} steps; Suslov to "
             f"{a.t_final / 4:g}); process CPU time, best of {a.repeat}, interleaved", "",
             "| peer | saved | hand (ns/step) | liefi run() (ns/step) | no guard (ns/step) | run() / hand "
             "| no guard / hand | max diff, 1000 steps | max diff, final |",
             "|---|---|---:|---:|---:|---:|---:|---:|---:|"]
    for r in rows:
        saved = "every step" if r["save_every"] == 1 else "last only"
        lines.append(f"| {r['peer']} | {saved} | {r['hand_ns_per_step']:.1f} | {r['liefi_ns_per_step']:.1f} "
                     f"| {r['liefi_no_guard_ns_per_step']:.1f} | {r['ratio']:.3f} | {r['ratio_no_guard']:.3f} "
                     f"| {r['max_abs_diff_1000_steps']:.1e} | {r['max_abs_diff_final']:.1e} |")
    if a.euler_steps:
        erows = euler_rows(int(a.euler_steps), a.repeat)
        lines += ["", f"Explicit Euler engine (`CompiledField.run`, {int(a.euler_steps):.0e} steps (Suslov: to t = 250), "
                  "the scenes' dt and "
                  "gains) against the hand kernels with their constants folded; best of "
                  f"{a.repeat}, interleaved", "",
                  "| scene | hand (ns/step) | engine (ns/step) | engine / hand | max diff, final |", "|---|---:|---:|---:|---:|"]
        lines += [f"| {r['scene']} | {r['hand_ns_per_step']:.1f} | {r['engine_ns_per_step']:.1f} | {r['ratio']:.3f} "
                  f"| {r['max_abs_diff_final']:.1e} |" for r in erows]
    else:
        erows = []
    text = "\n".join(lines)
    print(text)
    if a.json:
        with open(a.json, "w") as fh:
            json.dump({"cpu": cpu, "rows": rows, "euler": erows}, fh, indent=2)
    if a.markdown:
        with open(a.markdown, "w") as fh:
            fh.write(text + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
