"""Exports of a Solution (pandas, xarray, netCDF) and liefi.plot for a user's own run."""

import subprocess
import sys

import numpy as np
import pytest

import liefi
from liefi import scenes


@pytest.fixture(scope="module")
def knife_run():
    fi = scenes.get("knife-edge").integrator(gains=1.0)
    return fi, fi.run(0.5, dt=1e-2, scheme="rk4")


@pytest.fixture(scope="module")
def body_run():
    fi = scenes.get("rigid-body").integrator(gains=1.0)
    return fi, fi.run(0.3, dt=1e-2, scheme="rk4")


def test_to_dataframe(knife_run):
    pd = pytest.importorskip("pandas")
    fi, sol = knife_run
    df = sol.to_dataframe()
    assert isinstance(df, pd.DataFrame) and list(df.columns) == list(fi.names)
    assert df.index.name == "t" and np.array_equal(df.index.to_numpy(), sol.t)
    np.testing.assert_array_equal(df["p_x"].to_numpy(), sol["p_x"])
    inv = sol.to_dataframe(invariants=True)
    h = fi.invariant_values(sol.y.T)["h"]
    np.testing.assert_array_equal(inv["h"].to_numpy(), h)
    assert {"J_1", "h", "h~", "p_phi"} <= set(inv.columns)


def test_to_dataframe_of_a_batch(knife_run):
    pytest.importorskip("pandas")
    fi, _ = knife_run
    Y0 = np.stack([fi.y0, fi.y0, fi.y0])
    Y0[1, 5] = 0.6
    sol = fi.run(0.2, dt=1e-2, y0=Y0, check_stability=False)
    df = sol.to_dataframe()
    assert df.index.names == ["member", "t"] and df.shape == (3 * sol.t.size, fi.n)
    np.testing.assert_array_equal(df.loc[1]["p_phi"].to_numpy(), sol.y[1, 5])


def test_to_xarray_has_states_time_and_invariants(body_run):
    pytest.importorskip("xarray")
    fi, sol = body_run
    ds = sol.to_xarray()
    assert set(fi.names) <= set(ds.data_vars) and {"penalty", "h", "h~", "casimir"} <= set(ds.data_vars)
    np.testing.assert_array_equal(ds["t"].to_numpy(), sol.t)
    np.testing.assert_array_equal(ds["Pi_2"].to_numpy(), sol["Pi_2"])
    assert ds["h"].attrs["kind"] == "invariant" and ds["h"].attrs["target"] == float(ds["h"][0])  # h: from y0
    assert ds.attrs["energy"] == "h~" and "energy" not in ds  # the penalized energy is h~: one variable
    assert ds["h~"].attrs["target"] == fi.targets["energy"] and ds["Pi_1"].attrs["kind"] == "state"
    assert ds["penalty"].attrs["target"] == 0.0 and ds.attrs["scheme"] == "rk4"
    assert set(sol.to_xarray(invariants=False).data_vars) == set(fi.names)


def test_to_xarray_round_trips_through_netcdf(body_run, tmp_path):
    xr = pytest.importorskip("xarray")
    _, sol = body_run
    ds = sol.to_xarray()
    path = tmp_path / "run.nc"
    ds.to_netcdf(path, engine="scipy")  # netCDF3 through scipy: no netCDF4 library needed
    with xr.open_dataset(path, engine="scipy") as back:
        xr.testing.assert_identical(ds, back.load())


def test_to_xarray_of_a_batch(knife_run):
    pytest.importorskip("xarray")
    fi, _ = knife_run
    sol = fi.run(0.2, dt=1e-2, y0=np.stack([fi.y0, fi.y0]))
    ds = sol.to_xarray()
    assert ds["x"].dims == ("member", "t") and ds["J_1"].shape == (2, sol.t.size)


def test_invariants_need_the_integrator(knife_run):
    pytest.importorskip("pandas")
    _, sol = knife_run
    from liefi.schemes import integrate

    bare = integrate(sol.integrator.vector_field, sol.y[:, 0], 1e-2, 5, "rk4", names=sol.names)
    assert bare.integrator is None and list(bare.to_dataframe().columns) == list(sol.names)
    with pytest.raises(ValueError, match="does not know its integrator"):
        bare.to_dataframe(invariants=True)


@pytest.mark.parametrize("module, method", [("pandas", "to_dataframe"), ("xarray", "to_xarray")])
def test_missing_extra_is_named(knife_run, monkeypatch, module, method):
    _, sol = knife_run
    monkeypatch.setitem(sys.modules, module, None)  # "import module" now raises ImportError
    with pytest.raises(ImportError, match=r"pip install 'liefi\[export\]'"):
        getattr(sol, method)()


def test_import_liefi_loads_no_plotting_or_export_library():
    code = ("import sys, liefi; liefi.FeedbackIntegrator; "
            "print([m for m in ('matplotlib', 'pandas', 'xarray') if m in sys.modules])")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.strip() == "[]"


# --- liefi.plot ------------------------------------------------------------------------------------------------


def test_plot_overview_draws_states_drift_and_path(knife_run, tmp_path):
    pytest.importorskip("matplotlib")
    fi, sol = knife_run
    fig = liefi.plot.overview(sol)
    states, drift, path = fig.axes
    assert len(states.get_lines()) == fi.n
    assert drift.get_yscale() == "log" and {t.get_text() for t in drift.get_legend().get_texts()} >= {"$J_{1}$"}
    xs, ys = path.get_lines()[0].get_data()
    np.testing.assert_array_equal(xs, sol["x"])
    np.testing.assert_array_equal(ys, sol["y"])
    fig.savefig(tmp_path / "run.png")
    assert (tmp_path / "run.png").stat().st_size > 10_000


def test_plot_path_needs_named_components(body_run):
    pytest.importorskip("matplotlib")
    _, sol = body_run
    with pytest.raises(ValueError, match="no \\(x, y\\) components"):
        liefi.plot.path(sol)
    ax = liefi.plot.path(sol, x="Pi_1", y="Pi_2")
    assert ax.get_xlabel() == "$\\Pi_1$"
    with pytest.raises(ValueError, match="'q' is not a component"):
        liefi.plot.path(sol, x="q", y="Pi_2")
    assert len(liefi.plot.overview(sol).axes) == 2  # no path: states and drift


def test_plot_drift_of_one_member_and_named_invariants(knife_run):
    pytest.importorskip("matplotlib")
    fi, _ = knife_run
    sol = fi.run(0.2, dt=1e-2, y0=np.stack([fi.y0, fi.y0]))
    ax = liefi.plot.drift(sol, member=1, invariants=["J_1", "h"])
    assert len(ax.get_legend().get_texts()) == 2
    with pytest.raises(ValueError, match="member: the batch has 2 members"):
        liefi.plot.states(sol, member=2)
    with pytest.raises(ValueError, match="'E' is not monitored"):
        liefi.plot.drift(sol, invariants=["E"])
