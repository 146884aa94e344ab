"""Rolling without slipping from a body's data (:mod:`liefi.rolling`) against the textbook equations.

Oracles (written here, not liefi's derivation):

* Chaplygin's ball: ``M' = M x Omega``, ``Gamma' = Gamma x Omega``,
  ``M = I Omega + m a^2 Gamma x (Omega x Gamma)``;
* any body (Borisov & Mamaev 2002, Bloch Sec. 1.7): with ``K = I Omega + m r x (Omega x r)``
  the angular momentum about the contact point, ``K' = K x Omega + m r' x (Omega x r)
  + m g r x Gamma``, ``Gamma' = Gamma x Omega``, the centre of mass moving with
  ``u = -(R (Omega x r))_horizontal``.

liefi's field on the constraint set must agree, for a ball, an ellipsoid with an
offset centre of mass and misaligned inertia (the rattleback's data), and a disk.
"""

from __future__ import annotations

import numpy as np
import pytest

from liefi import rolling
from liefi.groups import SO3
from liefi.reduction import unreduce
from test_semidirect_reduction import plane_chart, plane_chart_jacobian

H = 1e-30


def _directional(fun, z, X):
    """``d fun(z) / dt`` along ``z' = X`` by complex step."""
    return np.asarray(fun(z + 1j * H * X)).imag / H


def _bodies():
    Q = SO3().exp(np.array([0.0, 0.0, 0.15]))
    return [
        ("ball", rolling.rolling_body(1.3, [0.3, 0.45, 0.5], rolling.sphere(0.9), gravity=9.81)),
        ("offset ball", rolling.rolling_body(1.0, [0.3, 0.4, 0.5], rolling.sphere(1.0, [0.05, -0.1, 0.2]), 9.81)),
        ("ellipsoid", rolling.rolling_body(1.0, [0.2, 0.3, 0.4], rolling.ellipsoid([0.3, 0.2, 0.1], [0, 0, -0.02], Q),
                                           9.81)),
        ("disk", rolling.rolling_body(1.0, [0.25, 0.25, 0.5], rolling.disk(1.0), 9.81,
                                      sample=SO3().exp(np.array([1.2, 0.0, 0.0])))),
    ]


BODIES = _bodies()


def _states(system, rng, count=4):
    out = []
    for _ in range(count):
        R = SO3().exp(rng.normal(size=3) * np.array([1.0, 0.6, 1.0]))
        out.append(rolling.rolling_start(system, R, rng.normal(size=3)))
    return np.array(out)


@pytest.mark.parametrize("name,system", BODIES, ids=[b[0] for b in BODIES])
def test_field_on_C_is_the_rolling_body_of_the_textbook(name, system):
    """On ``C``: ``K' = K x Omega + m r' x (Omega x r) + m g r x Gamma``, ``Gamma' = Gamma x Omega``,
    ``rho_i' = rho_i x Omega`` and ``u = -(R(Omega x r))_h``, from liefi's derived field."""
    rng = np.random.default_rng(4)
    # the mass at a tilted attitude (a disk lying flat has no contact point: its data are singular there)
    mass = system.metric(SO3().exp(np.array([0.4, -0.3, 0.2])).ravel())[3, 3]
    contact = {"ball": rolling.sphere(0.9), "offset ball": rolling.sphere(1.0, [0.05, -0.1, 0.2]),
               "ellipsoid": rolling.ellipsoid([0.3, 0.2, 0.1], [0, 0, -0.02], SO3().exp(np.array([0.0, 0.0, 0.15]))),
               "disk": rolling.disk(1.0)}[name]
    I = np.diag({"ball": [0.3, 0.45, 0.5], "offset ball": [0.3, 0.4, 0.5], "ellipsoid": [0.2, 0.3, 0.4],
                 "disk": [0.25, 0.25, 0.5]}[name])
    for y in _states(system, rng):
        z = y[11:]
        assert np.max(np.abs(system.constraint_momenta(z))) < 1e-14
        X = system.extended_vector_field(z)
        Xc = system.constrained_vector_field(z)
        np.testing.assert_allclose(X, Xc, atol=1e-13)

        def omega(zz):
            return np.linalg.solve(system.metric(zz[:9]), zz[9:])[:3]

        def r_of(zz):
            return contact(zz[6:9])

        rho1, rho2, G = z[0:3], z[3:6], z[6:9]
        W, r = omega(z), r_of(z)
        Wdot, rdot = _directional(omega, z, X), _directional(r_of, z, X)
        K = I @ W + mass * np.cross(r, np.cross(W, r))
        Kdot = I @ Wdot + mass * (np.cross(rdot, np.cross(W, r)) + np.cross(r, np.cross(Wdot, r) + np.cross(W, rdot)))
        want = np.cross(K, W) + mass * np.cross(rdot, np.cross(W, r)) + mass * 9.81 * np.cross(r, G)
        np.testing.assert_allclose(Kdot, want, atol=1e-12 * max(1.0, np.max(np.abs(want))))
        np.testing.assert_allclose(X[6:9], np.cross(G, W), atol=1e-14)
        np.testing.assert_allclose(X[0:3], np.cross(rho1, W), atol=1e-14)
        np.testing.assert_allclose(X[3:6], np.cross(rho2, W), atol=1e-14)
        u = np.linalg.solve(system.metric(z[:9]), z[9:])[3:]
        v = np.cross(W, r)  # (Omega x r) in body axes; R^T e_i . v are its horizontal components
        np.testing.assert_allclose(u, -np.array([rho1 @ v, rho2 @ v]), atol=1e-14)


def test_chaplygin_ball_is_chaplygins_system():
    """For the ball: ``M' = M x Omega`` with ``M = I Omega + m a^2 Gamma x (Omega x Gamma)``, which liefi's
    state gives as ``Pi + a Gamma x (p_1 rho_1 + p_2 rho_2)``."""
    from liefi.scenes.chaplygin_ball import contact_momentum

    I, m, a = np.array([0.3, 0.45, 0.5]), 1.3, 0.9
    ball = BODIES[0][1]
    for y in _states(ball, np.random.default_rng(2)):
        z = y[11:]
        X = ball.extended_vector_field(z)
        W, G = z[9:12] / I, z[6:9]
        M = contact_momentum(z, a)
        np.testing.assert_allclose(M, I * W + m * a**2 * np.cross(G, np.cross(W, G)), atol=1e-14)
        np.testing.assert_allclose(_directional(lambda zz: contact_momentum(zz, a), z, X), np.cross(M, W), atol=1e-13)


@pytest.mark.parametrize("name,system", BODIES[:3], ids=[b[0] for b in BODIES[:3]])
def test_rolling_body_extension_commutes_with_reduction(name, system):
    """The rolling body's own data on ``SO(3) x R^2``: ``pi`` carries the unreduced extended field (in Euler
    angles and the position) to the reduced one with ``g' = g dh~/dmu``, off ``C`` too."""
    rng = np.random.default_rng(9)
    q = np.concatenate([rng.uniform(-1, 1, (3, 3)) * [np.pi, 1.2, np.pi], rng.normal(size=(3, 2))], -1)
    p = rng.normal(size=(3, 5))
    un, pi = unreduce(system, plane_chart, plane_chart_jacobian, sample=q[0])
    Z = np.concatenate([q, p], -1)
    g, z = pi(q, p)
    X = un.extended_vector_field(Z)
    gdot, zdot = pi.push(q, p, X[..., :5], X[..., 5:])
    scale = max(1.0, np.max(np.abs(zdot)))
    np.testing.assert_allclose(zdot, system.extended_vector_field(z), atol=1e-12 * scale)
    np.testing.assert_allclose(gdot, system.reconstruction(g, z), atol=1e-12 * scale)


def test_bad_body_data_are_named():
    with pytest.raises(ValueError, match="mass"):
        rolling.rolling_body(-1.0, [1, 1, 1], rolling.sphere(1.0))
    with pytest.raises(ValueError, match="inertia"):
        rolling.rolling_body(1.0, [1, 1], rolling.sphere(1.0))
    with pytest.raises(ValueError, match="radius"):
        rolling.sphere(0.0)
    with pytest.raises(ValueError, match="semi_axes"):
        rolling.ellipsoid([1.0, -1.0, 1.0])
    with pytest.raises(ValueError, match="rotation"):
        rolling.ellipsoid([1.0, 1.0, 1.0], rotation=2 * np.eye(3))
    with pytest.raises(TypeError, match="contact"):
        rolling.rolling_body(1.0, [1, 1, 1], [0.0, 0.0, -1.0])
    with pytest.raises(ValueError, match="contact"):
        rolling.rolling_body(1.0, [1, 1, 1], lambda G: np.zeros(2))
    with pytest.raises(ValueError, match="sample="):
        rolling.rolling_body(1.0, [1, 1, 1], rolling.disk(1.0))
    with pytest.raises(ValueError, match="R: expected a rotation"):
        rolling.rolling_start(BODIES[0][1], 2 * np.eye(3), [0.0, 0.0, 1.0])
