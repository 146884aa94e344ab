"""Results in under a second (issue 17): the reference store, the lazy reference, and kernels loaded
from the cache without numba's registry refresh.

No wall-clock assertion: what is asserted is *what* runs -- whether the DOP853 reference is solved
(``Scene.solve_reference`` counted by monkeypatching), which file is trusted, which modules a
cached kernel's load imports.
"""

import json
import os
import subprocess
import sys
import warnings

import numpy as np
import pytest

from liefi import scenes
from liefi.scenes import store
from liefi.scenes.base import Scene

ROOT = os.path.dirname(os.path.dirname(os.path.abspath(__file__)))


class _Osc(type(scenes.get("oscillator"))):
    """The oscillator with its reference solved on the numpy field (no kernel to compile in a fresh cache)."""

    def _constrained_field(self, v, backend):
        return Scene._constrained_field(self, v, "numpy")


@pytest.fixture
def store_dir(monkeypatch, tmp_path):
    """A fresh private cache directory (hence a fresh store) for this test; counts the reference solves."""
    monkeypatch.setenv("LIEFI_CACHE_DIR", str(tmp_path / "cache"))
    monkeypatch.delenv("LIEFI_REFERENCE_STORE", raising=False)
    store._WARNED.clear()
    calls = []
    solve = Scene.solve_reference

    def counted(self, *a, **k):
        calls.append(self.name)
        return solve(self, *a, **k)

    monkeypatch.setattr(Scene, "solve_reference", counted)
    return tmp_path / "cache" / store.FOLDER, calls


_KW = {"t_final": 0.5, "dt": 1e-2, "scheme": "imex-rk4", "gains": "auto", "backend": "numpy"}


def _run(scene=None, **kw):
    sc = _Osc() if scene is None else scene
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # e.g. the step at the stability limit: not what is tested here
        warnings.simplefilter("error", store.ReferenceStoreWarning)
        return sc.run(**{**_KW, **kw})


def _files(folder):
    return sorted(p for p in folder.glob("*.npz"))


def test_second_run_reads_the_reference_from_the_store(store_dir):
    folder, calls = store_dir
    first = _run()
    assert first.max_error and calls == ["oscillator"]
    assert len(_files(folder)) == 1
    second = _run()  # a new scene object: nothing kept in memory
    assert second.max_error == first.max_error
    assert calls == ["oscillator"], "the second run solved the reference again"
    assert second.reference_seconds == 0.0
    for k in first.errors:
        np.testing.assert_array_equal(second.errors[k], first.errors[k])


@pytest.mark.parametrize("change", ["parameter", "instance", "variant", "times", "tolerance"])
def test_a_changed_input_is_not_read_from_the_store(store_dir, change):
    folder, calls = store_dir
    _run().max_error
    sc, kw = _Osc(), {}
    if change == "parameter":  # the start
        sc.q0 = (1.0, 1.0 + 1e-9, 1.0)
    elif change == "instance":  # a parameter set on the object, not the class
        sc.p0 = (0.0, 0.0, 1e-12)
    elif change == "variant":
        kw["variant"] = "original"
    elif change == "times":
        kw["dt"] = 2e-2
    else:
        sc.reference_rtol = 1e-11
    _run(sc, **kw).max_error
    assert calls == ["oscillator", "oscillator"]
    assert len(_files(folder)) == 2


def test_reference_is_computed_only_when_an_error_is_asked_for(store_dir):
    folder, calls = store_dir
    r = _run()
    assert calls == [] and not _files(folder), "the reference was computed before any error was asked for"
    assert r.max_drift  # the invariants need no reference
    r.max_error
    assert calls == ["oscillator"] and r.reference_seconds > 0.0
    r.errors, r.to_dict()
    assert calls == ["oscillator"]


def test_the_cli_json_reports_the_error_from_the_store(store_dir, capsys, monkeypatch):
    from liefi import cli

    _, calls = store_dir
    sc = scenes.get("oscillator")
    monkeypatch.setattr(type(sc), "_constrained_field", _Osc._constrained_field)
    argv = ["run", "oscillator", "--t-final", "0.5", "--dt", "0.01", "--backend", "numpy", "--json"]
    outs = []
    for _ in range(2):
        sc.__dict__.pop("_refcache", None)  # as in a new process: nothing kept in memory
        assert cli.main(argv) == 0
        outs.append(json.loads(capsys.readouterr().out))
    assert outs[0]["max_error"] == outs[1]["max_error"] and outs[0]["max_error"]["x"] > 0.0
    assert outs[1]["reference_seconds"] == 0.0 and calls == ["oscillator"]


@pytest.mark.parametrize("how", ["planted", "damaged", "renamed", "unsigned"])
def test_an_untrusted_file_is_removed_and_the_reference_solved_again(store_dir, how):
    folder, calls = store_dir
    first = _run().max_error
    (path,) = _files(folder)
    blob = path.read_bytes()
    if how == "planted":  # a valid npz with other values, with the head of a signed file
        import io

        buf = io.BytesIO()
        np.savez(buf, key=np.array(path.stem), names=np.array(["x"]), v0=np.zeros(51))
        path.write_bytes(blob[: len(store.MAGIC) + 32] + buf.getvalue())
    elif how == "damaged":
        path.write_bytes(blob[:-100])
    elif how == "unsigned":  # the payload alone, as np.savez would write it
        path.write_bytes(blob[len(store.MAGIC) + 32:])
    else:  # a file signed for another key, under this key's name
        sc = _Osc()
        sc.q0 = (2.0, 1.0, 1.0)
        _run(sc).max_error
        other = next(p for p in _files(folder) if p != path)
        path.write_bytes(other.read_bytes())
        calls.pop()
    with pytest.warns(store.ReferenceStoreWarning, match="not trusted"):
        again = _Osc().run(**_KW).max_error
    assert again == first
    assert calls == ["oscillator", "oscillator"]
    assert store.load(path.stem) is not None, "the reference solved again was not stored signed"


def test_an_unwritable_store_warns_and_the_run_goes_on(store_dir, monkeypatch):
    _, calls = store_dir

    def full(name, blob, prefix=None):
        raise OSError(28, "No space left on device")

    from liefi.engine import cache

    monkeypatch.setattr(cache, "atomic_write", full)
    with pytest.warns(store.ReferenceStoreWarning, match="cannot be kept"):
        r = _Osc().run(**_KW)
        r.max_error
    assert r.max_error["x"] >= 0.0 and calls == ["oscillator"]


def test_a_store_dir_that_is_not_a_directory_warns_and_the_run_goes_on(store_dir, tmp_path):
    folder, calls = store_dir
    folder.parent.mkdir(mode=0o700)
    folder.write_text("not a folder")
    with pytest.warns(store.ReferenceStoreWarning, match="not used|cannot be created"):
        assert _Osc().run(**_KW).max_error


def test_the_store_can_be_turned_off(store_dir, monkeypatch):
    folder, calls = store_dir
    monkeypatch.setenv("LIEFI_REFERENCE_STORE", "0")
    _run().max_error
    _run().max_error
    assert calls == ["oscillator", "oscillator"] and not folder.exists()


def test_a_scene_holding_something_else_than_data_is_not_stored(store_dir):
    folder, calls = store_dir
    sc = _Osc()
    sc.hook = lambda t: t  # could change the reference in a way the key cannot see
    _run(sc).max_error
    assert calls == ["oscillator"] and not _files(folder)


def test_key_encodes_types_and_values():
    assert store._canon(1) != store._canon(1.0) != store._canon("1.0")
    assert store._canon(np.array([1.0, 2.0])) != store._canon(np.array([1.0, 2.0], np.float32))
    assert store._canon({"a": (1, 2)}) == store._canon({"a": (1, 2)})
    with pytest.raises(TypeError):
        store._canon(object())


_LOAD = r"""
import json, sys
import numpy as np
import liefi
from liefi import scenes
sc = scenes.get("suslov")
fi = sc.integrator()
one = fi.run(0.2, dt=1e-2, scheme="rk4", backend="numba")
Y = np.repeat(fi.y0[None], 2, 0)
many = liefi.FeedbackIntegrator(sc.system, Y, gains=sc.gains, configuration=False).run(0.2, dt=1e-2, scheme="rk4", backend="numba")
print(json.dumps({"one": one.y[:, -1].tolist(), "many": np.asarray(many.y)[..., -1].tolist(),
                  "backend": [one.backend, many.backend],
                  "refreshed": "numba.np.arraymath" in sys.modules}))
"""


def test_a_cached_kernel_loads_without_numba_registry_refresh(tmp_path):
    pytest.importorskip("numba")
    env = {k: v for k, v in os.environ.items() if not k.startswith(("NUMBA_", "LIEFI_"))}
    env.update(LIEFI_CACHE_DIR=str(tmp_path / "kernels"), PYTHONPATH=ROOT)
    runs = []
    for _ in range(2):
        p = subprocess.run([sys.executable, "-c", _LOAD], cwd=ROOT, env=env, capture_output=True, text=True,
                           timeout=600)
        assert p.returncode == 0, p.stderr
        runs.append(json.loads(p.stdout.strip().splitlines()[-1]))
    compiled, loaded = runs
    assert compiled["refreshed"], "the first process compiled: numba's compiler refreshes its registries"
    assert not loaded["refreshed"], "loading cached kernels imported numba's compile-time registries"
    assert loaded["backend"] == ["numba", "numba"]
    assert loaded["one"] == compiled["one"] and loaded["many"] == compiled["many"]


def test_a_result_pickles_with_its_errors(store_dir):
    import pickle

    _, calls = store_dir
    r = _run()
    back = pickle.loads(pickle.dumps(r))
    assert calls == ["oscillator"] and back.max_error == r.max_error and back.max_error["x"] >= 0.0


def test_the_step_for_a_tolerance_is_kept_in_the_store(store_dir, monkeypatch):
    from liefi import tolerance

    folder, _ = store_dir
    pilots = []
    choose = tolerance.choose_step

    def counted(*a, **k):
        pilots.append(1)
        return choose(*a, **k)

    monkeypatch.setattr(tolerance, "choose_step", counted)
    args = (None, "imex-rk4", 0.5, 1e-6, None)
    first = _Osc().step_for_tolerance(*args, gains="auto")
    second = _Osc().step_for_tolerance(*args, gains="auto")
    assert pilots == [1] and second == first and first[0] > 0.0
    third = _Osc().step_for_tolerance(None, "imex-rk4", 0.5, 1e-8, None, gains="auto")
    assert pilots == [1, 1] and third[0] < first[0]
