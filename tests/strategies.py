"""Shared hypothesis strategies, random systems and independent oracles for the property tests.

Every property test that is about "any group" is parametrized over :data:`GROUPS`
(and every test about "any system" over :data:`SPACES`, which is derived from
``GROUPS``): a new group gets the whole suite by being added to ``GROUPS``.

Random data are drawn from a ``numpy`` generator seeded by hypothesis, so a
failing example is reproducible from the seed hypothesis prints.  The
*structure* (number of constraints ``K``, shape dimension ``n``, batch shape,
orthonormal or general constraints) is drawn by hypothesis directly.

The systems are the paper's three kinds (Section 2):

* ``lie``: ``LieGroupPhaseSpace(G)`` with a constant locked inertia and constant
  constraint vectors (``(sys:LiePoisson)``);
* ``cotangent``: ``CotangentBundle(n)`` with ``x``-dependent metric, constraints
  and potential (``(original:nonholo)``);
* ``bundle``: ``TrivialPrincipalBundle(G, n)`` with ``x``-dependent data
  (``(sys:QG:trivial)``);
* ``semidirect`` / ``semidirect-bundle``: the same two with an advected vector
  ``Gamma = g^{-1} . a_0`` in a representation of ``G`` (:data:`REPRESENTATIONS`:
  ``SO(3)`` on ``R^3``, ``SE(2)`` on ``R^3``, three copies of ``R^3`` under the
  rotation block of ``SO(3) x R^2``), reduced to ``(g x| V)*`` (``x T*X``); the
  data depend on ``(x, Gamma)``, drawn as the ``x``-dependent data below with
  ``x`` replaced by the data point ``y = (x, Gamma)``.

The ``x``-dependent data are batch-first and complex-step safe:
``m(x) = M0 + sin(x.c1) S1 + cos(x.c2) S2`` (SPD by construction), rows of
``E(x) = E0 + sin(x.d) E1`` (independent by construction, *not* orthonormal
for ``m``), ``U(x) = 1/2 x.Q x + a sin(x.b)``; with ``vector_potential`` a
momentum shift ``A(x) = A0 + sin(x.f) A1 + G x`` (entries of size ~0.3-0.5) (constant ``A0`` on a Lie
group), so that ``h = 1/2 (P - A).m^{-1}(P - A) + U`` and ``J = E (P - A)``.  With ``orthonormal=True`` the
rows are Gram--Schmidt orthonormalized in ``m(x)`` by analytic operations
(no conjugation), so the Gram matrix is the identity for every ``x``.

The oracles at the bottom compute ``h``, ``h~`` and ``J`` straight from the
data by the general formulas of Remark ``(remark:nonhol:general)``, with complex
arithmetic allowed, so their gradients can be taken by complex step
independently of :mod:`liefi.reduction`.
"""

from __future__ import annotations

import os
import sys
from dataclasses import dataclass, field

import numpy as np
import pytest
from hypothesis import HealthCheck, settings
from hypothesis import strategies as st

sys.path.insert(0, os.path.dirname(os.path.dirname(os.path.abspath(__file__))))

from liefi import CotangentBundle, LieGroupPhaseSpace, NonholonomicSystem, TrivialPrincipalBundle  # noqa: E402
from liefi.groups import S1, SE2, SE3, SO2, SO3, Representation, Rn  # noqa: E402
from liefi.reduction import evaluate as _evaluate  # noqa: E402

# ---------------------------------------------------------------------------
# the one list of groups
# ---------------------------------------------------------------------------

#: Every group liefi ships, in the embeddings the paper uses.  Add a group here
#: and every group, bracket, extension and Lyapunov test runs on it.
GROUPS = [
    pytest.param(SO3(), id="SO3"),
    pytest.param(SE2(), id="SE2"),
    pytest.param(SE2(S1()), id="SE2(S1)"),
    pytest.param(SO2(), id="SO2"),
    pytest.param(S1(), id="S1"),
    pytest.param(Rn(2), id="R2"),
    pytest.param(SE2() * S1(), id="SE2xS1"),
    pytest.param(SO3() * Rn(1), id="SO3xR1"),
    pytest.param(SE3(), id="SE3"),
    # the rotation block not first: a product must offset every factor's blocks
    pytest.param(S1() * SO3(), id="S1xSO3"),
    pytest.param(Rn(1) * SO2() * SE3(), id="R1xSO2xSE3"),
]


#: Representations with an advected vector ``(rep, a0)``: the heavy top's and the
#: rolling bodies' ``SO(3)`` on ``R^3``, ``SE(2)`` on homogeneous ``R^3`` (a non-orthogonal
#: action: no Casimir ``|Gamma|^2``), and the whole attitude of a body on a plane.
REPRESENTATIONS = [
    pytest.param((Representation(SO3()), np.array([0.0, 0.0, 1.0])), id="SO3xR3"),
    pytest.param((Representation(SE2()), np.array([0.3, -0.2, 1.0])), id="SE2xR3"),
    pytest.param((Representation(SO3() * Rn(2), block=(0, 3), copies=3), np.eye(3).ravel()),
                 id="SO3R2x(R3)^3"),
]


def _spaces():
    out = []
    for p in GROUPS:
        (G,) = p.values
        out.append(pytest.param(("lie", G), id=f"lie-{p.id}"))
    for p in GROUPS:
        (G,) = p.values
        out.append(pytest.param(("bundle", G), id=f"bundle-{p.id}"))
    out.append(pytest.param(("cotangent", None), id="cotangent"))
    for p in REPRESENTATIONS:
        (rep,) = p.values
        out.append(pytest.param(("semidirect", rep), id=f"semidirect-{p.id}"))
    out.append(pytest.param(("semidirect-bundle", REPRESENTATIONS[0].values[0]), id="semidirect-bundle-SO3xR3"))
    return out


def advected_space(kind, spec_group, n=0):
    """The phase space of a ``semidirect`` / ``semidirect-bundle`` spec (``spec_group = (rep, a0)``)."""
    rep, a0 = spec_group
    if kind == "semidirect":
        return LieGroupPhaseSpace(rep.group, advected=rep, a0=a0)
    return TrivialPrincipalBundle(rep.group, n, advected=rep, a0=a0)


#: ``(kind, group)`` for every system kind over every group (one cotangent entry).
SPACES = _spaces()

#: Batch shapes every batch-first function is checked on.
BATCH_SHAPES = st.sampled_from([(), (3,), (2, 2)])

#: Seeds for the numpy generator.
SEEDS = st.integers(0, 2**32 - 1)

#: Examples per property test; ``LIEFI_MAX_EXAMPLES=250 pytest tests`` for a thorough run.
MAX_EXAMPLES = int(os.environ.get("LIEFI_MAX_EXAMPLES", "25"))

#: Settings of the cheap property tests (algebra, brackets): ~25 examples, no deadline.
PROPERTY = settings(max_examples=MAX_EXAMPLES, deadline=None, suppress_health_check=[HealthCheck.too_slow])

#: Settings of the tests that build a random system per example (~10-20 ms each,
#: a third of it hypothesis' own bookkeeping): half as many examples per
#: parametrization.  Each such test runs over the 23 entries of ``SPACES``, so a
#: property is still checked on ~200 random systems per run, within the suite's
#: one-minute budget.
SYSTEM_PROPERTY = settings(
    max_examples=max(1, MAX_EXAMPLES // 2), deadline=None, suppress_health_check=[HealthCheck.too_slow]
)


# ---------------------------------------------------------------------------
# numeric helpers
# ---------------------------------------------------------------------------

STEP = 1e-30


def cs_grad(fun, z):
    """Gradient of a batch-first scalar (or ``(..., K)``) function by complex step.

    Returns shape ``(..., nz)`` for a scalar function and ``(..., K, nz)`` for a
    vector one.  Exact to rounding for analytic ``fun``.
    """
    z = np.asarray(z, dtype=float)
    nz = z.shape[-1]
    zc = z[..., None, :] + (1j * STEP) * np.eye(nz)  # (..., nz, nz): one probe per row
    f = np.asarray(fun(zc)).imag / STEP  # (..., nz) or (..., nz, K)
    if f.ndim == z.ndim:  # scalar function
        return f
    return np.swapaxes(f, -1, -2)


def central_grad(fun, z, h=1e-4):
    """Fourth-order central-difference gradient of a real batch-first scalar function."""
    z = np.asarray(z, dtype=float)
    nz = z.shape[-1]
    out = np.empty(z.shape)
    scale = np.maximum(1.0, np.abs(z))
    for k in range(nz):
        dz = np.zeros(z.shape)
        dz[..., k] = h * scale[..., k]
        f = lambda s: np.asarray(fun(z + s * dz))  # noqa: E731
        out[..., k] = (8 * (f(1) - f(-1)) - (f(2) - f(-2))) / (12 * h * scale[..., k])
    return out


def rel_err(a, b, scale=None):
    """``max |a - b| / scale`` with ``scale = max(1e-300, max|b|)`` by default."""
    a, b = np.asarray(a), np.asarray(b)
    if scale is None:
        scale = np.max(np.abs(b), initial=0.0)
    return float(np.max(np.abs(a - b), initial=0.0) / max(float(scale), 1e-300))


def dot(a, b):
    return np.einsum("...i,...i->...", a, b)


def field_scale(case, z):
    """Size of the terms that cancel in ``X~``: ``|B dh~| + |lambda~| |e^flat|`` (``X~`` itself may
    vanish identically, e.g. for ``K = D - 1`` on a Lie group)."""
    t = _evaluate(case.system, z)
    s = np.linalg.norm(case.space.hamiltonian_vector_field(z, t.dht), axis=-1)
    s = s + np.linalg.norm(case.space.hamiltonian_vector_field(z, t.dh), axis=-1)
    if case.K:
        lam = np.abs(case.system.extended_multipliers(z))
        s = s + np.einsum("...k,...k->...", lam, np.linalg.norm(t.Eflat, axis=-1))
    return s


# ---------------------------------------------------------------------------
# random data
# ---------------------------------------------------------------------------


def random_spd(rng, D, spread=1.0):
    """A symmetric positive definite ``D x D`` matrix with eigenvalues in ``[0.5, 0.5 + 2 spread]``-ish."""
    Q, _ = np.linalg.qr(rng.normal(size=(D, D)))
    lam = 0.5 + spread * rng.uniform(0.0, 2.0, size=D)
    return (Q * lam) @ Q.T


def random_constraints(rng, K, D):
    """``K`` independent, non-orthonormal rows: ``T Q[:K]`` with ``T`` unit lower triangular plus noise.

    Their singular values lie in ``[~0.4, ~2.5]``, so every Gram matrix with a
    well-conditioned metric is well conditioned.
    """
    if K == 0:
        return np.zeros((0, D))
    Q, _ = np.linalg.qr(rng.normal(size=(D, D)))
    T = np.diag(rng.uniform(0.6, 1.6, size=K)) + 0.4 * np.tril(rng.uniform(-1, 1, size=(K, K)), -1)
    return T @ Q[:K]


def _smin(A):
    return np.linalg.svd(A, compute_uv=False).min() if A.size else 1.0


def gram_schmidt(E, m):
    """Orthonormalize the rows of ``E`` (``(..., K, D)``) in the metric ``m`` (``(..., D, D)``).

    Analytic in ``E`` and ``m`` (no conjugation, no ``abs``): complex-step safe.
    """
    K = E.shape[-2]
    rows = []
    for i in range(K):
        r = E[..., i, :]
        for q in rows:
            r = r - np.einsum("...i,...ij,...j->...", r, m, q)[..., None] * q
        nrm = np.sqrt(np.einsum("...i,...ij,...j->...", r, m, r))
        rows.append(r / nrm[..., None])
    if not rows:
        return E
    return np.stack(rows, -2)


@dataclass
class Case:
    """A random system with the raw (complex-safe) data it was built from."""

    kind: str
    system: NonholonomicSystem
    metric: object  #: batch-first m(x), complex safe (constant: returns the array)
    constraints: object  #: batch-first E(x), rows e_i
    potential: object  #: batch-first U(x)
    orthonormal: bool
    constant_gram: bool  #: Gram matrix C = E m E^T independent of x
    rng: np.random.Generator = field(repr=False)
    vector_potential: object = None  #: batch-first A(x), or None

    def shift(self, x):
        """``A(x)`` (0 without a vector potential)."""
        return 0.0 if self.vector_potential is None else self.vector_potential(x)

    @property
    def space(self):
        return self.system.space

    @property
    def K(self):
        return self.system.K

    def random_state(self, shape=(), scale=1.0):
        """Random reduced states ``z = (x, mu, p_x)`` (``(x, Gamma, mu, p_x)``) of shape ``shape + (nz,)``."""
        return scale * self.rng.normal(size=tuple(shape) + (self.space.nz,))

    def constrained_state(self, shape=(), scale=1.0):
        """Random states on the constraint set ``J = 0`` (projected along ``m``)."""
        return self.system.project(self.random_state(shape, scale))


def build_case(kind, group, rng, K, n, orthonormal=False, vector_potential=False):
    """Build a random :class:`Case` of the given kind (see module docstring)."""
    if kind == "lie":
        space = LieGroupPhaseSpace(group)
        n = 0
    elif kind == "cotangent":
        space = CotangentBundle(n)
    elif kind == "bundle":
        space = TrivialPrincipalBundle(group, n)
    elif kind in ("semidirect", "semidirect-bundle"):
        space = advected_space(kind, group, n)
    else:  # pragma: no cover
        raise ValueError(kind)
    D = space.D
    n_shape, n = space.n, space.data_dim  # the data are drawn as functions of y = (x, Gamma)
    M0 = random_spd(rng, D)
    E0 = random_constraints(rng, K, D)

    if n == 0:
        m_const = M0
        E_const = gram_schmidt(E0, M0) if orthonormal else E0
        A_const = 0.5 * rng.normal(size=D) if vector_potential else None
        system = NonholonomicSystem(space, m_const, E_const if K else None, vector_potential=A_const)
        return Case(
            kind, system, lambda x: m_const, lambda x: E_const, lambda x: 0.0 * np.sum(x, -1),
            orthonormal, True, rng, None if A_const is None else (lambda x: A_const),
        )

    lmin = np.linalg.eigvalsh(M0).min()
    S1_ = rng.normal(size=(D, D))
    S1_ = S1_ + S1_.T
    S2_ = rng.normal(size=(D, D))
    S2_ = S2_ + S2_.T
    S1_ *= 0.2 * lmin / np.linalg.norm(S1_, 2)
    S2_ *= 0.2 * lmin / np.linalg.norm(S2_, 2)
    c1, c2, d = rng.normal(size=(3, n))
    E1 = rng.normal(size=(K, D))
    if K:
        E1 *= 0.3 * _smin(E0) / np.linalg.norm(E1, 2)
    Qp = random_spd(rng, n, 0.5)
    a, b = rng.normal(), rng.normal(size=n)

    def metric(x):
        s = np.sin(x @ c1)[..., None, None]
        c = np.cos(x @ c2)[..., None, None]
        return M0 + s * S1_ + c * S2_

    def raw_constraints(x):
        return E0 + np.sin(x @ d)[..., None, None] * E1

    if orthonormal:

        def constraints(x):
            return gram_schmidt(raw_constraints(x), metric(x))

    else:
        constraints = raw_constraints

    def potential(x):
        return 0.5 * np.einsum("...i,ij,...j->...", x, Qp, x) + a * np.sin(x @ b)

    shift = None
    if vector_potential:
        A0, A1, f = 0.5 * rng.normal(size=D), 0.3 * rng.normal(size=D), rng.normal(size=n)
        G = 0.3 * rng.normal(size=(D, n))

        def shift(x):
            return A0 + np.sin(x @ f)[..., None] * A1 + np.einsum("ij,...j->...i", G, x)

    def user(f):
        """The datum as the user writes it: ``f(x)``, or ``f(x, Gamma)`` with an advected vector."""
        if f is None or not space.k:
            return f
        return lambda x, G: f(np.concatenate([np.broadcast_to(x, G.shape[:-1] + (n_shape,)), G], -1))

    system = NonholonomicSystem(space, user(metric), user(constraints) if K else None, user(potential),
                                vector_potential=user(shift))
    return Case(kind, system, metric, constraints, potential, orthonormal, orthonormal or K == 0, rng, shift)


@st.composite
def cases(draw, spec, *, min_K=0, orthonormal=None, max_n=2, vector_potential=None):
    """A random :class:`Case` for ``spec = (kind, group)`` (an entry of :data:`SPACES`).

    ``K`` runs from ``min_K`` to ``D - 1``; ``orthonormal`` and ``vector_potential``
    None draw them.
    """
    kind, group = spec
    if kind == "lie":
        n = 0
        D = group.dim
    elif kind == "semidirect":
        n = 0
        D = group[0].group.dim
    elif kind == "semidirect-bundle":
        n = draw(st.integers(1, max_n))
        D = group[0].group.dim + n
    elif kind == "cotangent":
        n = draw(st.integers(max(1, min_K + 1), 3))
        D = n
    else:
        n = draw(st.integers(1, max_n))
        D = group.dim + n
    if min_K > D - 1:
        pytest.skip(f"D = {D}: no room for {min_K} constraint(s) (K <= D - 1)")
    K = draw(st.integers(min_K, D - 1))
    orth = draw(st.booleans()) if orthonormal is None else orthonormal
    vp = draw(st.booleans()) if vector_potential is None else vector_potential
    seed = draw(SEEDS)
    return build_case(kind, group, np.random.default_rng(seed), K, n, orth, vp)


# ---------------------------------------------------------------------------
# independent oracles (Remark remark:nonhol:general), complex-step safe
# ---------------------------------------------------------------------------


def _solve(A, b):
    return np.linalg.solve(A, b[..., None])[..., 0]


def oracle(case, z):
    """``(h, h~, J)`` at ``z`` from the raw data: ``h = 1/2 P.m^-1 P + U``,
    ``J = E P``, ``C = E m E^T``, ``h~ = h - 1/2 J.C^-1 J`` (``(def:H:tilde:general)``),
    with ``P`` replaced by the kinetic momentum ``P - A(x)`` when there is a vector potential."""
    n = case.space.data_dim
    x, P = z[..., :n], z[..., n:]
    P = P - case.shift(x)
    m = np.broadcast_to(case.metric(x), P.shape[:-1] + P.shape[-1:] * 2)
    U = case.potential(x)
    h = 0.5 * dot(P, _solve(m, P)) + U
    K = case.K
    if K == 0:
        return h, h, np.zeros(P.shape[:-1] + (0,), dtype=P.dtype)
    E = np.broadcast_to(case.constraints(x), P.shape[:-1] + (K, P.shape[-1]))
    J = np.einsum("...kj,...j->...k", E, P)
    C = E @ m @ np.swapaxes(E, -1, -2)
    ht = h - 0.5 * dot(J, _solve(C, J))
    return h, ht, J


def oracle_h(case):
    return lambda z: oracle(case, z)[0]


def oracle_ht(case):
    return lambda z: oracle(case, z)[1]


def oracle_J(case):
    return lambda z: oracle(case, z)[2]


def oracle_gram(case, x):
    E, m = case.constraints(x), case.metric(x)
    return E @ m @ np.swapaxes(E, -1, -2)
