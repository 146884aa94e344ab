"""Semidirect-product reduction: data that depend on the attitude through ``Gamma = g^{-1} . a_0``.

A system on ``T*(G x X)`` whose metric, potential and constraint rows depend on
the group element only through an advected vector ``Gamma = g^{-1} . a_0`` is
invariant under the isotropy group of ``a_0`` only.  liefi reduces it to
``(g x| V)* x T*X`` with state ``(x, Gamma, mu, p_x)`` (:mod:`liefi.phase_space`).
The checks, on ``SO(3) x| R^3`` (the heavy top's and rolling bodies' case), on
``SO(3) x| R^3`` times a shape circle, and on ``SO(3) x R^2`` with the whole
attitude advected (three copies of ``R^3``, a body on a plane), with random
``Gamma``-dependent metric, potential, constraint rows and vector potential:

* the extension/reduction diagram commutes: :func:`liefi.reduction.unreduce`
  writes the unreduced canonical system on ``T*Q`` in a chart (its data read at
  ``Gamma(s) = G(s)^{-1} a_0``), liefi extends both with the same code, and
  ``pi(q, p) = (g, z)`` carries ``H~``, ``H``, ``J``, ``Lambda~``, ``Lambda``,
  the extended field with ``g' = g dh~/dmu`` and, on ``C``, the constrained
  field, to 1e-12 relative;
* ``h~`` and every ``J_i`` are first integrals of the extended field off ``C``
  and it equals the constrained field on ``C`` (also run, with every other
  property test, through ``strategies.SPACES``' ``semidirect`` entries);
* the heavy top's textbook Euler--Poisson equations (a test oracle) are the
  reduced field, and ``Gamma`` stays ``g^{-1} a_0`` along the reconstructed flow.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from liefi import LieGroupPhaseSpace, NonholonomicSystem, TrivialPrincipalBundle
from liefi.groups import SO3, Representation, Rn
from liefi.reduction import group_velocity, unreduce
from strategies import PROPERTY, SPACES as ALL_SPACES, cs_grad, dot
from test_poisson_axioms import Poly, _setup
from test_reduction_diagram import _blockdiag, euler_zyx, euler_zyx_jacobian

#: relative discrepancy allowed on every arrow of the diagram (floor 1, as in test_reduction_diagram)
RTOL = 1e-12
BATCH = 3
SETTINGS = settings(max_examples=10, deadline=None, suppress_health_check=[HealthCheck.too_slow])


def _close(actual, desired, what):
    actual, desired = np.asarray(actual, float), np.asarray(desired, float)
    assert actual.shape == desired.shape, f"{what}: shapes {actual.shape} != {desired.shape}"
    scale = max(np.max(np.abs(desired), initial=0.0), np.max(np.abs(actual), initial=0.0), 1.0)
    err = np.max(np.abs(actual - desired), initial=0.0) / scale
    assert err <= RTOL, f"{what}: relative discrepancy {err:.3g}"


def _translation(s):
    """``(s_1, s_2) -> [[1, 0, s_1], [0, 1, s_2], [0, 0, 1]]`` (``Rn(2)``'s matrix)."""
    s = np.asarray(s)
    z, o = np.zeros_like(s[..., 0]), np.ones_like(s[..., 0])
    return np.stack([np.stack(r, -1) for r in ([o, z, s[..., 0]], [z, o, s[..., 1]], [z, z, o])], -2)


def plane_chart(s):
    """``SO(3) x R^2``: Euler angles and the position on the plane."""
    s = np.asarray(s)
    return _blockdiag(euler_zyx(s[..., :3]), _translation(s[..., 3:5]))


def plane_chart_jacobian(s):
    s = np.asarray(s)
    R, dR = euler_zyx(s[..., :3]), euler_zyx_jacobian(s[..., :3])
    T = _translation(s[..., 3:5])
    zT, zR = np.zeros_like(T), np.zeros_like(R)
    e = np.zeros(s.shape[:-1] + (3, 3))
    dT = [e.copy(), e.copy()]
    dT[0][..., 0, 2] = 1.0
    dT[1][..., 1, 2] = 1.0
    return np.stack([_blockdiag(dR[..., k, :, :], zT) for k in range(3)] + [_blockdiag(zR, d) for d in dT], -3)


#: (name, phase space, chart, chart_jacobian, bound on |s|)
SPACES = [
    ("so3xR3", LieGroupPhaseSpace(SO3(), advected=Representation(SO3()), a0=[0.2, -0.3, 1.0]),
     euler_zyx, euler_zyx_jacobian, (np.pi, 1.2, np.pi)),
    ("so3xR3 bundle S1", TrivialPrincipalBundle(SO3(), 1, names=("psi",), advected=Representation(SO3()),
                                                a0=[0.0, 0.0, 1.0]),
     euler_zyx, euler_zyx_jacobian, (np.pi, 1.2, np.pi)),
    ("so3R2x(R3)^3", LieGroupPhaseSpace(SO3() * Rn(2), advected=Representation(SO3() * Rn(2), block=(0, 3), copies=3),
                                        a0=np.eye(3).ravel()),
     plane_chart, plane_chart_jacobian, (np.pi, 1.2, np.pi, 2.0, 2.0)),
]


@st.composite
def systems(draw, entry):
    """Random data of ``y = (x, Gamma)``: ``m = M0 + sin(c.y) S1 + cos(b.y) S2`` (SPD), rows
    ``E = E0 + sin(d.y) E1`` (not orthonormal), ``U = a.y + 1/2 y.Q y``, and half the time
    ``A = A0 + sin(f.y) A1``; a batch of canonical states ``(q, p)`` in the chart's safe box."""
    name, space, chart, jac, bound = entry
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    D, nd = space.D, space.data_dim
    K = draw(st.integers(0, min(2, D - 1)))
    Q, _ = np.linalg.qr(rng.normal(size=(D, D)))
    M0 = (Q * rng.uniform(0.8, 2.5, D)) @ Q.T
    S1, S2 = (0.15 * (lambda A: A + A.T)(rng.normal(size=(D, D))) / np.sqrt(D) for _ in range(2))
    c, b, dd, f, a = (rng.normal(size=nd) for _ in range(5))
    E0 = np.eye(K, D) + 0.3 * rng.normal(size=(K, D))
    E1 = 0.2 * rng.normal(size=(K, D))
    Qp = 0.3 * rng.normal(size=(nd, nd))
    Qp = Qp + Qp.T
    A0, A1 = 0.4 * rng.normal(size=D), 0.3 * rng.normal(size=D)
    n = space.n

    def y(x, G):
        return np.concatenate([np.broadcast_to(x, G.shape[:-1] + (n,)), G], -1)

    def metric(x, G):
        yy = y(x, G)
        return M0 + np.sin(yy @ c)[..., None, None] * S1 + np.cos(yy @ b)[..., None, None] * S2

    def constraints(x, G):
        return E0 + np.sin(y(x, G) @ dd)[..., None, None] * E1

    def potential(x, G):
        yy = y(x, G)
        return yy @ a + 0.5 * np.einsum("...i,ij,...j->...", yy, Qp, yy)

    def vector_potential(x, G):
        return A0 + np.sin(y(x, G) @ f)[..., None] * A1

    d = space.d
    s = rng.uniform(-1, 1, (BATCH, d)) * np.asarray(bound)
    x = rng.uniform(-np.pi, np.pi, (BATCH, n))
    q = np.concatenate([s, x], -1)
    p = rng.uniform(-2, 2, (BATCH, D))
    reduced = NonholonomicSystem(
        space, metric, constraints if K else None, potential,
        vector_potential=vector_potential if draw(st.booleans()) else None,
    )
    unreduced, pi = unreduce(reduced, chart, jac, sample=q[0])
    return reduced, unreduced, pi, q, p


@pytest.mark.parametrize("entry", SPACES, ids=[e[0] for e in SPACES])
@SETTINGS
@given(data=st.data())
def test_extension_commutes_with_semidirect_reduction(entry, data):
    """``pi`` carries ``H~, H, J, Lambda~, Lambda`` to ``h~, h, J, lambda~, lambda``, the unreduced
    extended field to (``g dh~/dmu``, the reduced extended field), and on ``C`` the constrained field
    to (``g dh/dmu``, the reduced constrained field): to 1e-12 relative."""
    reduced, unreduced, pi, q, p = data.draw(systems(entry))
    N = q.shape[-1]
    Z = np.concatenate([q, p], -1)
    g, z = pi(q, p)
    _close(unreduced.extended_hamiltonian(Z), reduced.extended_hamiltonian(z), "h~ o pi = H~")
    _close(unreduced.hamiltonian(Z), reduced.hamiltonian(z), "h o pi = H")
    _close(unreduced.constraint_momenta(Z), reduced.constraint_momenta(z), "J o pi = J")
    _close(unreduced.extended_multipliers(Z), reduced.extended_multipliers(z), "lambda~ o pi = Lambda~")
    _close(unreduced.multipliers(Z), reduced.multipliers(z), "lambda o pi = Lambda")
    X = unreduced.extended_vector_field(Z)
    gdot, zdot = pi.push(q, p, X[..., :N], X[..., N:])
    _close(zdot, reduced.extended_vector_field(z), "T pi X~ = X~_red (Gamma' = -xi.Gamma, diamond term)")
    _close(gdot, reduced.reconstruction(g, z), "T pi X~ = g dh~/dmu")
    Zc = unreduced.project(Z)
    gc, zc = pi(Zc[..., :N], Zc[..., N:])
    Xc = unreduced.constrained_vector_field(Zc)
    gdot, zdot = pi.push(Zc[..., :N], Zc[..., N:], Xc[..., :N], Xc[..., N:])
    _close(zdot, reduced.constrained_vector_field(zc), "on C: T pi X = X_red")
    _close(gdot, reduced.reconstruction(gc, zc, extended=False), "on C: T pi X = g dh/dmu")


@pytest.mark.parametrize("entry", SPACES, ids=[e[0] for e in SPACES])
@SETTINGS
@given(data=st.data())
def test_advected_vector_is_g_inverse_a0(entry, data):
    """``pi`` puts ``Gamma = g^{-1} . a_0`` in ``z`` (``space.advected_vector(g)``), and its rate along
    the extended field is ``-xi . Gamma`` with ``xi = dh~/dmu``."""
    reduced, unreduced, pi, q, p = data.draw(systems(entry))
    sp = reduced.space
    g, z = pi(q, p)
    Gamma = sp.advected_part(z)
    _close(Gamma, sp.advected_vector(g), "Gamma = g^-1 . a0")
    rate = reduced.extended_vector_field(z)[..., sp.n : sp.data_dim]
    _close(rate, -sp.advected.action(group_velocity(reduced, z), Gamma), "Gamma' = -xi . Gamma")


def test_heavy_top_is_the_euler_poisson_system():
    """``Pi' = Pi x Omega + m g l Gamma x chi``, ``Gamma' = Gamma x Omega`` (textbook, a test oracle)
    from ``h = 1/2 Pi.I^-1 Pi + m g l Gamma.chi`` and nothing else; ``|Gamma|^2`` and ``<Pi, Gamma>``
    are kept by the field."""
    rng = np.random.default_rng(5)
    space = LieGroupPhaseSpace(SO3(), advected=Representation(SO3()), a0=[0.0, 0.0, 1.0])
    I = np.diag([1.0, 1.7, 2.4])
    chi, mgl = rng.normal(size=3), 3.1
    top = NonholonomicSystem(space, I, potential=lambda x, G: mgl * G @ chi)
    z = rng.normal(size=(4, 6))
    Gamma, Pi = z[..., :3], z[..., 3:]
    Omega = Pi @ np.linalg.inv(I)
    want = np.concatenate([np.cross(Gamma, Omega), np.cross(Pi, Omega) + mgl * np.cross(Gamma, chi)], -1)
    got = top.extended_vector_field(z)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-14 * np.max(np.abs(want)))
    np.testing.assert_allclose(np.einsum("...i,...i", Gamma, got[..., :3]), 0, atol=1e-14)
    np.testing.assert_allclose(np.einsum("...i,...i", Pi, got[..., :3]) + np.einsum("...i,...i", Gamma, got[..., 3:]),
                               0, atol=1e-13)


def test_advected_bad_input_is_named():
    """Wrong ``a0`` / representation: a ``ValueError`` naming the parameter."""
    rep = Representation(SO3())
    with pytest.raises(ValueError, match="a0: required"):
        LieGroupPhaseSpace(SO3(), advected=rep)
    with pytest.raises(ValueError, match="a0: expected 3"):
        LieGroupPhaseSpace(SO3(), advected=rep, a0=[0.0, 1.0])
    with pytest.raises(ValueError, match="a0: given without"):
        LieGroupPhaseSpace(SO3(), a0=[0.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="advected: a representation of"):
        LieGroupPhaseSpace(SO3() * Rn(2), advected=rep, a0=[0.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="block"):
        Representation(SO3() * Rn(2), block=(2, 3))
    sp = LieGroupPhaseSpace(SO3(), advected=rep, a0=[0.0, 0.0, 1.0])
    with pytest.raises(ValueError, match="sample: expected a data point"):
        NonholonomicSystem(sp, np.eye(3), potential=lambda x, G: G[..., 2], sample=[0.0, 1.0])


@pytest.mark.parametrize("spec", [p for p in ALL_SPACES if p.values[0][0].startswith("semidirect")])
@PROPERTY
@given(data=st.data())
def test_advected_casimirs(spec, data):
    """``{C, f} = 0`` for every ``f``: ``<Gamma_i, Gamma_j>`` (each pair of copies) when ``G`` acts by
    rotations, and ``<mu, Gamma>`` on ``so(3) x| R^3``; ``Gamma`` stays on its orbit."""
    sp, rng, z = _setup(data, spec)
    rep = sp.advected
    f = Poly(rng, sp.nz)
    s0, size = rep.block
    L = np.asarray(sp.group.hat(np.eye(sp.d)))[:, s0 : s0 + size, s0 : s0 + size]
    casimirs = []
    if np.allclose(L, -np.swapaxes(L, -1, -2)):  # rotations: every inner product of copies
        for i in range(rep.copies):
            for j in range(i, rep.copies):
                casimirs.append(lambda z, i=i, j=j: dot(sp.advected_part(z)[..., i * size : (i + 1) * size],
                                                       sp.advected_part(z)[..., j * size : (j + 1) * size]))
    if isinstance(sp.group, SO3) and not sp.n:  # so(3) x| R^3
        casimirs.append(lambda z: dot(sp.split(z)[1], sp.advected_part(z)))
    if not casimirs:
        pytest.skip("no Casimir of this kind here (SE(2) does not act by rotations on R^3)")
    for C in casimirs:
        val = sp.bracket(z, cs_grad(C, z), f.grad(z))
        assert np.max(np.abs(val), initial=0.0) <= 1e-12 * max(1.0, np.max(np.abs(f.grad(z))) * np.max(np.abs(z)) ** 2)
