"""Hand-written compiled kernels: the yardstick of ``bench_speed.py``.

What a competent person writes for one system without liefi: the feedback
integrator's field worked out on paper for that system, scalar state in local
variables, explicit Euler in a numba loop, nothing checked.  They live here,
outside the library, on purpose: liefi derives its fields from the data, and
these kernels are only the reference its generated code is timed against
(``bench_speed.py`` also checks they compute the same field as liefi).

All three use analytic derivatives.  Parameters are the scenes' (see
``liefi/scenes/*.py``); the formulas are the paper's with docs/paper_notes.md's
corrections (the knife edge's ``d H~ / d phi`` keeps the term the paper drops).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

# --------------------------------------------------------------------------------------
# Suslov problem on SO(3) with R integrated (12 numbers: R row-major, Pi)
# --------------------------------------------------------------------------------------


def suslov_params(inertia, a, k0, k1, k2, h0):
    """``(Iinv (9), e (3), e_flat = I e (3), k0, k1, k2, h0)`` as one flat array."""
    Iinv = np.linalg.inv(inertia)
    e = Iinv @ a / math.sqrt(a @ Iinv @ a)
    return np.concatenate([Iinv.ravel(), e, inertia @ e, [k0, k1, k2, h0]])


@njit(cache=True)
def suslov_field(y, c, out):
    """``Pi' = Pi x xi + lam~ e_flat - k1 J e - k2 dh xi``, ``R' = R hat(xi) - k0 R (R^T R - I)``,
    ``xi = I^{-1} Pi - J e``, ``lam~ = -Pi . (xi x e)``."""
    R11, R12, R13, R21, R22, R23, R31, R32, R33, P1, P2, P3 = (
        y[0], y[1], y[2], y[3], y[4], y[5], y[6], y[7], y[8], y[9], y[10], y[11])
    e1, e2, e3 = c[9], c[10], c[11]
    f1, f2, f3 = c[12], c[13], c[14]
    k0, k1, k2, h0 = c[15], c[16], c[17], c[18]
    W1 = c[0] * P1 + c[1] * P2 + c[2] * P3
    W2 = c[3] * P1 + c[4] * P2 + c[5] * P3
    W3 = c[6] * P1 + c[7] * P2 + c[8] * P3
    J = P1 * e1 + P2 * e2 + P3 * e3
    x1, x2, x3 = W1 - J * e1, W2 - J * e2, W3 - J * e3
    ht = 0.5 * (P1 * W1 + P2 * W2 + P3 * W3) - 0.5 * J * J
    c1, c2, c3 = x2 * e3 - x3 * e2, x3 * e1 - x1 * e3, x1 * e2 - x2 * e1
    lam = -(P1 * c1 + P2 * c2 + P3 * c3)
    dh = k2 * (ht - h0)
    kJ = k1 * J
    out[9] = P2 * x3 - P3 * x2 + lam * f1 - kJ * e1 - dh * x1
    out[10] = P3 * x1 - P1 * x3 + lam * f2 - kJ * e2 - dh * x2
    out[11] = P1 * x2 - P2 * x1 + lam * f3 - kJ * e3 - dh * x3
    # S = R^T R - I
    S11 = R11 * R11 + R21 * R21 + R31 * R31 - 1.0
    S22 = R12 * R12 + R22 * R22 + R32 * R32 - 1.0
    S33 = R13 * R13 + R23 * R23 + R33 * R33 - 1.0
    S12 = R11 * R12 + R21 * R22 + R31 * R32
    S13 = R11 * R13 + R21 * R23 + R31 * R33
    S23 = R12 * R13 + R22 * R23 + R32 * R33
    # R hat(xi) - k0 R S, row by row
    for r in range(3):
        a, b, d = y[3 * r], y[3 * r + 1], y[3 * r + 2]
        out[3 * r] = b * x3 - d * x2 - k0 * (a * S11 + b * S12 + d * S13)
        out[3 * r + 1] = d * x1 - a * x3 - k0 * (a * S12 + b * S22 + d * S23)
        out[3 * r + 2] = a * x2 - b * x1 - k0 * (a * S13 + b * S23 + d * S33)


@njit(cache=True)
def suslov_euler(y0, c, dt, n):
    """``n`` explicit Euler steps of :func:`suslov_field`, in place on a copy of ``y0``."""
    y = y0.copy()
    f = np.empty(12)
    for _ in range(n):
        suslov_field(y, c, f)
        for i in range(12):
            y[i] += dt * f[i]
    return y


# --------------------------------------------------------------------------------------
# Knife edge on an inclined plane: z = (x, y, phi, p_x, p_y, p_phi)
# --------------------------------------------------------------------------------------


def knife_params(m, Jin, g, alpha, k1, k2, k3, H0, pphi0):
    return np.array([m, Jin, g, alpha, k1, k2, k3, H0, pphi0, math.sqrt(m), m * g * math.sin(alpha)])


@njit(cache=True)
def knife_field(z, c, out):
    """``J1 = (p_x sin phi - p_y cos phi)/sqrt m``, ``H~ = H - J1^2/2``; canonical bracket;
    ``V = k1/2 J1^2 + k2/2 (H~ - H~0)^2 + k3/2 (p_phi - p_phi0)^2``."""
    px, py, pf = z[3], z[4], z[5]
    phi = z[2]
    m, Jin, k1, k2, k3, H0, pf0, sm, mgs = c[0], c[1], c[4], c[5], c[6], c[7], c[8], c[9], c[10]
    s, co = math.sin(phi), math.cos(phi)
    e1, e2 = s / sm, -co / sm
    J1 = px * e1 + py * e2
    dJ = (px * co + py * s) / sm  # d J1 / d phi
    # grad H~
    Hx, Hy, Hf = -mgs, 0.0, -J1 * dJ
    Hpx, Hpy, Hpf = px / m - J1 * e1, py / m - J1 * e2, pf / Jin
    Ht = 0.5 * (px * px + py * py) / m + 0.5 * pf * pf / Jin - mgs * z[0] - 0.5 * J1 * J1
    # lam~ = {H~, J1} = H~_q . J1_p - J1_q . H~_p
    lam = Hx * e1 + Hy * e2 - dJ * Hpf
    ef1, ef2 = m * e1, m * e2
    a = k1 * J1
    b = k2 * (Ht - H0)
    d = k3 * (pf - pf0)
    out[0] = Hpx - b * Hx
    out[1] = Hpy - b * Hy
    out[2] = Hpf - a * dJ - b * Hf
    out[3] = -Hx + lam * ef1 - a * e1 - b * Hpx
    out[4] = -Hy + lam * ef2 - a * e2 - b * Hpy
    out[5] = -Hf - b * Hpf - d


@njit(cache=True)
def knife_euler(z0, c, dt, n):
    z = z0.copy()
    f = np.empty(6)
    for _ in range(n):
        knife_field(z, c, f)
        for i in range(6):
            z[i] += dt * f[i]
    return z


# --------------------------------------------------------------------------------------
# Roller racer, reduced: z = (phi, Pi_theta, Pi_x, Pi_y, p_phi)
# --------------------------------------------------------------------------------------


def racer_params(m, I1, I2, d1, d2, k1, k2, k3, h0):
    return np.array([m, I1, I2, d1, d2, k1, k2, k3, h0, math.sqrt(m)])


@njit(cache=True)
def racer_field(z, c, out):
    """Orthonormal ``e_1(phi), e_2`` (so ``C = I``, ``dC = 0``), ``h~ = h - (J1^2 + J2^2)/2``,
    se(2)* bracket ``Lambda = [[0, -Py, Px], [Py, 0, 0], [-Px, 0, 0]]`` plus the canonical one
    on ``T*S^1``, ``lam~_i = {h~, J_i}``, ``e_i^flat = M e_i``."""
    phi, Pt, Px, Py, pf = z[0], z[1], z[2], z[3], z[4]
    m, I1, I2, d1, d2, k1, k2, k3, h0, sm = c[0], c[1], c[2], c[3], c[4], c[5], c[6], c[7], c[8], c[9]
    s, co = math.sin(phi), math.cos(phi)
    N2 = s * s / m + d1 * d1 * co * co / I1 + d2 * d2 / I2
    N = math.sqrt(N2)
    u0, u1, u3 = d1 * co / I1, -s / m, -d1 * co / I1 + d2 / I2
    du0, du1, du3 = -d1 * s / I1, -co / m, d1 * s / I1
    dN = s * co * (1.0 / m - d1 * d1 / I1) / N
    e0, e1, e3 = u0 / N, u1 / N, u3 / N
    de0, de1, de3 = (du0 - e0 * dN) / N, (du1 - e1 * dN) / N, (du3 - e3 * dN) / N
    J1 = e0 * Pt + e1 * Px + e3 * pf
    J2 = Py / sm
    dJ1 = de0 * Pt + de1 * Px + de3 * pf  # d J1 / d phi
    # v = M^{-1} P
    w = (Pt - pf) / I1
    v0, v1, v2, v3 = w, Px / m, Py / m, -w + pf / I2
    h = 0.5 * (Pt * v0 + Px * v1 + Py * v2 + pf * v3)
    ht = h - 0.5 * (J1 * J1 + J2 * J2)
    # grad h~: d/dphi and d/dP
    hf = -J1 * dJ1
    g0, g1, g2, g3 = v0 - J1 * e0, v1 - J1 * e1, v2 - J2 / sm, v3 - J1 * e3
    # Lie-Poisson part: Lambda grad h~
    L0 = -Py * g1 + Px * g2
    L1 = Py * g0
    L2 = -Px * g0
    # lam~_1 = grad_Pi h~ . Lambda grad_Pi J1 + h~_phi J1_pphi - J1_phi h~_pphi
    a0 = -Py * e1  # Lambda (e0, e1, 0)
    a1 = Py * e0
    a2 = -Px * e0
    lam1 = g0 * a0 + g1 * a1 + g2 * a2 + hf * e3 - dJ1 * g3
    # lam~_2 with grad_Pi J2 = (0, 0, 1/sm): Lambda column 2 / sm
    lam2 = (g0 * Px) / sm
    # e_flat: M e1 = (I1+I2) e0 + I2 e3, m e1, 0, I2 e0 + I2 e3 ; M e2 = (0, 0, sm, 0)
    f0 = (I1 + I2) * e0 + I2 * e3
    f1 = m * e1
    f3 = I2 * e0 + I2 * e3
    a = k1 * J1
    b = k2 * J2
    d = k3 * (ht - h0)
    out[0] = g3 - a * dJ1 - d * hf
    out[1] = L0 + lam1 * f0 - a * e0 - d * g0
    out[2] = L1 + lam1 * f1 - a * e1 - d * g1
    out[3] = L2 + lam2 * sm - b / sm - d * g2
    out[4] = -hf + lam1 * f3 - a * e3 - d * g3


@njit(cache=True)
def racer_euler(z0, c, dt, n):
    z = z0.copy()
    f = np.empty(5)
    for _ in range(n):
        racer_field(z, c, f)
        for i in range(5):
            z[i] += dt * f[i]
    return z


# --------------------------------------------------------------------------------------
# helpers: build the parameters of each kernel from a liefi scene
# --------------------------------------------------------------------------------------


def folded_euler(field, c, n_state):
    """Explicit Euler on ``field`` with its constants ``c`` folded into the compiled code.

    ``c`` becomes a tuple closed over by the kernel: numba freezes it as a
    compile-time constant, so after inlining the compiler sees every inertia,
    gain and target as a literal -- what a kernel written for one system with its
    numbers typed in gets.  Called as ``euler(y0, c, dt, n)`` like the others
    (``c`` is ignored).
    """
    C = tuple(float(v) for v in c)
    N = int(n_state)

    @njit
    def euler(y0, c_ignored, dt, n):
        y = y0.copy()
        f = np.empty(N)
        for _ in range(n):
            field(y, C, f)
            for i in range(N):
                y[i] += dt * f[i]
        return y

    return euler


def for_scene(scene, fi, *, folded=True):
    """``(field, euler, params)`` of the hand kernel for ``scene`` with ``fi``'s gains and targets.

    ``folded``: the Euler loop has the parameters folded in (:func:`folded_euler`);
    otherwise it reads them from ``params`` at run time.
    """
    g = fi.gains
    if scene.name == "suslov":
        c = suslov_params(scene.inertia, scene.a, g["penalty"], g["J_1"], g["energy"], fi.targets["energy"])
        field, euler = suslov_field, suslov_euler
    elif scene.name == "knife-edge":
        c = knife_params(scene.m, scene.J, scene.g, scene.alpha, g["J_1"], g["energy"], g["p_phi"],
                         fi.targets["energy"], fi.targets["p_phi"])
        field, euler = knife_field, knife_euler
    elif scene.name == "roller-racer":
        c = racer_params(scene.m, scene.I1, scene.I2, scene.d1, scene.d2, g["J_1"], g["J_2"], g["energy"],
                         fi.targets["energy"])
        field, euler = racer_field, racer_euler
    else:
        raise KeyError(scene.name)
    return field, folded_euler(field, c, fi.n) if folded else euler, c
