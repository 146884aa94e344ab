"""liefi's own bicycle: ``liefi.from_mechanics`` of the Whipple bicycle as a Kane user writes it, linearized
on its constraint set (``system.linearize``), against the benchmark of Meijaard, Papadopoulos, Ruina &
Schwab (2007): Table 2's eigenvalues at 0, 4, 5 and 10 m/s and the weave and capsize speeds, to 1e-10.

Two models (``tests/bicycle_model.py``): ``whipple_contact_coordinates`` has the rear contact's coordinates,
the pitch dependent through the front contact's height ``f(q) = 0`` and five velocity constraints, one of
them ``f'``: liefi keeps ``f`` as the holonomic datum and linearizes in the independent coordinates and
speeds; ``whipple_sympy_test`` is sympy's own test model (minimal speeds: the rear contact's place is
restored, the wheels' rates ``u3, u6`` get the coordinates ``q_u3, q_u6``; the pitch ``q4`` dependent).
The upright straight run at speed ``v`` is a steady motion: the rear contact moves forward at ``v`` and
the wheels turn at ``v / r``; the pitch solves ``f = 0`` (liefi's own ``f``, by Brent).

Then nonlinear runs of the contact-coordinates model from a lean rate of 0.5 rad/s (imex-rk8, dt = 0.01):
the model's own velocity constraints, its configuration constraint and its energy ``T + U`` held to 1e-12;
the lean decays at 5 m/s over [0, 10] and grows at 3 m/s.

Slow: sympy's ``kanes_equations`` (~20 s) and the build (~10-20 s) once per model, each linearization
about 0.5 s (the first ~12 s: the traced Jacobian), and ~80 of them for the two speeds; the run
at 5 m/s ~70 s (numpy backend).
"""

import numpy as np
import pytest
from scipy.optimize import brentq

import bicycle_model as bm

import liefi
from liefi.scenes.bicycle import upright  # the upright straight run at v: one home, with the scene

pytestmark = pytest.mark.slow
RTOL = 1e-10


#: per model: its builder, the minimal coordinates of the linearization, and the ignorable coordinates
MODELS = {
    "contact coordinates": (bm.whipple_contact_coordinates, ("q1", "q2", "q3", "q4", "q6", "q7", "q8", "u4", "u6", "u7"),
                            ("q1", "q2", "q6", "q8")),
    # sympy's test: no wheel angles (liefi adds q_u3, q_u6 for the wheels' rates) and the rear contact's place restored
    "sympy test": (bm.whipple_sympy_test, ("q1", "q2", "q5", "q_u3", "q_u6", "x_WR_cont", "y_WR_cont", "u2", "u3", "u5"),
                   ("q_u3", "q_u6", "x_WR_cont", "y_WR_cont")),
}


@pytest.fixture(scope="module", params=sorted(MODELS))
def bicycle(request):
    build, coordinates, ignorable = MODELS[request.param]
    bike = build()
    system = liefi.from_mechanics(bike.kane, bike.params)
    return bike, system, coordinates, ignorable


def eigenvalues(bike, system, v):
    q, u = upright(bike, system, v)
    return system.linearize(q, u=u)


@pytest.mark.parametrize("v", sorted(bm.BENCHMARK_EIGENVALUES))
def test_liefi_bicycle_reproduces_the_benchmark_eigenvalues(bicycle, v):
    bike, system, coordinates, ignorable = bicycle
    lin = eigenvalues(bike, system, v)
    # the minimal coordinates: the independent coordinates and the model's independent speeds
    assert lin.coordinates == coordinates
    lam = np.asarray(lin.nontrivial_eigenvalues)
    ref = np.asarray(bm.BENCHMARK_EIGENVALUES[v])
    assert lam.shape == (4,)
    for r in ref:  # each published value has its own computed one, and no two share one
        k = np.argmin(np.abs(lam - r))
        assert abs(lam[k] - r) <= RTOL * abs(r), (v, r, lam)
        lam = np.delete(lam, k)
    # the trivial modes are named: the contact's translations and the wheel angles, and the energy when moving
    names = [m.name for m in lin.trivial_modes]
    for j in ignorable:
        assert f"translation of {j} (ignorable)" in names
    assert ("energy" in names) == (v > 0)


def lateral(bike, lin):
    """The eigenvalues of ``A`` on the lean and steer and their rates, which no other coordinate feeds back into.

    Near the capsize speed the capsize eigenvalue passes through zero, where ``nontrivial_eigenvalues``
    cannot tell it from the trivial zeros (below ~1e-12 |A| it counts it with the family of steady
    motions); the lateral block is the benchmark's own 4 x 4 matrix and has no trivial zero.
    """
    k = [lin.coordinates.index(str(s.func)) for s in (bike.lean, bike.steer, bike.lean_rate, bike.steer_rate)]
    assert np.all(np.delete(lin.A[k], k, axis=1) == 0) or np.abs(np.delete(lin.A[k], k, axis=1)).max() < 1e-12 * \
        np.abs(lin.A).max()  # decoupled: lean and steer see no other coordinate at first order
    return np.linalg.eigvals(lin.A[np.ix_(k, k)])


def weave_and_capsize_speeds(bike, system):
    """The weave and capsize speeds: roots (Brent) of the weave pair's real part and of the capsize eigenvalue."""

    def weave(v):
        lam = lateral(bike, eigenvalues(bike, system, v))
        return lam[np.argmax(lam.imag)].real

    def capsize(v):
        lam = lateral(bike, eigenvalues(bike, system, v))
        return lam[lam.imag == 0].real.max()

    kw = dict(xtol=1e-14, rtol=1e-15, maxiter=100)
    return brentq(weave, 3.0, 5.0, **kw), brentq(capsize, 5.5, 8.0, **kw)


def test_liefi_bicycle_weave_and_capsize_speeds(bicycle):
    bike, system = bicycle[:2]
    lin = eigenvalues(bike, system, 5.0)  # the lateral block has the nontrivial eigenvalues
    np.testing.assert_allclose(np.sort_complex(lateral(bike, lin)), np.sort_complex(lin.nontrivial_eigenvalues), rtol=1e-12)
    vw, vc = weave_and_capsize_speeds(bike, system)
    assert abs(vw - bm.WEAVE_SPEED) <= RTOL * bm.WEAVE_SPEED, vw
    assert abs(vc - bm.CAPSIZE_SPEED) <= RTOL * bm.CAPSIZE_SPEED, vc


# --- nonlinear runs of the contact-coordinates bicycle: every declared constraint and the energy held -------
def declared_residuals(bike, system, sol):
    """The model's own velocity constraints (m/s), configuration constraint (m) and energy ``T + U`` (J) along
    ``sol``, evaluated from the model's expressions (``sympy.lambdify``), not from liefi's data."""
    import sympy

    Y = sol.y.T
    n = system.space.n
    names = [str(s) for s in system.space.shape_names]
    speeds = system.generalized_speeds(Y)
    X = np.concatenate([Y[:, [names.index(str(s.func)) for s in bike.q]],
                        np.stack([speeds[str(s.func)] for s in bike.u], -1)], -1)
    args = list(bike.q) + list(bike.u)
    out = []
    for e in (bike.nonholonomic, [bike.holonomic], [bike.energy]):
        fun = sympy.lambdify(args, sympy.Matrix(e).xreplace(bike.params), "numpy", cse=True)
        out.append(np.array([np.asarray(fun(*x), float).ravel() for x in X]))
    assert Y.shape[1] == 2 * n
    return out[0], out[1][:, 0], out[2][:, 0]


@pytest.fixture(scope="module")
def contact_bicycle():
    bike = bm.whipple_contact_coordinates()
    return bike, liefi.from_mechanics(bike.kane, bike.params)


@pytest.mark.parametrize("v, t_end", [(5.0, 10.0), (3.0, 1.5)])
def test_liefi_bicycle_runs_from_a_lean_rate_holding_every_constraint_and_the_energy(contact_bicycle, v, t_end):
    """From the upright run at ``v`` with a lean rate of 0.5 rad/s: self-stable at 5 m/s (the lean decays), the
    weave growing at 3 m/s (the bicycle then falls: at t ~ 1.8 s the lean passes -1 rad)."""
    bike, system = contact_bicycle
    q, _ = upright(bike, system, v)
    # the independent speeds (lean rate, rear wheel rate, steer rate); the others solve the constraints and f'
    z0 = system.state(q, u={"u4": 0.5, "u6": -v / bm.TABLE_1["rR"], "u7": 0.0})
    sol = liefi.FeedbackIntegrator(system, z0).run(t_end, t_eval=np.linspace(0.0, t_end, int(20 * t_end) + 1),
                                                   dt=0.01, scheme="imex-rk8", backend="numpy")
    velocity, f, energy = declared_residuals(bike, system, sol)
    assert np.abs(velocity).max() < 1e-12  # m/s: the rolling of both wheels
    assert np.abs(f).max() < 1e-12  # m: the front contact's height
    assert np.abs(energy - energy[0]).max() < 1e-12 * abs(energy[0])
    lean = sol.y[[str(s) for s in system.space.shape_names].index("q4")]
    first = np.abs(lean[sol.t <= 1.0]).max()  # the first swing, ~0.1 rad at 5 m/s, ~0.2 rad at 3 m/s
    last = np.abs(lean[sol.t >= t_end - 0.3]).max()
    if v == 5.0:
        assert last < 0.05 * first
    else:
        assert last > 1.5 * first
