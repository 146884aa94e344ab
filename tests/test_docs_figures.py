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
