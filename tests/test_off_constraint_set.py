"""The theory off the constraint set ``J != 0``, where ``h`` and ``h~`` (and ``dh``, ``dh~``) differ.

On ``C = {J = 0}`` ``h~ = h`` and the extended and constrained fields coincide
(``(theorem:first:integrals)``, ``(theorem:extension:nonhol)``), so a test that
only starts on ``C`` cannot tell them apart.  Here every quantity is checked at
random states off ``C`` against its definition, written from the raw data by
the oracles of ``strategies`` (complex-step gradients, the Gram matrix
``C = E m E^T``):

* the constrained field ``z' = B dh + sum_i lambda_i e_i^flat`` with
  ``lambda = C^-1 {h, J}`` (``(original:nonholo)``, ``(lambda:general)``), and
  the extended field with ``h~`` and ``lambda~ = C^-1 {h~, J}``
  (``(bam:qp)``, ``(lambda:tilde:general)``), on every kind of phase space;
* the feedback integrator's targets, ``invariant_values`` and
  ``V = 1/2 sum_i k_i J_i^2 + 1/2 k_E (E - E_0)^2 + k_0 P(g)`` with its gradient,
  from a start ``y0`` off ``C`` (so ``E_0 = h~(z0) != h(z0)``).
"""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import assume, given
from hypothesis import strategies as st

from liefi import FeedbackIntegrator
from liefi.reduction import full_vector_field
from strategies import (
    BATCH_SHAPES,
    SPACES,
    SYSTEM_PROPERTY,
    cases,
    cs_grad,
    oracle,
    oracle_gram,
    oracle_h,
    oracle_ht,
    oracle_J,
    rel_err,
)

pytestmark = pytest.mark.parametrize("spec", SPACES)

TOL = 1e-10


def _field_from_definition(case, z, H):
    """``B dH + sum_i lambda_i e_i^flat``, ``lambda = C^-1 {H, J}``, all from the data (``H`` an oracle)."""
    sp = case.space
    n = sp.data_dim  # the data are read at (x, Gamma); the momenta follow
    dH = cs_grad(H, z)  # (..., nz)
    dJ = cs_grad(oracle_J(case), z)  # (..., K, nz)
    B = sp.poisson_tensor(z)  # (..., nz, nz), {f, g} = df . B . dg
    X = np.einsum("...ij,...j->...i", B, dH)
    b = np.einsum("...i,...ij,...kj->...k", dH, B, dJ)  # {H, J_k}
    x = z[..., :n]
    C = np.broadcast_to(oracle_gram(case, x), z.shape[:-1] + (case.K, case.K))
    lam = np.linalg.solve(C, b[..., None])[..., 0]
    m = case.metric(x)
    E = case.constraints(x)
    Eflat = np.broadcast_to(E @ m, z.shape[:-1] + (case.K, sp.D))
    X[..., n:] += np.einsum("...k,...kj->...j", lam, Eflat)
    return X


@SYSTEM_PROPERTY
@given(data=st.data())
def test_constrained_and_extended_fields_off_constraint_set_match_definitions(spec, data):
    """Off ``J = 0`` the constrained field uses ``dh`` and ``lambda = C^-1 {h, J}``, the extended
    one ``dh~`` and ``lambda~``; each equals its definition from the data."""
    case = data.draw(cases(spec, min_K=1))
    z = case.random_state(data.draw(BATCH_SHAPES))
    sys_ = case.system
    J = sys_.constraint_momenta(z)
    assert np.max(np.abs(J)) > 1e-6  # really off the constraint set
    G, n, d = case.space.group, case.space.data_dim, case.space.d
    g = G.random_config(np.random.default_rng(0), z.shape[:-1])
    for kind, H, field in (("constrained", oracle_h(case), sys_.constrained_vector_field),
                           ("extended", oracle_ht(case), sys_.extended_vector_field)):
        want = _field_from_definition(case, z, H)
        # the group velocity is dH/dmu, so the reconstruction g' = g . dH/dmu (full_vector_field)
        xi = cs_grad(H, z)[..., n : n + d]
        want_full = np.concatenate([G.config_rate(g, xi).reshape(z.shape[:-1] + (-1,)), want], -1)
        for got in (field(z), full_vector_field(sys_, np.concatenate([g, z], -1), kind=kind)):
            assert rel_err(got, want_full if got.shape != z.shape else want, np.max(np.abs(want), initial=1.0)) < TOL, kind


def _start(case, rng, configuration):
    """``y0 = (g0, z0)`` off the group (when embedded) and off ``J = 0``."""
    G = case.space.group
    z0 = case.random_state()
    if not configuration or G.config_dim == 0:
        return z0, 0
    g0 = G.random_config(rng) + 0.05 * rng.normal(size=G.config_dim)
    return np.concatenate([g0, z0]), G.config_dim


@SYSTEM_PROPERTY
@given(data=st.data(), configuration=st.booleans())
def test_lyapunov_targets_and_invariant_values_from_a_start_off_constraint_set(spec, data, configuration):
    """From ``y0`` with ``J(z0) != 0``: the energy target is ``h~(z0)`` (``h(z0)`` for
    ``energy="original"``), the ``J`` targets are 0, ``invariant_values`` are the data's
    ``J, h, h~`` (``energy`` = the penalized one), and ``V``, ``grad V`` are the definition's."""
    kind = spec[0]
    original = data.draw(st.booleans())
    # energy="original" needs a constant Gram matrix (assumption A1): orthonormal x-dependent rows
    case = data.draw(cases(spec, min_K=1, orthonormal=True if original and kind != "lie" else None))
    rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
    y0, nc = _start(case, rng, configuration)
    energy = oracle_h(case) if original else oracle_ht(case)
    z0 = y0[nc:]
    assert np.max(np.abs(oracle_J(case)(z0))) > 1e-6
    G = case.space.group
    names = (["penalty"] if nc and G.penalty_hessian_bound() > 0 else []) + [f"J_{i + 1}" for i in range(case.K)] + ["energy"]
    gains = {k: float(rng.uniform(0.5, 2.0)) for k in names}
    fi = FeedbackIntegrator(case.system, y0, gains=gains, energy="original" if original else "extended",
                            configuration=configuration)
    assert fi.invariant_names == tuple(names)
    E0 = float(energy(z0))
    assert abs(fi.targets["energy"] - E0) < 1e-12 * max(1.0, abs(E0))
    # h - h~ = J^T C^-1 J / 2 can be tiny for a small drawn J: only a start where the two differ
    # tells the energy target h~ from h, so the draw is discarded otherwise
    assume(abs(float(oracle_h(case)(z0)) - float(oracle_ht(case)(z0))) > 1e-9)
    assert all(fi.targets[f"J_{i + 1}"] == 0.0 for i in range(case.K))

    y = np.concatenate([y0[:nc] + 0.05 * rng.normal(size=(3, nc)), case.random_state((3,))], -1) if nc else case.random_state((3,))
    vals = fi.invariant_values(y)
    h, ht, J = oracle(case, y[..., nc:])
    for key, want in (("h", h), ("h~", ht), ("energy", h if original else ht)):
        assert rel_err(vals[key], want, np.max(np.abs(want), initial=1.0)) < TOL, key
    for i in range(case.K):
        assert rel_err(vals[f"J_{i + 1}"], J[..., i], np.max(np.abs(J), initial=1.0)) < TOL

    def V(yy):
        g, z = yy[..., :nc], yy[..., nc:]
        hh, hht, JJ = oracle(case, z)
        E = hh if original else hht
        out = 0.5 * gains["energy"] * (E - E0) ** 2
        for i in range(case.K):
            out = out + 0.5 * gains[f"J_{i + 1}"] * JJ[..., i] ** 2
        if "penalty" in gains:
            out = out + gains["penalty"] * G.penalty(g)
        return out

    want = V(y)
    assert rel_err(fi.lyapunov(y), want, np.max(np.abs(want), initial=1.0)) < TOL
    dV = cs_grad(V, y)
    assert rel_err(fi.grad_lyapunov(y), dV, np.max(np.abs(dV), initial=1.0)) < TOL
    # V(y0) keeps only the constraint and embedding parts: the energy term vanishes at its target
    v0 = V(y0)
    assert rel_err(fi.lyapunov(y0), v0, max(abs(float(v0)), 1.0)) < TOL
