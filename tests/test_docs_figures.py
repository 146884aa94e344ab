"""The documentation's figures are readable where the site shows them."""

from __future__ import annotations

import importlib.util
import pathlib

import numpy as np
import pytest

ROOT = pathlib.Path(__file__).resolve().parents[1]

pytest.importorskip("matplotlib")


def _script(name):
    spec = importlib.util.spec_from_file_location(name, ROOT / "benchmarks" / f"{name}.py")
    mod = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(mod)
    return mod


def _knife_run():
    """The getting-started knife edge, on a short horizon (numpy backend)."""
    import liefi

    def constraints(q):
        return np.stack([np.sin(q[..., 2]), -np.cos(q[..., 2]), 0 * q[..., 2]], -1)

    knife = liefi.NonholonomicSystem(liefi.CotangentBundle(3, names=("x", "y", "phi")), np.eye(3), constraints,
                                     lambda q: -0.5 * q[..., 0])
    fi = liefi.FeedbackIntegrator(knife, knife.project(np.array([0, 0, 0, 0, 0, 0.5])), gains=10.0)
    return fi.run(1.0, dt=1e-2, scheme="rk4", backend="numpy")


def test_getting_started_figure_text_is_readable_in_the_text_column():
    """The overview of Getting started: its smallest text (the legends) at least 9 px high when the
    image is shown 800 px wide (it was 5.6 px: 7 pt legends in a 1518 px wide image), and the page's
    PNG is the one the script draws (its size)."""
    from PIL import Image

    gs = _script("getting_started_figure")
    fig = gs.overview_figure(_knife_run())
    assert gs.smallest_text_px(fig) >= 9.0
    png = Image.open(ROOT / "docs" / "getting-started" / "plot-overview.png")
    assert png.size[0] == round(gs.SIZE[0] * gs.DPI), png.size
    assert png.size[0] <= 1100 and (ROOT / "docs" / "getting-started" / "plot-overview.png").stat().st_size < 150_000


def _rattleback_like_result():
    """A run with the rattleback's many invariants and large, differing gains (a caption of ~330 characters)."""
    from types import SimpleNamespace

    names = ["penalty", "J_1", "J_2", "energy", "|rho1|^2", "rho1.rho2", "rho1.Gamma", "|rho2|^2", "rho2.Gamma",
             "|Gamma|^2"]
    t = np.linspace(0.0, 5.0, 50)
    gains = {k: 3.25924e10 * (1.7 + i) for i, k in enumerate(names)}
    return SimpleNamespace(scheme="imex-rk4", dt=1e-4, t_final=5.0, gains=gains, t=t, reference="numerical",
                           errors={"r_1": 1e-9 * (1 + t)}, invariants={k: 1e-16 * np.cos(t) for k in names},
                           scene="rattleback", variant="kane-levinson")


@pytest.mark.parametrize("stacked", [False, True], ids=["figure", "stacked"])
def test_scene_figure_caption_is_not_clipped(stacked):
    """The generic scene figure's title and run caption (the rattleback's: 10 gains) lie inside the
    figure, alone or stacked as ``liefi reproduce`` draws it (a subfigure); the caption was one line
    of ~330 characters, cut off at both sides of an 11-inch figure."""
    from matplotlib.backends.backend_agg import FigureCanvasAgg

    from liefi import plotting

    r = _rattleback_like_result()
    title = "Rattleback (Kane & Levinson 1982) rolling without slipping: the spin reverses"
    fig = plotting.new_figure(11, 8.0 if stacked else 4.0)
    for sub in (fig.subfigures(2, 1) if stacked else [fig]):
        plotting.generic(r, sub, title=title)
    FigureCanvasAgg(fig).draw()
    renderer = fig.canvas.get_renderer()
    captions = [t for t in fig.findobj(lambda a: hasattr(a, "get_text") and "imex-rk4" in str(a.get_text()))]
    assert len(captions) == (2 if stacked else 1)
    for t in captions:
        box = t.get_window_extent(renderer)
        assert 0 <= box.x0 and box.x1 <= fig.bbox.width, (box.x0, box.x1, fig.bbox.width)
