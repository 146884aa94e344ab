"""The paper's closed forms (Section 3) as oracles for what liefi derives from data alone.

Each system is built from its data only (metric, constraint vectors, potential);
the closed forms are transcribed *here* from the paper and compared at random
states (off the constraint set) and random parameter values, to 1e-12 relative.
Where the printed formula is wrong (docs/paper_notes.md) the test asserts liefi matches the
correct derivative *and* that the printed one differs where it should.
"""

from __future__ import annotations

import numpy as np
from hypothesis import example, given
from hypothesis import strategies as st

from liefi import CotangentBundle, FeedbackIntegrator, Invariant, LieGroupPhaseSpace, NonholonomicSystem
from liefi.groups import S1, SE2, SO3
from liefi.reduction import evaluate
from strategies import PROPERTY, SEEDS, cs_grad, random_spd, rel_err

TOL = 1e-12
pos = st.floats(0.2, 5.0)


def _close(got, want, scale=None, tol=TOL):
    err = rel_err(got, want, np.max(np.abs(want), initial=1e-300) if scale is None else scale)
    assert err < tol, err


def hat3(w):
    z = np.zeros_like(w[..., 0])
    return np.stack([np.stack([z, -w[..., 2], w[..., 1]], -1), np.stack([w[..., 2], z, -w[..., 0]], -1),
                     np.stack([-w[..., 1], w[..., 0], z], -1)], -2)


# ============================================================================ Suslov
def suslov(II, e):
    return NonholonomicSystem(LieGroupPhaseSpace(SO3()), II, e)


@PROPERTY
@given(seed=SEEDS, paper=st.booleans())
@example(seed=0, paper=True)
def test_suslov_closed_forms(seed, paper):
    """``(def:htilde:Suslov)``, ``(lambda:tilde:Suslov)``, ``(Suslov:extended)`` and
    ``(grad:tildeV:Suslov)`` at random ``(R, Pi)``, ``R`` off SO(3)."""
    rng = np.random.default_rng(seed)
    if paper:
        II = np.array([[1.0, 0, 0], [0, 1, 1], [0, 1, 2]])
        a = np.array([0.0, 0, 1])
    else:
        II, a = random_spd(rng, 3), rng.normal(size=3)
    Iinv = np.linalg.inv(II)
    e = Iinv @ a / np.sqrt(a @ Iinv @ a)  # e . II e = 1  (e:unit:Suslov)
    sys_ = suslov(II, e)
    Pi = rng.normal(size=(5, 3))
    R = SO3().random_config(rng, (5,)).reshape(5, 3, 3) + 0.1 * rng.normal(size=(5, 3, 3))

    J = Pi @ e
    Om = Pi @ Iinv
    ht = 0.5 * np.einsum("...i,...i->...", Pi, Om) - 0.5 * J**2  # (def:htilde:Suslov)
    lamt = -np.cross(Pi, Om) @ e  # (lambda:tilde:Suslov)
    xi = Om - J[:, None] * e
    Rdot = R @ hat3(xi)  # (Suslov:extended)
    Pidot = np.cross(Pi, xi) + lamt[:, None] * (II @ e)

    _close(sys_.extended_hamiltonian(Pi), ht)
    _close(sys_.extended_multipliers(Pi)[:, 0], lamt)
    _close(sys_.extended_vector_field(Pi), Pidot)
    _close(sys_.reconstruction(R.reshape(5, 9), Pi), Rdot.reshape(5, 9))
    # lambda = -e.(Pi x II^-1 Pi) too (orthonormal e, K = 1: {J, J} = 0)
    _close(sys_.multipliers(Pi)[:, 0], lamt)

    # (grad:tildeV:Suslov) and its Remark (h instead of h~)
    y0 = np.concatenate([np.eye(3).ravel(), sys_.project(rng.normal(size=3))])
    k0, k1, k2 = rng.uniform(0.5, 3, size=3)
    y = np.concatenate([R.reshape(5, 9), Pi], -1)
    for energy in ("extended", "original"):
        fi = FeedbackIntegrator(sys_, y0, gains={"penalty": k0, "J_1": k1, "energy": k2}, energy=energy)
        gV = fi.grad_lyapunov(y)
        E0 = fi.targets["energy"]
        S = np.swapaxes(R, -1, -2) @ R - np.eye(3)
        gR = k0 * R @ S
        if energy == "extended":
            gPi = k1 * J[:, None] * e + k2 * (ht - E0)[:, None] * xi
        else:
            h = 0.5 * np.einsum("...i,...i->...", Pi, Om)
            gPi = k1 * J[:, None] * e + k2 * (h - E0)[:, None] * Om
        _close(gV, np.concatenate([gR.reshape(5, 9), gPi], -1))
        _close(fi.unforced_vector_field(y), np.concatenate([Rdot.reshape(5, 9), Pidot], -1))


# ============================================================================ Chaplygin
def chaplygin(m, I, a, rotation=None):
    II = np.array([[I + m * a**2, 0, m * a], [0, m, 0], [m * a, 0, m]])
    s = np.sqrt(m * I * (I + m * a**2))
    e = np.array([m * a, 0, -(I + m * a**2)]) / s
    return NonholonomicSystem(LieGroupPhaseSpace(SE2(rotation)), II, e), II, e, s


@PROPERTY
@given(m=pos, I=pos, a=st.floats(-2.0, 2.0), seed=SEEDS)
@example(m=1.0, I=1.0, a=1.0, seed=0)
def test_chaplygin_data_are_consistent(m, I, a, seed):
    """The printed locked inertia reproduces the printed ``h``; ``e . II e = 1``; the constraint
    ``<Pi, e> = 0`` is ``v_y = 0`` (``e`` is parallel to ``II^-1 (0, 0, 1)``); ``(e:flat:Chap)``."""
    sys_, II, e, s = chaplygin(m, I, a)
    rng = np.random.default_rng(seed)
    Pi = rng.normal(size=(6, 3))
    th, x, y = Pi.T
    h_printed = (th - a * y) ** 2 / (2 * I) + (x**2 + y**2) / (2 * m)
    _close(sys_.hamiltonian(Pi), h_printed)
    assert abs(e @ II @ e - 1) < 1e-13
    v = np.linalg.solve(II, [0.0, 0, 1])
    assert np.linalg.norm(np.cross(v, e)) < 1e-13 * np.linalg.norm(v) * np.linalg.norm(e)
    eflat = evaluate(sys_, Pi).Eflat[0, 0]
    _close(eflat, -m * I / s * np.array([0.0, 0, 1]), scale=np.abs(eflat).max())


@PROPERTY
@given(m=pos, I=pos, a=st.floats(-2.0, 2.0), seed=SEEDS)
@example(m=1.0, I=1.0, a=1.0, seed=0)
def test_chaplygin_closed_forms(m, I, a, seed):
    """``(h:tilde:Chap)``, ``(lambda:Chap)`` and ``(extended:system:Chap)`` in both embeddings
    (angle: ``(extended:system:q:Chap)``; SO(2): ``(extended:SE2:SO2)``), and
    ``(nabla:Pi:V:Chap)``."""
    rng = np.random.default_rng(seed)
    Pi = rng.normal(size=(6, 3))
    th, px, py = Pi.T
    Ia = I + m * a**2
    ht = th**2 / (2 * Ia) + px**2 / (2 * m)  # (h:tilde:Chap)
    s = np.sqrt(m * I * Ia)
    lamt = -(th - a * py) * px / s  # (lambda:Chap)
    Pidot = np.stack([-px * py / m, th * py / Ia, -a * px * py / Ia], -1)  # (extended:system:Pi:Chap)
    theta = rng.uniform(-np.pi, np.pi, size=6)
    qdot = np.stack([th / Ia, px * np.cos(theta) / m, px * np.sin(theta) / m], -1)  # (extended:system:q:Chap)

    sys_a, II, e, _ = chaplygin(m, I, a, S1())
    # Natural scales: liefi forms h~ = h - J^2/2 and dh~ = II^-1 Pi - J e, which cancel at the
    # size of h and of the velocity II^-1 Pi (large for small I and large m a^2).
    h = sys_a.hamiltonian(Pi)
    vs = np.abs(np.linalg.solve(II, Pi.T)).max()
    ps = np.abs(Pi).max()
    _close(sys_a.extended_hamiltonian(Pi), ht, scale=np.abs(h).max())
    _close(sys_a.extended_multipliers(Pi)[:, 0], lamt, scale=ps * vs * np.abs(e).max())
    _close(sys_a.extended_vector_field(Pi), Pidot, scale=ps * vs * (1 + np.abs(e).max() * np.abs(II @ e).max()))
    q = np.stack([theta, rng.normal(size=6), rng.normal(size=6)], -1)
    _close(sys_a.reconstruction(q, Pi), qdot, scale=vs)

    # SO(2) embedding, R off the group: R' = -dh~/dPi_theta R Jp, (x, y)' = R (Pi_x / m, 0)
    sys_m, *_ = chaplygin(m, I, a)
    R = np.stack([np.stack([np.cos(theta), -np.sin(theta)], -1), np.stack([np.sin(theta), np.cos(theta)], -1)], -2)
    R = R + 0.1 * rng.normal(size=R.shape)
    Jp = np.array([[0.0, 1], [-1, 0]])
    Rdot = -(th / Ia)[:, None, None] * R @ Jp
    xydot = np.einsum("...ij,...j->...i", R, np.stack([px / m, 0 * px], -1))
    g = np.concatenate([R.reshape(6, 4), rng.normal(size=(6, 2))], -1)
    _close(sys_m.reconstruction(g, Pi), np.concatenate([Rdot.reshape(6, 4), xydot], -1), scale=vs * np.abs(R).max())

    # (nabla:Pi:V:Chap), and the SO(2) penalty gradient (docs/paper_notes.md item 4: the printed
    # -k0 R (R^T R - I) has the wrong sign; for V = k0/4 ||R^T R - I||^2 it is +k0 R (R^T R - I))
    k0, k1, k2 = rng.uniform(0.5, 3, size=3)
    y0 = np.concatenate([np.array([1.0, 0, 0, 1, 0, 0]), sys_m.project(rng.normal(size=3))])
    fi = FeedbackIntegrator(sys_m, y0, gains={"penalty": k0, "J_1": k1, "energy": k2})
    y = np.concatenate([g, Pi], -1)
    gV = fi.grad_lyapunov(y)
    J = Pi @ e
    gPi = k1 * J[:, None] * e + k2 * (ht - fi.targets["energy"])[:, None] * np.stack([th / Ia, px / m, 0 * px], -1)
    _close(gV[:, 6:], gPi, scale=k1 * np.abs(J).max() * np.abs(e).max() + k2 * (np.abs(h).max() + abs(fi.targets["energy"])) * vs)
    gR = k0 * R @ (np.swapaxes(R, -1, -2) @ R - np.eye(2))
    _close(gV[:, :4], gR.reshape(6, 4))
    assert np.all(np.sum(gV[:, :4] * (-gR.reshape(6, 4)), -1) < 0)  # the printed sign points uphill


# ============================================================================ vertical disk
@PROPERTY
@given(Jd=pos, m=pos, I=pos, rad=pos, seed=SEEDS)
@example(Jd=1.0, m=1.0, I=1.0, rad=1.0, seed=0)
def test_vertical_disk_closed_forms(Jd, m, I, rad, seed):
    """Vertical rolling disk on ``SE(2) x S^1``, inertia ``diag(J, m, m, I)``: ``h~``,
    ``lambda~_1``, ``lambda~_2``, ``(extended:eqn:vertical:disk)``; and the projected field
    has every momentum constant, as ``(further:extended:eqn:vertical:disk)``."""
    s2 = np.sqrt(m * I * (I + m * rad**2))
    E = np.array([[0, 0, 1, 0] / np.sqrt(m), [0, I, 0, -m * rad] / s2])
    G = SE2() * S1()
    sys_ = NonholonomicSystem(LieGroupPhaseSpace(G), np.diag([Jd, m, m, I]), E)
    rng = np.random.default_rng(seed)
    Pi = rng.normal(size=(6, 4))
    th, px, py, ps = Pi.T
    sv = (rad * px + ps) / (I + m * rad**2)
    ht = th**2 / (2 * Jd) + (rad * px + ps) ** 2 / (2 * (I + m * rad**2))
    lam1 = th * px / (Jd * np.sqrt(m))
    lam2 = -I / (Jd * s2) * th * py
    e1f = np.array([0, 0, np.sqrt(m), 0])
    e2f = np.array([0, m * I, 0, -m * rad * I]) / s2
    Pidot = (np.stack([-rad * sv * py, th * py / Jd, -th * px / Jd, 0 * th], -1)
             + lam1[:, None] * e1f + lam2[:, None] * e2f)
    _close(sys_.extended_hamiltonian(Pi), ht)
    lt = sys_.extended_multipliers(Pi)
    _close(lt[:, 0], lam1)
    _close(lt[:, 1], lam2)
    _close(evaluate(sys_, Pi).Eflat[0], np.stack([e1f, e2f]))
    _close(sys_.extended_vector_field(Pi), Pidot, scale=np.abs(Pi).max() ** 2 / min(Jd, m, I))
    # configuration: R' = R hat(Pi_theta / J), (x, y)' = R (R_disk s, 0), psi' = s
    theta = rng.uniform(-np.pi, np.pi, 6)
    Rm = np.stack([np.stack([np.cos(theta), -np.sin(theta)], -1), np.stack([np.sin(theta), np.cos(theta)], -1)], -2)
    g = np.concatenate([Rm.reshape(6, 4), rng.normal(size=(6, 3))], -1)
    W = np.array([[0.0, -1], [1, 0]])
    want = np.concatenate([(Rm @ W * (th / Jd)[:, None, None]).reshape(6, 4),
                           np.einsum("...ij,...j->...i", Rm, np.stack([rad * sv, 0 * sv], -1)), sv[:, None]], -1)
    _close(sys_.reconstruction(g, Pi), want)
    # (further:extended:eqn:vertical:disk): all four momenta are first integrals
    P = sys_.projected_vector_field(Pi)
    assert np.max(np.abs(P)) < 1e-13 * np.abs(Pi).max() ** 2


# ============================================================================ knife edge
def knife(m, Jk, g, alpha):
    def E(q):
        phi = q[..., 2]
        return np.stack([np.sin(phi), -np.cos(phi), 0 * phi], -1)[..., None, :] / np.sqrt(m)

    def U(q):
        return -m * g * q[..., 0] * np.sin(alpha)

    return NonholonomicSystem(CotangentBundle(3, names=("x", "y", "phi")), np.diag([m, m, Jk]), E, U)


@PROPERTY
@given(m=pos, Jk=pos, g=st.floats(0.5, 10), alpha=st.floats(0.05, 1.5), seed=SEEDS)
@example(m=1.0, Jk=1.0, g=1.0, alpha=np.pi / 6, seed=0)
def test_knife_edge_closed_forms(m, Jk, g, alpha, seed):
    """Knife edge: ``H~``, ``lambda~``, ``grad_p H~``, ``grad J_1`` as printed; ``grad_q H~``
    as *derived* (docs/paper_notes.md item 2: the printed ``(-m g sin alpha, 0, 0)`` drops the phi-component
    ``-(p_x cos phi + p_y sin phi) J_1 / sqrt(m)``, which vanishes on ``C`` only)."""
    sys_ = knife(m, Jk, g, alpha)
    rng = np.random.default_rng(seed)
    z = rng.normal(size=(6, 6))
    x, y, phi, px, py, pphi = z.T
    c, s = np.cos(phi), np.sin(phi)
    u = px * c + py * s
    J1 = (px * s - py * c) / np.sqrt(m)
    H = (px**2 + py**2) / (2 * m) + pphi**2 / (2 * Jk) - m * g * x * np.sin(alpha)
    Ht = u**2 / (2 * m) + pphi**2 / (2 * Jk) - m * g * x * np.sin(alpha)
    lamt = (-m * g * np.sin(alpha) * s - pphi * u / Jk) / np.sqrt(m)
    gradp = np.stack([u * c / m, u * s / m, pphi / Jk], -1)
    gradq_printed = np.stack([-m * g * np.sin(alpha) + 0 * x, 0 * x, 0 * x], -1)
    gradq = gradq_printed + np.stack([0 * x, 0 * x, -u * J1 / np.sqrt(m)], -1)

    t = evaluate(sys_, z)
    scale = max(1.0, np.abs(t.dht).max())
    _close(t.h, H)
    _close(t.ht, Ht)
    _close(t.J[:, 0], J1)
    _close(sys_.extended_multipliers(z)[:, 0], lamt)
    _close(t.dht[:, 3:], gradp)
    _close(t.dht[:, :3], gradq, scale=scale)
    _close(t.dJ[:, 0], np.stack([0 * x, 0 * x, u / np.sqrt(m), s / np.sqrt(m), -c / np.sqrt(m), 0 * x], -1))
    assert np.all(np.abs(t.dht[:, 2] - gradq_printed[:, 2]) > 1e-3 * np.abs(u * J1)), "printed grad_q H~ should differ off C"
    # on C the printed formula is right
    zc = sys_.project(z)
    tc = evaluate(sys_, zc)
    _close(tc.dht[:, :3], np.stack([-m * g * np.sin(alpha) + 0 * x, 0 * x, 0 * x], -1), scale=scale)
    # (ext:sys:kinfe): q' = grad_p H~, p' = -grad_q H~ + lambda~ m e
    e = np.stack([s, -c, 0 * s], -1) / np.sqrt(m)
    want = np.concatenate([gradp, -gradq + lamt[:, None] * np.array([m, m, Jk]) * e], -1)
    _close(sys_.extended_vector_field(z), want, scale=max(1.0, np.abs(want).max()))
    # the feedback integrator's grad V (with J_2 = p_phi), with the *correct* grad_q H~
    y0 = sys_.project(rng.normal(size=6))
    k1, k2, k3 = rng.uniform(0.5, 3, size=3)
    fi = FeedbackIntegrator(sys_, y0, invariants=("constraints", "energy", "p_phi"), gains={"J_1": k1, "p_phi": k2, "energy": k3})
    dHt = Ht - fi.targets["energy"]
    dJ2 = pphi - fi.targets["p_phi"]
    gV = (k1 * J1[:, None] * t.dJ[:, 0] + k2 * dJ2[:, None] * np.array([0, 0, 0, 0, 0, 1.0])
          + k3 * dHt[:, None] * np.concatenate([gradq, gradp], -1))
    _close(fi.grad_lyapunov(z), gV, scale=max(1.0, np.abs(gV).max()))


# ============================================================================ oscillator
def oscillator():
    def E(q):
        y = q[..., 1]
        return (np.stack([1 + 0 * y, 0 * y, y], -1) / np.sqrt(1 + y**2)[..., None])[..., None, :]

    return NonholonomicSystem(CotangentBundle(3, names=("x", "y", "z")), np.eye(3), E, lambda q: 0.5 * np.sum(q * q, -1))


@PROPERTY
@given(seed=SEEDS, scale=st.sampled_from([0.1, 1.0, 3.0]))
@example(seed=0, scale=1.0)
def test_nonholonomic_oscillator_closed_forms(seed, scale):
    """Nonholonomic oscillator, ``e = (1, 0, y)/sqrt(1 + y^2)``: ``H~``, ``lambda~``,
    ``grad_q H~``, ``grad_p H~``, ``grad J``; and ``H_y`` is a first integral on ``C`` only
    (docs/paper_notes.md item 5): ``dH_y . X~ = -p_y (y p_x - p_z)(p_x + y p_z)/(1 + y^2)^2``."""
    sys_ = oscillator()
    rng = np.random.default_rng(seed)
    zz = scale * rng.normal(size=(6, 6))
    x, y, z, px, py, pz = zz.T
    w = 1 + y**2
    Ht = (y * px - pz) ** 2 / (2 * w) + py**2 / 2 + (x**2 + y**2 + z**2) / 2
    gq = np.stack([x, y + (y * px - pz) * (px + y * pz) / w**2, z], -1)
    gp = np.stack([(y * px - pz) * y / w, py, (pz - y * px) / w], -1)
    lamt = ((x + y * z) * w + (px * y - pz) * py) / w**1.5
    t = evaluate(sys_, zz)
    sc = max(1.0, np.abs(zz).max() ** 2)
    _close(t.ht, Ht, scale=sc)
    _close(t.dht, np.concatenate([gq, gp], -1), scale=sc)
    _close(sys_.extended_multipliers(zz)[:, 0], lamt, scale=sc)
    _close(t.dJ[:, 0], np.stack([0 * y, (pz - y * px) / w**1.5, 0 * y, 1 / np.sqrt(w), 0 * y, y / np.sqrt(w)], -1), scale=sc)
    X = sys_.extended_vector_field(zz)
    dHy = np.stack([0 * y, y, 0 * y, 0 * y, py, 0 * y], -1)
    drift = np.einsum("...i,...i->...", dHy, X)
    _close(drift, -py * (y * px - pz) * (px + y * pz) / w**2, scale=sc**1.5)
    zc = sys_.project(zz)
    assert np.max(np.abs(np.einsum("...i,...i->...", dHy, sys_.extended_vector_field(zc)))) < 1e-13 * sc**1.5


# ============================================================================ Heisenberg
def heisenberg():
    def E(q):
        x, y = q[..., 0], q[..., 1]
        return np.stack([-y, x, 1 + 0 * x], -1)[..., None, :]  # not normalized

    return NonholonomicSystem(CotangentBundle(3, names=("x", "y", "z")), np.eye(3), E)


@PROPERTY
@given(seed=SEEDS, scale=st.sampled_from([0.1, 1.0, 3.0]))
@example(seed=0, scale=1.0)
def test_heisenberg_closed_forms(seed, scale):
    """Heisenberg with the non-normalized ``e = (-y, x, 1)``: ``lambda = 0`` by the general formula
    ``(lambda:general)``; ``H~ = |p|^2/2 - (p.e)^2 / (2 (1 + x^2 + y^2))`` (``(def:H:tilde:general)``,
    Gram ``C = 1 + x^2 + y^2``); and ``lambda~ = 0`` too (``{1/C, J} = 0``: ``C`` is rotation invariant)."""
    sys_ = heisenberg()
    rng = np.random.default_rng(seed)
    zz = scale * rng.normal(size=(6, 6))
    x, y, z, px, py, pz = zz.T
    C = 1 + x**2 + y**2
    J = pz - y * px + x * py
    sc = max(1.0, np.abs(zz).max() ** 3)
    _close(sys_.gram_matrix(zz[:, :3])[:, 0, 0], C)
    _close(sys_.multipliers(zz)[:, 0], 0 * x, scale=sc)
    _close(sys_.extended_multipliers(zz)[:, 0], 0 * x, scale=sc)
    _close(sys_.extended_hamiltonian(zz), 0.5 * (px**2 + py**2 + pz**2) - J**2 / (2 * C))
    # the constrained (original) field is q' = p, p' = 0 (Heisenberg:original)
    _close(sys_.constrained_vector_field(zz), np.concatenate([zz[:, 3:], 0 * zz[:, 3:]], -1), scale=sc)
    # J_2 = x p_y - y p_x is a first integral of it
    dJ2 = np.stack([py, -px, 0 * x, -y, x, 0 * x], -1)
    assert np.max(np.abs(np.einsum("...i,...i->...", dJ2, sys_.constrained_vector_field(zz)))) < 1e-13 * sc
    # a user Invariant built from it is accepted by the feedback integrator (complex-step route)
    inv = Invariant("L_z", lambda q: q[..., 0] * q[..., 4] - q[..., 1] * q[..., 3])
    y0 = sys_.project(zz[0])
    fi = FeedbackIntegrator(sys_, y0, invariants=("constraints", "energy", inv))
    _close(cs_grad(inv.fun, zz), dJ2)
    assert "L_z" in fi.invariant_names
    assert fi.targets["L_z"] == inv.fun(y0)
    assert fi.lyapunov(y0) < 1e-24 * max(1.0, np.abs(y0).max()) ** 6  # J(y0) ~ eps |y0|^2
