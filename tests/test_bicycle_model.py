"""The benchmark bicycle's peer is right: sympy's own linearization of the two Kane models of
``tests/bicycle_model.py`` gives the eigenvalues and speeds published by Meijaard et al. (2007)."""

import math

import numpy as np
import pytest

import bicycle_model as bm

#: PyDy's Carvallo-Whipple example prints Table 1 converted to Moore's frames (16 digits).
PYDY_CONSTANTS = {
    "rf": 0.35, "rr": 0.3, "d1": 0.9534570696121849, "d3": 0.03207142672761929, "d2": 0.2676445084476887,
    "l1": 0.4707271515135145, "l2": -0.47792881146460797, "l4": -0.3699518200282974, "l3": -0.00597083392418685,
    "mc": 85.0, "md": 2.0, "me": 4.0, "mf": 3.0, "id11": 0.0603, "id22": 0.12, "if11": 0.1405, "if22": 0.28,
    "ic11": 7.178169776497895, "ic22": 11.0, "ic31": 3.8225535938357873, "ic33": 4.821830223502103,
    "ie11": 0.05841337700152972, "ie22": 0.06, "ie31": 0.009119225261946298, "ie33": 0.007586622998470264,
    "g": 9.81,
}


def test_table_1_converted_to_moore_frames_matches_pydy_example():
    got = bm.moore_parameters()
    assert set(got) == set(PYDY_CONSTANTS)
    for name, ref in PYDY_CONSTANTS.items():
        assert got[name] == pytest.approx(ref, rel=1e-14, abs=1e-17), name


def test_table_1_principal_inertias_are_the_round_numbers_the_paper_promises():
    # Table 1's caption: the principal inertias are "exactly described with only a few digits".
    t = bm.TABLE_1
    ib = np.linalg.eigvalsh([[t["IBxx"], t["IBxz"]], [t["IBxz"], t["IBzz"]]])
    ih = np.linalg.eigvalsh([[t["IHxx"], t["IHxz"]], [t["IHxz"], t["IHzz"]]])
    assert ib == pytest.approx([2.0, 10.0], abs=1e-13)
    assert ih == pytest.approx([0.006, 0.06], abs=1e-15)
    assert t["lam"] == math.pi / 10


def _relative_errors(got, ref):
    ref = np.asarray(ref)
    ref = ref[np.lexsort((ref.imag, ref.real))]
    return np.abs(got - ref) / np.abs(ref)


@pytest.fixture(scope="module")
def lateral():
    # sympy's own route, as test_kane3.py takes it: KanesMethod.linearize of the model as
    # that test writes it (about three CPU minutes).  The contact-coordinates model is
    # checked by complex steps below (sympy's linearizer did not finish on it in 14 CPU
    # minutes).
    pytest.importorskip("sympy")
    return bm.lateral_matrix(bm.whipple_sympy_test())


@pytest.mark.slow
@pytest.mark.parametrize("v", sorted(bm.BENCHMARK_EIGENVALUES))
def test_benchmark_eigenvalues(lateral, v):
    err = _relative_errors(bm.eigenvalues(lateral(v)), bm.BENCHMARK_EIGENVALUES[v])
    assert err.max() < 1e-10, err


@pytest.mark.slow
def test_weave_and_capsize_speeds(lateral):
    weave, capsize = bm.weave_and_capsize_speeds(lateral)
    assert abs(weave - bm.WEAVE_SPEED) / bm.WEAVE_SPEED < 1e-10
    assert abs(capsize - bm.CAPSIZE_SPEED) / bm.CAPSIZE_SPEED < 1e-10


@pytest.mark.slow
@pytest.mark.parametrize("builder", ["whipple_sympy_test", "whipple_contact_coordinates"])
def test_generated_numerics_give_the_benchmark_eigenvalues(builder):
    # The right-hand side the peer integrates (mass_matrix_full, forcing_full), linearized on
    # the constraint set by complex steps: the nonlinear model itself is the benchmark's.
    pytest.importorskip("sympy")
    lateral = bm.complex_step_lateral(getattr(bm, builder)())
    for v, ref in bm.BENCHMARK_EIGENVALUES.items():
        err = _relative_errors(bm.eigenvalues(lateral(v)), ref)
        assert err.max() < 1e-10, (v, err)
    weave, capsize = bm.weave_and_capsize_speeds(lateral)
    assert abs(weave - bm.WEAVE_SPEED) / bm.WEAVE_SPEED < 1e-10
    assert abs(capsize - bm.CAPSIZE_SPEED) / bm.CAPSIZE_SPEED < 1e-10


@pytest.mark.slow
def test_peer_measures_the_drift_it_reports():
    # benchmarks/bicycle_peer.py on 1 s of the self-stable run: the tight run holds the
    # front contact on the ground, the rolling and the energy near rounding; the loose run
    # lets them drift by orders of magnitude more, and the table says so.
    pytest.importorskip("sympy")
    import os
    import sys
    sys.path.insert(0, os.path.join(os.path.dirname(os.path.dirname(os.path.abspath(__file__))), "benchmarks"))
    import bicycle_peer as bp
    res = bp.phase_run("sympy-test", bp.CASES[:1], bp.METHODS, 1.0)
    tight, loose = res["rows"]
    assert (tight["method"], loose["method"]) == ("DOP853", "RK45")
    for key in ("holonomic", "nonholonomic", "energy"):
        assert tight[key] < 1e-11, (key, tight[key])
        assert loose[key] > 100 * tight[key], (key, loose[key], tight[key])
    assert not tight["fell"] and tight["t_end"] == 1.0
    text = bp.table("sympy-test", None, None, res, 0.0, 1.0)
    assert "DOP853 1e-12" in text and "RK45 1e-06" in text
