"""The Poisson structure of the reduced phase spaces ``g* x T*X``.

``(bracket:QG:trivial)``: ``{f, g} = -<mu, [f_mu, g_mu]> + f_x . g_px - g_x . f_px``,
the minus Lie--Poisson bracket on ``g*`` plus the canonical one on ``T*X``.  It
must be antisymmetric, satisfy the Leibniz rule and the Jacobi identity, and
be represented by the antisymmetric tensor ``B(z)`` with ``{f, g} = df . B dg``
and ``X_h = B dh``.

Test functions are random cubic polynomials ``f(z) = c + b.z + 1/2 z.A z +
1/6 T[z, z, z]`` with exact (analytic) gradients; the gradient of a bracket
``{g, k}(z)`` -- needed for the Jacobi identity -- is taken by complex step,
which is exact to rounding because the bracket is polynomial in ``z``.
Runs over every group (``lie-*``, ``bundle-*``) and the cotangent bundle.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given
from hypothesis import strategies as st

from liefi import CotangentBundle, LieGroupPhaseSpace, TrivialPrincipalBundle
from strategies import BATCH_SHAPES, PROPERTY, SEEDS, SPACES, advected_space, cs_grad, dot

pytestmark = pytest.mark.parametrize("spec", SPACES)


@st.composite
def phase_spaces(draw, spec):
    kind, G = spec
    if kind == "lie":
        return LieGroupPhaseSpace(G)
    if kind == "cotangent":
        return CotangentBundle(draw(st.integers(1, 3)))
    if kind == "semidirect":
        return advected_space(kind, G)
    if kind == "semidirect-bundle":
        return advected_space(kind, G, draw(st.integers(1, 2)))
    return TrivialPrincipalBundle(G, draw(st.integers(1, 2)))


class Poly:
    """A random cubic polynomial on ``R^nz`` with its exact gradient (complex safe)."""

    def __init__(self, rng, nz):
        self.c = rng.normal()
        self.b = rng.normal(size=nz)
        A = rng.normal(size=(nz, nz))
        self.A = A + A.T
        T = rng.normal(size=(nz, nz, nz))
        self.T = sum(np.transpose(T, p) for p in [(0, 1, 2), (0, 2, 1), (1, 0, 2), (1, 2, 0), (2, 0, 1), (2, 1, 0)]) / 6

    def __call__(self, z):
        return (
            self.c
            + z @ self.b
            + 0.5 * np.einsum("...i,ij,...j->...", z, self.A, z)
            + np.einsum("ijk,...i,...j,...k->...", self.T, z, z, z) / 6
        )

    def grad(self, z):
        return self.b + z @ self.A + 0.5 * np.einsum("ijk,...j,...k->...i", self.T, z, z)


def _setup(data, spec, shape=None):
    sp = data.draw(phase_spaces(spec))
    rng = np.random.default_rng(data.draw(SEEDS))
    shape = data.draw(BATCH_SHAPES) if shape is None else shape
    z = rng.normal(size=tuple(shape) + (sp.nz,))
    return sp, rng, z


@PROPERTY
@given(data=st.data())
def test_polynomial_gradients_are_exact(spec, data):
    """Sanity of the test functions: the analytic gradient equals the complex-step one."""
    sp, rng, z = _setup(data, spec)
    f = Poly(rng, sp.nz)
    np.testing.assert_allclose(f.grad(z), cs_grad(f, z), rtol=1e-13, atol=1e-13)


@PROPERTY
@given(data=st.data())
def test_bracket_antisymmetry(spec, data):
    """``{f, g} = -{g, f}`` and ``{f, f} = 0``."""
    sp, rng, z = _setup(data, spec)
    f, g = Poly(rng, sp.nz), Poly(rng, sp.nz)
    fg = sp.bracket(z, f.grad(z), g.grad(z))
    assert np.shape(fg) == z.shape[:-1]
    np.testing.assert_allclose(fg, -sp.bracket(z, g.grad(z), f.grad(z)), rtol=1e-14, atol=1e-12)
    np.testing.assert_allclose(sp.bracket(z, f.grad(z), f.grad(z)), 0.0, atol=1e-11)


@PROPERTY
@given(data=st.data())
def test_leibniz_rule(spec, data):
    """``{f, g k} = {f, g} k + g {f, k}``."""
    sp, rng, z = _setup(data, spec)
    f, g, k = (Poly(rng, sp.nz) for _ in range(3))
    d_gk = g.grad(z) * k(z)[..., None] + g(z)[..., None] * k.grad(z)
    lhs = sp.bracket(z, f.grad(z), d_gk)
    rhs = sp.bracket(z, f.grad(z), g.grad(z)) * k(z) + g(z) * sp.bracket(z, f.grad(z), k.grad(z))
    scale = np.max(np.abs(rhs), initial=1.0)
    np.testing.assert_allclose(lhs, rhs, atol=1e-12 * scale)


def _bracket_fun(sp, f, g):
    """The function ``z -> {f, g}(z)`` (complex safe)."""
    return lambda z: sp.bracket(z, f.grad(z), g.grad(z))


@PROPERTY
@given(data=st.data())
def test_jacobi_identity(spec, data):
    """``{f, {g, k}} + {g, {k, f}} + {k, {f, g}} = 0`` for cubic polynomials."""
    sp, rng, z = _setup(data, spec)
    f, g, k = (Poly(rng, sp.nz) for _ in range(3))
    terms = [
        sp.bracket(z, a.grad(z), cs_grad(_bracket_fun(sp, b, c), z))
        for a, b, c in ((f, g, k), (g, k, f), (k, f, g))
    ]
    total = sum(terms)
    scale = max(1.0, max(np.max(np.abs(t), initial=0.0) for t in terms))
    assert np.max(np.abs(total), initial=0.0) <= 1e-12 * scale


@PROPERTY
@given(data=st.data())
def test_poisson_tensor_is_antisymmetric_and_reproduces_bracket(spec, data):
    """``B(z)^T = -B(z)`` and ``{f, g}(z) = df . B(z) dg``."""
    sp, rng, z = _setup(data, spec)
    f, g = Poly(rng, sp.nz), Poly(rng, sp.nz)
    B = sp.poisson_tensor(z)
    assert B.shape == z.shape[:-1] + (sp.nz, sp.nz)
    np.testing.assert_array_equal(B, -np.swapaxes(B, -1, -2))
    via_B = np.einsum("...i,...ij,...j->...", f.grad(z), B, g.grad(z))
    np.testing.assert_allclose(via_B, sp.bracket(z, f.grad(z), g.grad(z)), rtol=1e-13, atol=1e-11)


@PROPERTY
@given(data=st.data())
def test_hamiltonian_vector_field_is_B_dh(spec, data):
    """``X_h(z) = B(z) dh`` and ``{f, h} = df . X_h``; ``dh . X_h = 0`` (energy)."""
    sp, rng, z = _setup(data, spec)
    f, h = Poly(rng, sp.nz), Poly(rng, sp.nz)
    X = sp.hamiltonian_vector_field(z, h.grad(z))
    assert X.shape == z.shape
    BX = np.einsum("...ij,...j->...i", sp.poisson_tensor(z), h.grad(z))
    np.testing.assert_allclose(X, BX, rtol=1e-14, atol=1e-12)
    np.testing.assert_allclose(dot(f.grad(z), X), sp.bracket(z, f.grad(z), h.grad(z)), rtol=1e-13, atol=1e-11)
    np.testing.assert_allclose(dot(h.grad(z), X), 0.0, atol=1e-11 * np.max(np.abs(X), initial=1.0) ** 2)


@PROPERTY
@given(data=st.data())
def test_coordinate_brackets(spec, data):
    """``{x_i, p_j} = delta_ij``, ``{x_i, x_j} = {p_i, p_j} = 0``, ``{mu_a, mu_b} = -<mu, [E_a, E_b]>``,
    ``{mu_a, x_i} = {mu_a, p_i} = 0`` -- the bracket ``(bracket:QG:trivial)`` on coordinate functions."""
    sp, rng, z = _setup(data, spec, shape=())
    n, d, nz, a = sp.n, sp.d, sp.nz, sp.data_dim
    eye = np.eye(nz)
    B = np.array([[sp.bracket(z, eye[i], eye[j]) for j in range(nz)] for i in range(nz)])
    want = np.zeros((nz, nz))
    want[:n, a + d :] = np.eye(n)
    want[a + d :, :n] = -np.eye(n)
    if d:
        E = np.eye(d)
        mu = z[a : a + d]
        want[a : a + d, a : a + d] = -np.array([[mu @ sp.group.bracket(E[i], E[j]) for j in range(d)] for i in range(d)])
    if sp.k:
        # {mu_b, Gamma} = E_b . Gamma (the group matrix's block acting on each copy), {Gamma, Gamma} = 0
        rep, Gamma = sp.advected, z[n:a]
        s0, size = rep.block
        for b in range(d):
            Lb = np.asarray(sp.group.hat(np.eye(d)[b]))[s0 : s0 + size, s0 : s0 + size]
            act = np.concatenate([Lb @ c for c in Gamma.reshape(rep.copies, size)])
            want[a + b, n:a] = act
            want[n:a, a + b] = -act
    np.testing.assert_allclose(B, want, atol=1e-15)
