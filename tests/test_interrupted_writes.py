"""An interrupt (Ctrl-C, SIGTERM) in the middle of writing an output leaves no half-written file.

Every output of ``liefi run --out``, ``reproduce`` and ``bench`` (figures, CSV, ``summary.json``, the long-horizon
curves' ``.npz``) is written whole or not at all (:func:`liefi._files.replacing`): the interrupt is simulated
inside the writer (deterministic, no timing), after part of the file is written.  The file as it was before
stays (or none), and no temporary file is left behind; a later write works.
"""

from __future__ import annotations

import csv
import os

import numpy as np
import pytest


def _half_then_interrupt(path, *args, **kwargs):
    """A writer cut short: part of the bytes in ``path``, then Ctrl-C."""
    with open(path, "wb") as fh:
        fh.write(b"\x89PNG half")
    raise KeyboardInterrupt


def _figure():
    pytest.importorskip("matplotlib")
    from matplotlib.figure import Figure

    fig = Figure()
    fig.add_subplot().plot([0, 1], [1, 0])
    return fig


def _save_figure(path, monkeypatch, cut):
    from liefi.results import scene_figures

    fig = _figure()
    if cut:
        monkeypatch.setattr(fig, "savefig", _half_then_interrupt)
    scene_figures.save(fig, str(path))


def _write_csv(path, monkeypatch, cut):
    from liefi.bench.core import write_csv

    if cut:
        real = csv.DictWriter.writerow

        def writerow(self, row):
            real(self, row)
            self.writerow = None  # the second row is never written
            raise KeyboardInterrupt

        monkeypatch.setattr(csv.DictWriter, "writerow", writerow)
    write_csv([{"scene": "a", "status": "ok"}, {"scene": "b", "status": "ok"}], str(path))


def _save_curves(path, monkeypatch, cut):
    from liefi.bench import plots

    if cut:
        monkeypatch.setattr(np, "savez_compressed", _half_then_interrupt)
    plots.save_curves({"FI": (np.arange(3.0), {"h": np.ones(3)}, 0.1, "FI", "rk4")}, str(path))


def _write_summary(path, monkeypatch, cut):
    from liefi import _json
    from liefi.reproduce import Output

    if cut:
        def dumps(*a, **k):
            raise KeyboardInterrupt

        monkeypatch.setattr(_json, "dumps", dumps)
    out = Output(str(path.parent), command="bench")
    out._atomic(path.name, lambda f: (f.write('{"half": '), f.write(_json.dumps({"runs": 2})), f.write("}")))


@pytest.mark.parametrize("write, name", [(_save_figure, "fig.png"), (_write_csv, "rows.csv"),
                                         (_save_curves, "curves.npz"), (_write_summary, "summary.json")])
def test_an_interrupt_while_writing_leaves_the_old_file_whole_and_no_temporary(tmp_path, monkeypatch, write, name):
    path = tmp_path / name
    old = b"the previous, complete file"
    path.write_bytes(old)
    with monkeypatch.context() as m, pytest.raises(KeyboardInterrupt):
        write(path, m, cut=True)
    assert path.read_bytes() == old  # before: the file cut to its first bytes
    assert sorted(os.listdir(tmp_path)) == [name]  # no temporary file left
    write(path, monkeypatch, cut=False)  # and the next write replaces it
    assert path.read_bytes() != old and path.stat().st_size > 0
    assert sorted(os.listdir(tmp_path)) == [name]
    assert oct(path.stat().st_mode & 0o777) == oct(0o666 & ~_umask())  # the usual mode, not mkstemp's 0600


def _umask():
    m = os.umask(0)
    os.umask(m)
    return m
