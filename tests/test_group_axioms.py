"""The Lie group axioms liefi's groups must satisfy, each test named after its identity.

Every test runs over every group in ``strategies.GROUPS`` and the batch shapes
``()``, ``(3,)``, ``(2, 2)``.  The algebra structure (bracket, ``ad``, ``ad*``)
is derived in liefi from ``hat``/``vee``; the embedding (``config_rate``,
``penalty``) is supplied per group; both are checked here against definitions
that do not go through the code under test (matrix commutators,
``scipy.linalg.expm``, complex-step derivatives).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st
from scipy.linalg import expm

from liefi.groups import S1, SE2, SE3, SO2, SO3, ProductGroup, Rn
from strategies import BATCH_SHAPES, GROUPS, PROPERTY, SEEDS, cs_grad, rel_err

pytestmark = pytest.mark.parametrize("G", GROUPS)


def _alg(G, rng, shape, scale=1.0):
    return scale * rng.normal(size=tuple(shape) + (G.dim,))


def rotation_blocks(G):
    """Oracle: ``[(first row, k), ...]`` of the rotation blocks of ``G``'s matrix, from what each
    shipped group is (not from its declaration): SO(k) and SE(3)/SE(2) with a matrix rotation
    have one, an angle chart and R^n none, a product its factors' at their matrix offsets."""
    if isinstance(G, ProductGroup):
        out, off = [], 0
        for f in G.factors:
            out += [(off + i, k) for i, k in rotation_blocks(f)]
            off += f.matrix_dim
        return out
    if isinstance(G, SO3) or isinstance(G, SE3):
        return [(0, 3)]
    if isinstance(G, SO2) or (isinstance(G, SE2) and isinstance(G.rotation_group, SO2)):
        return [(0, 2)]
    assert isinstance(G, (S1, SE2, Rn)), f"rotation_blocks: add an oracle for {G!r}"
    return []


def _comm(A, B):
    return A @ B - B @ A


# --------------------------------------------------------------------- bracket
@PROPERTY
@given(seed=SEEDS, shape=BATCH_SHAPES)
def test_bracket_antisymmetry(G, seed, shape):
    """``[xi, eta] = -[eta, xi]``."""
    rng = np.random.default_rng(seed)
    xi, eta = _alg(G, rng, shape), _alg(G, rng, shape)
    assert G.bracket(xi, eta).shape == tuple(shape) + (G.dim,)
    np.testing.assert_allclose(G.bracket(xi, eta), -G.bracket(eta, xi), atol=1e-14)
    np.testing.assert_allclose(G.bracket(xi, xi), 0.0, atol=1e-14)


@PROPERTY
@given(seed=SEEDS, shape=BATCH_SHAPES)
def test_jacobi_identity(G, seed, shape):
    """``[xi, [eta, zeta]] + [eta, [zeta, xi]] + [zeta, [xi, eta]] = 0``."""
    rng = np.random.default_rng(seed)
    a, b, c = (_alg(G, rng, shape) for _ in range(3))
    br = G.bracket
    jac = br(a, br(b, c)) + br(b, br(c, a)) + br(c, br(a, b))
    assert np.max(np.abs(jac), initial=0.0) < 1e-13


@PROPERTY
@given(seed=SEEDS, shape=BATCH_SHAPES)
def test_hat_is_a_lie_algebra_homomorphism(G, seed, shape):
    """``hat([xi, eta]) = [hat xi, hat eta]`` (matrix commutator)."""
    rng = np.random.default_rng(seed)
    xi, eta = _alg(G, rng, shape), _alg(G, rng, shape)
    np.testing.assert_allclose(G.hat(G.bracket(xi, eta)), _comm(G.hat(xi), G.hat(eta)), atol=1e-13)


@PROPERTY
@given(seed=SEEDS, shape=BATCH_SHAPES)
def test_vee_inverts_hat(G, seed, shape):
    """``vee(hat(xi)) = xi`` and ``hat(vee(X)) = X`` on the algebra; ``hat`` is linear."""
    rng = np.random.default_rng(seed)
    xi, eta = _alg(G, rng, shape), _alg(G, rng, shape)
    X = G.hat(xi)
    assert X.shape == tuple(shape) + (G.matrix_dim, G.matrix_dim)
    np.testing.assert_array_equal(G.vee(X), xi)
    np.testing.assert_array_equal(G.hat(G.vee(X)), X)
    np.testing.assert_allclose(G.hat(2.0 * xi - eta), 2.0 * X - G.hat(eta), atol=1e-15)


@PROPERTY
@given(seed=SEEDS, shape=BATCH_SHAPES)
def test_ad_matrix_is_bracket(G, seed, shape):
    """``ad(xi) @ eta = [xi, eta]``."""
    rng = np.random.default_rng(seed)
    xi, eta = _alg(G, rng, shape), _alg(G, rng, shape)
    np.testing.assert_allclose(np.einsum("...ij,...j->...i", G.ad(xi), eta), G.bracket(xi, eta), atol=1e-14)


@PROPERTY
@given(seed=SEEDS, shape=BATCH_SHAPES)
def test_coadjoint_is_dual_of_adjoint(G, seed, shape):
    """``<ad*_xi mu, eta> = <mu, ad_xi eta> = <mu, [xi, eta]>``."""
    rng = np.random.default_rng(seed)
    xi, eta, mu = _alg(G, rng, shape), _alg(G, rng, shape), _alg(G, rng, shape)
    lhs = np.einsum("...i,...i->...", G.ad_star(xi, mu), eta)
    rhs = np.einsum("...i,...i->...", mu, G.bracket(xi, eta))
    rhs2 = np.einsum("...i,...ij,...j->...", mu, G.ad(xi), eta)
    np.testing.assert_allclose(lhs, rhs, atol=1e-13)
    np.testing.assert_allclose(lhs, rhs2, atol=1e-13)


@PROPERTY
@given(seed=SEEDS)
def test_lie_poisson_tensor_is_minus_mu_bracket(G, seed):
    """``Lambda(mu)_ab = -<mu, [E_a, E_b]>``: antisymmetric, and ``Lambda(mu) dh = ad*_dh mu``."""
    rng = np.random.default_rng(seed)
    mu, dh = _alg(G, rng, (4,)), _alg(G, rng, (4,))
    L = G.lie_poisson_tensor(mu)
    np.testing.assert_allclose(L, -np.swapaxes(L, -1, -2), atol=1e-15)
    E = np.eye(G.dim)
    ref = -np.einsum("...c,abc->...ab", mu, G.bracket(E[:, None, :], E[None, :, :]))
    np.testing.assert_allclose(L, ref, atol=1e-14)
    np.testing.assert_allclose(np.einsum("...ab,...b->...a", L, dh), G.ad_star(dh, mu), atol=1e-13)


# --------------------------------------------------------------------- exp
@PROPERTY
@given(seed=SEEDS, shape=BATCH_SHAPES, log_scale=st.sampled_from([-9.0, -4.1, -3.9, -2.0, 0.0, 0.5]))
def test_exp_agrees_with_expm_of_hat(G, seed, shape, log_scale):
    """``exp(xi) = expm(hat(xi))``, also at small angles (Taylor branches)."""
    rng = np.random.default_rng(seed)
    xi = _alg(G, rng, shape, 10.0**log_scale)
    got = np.asarray(G.exp(xi))
    assert got.shape == tuple(shape) + (G.matrix_dim, G.matrix_dim)
    X = G.hat(xi).reshape(-1, G.matrix_dim, G.matrix_dim)
    ref = np.stack([expm(a) for a in X]).reshape(got.shape)
    # expm itself is accurate to ~1e-15 |hat xi|^2 at the larger angles
    tol = 1e-14 * (1.0 + np.max(np.abs(xi), initial=0.0) ** 2)
    np.testing.assert_allclose(got, ref, atol=tol, rtol=0)


# ----------------------------------------------------------- configuration embedding
@PROPERTY
@given(seed=SEEDS, shape=BATCH_SHAPES)
def test_config_matrix_round_trip(G, seed, shape):
    """``matrix_to_config(config_to_matrix(g)) = g`` for ``g`` on the group, and back."""
    rng = np.random.default_rng(seed)
    g = G.random_config(rng, shape)
    assert g.shape == tuple(shape) + (G.config_dim,)
    M = G.config_to_matrix(g)
    np.testing.assert_allclose(G.matrix_to_config(M), g, atol=1e-14)
    np.testing.assert_allclose(G.config_to_matrix(G.matrix_to_config(M)), M, atol=1e-14)
    np.testing.assert_allclose(G.config_to_matrix(G.identity_config()), np.eye(G.matrix_dim), atol=0)


@PROPERTY
@given(seed=SEEDS, shape=BATCH_SHAPES)
def test_config_rate_is_left_reconstruction(G, seed, shape):
    """``config_rate(g, xi)`` is ``g' = g . xi`` in the stored numbers:

    (i) pushed forward by the embedding, ``d/ds config_to_matrix(g + s config_rate(g, xi))
    = config_to_matrix(g) hat(xi)`` (complex step in ``s``);
    (ii) it is the ``t``-derivative at 0 of the stored numbers of the curve ``g exp(t xi)``,
    ``d/dt matrix_to_config(config_to_matrix(g) exp(t xi))`` (4th-order central difference;
    ``g`` near the identity so that an angle chart stays away from its cut).
    """
    rng = np.random.default_rng(seed)
    g = G.random_config(rng, shape)
    xi = _alg(G, rng, shape)
    rate = G.config_rate(g, xi)
    assert rate.shape == g.shape
    M = G.config_to_matrix(g)
    target = M @ G.hat(xi)
    h = 1e-30
    dM = np.asarray(G.config_to_matrix(g + 1j * h * rate)).imag / h
    np.testing.assert_allclose(dM, target, atol=1e-13 * max(1.0, np.abs(target).max()))

    g1 = G.matrix_to_config(G.exp(_alg(G, rng, shape, 0.3)))
    M1 = G.config_to_matrix(g1)

    def curve(t):
        return G.matrix_to_config(M1 @ np.asarray(G.exp(t * xi)))

    s = 1e-3
    d = (8 * (curve(s) - curve(-s)) - (curve(2 * s) - curve(-2 * s))) / (12 * s)
    want = G.config_rate(g1, xi)
    np.testing.assert_allclose(d, want, atol=1e-9 * max(1.0, np.abs(want).max()))


@PROPERTY
@given(seed=SEEDS, shape=BATCH_SHAPES)
def test_penalty_vanishes_on_the_group(G, seed, shape):
    """``penalty(g) = 0`` and ``penalty_grad(g) = 0`` for ``g`` on the group."""
    rng = np.random.default_rng(seed)
    g = G.random_config(rng, shape)
    P = np.asarray(G.penalty(g))
    assert P.shape == tuple(shape)
    assert np.max(np.abs(P), initial=0.0) < 1e-28
    assert np.max(np.abs(G.penalty_grad(g)), initial=0.0) < 1e-14


@PROPERTY
@given(seed=SEEDS, shape=BATCH_SHAPES, off=st.sampled_from([1e-3, 0.1, 0.5]))
def test_penalty_gradient_is_gradient_of_penalty(G, seed, shape, off):
    """``penalty_grad = d penalty / d g`` (complex step) at off-group points, with
    ``penalty = 1/4 ||R^T R - I||_F^2`` per rotation block (docs/paper_notes.md item 4: gradient ``R (R^T R - I)``)."""
    rng = np.random.default_rng(seed)
    g = G.random_config(rng, shape) + off * rng.normal(size=tuple(shape) + (G.config_dim,))
    grad = G.penalty_grad(g)
    assert grad.shape == g.shape
    ref = cs_grad(G.penalty, g)
    assert rel_err(grad, ref, max(1e-12, np.abs(ref).max())) < 1e-12
    # the value itself, block by block, from the definition on the group matrix
    M = G.config_to_matrix(g)
    want = np.zeros(tuple(shape))
    for i, r in rotation_blocks(G):
        R = M[..., i : i + r, i : i + r]
        S = np.swapaxes(R, -1, -2) @ R - np.eye(r)
        want = want + 0.25 * np.sum(S * S, axis=(-1, -2))
    pen = np.asarray(G.penalty(g))
    np.testing.assert_allclose(pen, want, rtol=1e-12, atol=1e-300)


@PROPERTY
@given(seed=SEEDS)
def test_penalty_hessian_bound_is_largest_hessian_eigenvalue(G, seed):
    """On the group the Hessian of the penalty has largest eigenvalue ``penalty_hessian_bound()``."""
    rng = np.random.default_rng(seed)
    g = G.random_config(rng)
    H = cs_grad(G.penalty_grad, g)  # (config_dim, config_dim)
    np.testing.assert_allclose(H, H.T, atol=1e-12)
    top = np.linalg.eigvalsh(H).max() if H.size else 0.0
    assert abs(top - G.penalty_hessian_bound()) < 1e-10


@PROPERTY
@given(seed=SEEDS, shape=st.sampled_from([(3,), (2, 2)]))
def test_batch_equals_loop(G, seed, shape):
    """Every batch-first operation on a batch equals the operation on each member."""
    rng = np.random.default_rng(seed)
    xi, eta = _alg(G, rng, shape), _alg(G, rng, shape)
    g = G.random_config(rng, shape) + 0.1 * rng.normal(size=tuple(shape) + (G.config_dim,))
    ops = {
        "bracket": lambda a, b, c: G.bracket(a, b),
        "ad_star": lambda a, b, c: G.ad_star(a, b),
        "hat": lambda a, b, c: G.hat(a),
        "exp": lambda a, b, c: G.exp(a),
        "config_rate": lambda a, b, c: G.config_rate(c, a),
        "config_to_matrix": lambda a, b, c: G.config_to_matrix(c),
        "penalty": lambda a, b, c: G.penalty(c),
        "penalty_grad": lambda a, b, c: G.penalty_grad(c),
    }
    for name, op in ops.items():
        batch = np.asarray(op(xi, eta, g))
        for idx in np.ndindex(*shape):
            np.testing.assert_allclose(batch[idx], op(xi[idx], eta[idx], g[idx]), rtol=1e-14, atol=1e-15, err_msg=name)
