"""The extension theorems of Section 2, in the general (non-orthonormal) form of
Remark ``(remark:nonhol:general)``, over every kind of system and every group.

* ``(theorem:extension:nonhol)`` (and its reduced versions): on ``C = {J = 0}``
  the extended field equals the constrained one, and ``C`` is invariant;
* ``(theorem:first:integrals)``: ``h~`` and every ``J_i`` are first integrals of
  the extended field *everywhere*; ``h~ = h`` and ``lambda~ = lambda`` on ``C``;
* ``(corollary:H:instead)``: ``h = h~ + 1/2 J.C^-1 J`` is a first integral
  everywhere **when the Gram matrix ``C`` is constant along the flow**
  (orthonormal ``e_i`` as in the main text, or constant data).  With
  ``x``-dependent, non-orthonormal ``e_i`` the Remark's claim that "all the
  theorems and corollaries hold" fails for the corollary: ``dh/dt =
  -1/2 w.(dC/dt) w`` with ``w = C^-1 J``, which vanishes on ``C`` only.  That
  exact drift is asserted by :func:`test_original_hamiltonian_drift_with_varying_gram`.

Gradients come from :func:`liefi.reduction.evaluate` and, independently, from
complex-step derivatives of oracles written from the data in
``strategies.oracle``; the two routes must agree to ``1e-10`` relative.
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from liefi.reduction import evaluate, group_velocity
from liefi.schemes import integrate
from strategies import (
    BATCH_SHAPES,
    SYSTEM_PROPERTY,
    SPACES,
    cases,
    central_grad,
    cs_grad,
    dot,
    field_scale,
    oracle,
    oracle_gram,
    oracle_h,
    oracle_ht,
    oracle_J,
    rel_err,
)

pytestmark = pytest.mark.parametrize("spec", SPACES)

#: Tolerance of the identities (observed: ~1e-15 relative).
TOL = 1e-10


def _draw(data, spec, **kw):
    case = data.draw(cases(spec, **kw))
    shape = data.draw(BATCH_SHAPES)
    return case, case.random_state(shape)


def _orthogonality(grad, X, scale):
    """``|grad . X| / (|grad| scale)`` (max over the batch and over the rows of ``grad``)."""
    num = np.abs(np.einsum("...j,...j->...", grad, X))
    scale = np.asarray(scale)[..., None] if num.ndim > np.ndim(scale) else scale
    den = np.linalg.norm(grad, axis=-1) * scale + 1e-300
    return float(np.max(num / den, initial=0.0))


def _Xbroadcast(X, K):
    return np.broadcast_to(X[..., None, :], X.shape[:-1] + (K, X.shape[-1]))


# ------------------------------------------------------------------ the two gradient routes
@SYSTEM_PROPERTY
@given(data=st.data())
def test_gradients_agree_with_complex_step_of_data(spec, data):
    """``evaluate``'s ``h, h~, J`` and ``dh, dh~, dJ`` equal the oracle's values and
    complex-step gradients (``(def:H:tilde:general)`` written from the data)."""
    case, z = _draw(data, spec)
    t = evaluate(case.system, z)
    h, ht, J = oracle(case, z)
    assert t.dht.shape == z.shape and t.dJ.shape == z.shape[:-1] + (case.K, z.shape[-1])
    for got, want in ((t.h, h), (t.ht, ht), (t.J, J), (case.system.extended_hamiltonian(z), ht),
                      (case.system.hamiltonian(z), h), (case.system.constraint_momenta(z), J)):
        assert rel_err(got, want, np.max(np.abs(want), initial=1.0)) < TOL
    for got, fun in ((t.dh, oracle_h(case)), (t.dht, oracle_ht(case)), (t.dJ, oracle_J(case))):
        want = cs_grad(fun, z)
        assert rel_err(got, want, np.max(np.abs(want), initial=1.0)) < TOL
    np.testing.assert_allclose(t.Cinv, np.linalg.inv(oracle_gram(case, z[..., : case.space.data_dim])), rtol=1e-10, atol=1e-12)


@settings(max_examples=6, deadline=None)
@given(data=st.data())
def test_extended_hamiltonian_gradient_by_finite_differences(spec, data):
    """``dh~`` against 4th-order central differences of the public ``system.extended_hamiltonian``
    (which casts to float, so the complex step cannot be applied to it directly)."""
    case, z = _draw(data, spec)
    want = central_grad(case.system.extended_hamiltonian, z, h=1e-3)
    got = evaluate(case.system, z).dht
    assert rel_err(got, want, np.max(np.abs(want), initial=1.0)) < 1e-7


# ------------------------------------------------------------------ (theorem:extension:nonhol)
@SYSTEM_PROPERTY
@given(data=st.data())
def test_extended_field_equals_constrained_field_on_constraint_set(spec, data):
    """``(theorem:extension:nonhol)``: at ``z`` on ``C`` (``system.project``) the extended and
    constrained fields coincide (momenta and shape, and the reconstruction velocity), and ``C``
    is invariant: ``J'(t) = dJ_i . X~ = 0`` there."""
    case, z = _draw(data, spec)
    sys_ = case.system
    zc = sys_.project(z)
    J = sys_.constraint_momenta(zc)
    assert np.max(np.abs(J), initial=0.0) < 1e-12 * max(1.0, np.max(np.abs(zc)))
    Xe, Xc = sys_.extended_vector_field(zc), sys_.constrained_vector_field(zc)
    assert Xe.shape == z.shape
    assert rel_err(Xe, Xc, np.max(np.abs(Xc), initial=1.0)) < TOL
    xi_e = group_velocity(sys_, zc, extended=True)
    xi_c = group_velocity(sys_, zc, extended=False)
    assert rel_err(xi_e, xi_c, np.max(np.abs(xi_c), initial=1.0)) < TOL
    np.testing.assert_allclose(sys_.projected_vector_field(zc), Xe, rtol=1e-12, atol=1e-12 * np.max(np.abs(Xe), initial=1.0))
    if case.K:
        dJ = cs_grad(oracle_J(case), zc)
        assert _orthogonality(dJ, _Xbroadcast(Xe, case.K), field_scale(case, zc)) < TOL


@SYSTEM_PROPERTY
@given(data=st.data())
def test_projection_is_metric_orthogonal(spec, data):
    """``project`` is the ``m``-closest point of ``C``: ``J(Pz) = 0``, ``Pz - z`` lies in
    ``span(e_i^flat)``, and projecting twice changes nothing."""
    case, z = _draw(data, spec, min_K=1)
    sys_, n = case.system, case.space.data_dim
    zc = sys_.project(z)
    np.testing.assert_array_equal(zc[..., :n], z[..., :n])
    dP = (zc - z)[..., n:]
    Eflat = np.broadcast_to(case.constraints(z[..., :n]) @ case.metric(z[..., :n]), z.shape[:-1] + (case.K, case.space.D))
    coef = np.linalg.lstsq(Eflat.reshape(-1, case.K, case.space.D)[0].T, dP.reshape(-1, case.space.D)[0], rcond=None)
    resid = dP.reshape(-1, case.space.D)[0] - Eflat.reshape(-1, case.K, case.space.D)[0].T @ coef[0]
    assert np.max(np.abs(resid)) < 1e-12 * max(1.0, np.max(np.abs(dP)))
    np.testing.assert_allclose(sys_.project(zc), zc, atol=1e-13 * max(1.0, np.max(np.abs(zc))))


# ------------------------------------------------------------------ (theorem:first:integrals)
@SYSTEM_PROPERTY
@given(data=st.data())
def test_extended_hamiltonian_and_constraint_momenta_are_first_integrals(spec, data):
    """``(theorem:first:integrals)``: ``dh~ . X~ = 0`` and ``dJ_i . X~ = 0`` for every ``i``,
    everywhere (off ``C`` too), with the gradients of both routes."""
    case, z = _draw(data, spec)
    X = case.system.extended_vector_field(z)
    sc = field_scale(case, z)
    t = evaluate(case.system, z)
    assert _orthogonality(t.dht, X, sc) < TOL
    assert _orthogonality(cs_grad(oracle_ht(case), z), X, sc) < TOL
    if case.K:
        XK = _Xbroadcast(X, case.K)
        assert _orthogonality(t.dJ, XK, sc) < TOL
        assert _orthogonality(cs_grad(oracle_J(case), z), XK, sc) < TOL


@SYSTEM_PROPERTY
@given(data=st.data())
def test_original_hamiltonian_is_first_integral(spec, data):
    """``(corollary:H:instead)``: ``dh . X~ = 0`` everywhere when the Gram matrix is constant
    (constant data, or ``x``-dependent ``e_i`` orthonormal for ``m(x)`` as in the main text)."""
    kind = spec[0]
    case, z = _draw(data, spec, orthonormal=None if kind == "lie" else True)
    assert case.constant_gram
    X = case.system.extended_vector_field(z)
    sc = field_scale(case, z)
    assert _orthogonality(evaluate(case.system, z).dh, X, sc) < TOL
    assert _orthogonality(cs_grad(oracle_h(case), z), X, sc) < TOL


@SYSTEM_PROPERTY
@given(data=st.data())
def test_original_hamiltonian_drift_with_varying_gram(spec, data):
    """General Remark with ``x``-dependent Gram matrix ``C(x)``: ``h`` is *not* a first integral
    off ``C``; exactly ``dh . X~ = -1/2 w.(dC/dx . x') w`` with ``w = C^-1 J``, zero on ``C``."""
    kind = spec[0]
    if kind == "lie":
        pytest.skip("constant data: the Gram matrix is constant")
    case, z = _draw(data, spec, min_K=1, orthonormal=False)
    sys_, n = case.system, case.space.data_dim
    X = sys_.extended_vector_field(z)
    t = evaluate(sys_, z)
    w = np.einsum("...kl,...l->...k", t.Cinv, t.J)
    # dC/dt = sum_k dC/dx_k x'_k, by complex step of the oracle's Gram matrix along x' (= X[:n])
    xdot = X[..., :n]
    dC = np.asarray(oracle_gram(case, z[..., :n] + 1e-30j * xdot)).imag / 1e-30
    drift = -0.5 * np.einsum("...k,...kl,...l->...", w, dC, w)
    got = dot(t.dh, X)
    scale = np.max(np.linalg.norm(t.dh, axis=-1) * np.linalg.norm(X, axis=-1), initial=1e-300)
    assert np.max(np.abs(got - drift), initial=0.0) < TOL * scale
    # ... and it vanishes on the constraint set
    zc = sys_.project(z)
    assert _orthogonality(evaluate(sys_, zc).dh, sys_.extended_vector_field(zc), field_scale(case, zc)) < TOL


@SYSTEM_PROPERTY
@given(data=st.data())
def test_extended_quantities_equal_originals_on_constraint_set(spec, data):
    """``(theorem:first:integrals)``: ``h~ = h`` and ``lambda~ = lambda`` on ``C``; and
    ``h - h~ = 1/2 J.C^-1 J >= 0`` everywhere (``(def:H:tilde:general)``)."""
    case, z = _draw(data, spec)
    sys_ = case.system
    zc = sys_.project(z)
    h, ht = sys_.hamiltonian(zc), sys_.extended_hamiltonian(zc)
    assert rel_err(ht, h, np.max(np.abs(h), initial=1.0)) < 1e-12
    t = evaluate(sys_, z)
    gap = 0.5 * np.einsum("...k,...kl,...l->...", t.J, t.Cinv, t.J)
    np.testing.assert_allclose(t.h - t.ht, gap, rtol=1e-10, atol=1e-12 * np.max(np.abs(t.h), initial=1.0))
    assert np.all(gap >= -1e-14)
    if case.K:
        lam, lamt = sys_.multipliers(zc), sys_.extended_multipliers(zc)
        assert lam.shape == z.shape[:-1] + (case.K,)
        assert rel_err(lamt, lam, np.max(np.abs(lam), initial=1.0)) < TOL


@SYSTEM_PROPERTY
@given(data=st.data())
def test_extended_multipliers_differ_off_constraint_set(spec, data):
    """``lambda~ - lambda = -C^-1 {1/2 J.C^-1 J, J}`` everywhere (from ``h - h~``), which is
    nonzero off ``C`` for ``x``-dependent non-orthonormal constraints (sanity: the extension
    really changes the force off ``C``)."""
    case, z = _draw(data, spec, min_K=1)
    sys_ = case.system
    diff = sys_.extended_multipliers(z) - sys_.multipliers(z)
    t = evaluate(sys_, z)
    dgap = cs_grad(lambda y: oracle(case, y)[0] - oracle(case, y)[1], z)  # d(h - h~)
    br = sys_.space.bracket(z[..., None, :], dgap[..., None, :], t.dJ)  # {h - h~, J_l}
    want = -np.einsum("...lk,...l->...k", t.Cinv, br)
    scale = np.max(np.abs(sys_.multipliers(z)), initial=1.0)
    assert np.max(np.abs(diff - want), initial=0.0) < TOL * scale
    if spec[0] != "lie" and not case.orthonormal:
        assert np.max(np.abs(diff)) > 1e-8 * scale


@SYSTEM_PROPERTY
@given(data=st.data())
def test_constrained_field_keeps_constraint_momenta(spec, data):
    """``(def:lambda)`` / ``(lambda:general)``: ``dJ_i . X_constrained = 0`` everywhere
    (this is how ``lambda`` is defined), while ``h`` is conserved by it only on ``C``."""
    case, z = _draw(data, spec, min_K=1)
    X = case.system.constrained_vector_field(z)
    assert _orthogonality(evaluate(case.system, z).dJ, _Xbroadcast(X, case.K), field_scale(case, z)) < TOL
    zc = case.system.project(z)
    Xc = case.system.constrained_vector_field(zc)
    assert _orthogonality(evaluate(case.system, zc).dh, Xc, field_scale(case, zc)) < TOL


# ------------------------------------------------------------------ a short integration
@settings(max_examples=3, deadline=None)
@given(data=st.data())
def test_rk4_extended_field_conserves_first_integrals(spec, data):
    """RK4 on the extended field (no feedback) from an arbitrary state keeps ``h~`` and
    ``J`` (and ``h`` when the Gram matrix is constant) to ~1e-8 over a short horizon."""
    case = data.draw(cases(spec))
    z0 = case.random_state((2,), scale=0.5)
    sol = integrate(case.system.extended_vector_field, z0, 4e-3, 25, "rk4")
    zs = np.moveaxis(sol.y, -1, 0)  # (n_t, 2, nz)
    h, ht, J = oracle(case, zs)
    tol = 1e-8
    assert np.max(np.abs(ht - ht[0])) < tol * max(1.0, np.abs(ht[0]).max())
    if case.K:
        assert np.max(np.abs(J - J[0])) < tol * max(1.0, np.abs(J[0]).max())
    if case.constant_gram:
        assert np.max(np.abs(h - h[0])) < tol * max(1.0, np.abs(h[0]).max())
