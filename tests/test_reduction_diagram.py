"""Extension commutes with reduction: the diagrams of Sections 2.2 and 2.3, numerically.

For a reduced system on ``g*`` or ``g* x T*X`` (random SPD mass tensor, random
*non-orthonormal* constraint rows, random potential, and half the time a random
vector potential ``A(x)``, constant on ``g*``; and the paper's Suslov,
Chaplygin, vertical-disk and roller-racer data) :func:`liefi.reduction.unreduce`
writes down the unreduced canonical system on ``T*Q`` in a chart ``q = (s, x)``.
liefi then extends *both* with the same generic code, and the projection
``pi(q, p) = (g, z)`` (left trivialization) must carry

* ``H~`` to ``h~`` and ``H`` to ``h``               (``h~ o pi = H~``, ``h o pi = H``),
* ``J_i`` to ``J_i``                                  (``J_i o pi = J_i``),
* ``Lambda~_i`` to ``lambda~_i``, ``Lambda_i`` to ``lambda_i``,
* the extended field ``(bam:qp)`` to ``(reconstruction, (new:red:bam))`` /
  ``(new:red:bam:QG:trivial)``, and the constrained field ``(original:nonholo)``
  on ``C`` to ``(sys:LiePoisson)`` / ``(sys:QG:trivial)``, group part included,

everywhere on the phase space (on ``C`` for the constrained field), to
``RTOL`` relative.  The paper's closed forms (unreduced Hamiltonians and
constraints, ``lambda~`` of Suslov, Chaplygin and the vertical disk, the
extended Chaplygin and vertical-disk fields) serve as oracles for the corners.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import pytest
from hypothesis import HealthCheck, assume, given, settings
from hypothesis import strategies as st
from hypothesis.extra import numpy as hnp

from liefi import CotangentBundle, LieGroupPhaseSpace, NonholonomicSystem, TrivialPrincipalBundle
from liefi import _diff
from liefi.groups import S1, SE2, SO2, SO3
from liefi.reduction import group_velocity, unreduce

#: Largest relative discrepancy allowed on any arrow of the diagram.
RTOL = 1e-10
#: Number of states per drawn example (every check is batched).
BATCH = 3
#: Worst discrepancy seen per (case, arrow); printed by ``python tests/test_reduction_diagram.py``.
WORST: dict = {}

SETTINGS = settings(
    max_examples=15, deadline=None, suppress_health_check=[HealthCheck.too_slow, HealthCheck.filter_too_much]
)


# ----------------------------------------------------------------------------- charts
# Batch-first and complex-step safe (np.stack of analytic functions, no casts).


def _mat(rows):
    return np.stack([np.stack(r, -1) for r in rows], -2)


def _rx(a):
    c, s, z, o = np.cos(a), np.sin(a), np.zeros_like(a), np.ones_like(a)
    return _mat([[o, z, z], [z, c, -s], [z, s, c]])


def _ry(a):
    c, s, z, o = np.cos(a), np.sin(a), np.zeros_like(a), np.ones_like(a)
    return _mat([[c, z, s], [z, o, z], [-s, z, c]])


def _rz(a):
    c, s, z, o = np.cos(a), np.sin(a), np.zeros_like(a), np.ones_like(a)
    return _mat([[c, -s, z], [s, c, z], [z, z, o]])


_E = SO3().hat(np.eye(3))  # hat(e_1), hat(e_2), hat(e_3): R_axis' = R_axis hat(e_axis)


def euler_zyx(s):
    """``R = Rz(s_0) Ry(s_1) Rx(s_2)`` (yaw-pitch-roll); gimbal lock at ``s_1 = +-pi/2``."""
    s = np.asarray(s)
    return _rz(s[..., 0]) @ _ry(s[..., 1]) @ _rx(s[..., 2])


def euler_zyx_jacobian(s):
    s = np.asarray(s)
    Z, Y, X = _rz(s[..., 0]), _ry(s[..., 1]), _rx(s[..., 2])
    return np.stack([Z @ _E[2] @ Y @ X, Z @ Y @ _E[1] @ X, Z @ Y @ X @ _E[0]], -3)


def _rot2(a):
    c, s = np.cos(a), np.sin(a)
    return _mat([[c, -s], [s, c]])


def se2_chart(s):
    """``(theta, x, y) -> [[R(theta), (x, y)], [0, 1]]`` (Marsden--Ratiu 14.6)."""
    s = np.asarray(s)
    th, x, y = s[..., 0], s[..., 1], s[..., 2]
    c, sn, z, o = np.cos(th), np.sin(th), np.zeros_like(th), np.ones_like(th)
    return _mat([[c, -sn, x], [sn, c, y], [z, z, o]])


def se2_chart_jacobian(s):
    s = np.asarray(s)
    th = s[..., 0]
    c, sn, z, o = np.cos(th), np.sin(th), np.zeros_like(th), np.ones_like(th)
    d_th = _mat([[-sn, -c, z], [c, -sn, z], [z, z, z]])
    d_x = _mat([[z, z, o], [z, z, z], [z, z, z]])
    d_y = _mat([[z, z, z], [z, z, o], [z, z, z]])
    return np.stack([d_th, d_x, d_y], -3)


def _blockdiag(A, B):
    """Block diagonal of ``A (..., a, a)`` and ``B (..., b, b)`` without in-place filling."""
    za = np.zeros(A.shape[:-1] + B.shape[-1:], dtype=np.result_type(A, B))
    zb = np.zeros(B.shape[:-1] + A.shape[-1:], dtype=np.result_type(A, B))
    return np.concatenate([np.concatenate([A, za], -1), np.concatenate([zb, B], -1)], -2)


def se2s1_chart(s):
    """``(theta, x, y, psi) -> blockdiag(SE(2) element, R(psi))``: SE(2) x S^1 as a Lie group."""
    s = np.asarray(s)
    return _blockdiag(se2_chart(s[..., :3]), _rot2(s[..., 3]))


def se2s1_chart_jacobian(s):
    s = np.asarray(s)
    A, dA = se2_chart(s[..., :3]), se2_chart_jacobian(s[..., :3])
    psi = s[..., 3]
    R, dR = _rot2(psi), _mat([[-np.sin(psi), -np.cos(psi)], [np.cos(psi), -np.sin(psi)]])
    zR = np.zeros_like(R)
    first = [_blockdiag(dA[..., k, :, :], zR) for k in range(3)]
    return np.stack(first + [_blockdiag(np.zeros_like(A), dR)], -3)


# ----------------------------------------------------------------------------- cases


@dataclass(frozen=True)
class Case:
    """A group with a chart, reduced either on ``g*`` (``n = 0``) or on ``g* x T*S^1`` (``n = 1``)."""

    name: str
    group: object
    chart: object
    jacobian: object
    s_bound: tuple  # |s_k| <= s_bound[k] keeps the chart away from its singularities
    n: int = 0

    def space(self):
        if self.n == 0:
            return LieGroupPhaseSpace(self.group)
        return TrivialPrincipalBundle(self.group, self.n, names=("psi",))

    def __repr__(self):
        return self.name


PI = np.pi
SE2_BOUND = (PI, 2.0, 2.0)
CASES = [
    Case("SO3", SO3(), euler_zyx, euler_zyx_jacobian, (PI, 1.2, PI)),
    Case("SE2", SE2(SO2()), se2_chart, se2_chart_jacobian, SE2_BOUND),
    Case("SE2(angle)", SE2(S1()), se2_chart, se2_chart_jacobian, SE2_BOUND),
    Case("SE2xS1", SE2(SO2()) * SO2(), se2s1_chart, se2s1_chart_jacobian, SE2_BOUND + (PI,)),
    Case("SE2xS1(angle)", SE2(S1()) * S1(), se2s1_chart, se2s1_chart_jacobian, SE2_BOUND + (PI,)),
    Case("SE2 bundle S1", SE2(SO2()), se2_chart, se2_chart_jacobian, SE2_BOUND, n=1),
    Case("SE2(angle) bundle S1", SE2(S1()), se2_chart, se2_chart_jacobian, SE2_BOUND, n=1),
]


# ----------------------------------------------------------------------------- strategies


def _floats(lo, hi):
    return st.floats(lo, hi, allow_nan=False, allow_infinity=False)


def _array(draw, shape, lo=-1.0, hi=1.0):
    return draw(hnp.arrays(float, shape, elements=_floats(lo, hi)))


@st.composite
def states(draw, case, D):
    """``BATCH`` canonical states ``(q, p)``, ``q = (s, x)`` inside the chart's safe box."""
    d = case.group.dim
    b = np.asarray(case.s_bound)
    s = _array(draw, (BATCH, d)) * b
    x = _array(draw, (BATCH, case.n), -PI, PI)
    p = _array(draw, (BATCH, D), -2.0, 2.0)
    return np.concatenate([s, x], -1), p


@st.composite
def random_systems(draw, case):
    """A reduced system with random SPD mass tensor and random non-orthonormal constraints.

    On ``g* x T*S^1`` the mass tensor, the constraints and the potential depend on
    ``psi``: ``m = L L^T + c I`` with ``L = A0 + sin(psi) A1 + cos(psi) A2``,
    ``E = [I_K 0] + R0 + sin(psi) R1 + cos(2 psi) R2`` (roller-racer-like),
    ``A = a0 + sin(psi) a1 + cos(psi) a2`` when a vector potential is drawn (a
    constant ``a0`` on ``g*``: a gyrostat's rotor momentum).
    """
    d, n = case.group.dim, case.n
    D = d + n
    K = draw(st.integers(0, D - 1))
    c = draw(_floats(0.2, 2.0))
    base = np.eye(K, D)
    if n == 0:
        A = _array(draw, (D, D))
        metric = A @ A.T + c * np.eye(D)
        constraints = base + _array(draw, (K, D), -0.7, 0.7)
        potential = None
    else:
        A0, A1, A2 = (_array(draw, (D, D)) for _ in range(3))
        R0, R1, R2 = (_array(draw, (K, D), -0.5, 0.5) for _ in range(3))
        u = _array(draw, (2,))

        def metric(x):
            psi = np.asarray(x)[..., 0, None, None]
            L = A0 + np.sin(psi) * A1 + np.cos(psi) * A2
            return L @ np.swapaxes(L, -1, -2) + c * np.eye(D)

        def constraints(x):
            psi = np.asarray(x)[..., 0, None, None]
            return base + R0 + np.sin(psi) * R1 + np.cos(2 * psi) * R2

        def potential(x):
            psi = np.asarray(x)[..., 0]
            return u[0] * np.cos(psi) + u[1] * np.sin(2 * psi)

    vector_potential = None
    if draw(st.booleans()):
        a0, a1, a2 = (_array(draw, (D,)) for _ in range(3))
        if n == 0:
            vector_potential = a0
        else:

            def vector_potential(x):
                psi = np.asarray(x)[..., 0, None]
                return a0 + np.sin(psi) * a1 + np.cos(psi) * a2

    q, p = draw(states(case, D))
    # independent constraints at every drawn shape point (else the system is singular)
    for xi in q[:, d:] if n else [np.zeros(0)]:
        E = constraints(xi) if callable(constraints) else constraints
        m = metric(xi) if callable(metric) else metric
        assume(K == 0 or np.linalg.cond(E @ m @ E.T) < 1e6)
    reduced = NonholonomicSystem(
        case.space(), metric, constraints if K else None, potential,
        vector_potential=vector_potential, sample=q[0, d:],
    )
    return reduced, q, p


# ----------------------------------------------------------------------------- checks


def _close(actual, desired, case, arrow):
    """Assert ``actual == desired`` to ``RTOL`` relative and record the discrepancy.

    Norm-wise over the batch: ``max|a - b| / max(|a|, |b|, 1)``.  The floor 1 is
    the scale of the inputs (states and data are O(1)); without it a quantity
    that vanishes by symmetry (``lambda`` for an isotropic metric, say) would
    compare rounding error with rounding error.
    """
    actual, desired = np.asarray(actual, float), np.asarray(desired, float)
    assert actual.shape == desired.shape, f"{arrow}: shapes {actual.shape} != {desired.shape}"
    scale = max(np.max(np.abs(desired), initial=0.0), np.max(np.abs(actual), initial=0.0), 1.0)
    err = np.max(np.abs(actual - desired), initial=0.0) / scale
    key = (str(case), arrow)
    WORST[key] = max(WORST.get(key, 0.0), err)
    assert err <= RTOL, f"{case}: {arrow} fails, relative discrepancy {err:.3g}"


def _build(case, reduced, q):
    unreduced, pi = unreduce(reduced, case.chart, case.jacobian, sample=q[0])
    return unreduced, pi


def _split(Z, N):
    return Z[..., :N], Z[..., N:]


def check_functions(case, reduced, unreduced, pi, q, p):
    """``h~ o pi = H~``, ``h o pi = H``, ``J o pi = J``, ``lambda~ o pi = Lambda~``, ``lambda o pi = Lambda``."""
    Z = np.concatenate([q, p], -1)
    _, z = pi(q, p)
    _close(unreduced.extended_hamiltonian(Z), reduced.extended_hamiltonian(z), case, "h~ o pi = H~")
    _close(unreduced.hamiltonian(Z), reduced.hamiltonian(z), case, "h o pi = H")
    _close(unreduced.constraint_momenta(Z), reduced.constraint_momenta(z), case, "J o pi = J")
    CQ = unreduced.gram_matrix(q)
    C = np.broadcast_to(reduced.gram_matrix(z[..., : reduced.space.n]), CQ.shape)  # unbatched if constant
    _close(CQ, C, case, "C o pi = C (Gram)")
    _close(unreduced.extended_multipliers(Z), reduced.extended_multipliers(z), case, "lambda~ o pi = Lambda~")
    _close(unreduced.multipliers(Z), reduced.multipliers(z), case, "lambda o pi = Lambda")


def check_extended_field(case, reduced, unreduced, pi, q, p):
    """``T pi . X~(q, p) = (g . dh~/dmu, X~_red(z))``: the extended fields are pi-related."""
    N = q.shape[-1]
    Z = np.concatenate([q, p], -1)
    g, z = pi(q, p)
    qdot, pdot = _split(unreduced.extended_vector_field(Z), N)
    gdot, zdot = pi.push(q, p, qdot, pdot)
    _close(zdot, reduced.extended_vector_field(z), case, "T pi X~ = X~_red")
    _close(gdot, reduced.reconstruction(g, z), case, "T pi X~ = g.dh~/dmu")


def check_constrained_field(case, reduced, unreduced, pi, q, p):
    """On ``C``: ``T pi . X(q, p) = (g . dh/dmu, X_red(z))`` and ``lambda o pi = Lambda``."""
    N = q.shape[-1]
    Zc = unreduced.project(np.concatenate([q, p], -1))
    qc, pc = _split(Zc, N)
    g, z = pi(qc, pc)
    # on C up to the rounding of the projection (Gram matrices with condition up to 1e6 are drawn)
    J = reduced.constraint_momenta(z)
    assert np.max(np.abs(J), initial=0.0) <= 1e-8 * max(1.0, np.max(np.abs(z)))
    qdot, pdot = _split(unreduced.constrained_vector_field(Zc), N)
    gdot, zdot = pi.push(qc, pc, qdot, pdot)
    _close(zdot, reduced.constrained_vector_field(z), case, "on C: T pi X = X_red")
    _close(gdot, reduced.reconstruction(g, z, extended=False), case, "on C: T pi X = g.dh/dmu")
    _close(unreduced.multipliers(Zc), reduced.multipliers(z), case, "on C: lambda o pi = Lambda")


# ----------------------------------------------------------------------------- the diagram, random data


@pytest.mark.parametrize("case", CASES, ids=str)
@SETTINGS
@given(data=st.data())
def test_extension_commutes_with_reduction_functions(case, data):
    reduced, q, p = data.draw(random_systems(case))
    unreduced, pi = _build(case, reduced, q)
    check_functions(case, reduced, unreduced, pi, q, p)


@pytest.mark.parametrize("case", CASES, ids=str)
@SETTINGS
@given(data=st.data())
def test_extension_commutes_with_reduction_extended_field(case, data):
    reduced, q, p = data.draw(random_systems(case))
    unreduced, pi = _build(case, reduced, q)
    check_extended_field(case, reduced, unreduced, pi, q, p)


@pytest.mark.parametrize("case", CASES, ids=str)
@SETTINGS
@given(data=st.data())
def test_extension_commutes_with_reduction_constrained_field_on_C(case, data):
    reduced, q, p = data.draw(random_systems(case))
    unreduced, pi = _build(case, reduced, q)
    check_constrained_field(case, reduced, unreduced, pi, q, p)


@pytest.mark.parametrize("case", CASES, ids=str)
@SETTINGS
@given(data=st.data())
def test_extension_commutes_with_reduction_group_part_in_matrices(case, data):
    """``G(s(t))' = G . hat(dh~/dmu)`` along the unreduced extended field, as matrices.

    ``G'`` is the complex-step derivative of the *chart* along ``s'`` (neither
    ``chart_jacobian`` nor the group's ``config_rate`` is used), so this closes
    the group part of the diagram independently of :meth:`LeftTrivialization.push`.
    """
    reduced, q, p = data.draw(random_systems(case))
    unreduced, pi = _build(case, reduced, q)
    d = case.group.dim
    qdot = unreduced.extended_vector_field(np.concatenate([q, p], -1))[..., : q.shape[-1]]
    s, sdot = q[..., :d], qdot[..., :d]
    h = _diff.STEP
    Gdot = np.asarray(case.chart(s + 1j * h * sdot)).imag / h
    _, z = pi(q, p)
    xi = group_velocity(reduced, z)
    _close(Gdot, np.asarray(case.chart(s)) @ case.group.hat(xi), case, "G' = G hat(dh~/dmu)")


@pytest.mark.parametrize("case", CASES, ids=str)
@SETTINGS
@given(data=st.data())
def test_left_trivialization_lift_is_a_right_inverse(case, data):
    reduced, q, p = data.draw(random_systems(case))
    _, pi = _build(case, reduced, q)
    g, z = pi(q, p)
    q2, p2 = pi.lift(q[..., : case.group.dim], z)
    np.testing.assert_allclose(q2, q, rtol=0, atol=1e-14)
    np.testing.assert_allclose(p2, p, rtol=1e-12, atol=1e-12)
    np.testing.assert_allclose(case.group.config_to_matrix(g), case.chart(q[..., : case.group.dim]), atol=1e-14)


# ----------------------------------------------------------------------------- the paper's systems


def _suslov():
    Ib = np.array([[2.0, 0.3, -0.2], [0.3, 1.5, 0.1], [-0.2, 0.1, 1.0]])
    e = np.array([0.3, -0.5, 0.8])
    e = e / np.sqrt(e @ Ib @ e)  # (e:unit:Suslov)
    reduced = NonholonomicSystem(LieGroupPhaseSpace(SO3()), Ib, e)

    def oracles(q, p, unreduced, pi):
        _, Pi = pi(q, p)
        lam = -np.einsum("i,...i->...", e, np.cross(Pi, np.linalg.solve(Ib, Pi[..., None])[..., 0]))
        return {"lambda~ (lambda:tilde:Suslov)": (unreduced.extended_multipliers(np.concatenate([q, p], -1))[..., 0], lam)}

    return CASES[0], reduced, oracles


def _chaplygin():
    m, I, a = 1.3, 0.7, 0.4
    Ib = np.array([[I + m * a**2, 0, m * a], [0, m, 0], [m * a, 0, m]])
    nrm = np.sqrt(m * I * (I + m * a**2))
    e = np.array([m * a, 0, -(I + m * a**2)]) / nrm
    case = CASES[2]  # SE2(S1()): stored numbers are the paper's (theta, x, y)
    reduced = NonholonomicSystem(case.space(), Ib, e)

    def oracles(q, p, unreduced, pi):
        Z = np.concatenate([q, p], -1)
        th = q[..., 0]
        pth, px, py = p[..., 0], p[..., 1], p[..., 2]
        H = (pth - a * (-px * np.sin(th) + py * np.cos(th))) ** 2 / (2 * I) + (px**2 + py**2) / (2 * m)
        C = (m * a * pth - (I + m * a**2) * (-px * np.sin(th) + py * np.cos(th))) / nrm
        g, Pi = pi(q, p)
        Pt, Px, Py = Pi[..., 0], Pi[..., 1], Pi[..., 2]
        lam = -(Pt - a * Py) * Px / nrm  # (lambda:Chap)
        qdot, pdot = _split(unreduced.extended_vector_field(Z), 3)
        gdot, zdot = pi.push(q, p, qdot, pdot)
        rates = np.stack([Pt / (I + m * a**2), Px * np.cos(th) / m, Px * np.sin(th) / m], -1)
        Pidot = np.stack([-Px * Py / m, Pt * Py / (I + m * a**2), -a * Px * Py / (I + m * a**2)], -1)
        return {
            "H (paper)": (unreduced.hamiltonian(Z), H),
            "C (paper)": (unreduced.constraint_momenta(Z)[..., 0], C),
            "lambda~ (lambda:Chap)": (unreduced.extended_multipliers(Z)[..., 0], lam),
            "T pi X~ = (extended:system:Chap), g": (gdot, rates),
            "T pi X~ = (extended:system:Chap), Pi": (zdot, Pidot),
        }

    return case, reduced, oracles


def _vertical_disk():
    Jm, m, I, R = 0.6, 1.1, 0.9, 0.5
    Ib = np.diag([Jm, m, m, I])
    nrm = np.sqrt(m * I * (I + m * R**2))
    e = np.array([[0, 0, 1, 0] / np.sqrt(m), np.array([0, I, 0, -m * R]) / nrm])
    case = CASES[4]  # SE2(S1()) * S1(): stored numbers are (theta, x, y, psi)
    reduced = NonholonomicSystem(case.space(), Ib, e)

    def oracles(q, p, unreduced, pi):
        Z = np.concatenate([q, p], -1)
        th = q[..., 0]
        pth, px, py, pps = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
        H = pth**2 / (2 * Jm) + (px**2 + py**2) / (2 * m) + pps**2 / (2 * I)
        C = np.stack([(-px * np.sin(th) + py * np.cos(th)) / np.sqrt(m), (I * (px * np.cos(th) + py * np.sin(th)) - m * R * pps) / nrm], -1)
        g, Pi = pi(q, p)
        Pt, Px, Py, Pp = (Pi[..., k] for k in range(4))
        lam = np.stack([Pt * Px / (Jm * np.sqrt(m)), -I * Pt * Py / (Jm * nrm)], -1)
        w = (R * Px + Pp) / (I + m * R**2)
        rates = np.stack([Pt / Jm, R * w * np.cos(th), R * w * np.sin(th), w], -1)
        eflat = np.array([[0, 0, np.sqrt(m), 0], np.array([0, m * I, 0, -m * R * I]) / nrm])
        Pidot = np.stack([-R * w * Py, Pt * Py / Jm, -Pt * Px / Jm, 0 * Pt], -1) + lam @ eflat
        qdot, pdot = _split(unreduced.extended_vector_field(Z), 4)
        gdot, zdot = pi.push(q, p, qdot, pdot)
        return {
            "H (paper)": (unreduced.hamiltonian(Z), H),
            "C (paper)": (unreduced.constraint_momenta(Z), C),
            "lambda~ (paper)": (unreduced.extended_multipliers(Z), lam),
            "T pi X~ = (extended:eqn:vertical:disk), g": (gdot, rates),
            "T pi X~ = (extended:eqn:vertical:disk), Pi": (zdot, Pidot),
        }

    return case, reduced, oracles


def _roller_racer():
    m, I1, I2, d1, d2 = 1.2, 0.8, 0.5, 0.7, 0.4
    Ib = np.array([[I1 + I2, 0, 0, I2], [0, m, 0, 0], [0, 0, m, 0], [I2, 0, 0, I2]])

    def nrm(phi):
        return np.sqrt(np.sin(phi) ** 2 / m + d1**2 * np.cos(phi) ** 2 / I1 + d2**2 / I2)

    def constraints(x):
        phi = np.asarray(x)[..., 0]
        z = np.zeros_like(phi)
        e1 = np.stack([d1 * np.cos(phi) / I1, -np.sin(phi) / m, z, -d1 * np.cos(phi) / I1 + d2 / I2], -1) / nrm(phi)[..., None]
        e2 = np.stack([z, z, z + 1, z], -1) / np.sqrt(m)
        return np.stack([e1, e2], -2)

    case = CASES[6]  # SE2(S1()) with X = S^1 (phi)
    reduced = NonholonomicSystem(case.space(), Ib, constraints)

    def oracles(q, p, unreduced, pi):
        Z = np.concatenate([q, p], -1)
        th, phi = q[..., 0], q[..., 3]
        pth, px, py, pph = p[..., 0], p[..., 1], p[..., 2], p[..., 3]
        H = (px**2 + py**2) / (2 * m) + (pth - pph) ** 2 / (2 * I1) + pph**2 / (2 * I2)
        # docs/paper_notes.md item 6: the printed constraint misses -d1 cos(phi) / I1 p_phi
        C1 = (d1 * np.cos(phi) / I1 * pth - np.sin(phi) / m * (px * np.cos(th) + py * np.sin(th))
              + (d2 / I2 - d1 * np.cos(phi) / I1) * pph) / nrm(phi)
        C2 = (-px * np.sin(th) + py * np.cos(th)) / np.sqrt(m)
        return {
            "H (paper)": (unreduced.hamiltonian(Z), H),
            "C (paper, slip 6 corrected)": (unreduced.constraint_momenta(Z), np.stack([C1, C2], -1)),
        }

    return case, reduced, oracles


PAPER = {"suslov": _suslov, "chaplygin": _chaplygin, "vertical_disk": _vertical_disk, "roller_racer": _roller_racer}


@pytest.mark.parametrize("name", list(PAPER))
@settings(max_examples=15, deadline=None)
@given(data=st.data())
def test_extension_commutes_with_reduction_paper_systems(name, data):
    case, reduced, oracles = PAPER[name]()
    q, p = data.draw(states(case, reduced.space.D))
    unreduced, pi = _build(case, reduced, q)
    label = f"{name} ({case})"
    check_functions(label, reduced, unreduced, pi, q, p)
    check_extended_field(label, reduced, unreduced, pi, q, p)
    check_constrained_field(label, reduced, unreduced, pi, q, p)
    for arrow, (actual, desired) in oracles(q, p, unreduced, pi).items():
        _close(actual, desired, label, arrow)


@pytest.mark.parametrize("case", CASES, ids=str)
@SETTINGS
@given(data=st.data())
def test_unreduced_data_derivatives_match_complex_step(case, data):
    """The chain-rule ``dM/dq``, ``de_i/dq``, ``dU/dq`` of :func:`unreduce` equal a complex step of ``M``, ``e_i``, ``U``.

    (liefi does not check analytic derivatives itself; the random data here are
    complex-step safe, so the composite functions can be complex-stepped directly.)
    """
    reduced, q, p = data.draw(random_systems(case))
    unreduced, _ = _build(case, reduced, q)
    for datum in (unreduced.metric, unreduced.constraints, unreduced.potential):
        if datum.constant:
            continue
        _, analytic = datum.with_derivative(q)
        _, cs = _diff.jacobian(datum.fun, q)
        _close(analytic, cs, case, f"d{datum.name}/dq (chain rule = complex step)")


@SETTINGS
@given(data=st.data())
def test_extension_commutes_with_reduction_orthonormalized(data):
    """``orthonormalize=True`` upstairs and downstairs: same rows, Gram = I on both levels."""
    case = CASES[5]
    reduced, q, p = data.draw(random_systems(case))
    assume(reduced.K > 0)
    ortho = NonholonomicSystem(
        case.space(), reduced.metric.fun, reduced.constraints.fun, reduced.potential.fun, sample=q[0, 3:], orthonormalize=True
    )
    unreduced, pi = _build(case, ortho, q)
    assert unreduced.orthonormalized
    _close(unreduced.gram_matrix(q), np.broadcast_to(np.eye(ortho.K), (BATCH, ortho.K, ortho.K)), case, "orthonormal: C_Q = I")
    check_functions(case, ortho, unreduced, pi, q, p)
    check_extended_field(case, ortho, unreduced, pi, q, p)


# ----------------------------------------------------------------------------- errors


def test_unreduce_rejects_a_wrong_chart_jacobian():
    reduced = NonholonomicSystem(LieGroupPhaseSpace(SO3()), np.eye(3))
    with pytest.raises(ValueError, match="chart_jacobian"):
        unreduce(reduced, euler_zyx, lambda s: -euler_zyx_jacobian(s))


@pytest.mark.filterwarnings("ignore:Casting complex values to real")
def test_unreduce_rejects_a_chart_that_is_not_complex_step_safe():
    reduced = NonholonomicSystem(LieGroupPhaseSpace(SE2(S1())), np.eye(3))

    def real_chart(s):
        return se2_chart(np.asarray(s, dtype=float))

    with pytest.raises(ValueError, match="chart"):
        unreduce(reduced, real_chart, se2_chart_jacobian)


def test_unreduce_rejects_a_singular_chart_point():
    reduced = NonholonomicSystem(LieGroupPhaseSpace(SO3()), np.eye(3))
    with pytest.raises(ValueError, match="singular"):
        unreduce(reduced, euler_zyx, euler_zyx_jacobian, sample=[0.1, np.pi / 2, 0.2])


def test_unreduce_rejects_a_system_without_symmetry():
    reduced = NonholonomicSystem(CotangentBundle(2), np.eye(2))
    with pytest.raises(ValueError, match="LieGroupPhaseSpace"):
        unreduce(reduced, euler_zyx, euler_zyx_jacobian)


if __name__ == "__main__":  # print the worst discrepancy per (case, arrow)
    import sys

    code = pytest.main([__file__, "-q", "-p", "no:cacheprovider"])
    # pytest imported this file again under its own module name: read that copy's record
    worst = next(m.WORST for k, m in list(sys.modules.items()) if k != "__main__" and getattr(m, "__file__", None) == __file__)
    width = max(len(c) for c, _ in worst)
    for (c, arrow), err in sorted(worst.items()):
        print(f"{c:<{width}}  {arrow:<45}  {err:.2e}")
    sys.exit(code)
