"""The figure of ``docs/getting-started.md``: ``liefi.plot.overview`` of the page's knife-edge run.

The page's own python blocks run, in order, up to the one that draws the overview (so the
figure is the page's ``run``), and the overview is drawn at the size the page shows it:
about 1000 px wide, with labels and legends of at least 10 pt, so that they stay readable
when the site scales the image to its text column (about 800 px).  Run from the repository
root (matplotlib needed)::

    python benchmarks/getting_started_figure.py      # writes docs/getting-started/plot-overview.png
"""

from __future__ import annotations

import argparse
import contextlib
import io
import pathlib
import re
import sys

ROOT = pathlib.Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

PAGE = ROOT / "docs" / "getting-started.md"
OUT = ROOT / "docs" / "getting-started" / "plot-overview.png"

#: the figure's size (inches) and resolution: 10.5 x 3.7 in at 96 dpi, 1008 x 355 px
SIZE, DPI = (10.5, 3.7), 96
#: font sizes (points) of the tick labels, axis labels and titles, and of the legends
FONT, LEGEND = 11, 10
#: the width (px) of the site's text column, at which the image is seen
COLUMN_PX = 800


def page_run(page=PAGE):
    """The ``run`` of the page: its python blocks executed in order up to the overview's."""
    text = page.read_text()
    ns = {"__name__": "getting_started_figure"}
    with contextlib.redirect_stdout(io.StringIO()):  # the page's prints
        for m in re.finditer(r"```python\n(.*?)\n```", text, re.S):
            code = m.group(1)
            last = "liefi.plot.overview(run)" in code
            if last:
                code = code.split("fig = liefi.plot.overview(run)")[0]
            exec(compile(code, str(page), "exec"), ns)  # noqa: S102 -- the docs' own code
            if last:
                return ns["run"]
    raise ValueError(f"{page}: no block draws liefi.plot.overview(run)")


def overview_figure(run):
    """``liefi.plot.overview(run)`` at the page's size, its text at :data:`FONT` / :data:`LEGEND` points."""
    import liefi.plot
    from liefi import plotting

    fig = plotting.new_figure(*SIZE)
    fig.set_dpi(DPI)
    liefi.plot.overview(run, fig=fig)
    for ax in fig.axes:
        ax.tick_params(labelsize=FONT)
        for item in (ax.title, ax.xaxis.label, ax.yaxis.label):
            item.set_fontsize(FONT)
        legend = ax.get_legend()
        if legend is not None:
            for t in legend.get_texts():
                t.set_fontsize(LEGEND)
    return fig


def smallest_text_px(fig, column_px=COLUMN_PX):
    """The height (px) of the figure's smallest text when the image is shown ``column_px`` wide."""
    width_px = fig.get_figwidth() * fig.dpi
    scale = min(1.0, column_px / width_px)
    sizes = [t.get_fontsize() for t in fig.findobj(lambda a: hasattr(a, "get_fontsize") and hasattr(a, "get_text"))
             if t.get_visible() and t.get_text()]
    return min(sizes) * fig.dpi / 72 * scale


def main(argv=None):
    p = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    p.add_argument("--out", default=str(OUT))
    args = p.parse_args(argv)
    fig = overview_figure(page_run())
    fig.savefig(args.out, dpi=DPI)
    size = pathlib.Path(args.out).stat().st_size
    print(f"{args.out}: {size / 1024:.0f} kB, smallest text {smallest_text_px(fig):.1f} px at {COLUMN_PX} px wide")


if __name__ == "__main__":
    main()
