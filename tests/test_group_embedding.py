"""Groups declare their embedding; liefi derives the penalty, checks the declaration, and a
user's SE(3) is as well kept on the group as the shipped SO(3) (issue: groups declare their embedding)."""

from __future__ import annotations

import numpy as np
import pytest

import liefi
from liefi.groups import SE3, SO3, LieGroup, MatrixLieGroup
from strategies import GROUPS, cs_grad


def test_se3_penalty_zero_on_group_positive_off_and_gradient_by_complex_step():
    G = SE3()
    rng = np.random.default_rng(1)
    g = G.random_config(rng, (5,))
    assert G.config_dim == 12 and G.penalty_hessian_bound() == 2.0
    assert np.max(np.abs(G.penalty(g))) < 1e-28
    assert np.max(np.abs(G.penalty_grad(g))) < 1e-14
    off = g + 0.1 * rng.normal(size=g.shape)
    P = G.penalty(off)
    R = G.config_to_matrix(off)[..., :3, :3]
    S = np.swapaxes(R, -1, -2) @ R - np.eye(3)
    np.testing.assert_allclose(P, 0.25 * np.sum(S * S, axis=(-2, -1)), rtol=1e-13)
    assert np.all(P > 0)
    # moving only the translation column leaves the penalty unchanged
    t_only = g.copy()
    t_only[..., [3, 7, 11]] += 1.0
    assert np.max(np.abs(G.penalty(t_only))) < 1e-28
    ref = cs_grad(G.penalty, off)
    np.testing.assert_allclose(G.penalty_grad(off), ref, rtol=1e-12, atol=1e-14 * np.abs(ref).max())
    np.testing.assert_array_equal(G.penalty_grad(off)[..., [3, 7, 11]], 0.0)


@pytest.mark.parametrize("G", GROUPS)
def test_declaration_is_traceable_on_object_arrays(G):
    """``orthogonal_matrices`` and the derived penalty gradient run on numpy object arrays
    (the compiled engine's symbolic scalars) and give the numbers of the float path."""
    rng = np.random.default_rng(2)
    g = G.random_config(rng) + 0.1 * rng.normal(size=G.config_dim)
    go = np.empty(G.config_dim, dtype=object)
    go[:] = list(g)
    blocks = G.orthogonal_matrices(go)
    for Ro, R in zip(blocks, G.orthogonal_matrices(g)):
        assert Ro.dtype == object
        np.testing.assert_array_equal(Ro.astype(float), R)
    np.testing.assert_allclose(np.asarray(G.penalty_grad(go), dtype=float), G.penalty_grad(g), rtol=1e-13, atol=1e-15)
    np.testing.assert_allclose(float(G.penalty(go)), G.penalty(g), rtol=1e-13, atol=1e-300)


class _SE3Undeclared(SE3):
    orthogonal_blocks = ()


def _blade(G):
    """A rigid body on SE(3) whose body velocity along its y axis is zero (a blade), from data only."""
    M = np.diag([1.0, 2.0, 3.0, 2.0, 2.0, 2.0])
    a = np.array([[0, 0, 0, 0, 1.0, 0]])
    return liefi.NonholonomicSystem(liefi.LieGroupPhaseSpace(G), M, a @ np.linalg.inv(M))


def _orthogonality(y, nc):
    R = SE3().config_to_matrix(y[:, :nc])[..., :3, :3] if nc == 12 else y[:, :9].reshape(-1, 3, 3)
    return float(np.max(np.linalg.norm(np.swapaxes(R, -1, -2) @ R - np.eye(3), axis=(-2, -1))))


def test_se3_rigid_body_with_blade_keeps_rotation_like_so3():
    """Euler, dt = 5e-3, t = 10, gains 1: ``||R^T R - I||`` of the SE(3) blade equals the SO(3)
    free body's (the same rotation dynamics) and is far below an SE(3) without the declaration."""
    Pi0 = np.array([1.0, 0.5, -0.7])
    out = {}
    for name, sys_, z0 in (
        ("se3", _blade(SE3()), np.r_[Pi0, 0.8, 0.0, 0.3]),
        ("undeclared", _blade(_SE3Undeclared()), np.r_[Pi0, 0.8, 0.0, 0.3]),
        ("so3", liefi.NonholonomicSystem(liefi.LieGroupPhaseSpace(SO3()), np.diag([1.0, 2.0, 3.0])), Pi0),
    ):
        G = sys_.space.group
        fi = liefi.FeedbackIntegrator(sys_, np.r_[G.identity_config(), z0], gains=1.0)
        assert ("penalty" in fi.invariant_names) == (name != "undeclared")
        sol = fi.run(10.0, dt=5e-3, scheme="euler", check_stability=False, backend="numpy")
        out[name] = _orthogonality(sol.y.T, G.config_dim)
    assert out["se3"] < 1.1 * out["so3"] and out["so3"] < 1.1 * out["se3"], out
    assert out["undeclared"] > 10 * out["se3"], out


def test_user_group_with_a_rotation_block_needs_only_hat_vee_and_declaration():
    """The README's SE(3): ``hat``, ``vee`` and ``orthogonal_blocks``; the same penalty as ``SE3``."""

    class MySE3(MatrixLieGroup):
        dim, matrix_dim = 6, 4
        orthogonal_blocks = ((0, 3),)  # G[0:3, 0:3] is a rotation

        def hat(self, xi):
            xi = np.asarray(xi)
            z = np.zeros_like(xi[..., 0])
            w1, w2, w3, v1, v2, v3 = (xi[..., i] for i in range(6))
            rows = [[z, -w3, w2, v1], [w3, z, -w1, v2], [-w2, w1, z, v3], [z, z, z, z]]
            return np.stack([np.stack(r, -1) for r in rows], -2)

        def vee(self, X):
            return np.stack([X[..., 2, 1], X[..., 0, 2], X[..., 1, 0], X[..., 0, 3], X[..., 1, 3], X[..., 2, 3]], -1)

    G, ref = MySE3(), SE3()
    rng = np.random.default_rng(3)
    g = ref.random_config(rng, (4,)) + 0.05 * rng.normal(size=(4, 12))
    assert G.config_dim == 12
    np.testing.assert_allclose(G.structure_constants, ref.structure_constants, atol=0)
    np.testing.assert_allclose(G.penalty(g), ref.penalty(g), rtol=1e-15)
    np.testing.assert_allclose(G.penalty_grad(g), ref.penalty_grad(g), rtol=1e-15)
    xi = rng.normal(size=(4, 6))
    np.testing.assert_allclose(G.config_rate(g, xi), ref.config_rate(g, xi), rtol=1e-15)
    G.check()


def test_check_names_a_penalty_gradient_that_breaks_the_complex_step():
    """An override that fills a float buffer loses the imaginary part (stiffness estimated as 0):
    building a system says which method and why."""

    class Buffered(SO3):
        def penalty_grad(self, g):
            out = np.zeros(np.shape(g))
            with np.errstate(all="ignore"):
                import warnings

                with warnings.catch_warnings():
                    warnings.simplefilter("ignore")
                    out[...] = super().penalty_grad(g)
            return out

    with pytest.raises(ValueError, match="Buffered.penalty_grad"):
        liefi.NonholonomicSystem(liefi.LieGroupPhaseSpace(Buffered()), np.eye(3))


def test_check_rejects_a_declaration_that_is_not_a_selection():
    class Scaled(SO3):
        def orthogonal_matrices(self, g):
            return [2.0 * np.asarray(g).reshape(np.shape(g)[:-1] + (3, 3))]

    with pytest.raises(ValueError, match="orthogonal_matrices: every block entry must be one stored number"):
        Scaled().check()

    class ConstantRow(SE3):
        orthogonal_blocks = ((0, 4),)

    with pytest.raises(ValueError, match="orthogonal_blocks: block \\(0, 4\\) covers a row"):
        ConstantRow().check()


def test_check_rejects_a_penalty_that_does_not_vanish_on_the_group():
    class Wrong(SO3):
        def penalty(self, g):
            return super().penalty(g) + 1.0

    with pytest.raises(ValueError, match="Wrong.penalty: .* at a point of the group"):
        Wrong().check()


def test_check_runs_once_per_group_object():
    G = SE3()
    calls = []

    class Counting(SE3):
        def orthogonal_matrices(self, g):
            calls.append(1)
            return super().orthogonal_matrices(g)

    C = Counting()
    C.check()
    n = len(calls)
    C.check()
    assert len(calls) == n > 0
    assert G == SE3() and isinstance(G, LieGroup)


@pytest.mark.parametrize("G", GROUPS, ids=repr)
def test_penalty_hessian_max_is_the_largest_eigenvalue_of_the_complex_step_hessian(G):
    """``3 s_max^2 - 1`` (closed form) against the spectrum of the complex-step Hessian, off the group."""
    from liefi import _diff

    rng = np.random.default_rng(3)
    g = G.random_config(rng, (5,)) + 0.3 * rng.normal(size=(5, G.config_dim))  # well off the group
    H = _diff.jacobian(G.penalty_grad, g)[1]
    want = np.linalg.eigvalsh(0.5 * (H + np.swapaxes(H, -1, -2)))[..., -1]
    if not G.orthogonal_matrices(g):
        want = np.zeros(5)
    np.testing.assert_allclose(G.penalty_hessian_max(g), want, rtol=1e-12, atol=1e-12)
    on = G.random_config(rng, (3,))
    np.testing.assert_allclose(G.penalty_hessian_max(on), G.penalty_hessian_bound(), atol=1e-12)
