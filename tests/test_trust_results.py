"""Results a user can trust (issue 23): exports with one column per quantity and nothing hidden, figures
that show a rolling body readably, a path drawn between the steps, an animation helper, and clear
errors for bad input to projections, constants, masses, tolerances and starts."""

import dataclasses
import warnings

import numpy as np
import pytest

import liefi
from liefi import scenes

KNIFE = ("x", "y", "phi", "p_x", "p_y", "p_phi")


@pytest.fixture(scope="module")
def knife():
    fi = scenes.get("knife-edge").integrator(gains=1.0)
    return fi, fi.run(0.3, dt=1e-2, scheme="rk4")


def _named(sol, **renames):
    """The knife-edge run with some components renamed (as a user's own system would name them)."""
    return dataclasses.replace(sol, names=tuple(renames.get(n, n) for n in sol.names))


# --- exports -----------------------------------------------------------------------------------------------


@pytest.fixture(scope="module")
def ensemble():
    """An ensemble whose members have their own energy targets (an integrator built on a batch)."""
    sc = scenes.get("knife-edge")
    base = sc.integrator(gains=1.0)
    Y0 = np.stack([base.y0, base.y0])
    Y0[1, 5] = 0.6
    fi = liefi.FeedbackIntegrator(sc.system, Y0, gains=1.0, configuration=base.configuration)
    return fi, fi.run(0.1, dt=1e-2, scheme="rk4")


def test_to_xarray_of_an_ensemble_with_per_member_targets(ensemble, tmp_path):
    xr = pytest.importorskip("xarray")
    fi, sol = ensemble
    assert np.ndim(fi.targets["energy"]) == 1  # one target per member
    ds = sol.to_xarray()
    h0 = fi.invariant_values(sol.y[..., 0])["h~"]
    np.testing.assert_array_equal(ds["h~"].attrs["target"], fi.targets["energy"])
    np.testing.assert_allclose(ds["h~"].attrs["target"], h0, rtol=1e-15)
    assert ds["J_1"].attrs["target"] == 0.0 and ds["x"].dims == ("member", "t")
    path = tmp_path / "ens.nc"
    ds.to_netcdf(path, engine="scipy")
    with xr.open_dataset(path, engine="scipy") as back:
        xr.testing.assert_identical(ds, back.load())


def test_plot_drift_of_an_ensemble_member_with_its_own_target(ensemble):
    pytest.importorskip("matplotlib")
    import liefi.plot

    fi, sol = ensemble
    ax = liefi.plot.drift(sol, member=1, invariants=["h~"])
    (line,) = ax.get_lines()
    drift = np.asarray(line.get_ydata(), dtype=float)
    assert drift.size == sol.t.size and np.nanmax(drift) < 1e-9  # against member 1's own energy (0.18), not 0.125


def test_energy_is_one_column_not_two(knife):
    pd = pytest.importorskip("pandas")
    pytest.importorskip("xarray")
    fi, sol = knife
    df = sol.to_dataframe(invariants=True)
    ds = sol.to_xarray()
    h = fi.invariant_values(sol.y.T)
    for cols in (list(df.columns), list(ds.data_vars)):
        assert "energy" not in cols and cols.count("h~") == 1 and "h" in cols
        assert len(cols) == len(set(cols)) == fi.n + 3  # the states, J_1, h, h~ (p_phi is a state and an invariant)
    assert isinstance(df, pd.DataFrame) and ds.attrs["energy"] == "h~"
    np.testing.assert_array_equal(ds["h~"].to_numpy(), h["energy"])  # the penalized energy is h~
    assert ds["h~"].attrs["target"] == fi.targets["energy"]


def test_names_that_repeat_are_refused_in_both_exports(knife):
    pytest.importorskip("pandas")
    pytest.importorskip("xarray")
    _, sol = knife
    bad = _named(sol, y="x", phi="z")  # x, x, z, ...
    for export in (bad.to_dataframe, bad.to_xarray):
        with pytest.raises(ValueError, match=r"names: .*'x' at \[0, 1\].*distinct names"):
            export()


@pytest.mark.parametrize("name", ["h", "h~", "J_1", "energy"])
def test_a_component_named_as_an_invariant_hides_nothing(knife, name):
    pytest.importorskip("pandas")
    pytest.importorskip("xarray")
    fi, sol = knife
    own = _named(sol, phi=name)
    inv = fi.invariant_values(sol.y.T)
    df = own.to_dataframe(invariants=True)
    ds = own.to_xarray()
    for table in (df, ds):
        np.testing.assert_array_equal(np.asarray(table[name]), sol["phi"])  # the component under its name
        for k in ("J_1", "h", "h~"):  # every invariant is there, under its name or suffixed
            key = f"{k}_invariant" if k == name else k
            np.testing.assert_array_equal(np.asarray(table[key]), inv[k])
    if name != "energy":
        assert df.attrs["renamed"] == ds.attrs["renamed"] == f"{name}->{name}_invariant"
        assert ds[f"{name}_invariant"].attrs["name"] == name


def test_a_component_named_t(knife, tmp_path):
    pytest.importorskip("pandas")
    xr = pytest.importorskip("xarray")
    _, sol = knife
    own = _named(sol, phi="t")
    ds = own.to_xarray()
    np.testing.assert_array_equal(ds["t"].to_numpy(), sol.t)
    np.testing.assert_array_equal(ds["t_state"].to_numpy(), sol["phi"])
    assert ds["t_state"].attrs["name"] == "t" and ds.attrs["renamed"] == "t->t_state"
    df = own.to_dataframe()
    np.testing.assert_array_equal(df["t_state"].to_numpy(), sol["phi"])
    assert df.reset_index()["t"].tolist() == sol.t.tolist()  # the index and the column both survive


def test_non_latin1_names_round_trip_through_netcdf3(knife, tmp_path):
    pytest.importorskip("pandas")
    xr = pytest.importorskip("xarray")
    _, sol = knife
    own = _named(sol, phi="θ", p_phi="p_θ")
    ds = own.to_xarray()
    path = tmp_path / "theta.nc"
    ds.to_netcdf(path, engine="scipy")
    with xr.open_dataset(path, engine="scipy") as back:
        back = back.load()
    xr.testing.assert_identical(ds, back)
    by_name = {v.attrs.get("name", k): k for k, v in back.data_vars.items()}
    np.testing.assert_array_equal(back[by_name["θ"]].to_numpy(), sol["phi"])
    np.testing.assert_array_equal(back[by_name["p_θ"]].to_numpy(), sol["p_phi"])
    assert back.attrs["state_names"].split(",")[2] == "θ"
    assert "θ" in own.to_dataframe().columns  # pandas keeps the name as given


# --- bad input ---------------------------------------------------------------------------------------------


def test_projecting_a_state_with_nan_names_it():
    sys_ = scenes.get("knife-edge").system
    with pytest.raises(ValueError, match=r"^z: contains non-finite numbers .*\['p_x'\]"):
        sys_.project([0.0, 0.0, 0.3, np.nan, 0.0, 0.5])
    with pytest.raises(ValueError, match=r"^z: contains non-finite .*\['p_y'\] of the states at batch index \[\[1\]\]"):
        sys_.project([[0.0, 0.0, 0.3, 1.0, 0.0, 0.5], [0.0, 0.0, 0.3, 1.0, np.inf, 0.5]])
    with pytest.raises(ValueError, match=r"^z: expected a state of 6 numbers .*got shape \(7,\)"):
        sys_.project(np.ones(7))
    z = sys_.project([0.0, 0.0, 0.3, 1.0, 0.0, 0.5])  # a good state still projects onto J = 0
    assert np.all(np.isfinite(z)) and z[2] == 0.3


def _sleigh():
    from models import sleigh_model

    return sleigh_model()[0], {"m": 1.0, "I": 0.5, "a": 0.3}


@pytest.mark.parametrize("value, says", [("abc", r"expected a real number \(or one per member\), got 'abc'"),
                                         (1 + 2j, r"complex values .*expected a real number")])
def test_bad_constants_are_named(value, says):
    model, constants = _sleigh()
    with pytest.raises(ValueError, match=r"^constants\['m'\]: " + says):
        liefi.from_mechanics(model, constants=dict(constants, m=value))
    fine = liefi.from_mechanics(model, constants=constants)
    with pytest.raises(ValueError, match=r"^constants\['a'\]: " + says):
        fine.constants = {"a": value}


@pytest.mark.parametrize("make, name", [
    (lambda r, v: r.rolling_body(v, [1.0, 1.0, 1.0], r.sphere(1.0)), "mass"),
    (lambda r, v: r.rolling_body(1.0, [1.0, 1.0, 1.0], r.sphere(1.0), gravity=v), "gravity"),
    (lambda r, v: r.sphere(v), "radius"),
    (lambda r, v: r.disk(v), "radius"),
])
@pytest.mark.parametrize("value", ["abc", 1 + 2j, [1.0, 2.0]])
def test_bad_rolling_numbers_are_named(make, name, value):
    from liefi import rolling

    with pytest.raises(ValueError, match=rf"^{name}: (expected|complex values)"):
        make(rolling, value)


@pytest.mark.parametrize("atol", [1e-8 + 1j, "abc", [1e-8j] * 6])
def test_bad_atol_is_named(knife, atol):
    fi, _ = knife
    with pytest.raises(ValueError, match=r"^atol: .*(expected a number >= 0|complex values)"):
        fi.run(0.1, rtol=1e-6, atol=atol, backend="numpy")


@pytest.mark.parametrize("kw", [{"dt": 1e-2, "scheme": "rk4"}, {"rtol": 1e-6}])
def test_complex_or_text_start_is_named_not_cast(knife, kw):
    fi, _ = knife
    y0 = fi.y0.astype(complex)
    y0[3] += 1e-3j
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no ComplexWarning on the way: the imaginary part is not dropped
        with pytest.raises(ValueError, match=r"^y0: complex values .*expected a state of 6 real numbers"):
            fi.run(0.1, y0=y0, backend="numpy", **kw)
        with pytest.raises(ValueError, match=r"^y0: expected a state of 6 real numbers .*got \['abc'"):
            fi.run(0.1, y0=["abc"] * 6, backend="numpy", **kw)
        with pytest.raises(ValueError, match=r"^y0: contains non-finite numbers .*\['p_phi'\]"):
            fi.run(0.1, y0=np.r_[fi.y0[:5], np.nan], backend="numpy", **kw)


# --- figures ---------------------------------------------------------------------------------------------


def _rolling_solution(with_dense):
    """A rolling body's run, made by hand: a ball of radius 1 whose centre of mass, 0.1 off its geometric centre,
    goes round a circle of radius 2 while the ball turns about the vertical, in liefi.rolling's 25 components.
    ``with_dense``: ``sol.sol(t)`` is the exact motion (what a dense output of the run gives between the steps)."""
    from liefi import rolling

    def state(t):
        t = np.asarray(t, dtype=float)
        c, s = np.cos(t), np.sin(t)
        R = np.zeros(t.shape + (3, 3))
        R[..., 0, 0], R[..., 0, 1], R[..., 1, 0], R[..., 1, 1], R[..., 2, 2] = c, -s, s, c, 1.0
        Y = np.concatenate([R.reshape(t.shape + (9,)), np.stack([2 * c, 2 * s], -1), rolling.attitude_state(R),
                            np.zeros(t.shape + (5,))], -1)
        return np.moveaxis(Y, -1, 0)

    t = np.linspace(0.0, 2 * np.pi, 9)  # 8 long steps: a polygon if drawn at the steps
    names = tuple(f"R{i}{j}" for i in (1, 2, 3) for j in (1, 2, 3)) + ("r_1", "r_2") + rolling.ATTITUDE_NAMES + (
        "Pi_1", "Pi_2", "Pi_3", "p_1", "p_2")
    sol = liefi.Solution(t, state(t), "rk4", t[1], t.size - 1, 4 * (t.size - 1), 0.0, names=names,
                         sol=state if with_dense else None)
    return sol, rolling.sphere(1.0, offset=(0.1, 0.0, 0.0))


def test_overview_of_a_rolling_body_draws_a_readable_selection(tmp_path):
    pytest.importorskip("matplotlib")
    import liefi.plot

    sol, _ = _rolling_solution(True)
    assert len(sol.names) == 25
    fig = liefi.plot.overview(sol)
    states = fig.axes[0]
    labels = [t.get_text() for t in states.get_legend().get_texts()]
    assert len(states.get_lines()) == len(labels) == 10 <= liefi.plot.MAX_STATES
    from liefi.plotting import label

    shown = ("r_1", "r_2", "Gamma_1", "Gamma_2", "Gamma_3", "Pi_1", "Pi_2", "Pi_3", "p_1", "p_2")
    assert labels == [label(n) for n in shown]  # not R11..R33, rho1_*, rho2_*: the attitude shows through Gamma
    assert "10 of 25" in states.get_title()
    fig.savefig(tmp_path / "rolling.png")  # lays the legend out
    box, legend = states.get_window_extent(), states.get_legend().get_window_extent()
    assert legend.height < box.height and legend.width < box.width  # the legend fits in its panel
    every = liefi.plot.states(sol, names=sol.names)  # all of them when asked
    assert len(every.get_lines()) == 25


def test_path_is_drawn_between_the_steps_from_the_dense_output():
    pytest.importorskip("matplotlib")
    import liefi.plot

    sol, _ = _rolling_solution(True)
    ax = liefi.plot.path(sol)
    xs, ys = ax.get_lines()[0].get_data()
    assert xs.size >= 16 * (sol.t.size - 1)  # not only the 9 saved states
    np.testing.assert_allclose(np.hypot(xs, ys), 2.0, rtol=1e-14)  # on the circle, not on its chords
    assert liefi.plot._max_turn(xs, ys) < 5.0  # smooth, where the 9 saved states turn by 45 degrees
    coarse, _ = _rolling_solution(False)
    with pytest.warns(UserWarning, match=r"path: drawn through the 9 saved states only.*45 degrees.*dense_output=True"):
        ax = liefi.plot.path(coarse)
    assert ax.get_lines()[0].get_data()[0].size == 9


def _gif_frames(path):
    from PIL import Image

    with Image.open(path) as im:
        assert im.format == "GIF"
        return im.n_frames, im.size


def test_animate_a_planar_body_writes_a_gif(knife, tmp_path):
    pytest.importorskip("matplotlib")
    import liefi.plot

    _, sol = knife
    out = liefi.plot.animate(sol, tmp_path / "knife.gif", frames=4, dpi=40)
    assert out == tmp_path / "knife.gif" and _gif_frames(out) == (4, (168, 168))
    with pytest.raises(ValueError, match=r"^filename: .*ending in \.gif"):
        liefi.plot.animate(sol, tmp_path / "knife.mp4", frames=4)
    with pytest.raises(ValueError, match=r"^frames: "):
        liefi.plot.animate(sol, tmp_path / "k.gif", frames=0)


def test_animate_a_rolling_body_draws_its_contact_path(tmp_path):
    pytest.importorskip("matplotlib")
    import liefi.plot
    from liefi import rolling

    sol, ball = _rolling_solution(True)
    out = liefi.plot.animate(sol, tmp_path / "ball.gif", contact=ball, frames=3, dpi=40)
    assert _gif_frames(out)[0] == 3
    # the contact point is under the geometric centre: the centre of mass minus R (0.1, 0, 0), horizontally
    P = rolling.contact_point(sol.y[9:11].T, sol.y[11:20].T, ball)
    np.testing.assert_allclose(P, sol.y[9:11].T - 0.1 * sol.y[[0, 3]].T, atol=1e-15)
    with pytest.raises(ValueError, match=r"contact: the contact point needs the components"):
        liefi.plot.animate(_named(_rolling_solution(False)[0], r_1="q"), tmp_path / "x.gif", contact=ball, frames=2)


def test_drift_of_energy_is_that_of_h_tilde(knife):
    pytest.importorskip("matplotlib")
    import liefi.plot

    _, sol = knife
    a = liefi.plot.drift(sol, invariants=["energy"]).get_lines()[0].get_ydata()
    b = liefi.plot.drift(sol, invariants=["h~"]).get_lines()[0].get_ydata()
    np.testing.assert_array_equal(a, b)
    assert len(liefi.plot.drift(sol).get_lines()) == 4  # J_1, h, h~, p_phi: energy not drawn twice


def test_a_cusp_of_the_motion_is_not_taken_for_a_corner():
    t = np.linspace(0.0, 2 * np.pi, 2001)
    cycloid_x, cycloid_y = t - np.sin(t), 1 - np.cos(t)  # a cusp at both ends: the motion stops and turns
    cusp_x, cusp_y = np.r_[cycloid_x, 2 * np.pi + cycloid_x[1:]], np.r_[cycloid_y, cycloid_y[1:]]
    import liefi.plot

    assert liefi.plot._max_turn(cusp_x, cusp_y) < 2.0
    s = np.linspace(0.0, 2 * np.pi, 9)
    assert liefi.plot._max_turn(np.cos(s), np.sin(s)) == pytest.approx(45.0)
