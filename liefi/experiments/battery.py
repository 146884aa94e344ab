"""The extreme-case battery of the stability machinery, and the stiff work-precision study.

:func:`run_battery` runs every scene through the cases of :data:`BATTERY_CASES`
(tiny and huge gains, automatic gains, long horizons, a mass ratio of 1e6,
large momenta, starts off the invariant set, steps at and past the limit) and
the scene's own cases (``Scene.stability_cases``), and says for each whether
the run was refused, stopped, warned or silently drifted.
:func:`stiff_work_precision` compares the explicit schemes, the split
``imex-*`` schemes and implicit ``solve_ivp`` on one scene.
"""

from __future__ import annotations

import math
import time
import warnings
from dataclasses import dataclass, field

import numpy as np

from .._progress import Progress
from ..schemes import IntegrationError
from ..schemes import split as _stiff
from ..integrator.stability import (
    GUARD_DRIFT,
    LiefiStabilityWarning,
    StabilityError,
    _fmt_gains,
    drift,
    drift_scales,
    estimate,
)

# --------------------------------------------------------------------------------
# the extreme-case battery
# --------------------------------------------------------------------------------


@dataclass
class BatteryResult:
    """One case of :func:`run_battery`.

    ``outcome``: ``"ok"``, ``"ok (warned)"``, ``"refused"`` (a ``ValueError``
    before the run), ``"stopped"`` (:class:`StabilityError` or
    :class:`~liefi.schemes.IntegrationError` at the moment it failed, with
    ``t_fail``), or the failures the battery exists to catch: ``"SILENT DRIFT"``
    (a result returned with drift above 1 % of scale and no warning) and
    ``"CRASH"`` (any other exception).  Drifts are ``max_t |I(t) - I_0|`` over
    the constraint momenta (``drift_J``), the penalized energy (``drift_E``) and
    the other invariants (``drift_other``), against the targets (for a start off
    the invariant set: over the second half of the run); ``error`` is the max
    error against the exact solution where the scene has one.
    """

    scene: str
    case: str
    outcome: str
    drift_J: float = math.nan
    drift_E: float = math.nan
    drift_other: float = math.nan
    rel_drift: float = math.nan
    error: float = math.nan
    cpu: float = math.nan
    t_fail: float = math.nan
    note: str = ""

    def row(self):
        def f(x):
            return "-" if not isinstance(x, float) or not math.isfinite(x) else f"{x:.2g}"

        note = self.note.replace("|", "/")
        if len(note) > 160:
            note = note[:157] + "..."
        return (f"| {self.scene} | {self.case} | {self.outcome} | {f(self.drift_J)} | {f(self.drift_E)} | "
                f"{f(self.drift_other)} | {f(self.error)} | {f(self.cpu)} | {note} |")


BATTERY_HEADER = (
    "| scene | case | outcome | drift J | drift energy | drift other | error | cpu s | note |\n"
    "| --- | --- | --- | --- | --- | --- | --- | --- | --- |"
)

#: The cases of :func:`run_battery` (scene-specific ones are added for ``roller-racer`` and ``heisenberg``).
BATTERY_CASES = (
    "paper", "k=1e-2", "k=1", "k=1e2", "k=1e4", "k=1e6", "k=1e6 imex-euler", "auto",
    "horizon 1e4 auto", "mass ratio 1e6", "mass ratio 1e6 auto", "momenta x1e3", "momenta x1e3 auto",
    "off-set 0.1", "off-set 1", "dt at limit", "dt 1.1x limit",
)
def battery_table(results):
    """The markdown table of a list of :class:`BatteryResult`."""
    return BATTERY_HEADER + "\n" + "\n".join(r.row() for r in results)


def _with_mass_ratio(sc, ratio):
    """A copy of scene ``sc`` whose metric is ``S m S``, ``S = diag(sqrt(logspace(0, log10 ratio, D)))``.

    The constraint set, the potential, the vector potential (every other datum:
    :meth:`liefi.NonholonomicSystem.with_scaled_metric`) and the start are
    unchanged; the mass (inertia) ratio spans ``ratio``.  The copy has no reference solution.
    """
    import copy

    sys = sc.system
    D = sys.space.D
    S = np.diag(np.sqrt(np.logspace(0.0, math.log10(ratio), D)))
    n = sys.space.n
    nc = sys.space.group.config_dim
    x0 = np.asarray(sc.initial_state(sc.variant()), float)[nc : nc + n]
    # every datum kept (constraints, potential, vector potential, derivatives): only the metric changes
    new = sys.with_scaled_metric(S, sample=x0 if n else None)
    sc2 = copy.copy(sc)
    sc2.__dict__ = dict(sc.__dict__)
    sc2.__dict__["system"] = new
    sc2.__dict__.pop("_refcache", None)
    return sc2


def _battery_case(task):
    """Run one ``(scene name, case, quick, backend)``; never raises (module level for process pools)."""
    name, case, quick, backend = task
    from .. import scenes as _scenes

    try:
        sc = _scenes.get(name)
        return _battery_run_case(sc, case, quick, backend)
    except Exception as exc:  # noqa: BLE001 -- the battery reports, it does not stop
        return BatteryResult(name, case, "CRASH", note=f"{type(exc).__name__}: {exc}")


def _battery_run_case(sc, case, quick, backend):

    v = sc.variant(sc.stability_variant)
    T = min(float(sc.t_final), 2.0 if quick else 10.0)
    dt = float(sc.dt)
    scheme = sc.scheme
    gains = None
    y_start = None
    off = None
    scene = sc
    has_ref = sc.reference == "exact"
    if case == "paper":
        pass
    elif case.startswith("k=") and case.endswith("imex-euler"):
        gains, scheme = float(case[2:].split()[0]), "imex-euler"
    elif case.startswith("k="):
        gains = float(case[2:])
    elif case == "auto":
        gains = "auto"
    elif case == "horizon 1e4 auto":
        gains, T = "auto", (100.0 if quick else 1e4)
    elif case.startswith("mass ratio"):
        scene = _with_mass_ratio(sc, 1e6)
        has_ref = False
        gains = "auto" if case.endswith("auto") else None
    elif case.startswith("momenta x1e3"):
        full = np.array(sc.initial_state(v), float)
        nc = sc.system.space.group.config_dim
        full[nc + sc.system.space.n :] *= 1e3
        y_start = full
        has_ref = False
        gains = "auto" if case.endswith("auto") else None
    elif case.startswith("off-set"):
        off = float(case.split()[1])
    elif case.removesuffix(" auto") in sc.stability_cases:
        scene, v, has_ref = sc.stability_case(case.removesuffix(" auto"))
        gains = "auto" if case.endswith(" auto") else None
    elif case.startswith("dt"):
        pass
    else:
        raise ValueError(f"case: unknown battery case {case!r}")

    fi = scene.integrator(v, gains=gains, y0=y_start)
    if case.startswith("dt"):
        est = estimate(fi, dt, scheme, t_final=T, resolution=False)
        dt = est.dt_safe * (1.1 if "1.1x" in case else 1.0)
    if off is not None:
        jet = fi.invariant_gradients(fi.y0)
        rng = np.random.default_rng(0)
        u = np.einsum("m,mn->n", rng.normal(size=len(jet.names)), jet.grad)
        u = u / np.linalg.norm(u)
        y_start = fi.y0 + off * u
    n = max(1, int(round(T / dt)))
    T = n * dt
    bk = "numpy" if _stiff.is_split_scheme(scheme) else backend
    caught = []
    t0 = time.process_time()
    try:
        with warnings.catch_warnings(record=True) as w:
            warnings.simplefilter("always", LiefiStabilityWarning)
            sol = fi.run(T, dt=dt, scheme=scheme, y0=y_start if off is not None else None,
                         save_every=max(1, n // 4000), backend=bk)
            caught = [str(x.message) for x in w if issubclass(x.category, LiefiStabilityWarning)]
    except StabilityError as exc:
        return BatteryResult(sc.name, case, "stopped", cpu=time.process_time() - t0, t_fail=exc.t,
                             note=f"StabilityError at t={exc.t:.4g}: {exc}")
    except IntegrationError as exc:
        return BatteryResult(sc.name, case, "stopped", cpu=time.process_time() - t0, t_fail=exc.t,
                             note=f"IntegrationError at t={exc.t:.4g}: {exc}")
    except ValueError as exc:
        return BatteryResult(sc.name, case, "refused", cpu=time.process_time() - t0, note=f"ValueError: {exc}")
    cpu = time.process_time() - t0
    Y = np.moveaxis(sol.y, -1, 0)
    t = sol.t
    keep = t >= (0.5 * T if off is not None else -1.0)
    with np.errstate(all="ignore"):
        jet = fi.invariant_gradients(Y)
        res = np.abs(jet.residual)
        scales = drift_scales(fi)
        cur = drift_scales(fi, Y[keep])
        scales = {k: max(scales.get(k, 0.0), cur.get(k, 0.0)) or 1.0 for k in cur}
        dJ = [j for j, nm in enumerate(jet.names) if nm.startswith("J_")]
        dE = [j for j, nm in enumerate(jet.names) if nm == "energy"]
        dO = [j for j, nm in enumerate(jet.names) if not nm.startswith("J_") and nm != "energy"]

        def mx(idx):
            return float(np.max(res[keep][..., idx])) if idx else math.nan

        rel = max(
            (float(np.max(res[keep][..., j])) / scales.get(nm, 1.0) for j, nm in enumerate(jet.names)), default=0.0
        )
        other = mx(dO)
        if fi.use_penalty:
            P = fi.system.space.group.penalty(Y[keep][..., : fi.nc])
            orth = float(np.max(2 * np.sqrt(np.maximum(P, 0))))
            other = orth if not math.isfinite(other) else max(other, orth)
            rel = max(rel, orth)
        err = math.nan
        if has_ref and y_start is None:
            ref = scene.exact(t, v)
            errs = [np.max(np.abs(Y[:, fi.names.index(k)] - ref[k])) for k in scene.error_variables
                    if k in fi.names and k in ref]
            err = float(max(errs)) if errs else math.nan
    notes = []
    returning = None
    if off is not None:
        d_all = np.array([drift(fi, Y[i], scales)[0] for i in range(len(t))])
        d0 = d_all[0]
        back = np.nonzero(d_all <= 1e-3 * d0)[0]
        returning = d_all[-1] <= 0.1 * d0
        notes.append(f"start drift {d0:.3g} x scale, end {d_all[-1]:.3g}; " + (
            f"back to 1e-3 of it by t = {t[back[0]]:.3g}" if back.size else "not back to 1e-3 of it within the run"))
    if isinstance(gains, str) and sol.stability.gain_history:
        g0, g1 = sol.stability.gains, sol.stability.final_gains
        notes.append("auto gains " + _fmt_gains(g0) + (f" -> {_fmt_gains(g1)}" if g1 != g0 else ""))
    if case.startswith("dt"):
        notes.append(f"dt = {dt:.4g}")
    if caught:
        notes.append("warned: " + caught[0][6:])
    outcome = "ok (warned)" if caught else "ok"
    if not (rel <= GUARD_DRIFT):
        if returning:
            outcome = "returning"
        else:
            outcome = "drift (warned)" if caught else "SILENT DRIFT"
    return BatteryResult(sc.name, case, outcome, mx(dJ), mx(dE), other, rel, err, cpu, note="; ".join(notes))


def run_battery(scenes=None, cases=None, *, quick=False, backend="auto", executor=None):
    """Run the extreme cases on every scene; returns a list of :class:`BatteryResult`.

    Cases (:data:`BATTERY_CASES`, plus each scene's ``stability_cases``): the paper's
    settings; every gain equal to ``1e-2 ... 1e6`` with the scene's scheme and
    step (and ``1e6`` with ``imex-euler``); ``gains="auto"``; a horizon of ``1e4``
    with automatic gains; the metric scaled to a mass/inertia ratio of ``1e6``;
    momenta ``1e3`` times the paper's; starts at distance ``0.1`` and ``1`` off the
    invariant set (along the invariants' gradients; the note says how fast the
    drift returns); the roller racer where ``d1 cos(phi) + d2 = 0`` and the
    Heisenberg system at ``|q| ~ 1e3``; ``dt`` at the estimated limit and 10 %
    past it.  Other runs last ``min(t_final, 10)`` (``quick``: 2, horizon 100).

    ``executor``: any ``concurrent.futures.Executor`` (cases run as
    ``executor.map``); default serial.
    """
    from .. import scenes as _scenes

    names = list(_scenes.names() if scenes is None else scenes)
    tasks = []
    for nm in names:
        cs = list(BATTERY_CASES if cases is None else cases)
        if cases is None:
            sc = _scenes.get(nm)
            cs += [c + suffix for c in sc.stability_cases for suffix in ("", " auto")]
        tasks += [(nm, c, bool(quick), backend) for c in cs]
    mapper = map if executor is None else executor.map
    out = []
    with Progress(len(tasks), "battery", unit="case") as bar:
        for r in mapper(_battery_case, tasks):
            out.append(r)
            bar.update()
    return out


# --------------------------------------------------------------------------------
# work-precision of the stiff-safe schemes next to the explicit ones
# --------------------------------------------------------------------------------

#: ``(label, scheme, gains)`` compared by :func:`stiff_work_precision`.
WP_METHODS = (
    ("euler, k=1000", "euler", 1000.0),
    ("euler, auto", "euler", "auto"),
    ("heun, auto", "heun", "auto"),
    ("rk4, auto", "rk4", "auto"),
    ("imex-euler, k=1000", "imex-euler", 1000.0),
    ("imex-euler, k=1e6", "imex-euler", 1e6),
    ("imex-rk4, k=1000", "imex-rk4", 1000.0),
    ("imex-rk4, k=1e6", "imex-rk4", 1e6),
)


def stiff_work_precision(scene, *, t_final=5.0, dts=(2e-2, 1e-2, 5e-3, 2e-3, 1e-3),
                         rtols=(1e-4, 1e-6, 1e-8), methods=WP_METHODS, ivp=("Radau", "BDF"), ivp_gains=1000.0):
    """Error, drift and CPU time of explicit, split and implicit (``solve_ivp``) runs of a scene.

    Every run is on the numpy path (the same field evaluation for all), so the
    CPU times compare the schemes, not the backends.  Returns a list of dicts
    (``label``, ``scheme``, ``dt`` or ``rtol``, ``outcome``, ``error``, ``drift``, ``cpu``).
    """
    from .. import scenes as _scenes

    sc = _scenes.get(scene) if isinstance(scene, str) else scene
    rows = []
    for label, scheme, gains in methods:
        for dt in dts:
            row = {"label": label, "scheme": scheme, "dt": dt, "rtol": None}
            try:
                with warnings.catch_warnings():
                    warnings.simplefilter("ignore", LiefiStabilityWarning)
                    r = sc.run(dt=dt, t_final=t_final, scheme=scheme, gains=gains)
                row.update(outcome="ok", error=max(r.max_error.values(), default=math.nan),
                           drift=max(r.max_drift.values(), default=math.nan), cpu=r.cpu_seconds)
            except (ValueError, IntegrationError) as exc:
                row.update(outcome=type(exc).__name__, error=math.nan, drift=math.nan, cpu=math.nan,
                           message=str(exc)[:200])
            rows.append(row)
    for method in ivp:
        for rtol in rtols:
            row = {"label": f"scipy:{method}, k={ivp_gains:g}", "scheme": f"scipy:{method}", "dt": None, "rtol": rtol}
            try:
                r = sc.run(t_final=t_final, scheme=f"scipy:{method}", gains=ivp_gains, rtol=rtol, atol=rtol * 1e-2)
                row.update(outcome="ok", error=max(r.max_error.values(), default=math.nan),
                           drift=max(r.max_drift.values(), default=math.nan), cpu=r.cpu_seconds)
            except Exception as exc:  # noqa: BLE001 -- report, do not stop
                row.update(outcome=type(exc).__name__, error=math.nan, drift=math.nan, cpu=math.nan,
                           message=str(exc)[:200])
            rows.append(row)
    return rows


def plot_work_precision(rows, path=None, title=""):
    """Two panels: max error and max invariant drift against CPU seconds, one line per method."""
    import matplotlib

    if path is not None:
        matplotlib.use("Agg", force=False)
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 2, figsize=(10, 4.2))
    labels = list(dict.fromkeys(r["label"] for r in rows))
    for i, lab in enumerate(labels):
        rs = [r for r in rows if r["label"] == lab and r["outcome"] == "ok"]
        if not rs:
            continue
        style = "--" if lab.startswith("imex") else (":" if lab.startswith("scipy") else "-")
        for ax, key in zip(axes, ("error", "drift")):
            ax.loglog([r["cpu"] for r in rs], [max(r[key], 1e-17) for r in rs], style, marker="o", ms=3,
                      label=lab, color=f"C{i % 10}")
    for ax, key in zip(axes, ("max error against the exact solution", "max invariant drift")):
        ax.set_xlabel("CPU seconds")
        ax.set_ylabel(key)
        ax.grid(True, which="both", alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.suptitle(title, fontsize=10)
    fig.tight_layout()
    if path is not None:
        from .._files import replacing

        with replacing(path) as tmp:  # whole or not at all
            fig.savefig(tmp, dpi=110)
        plt.close(fig)
    return fig


# --------------------------------------------------------------------------------
# ``liefi stability SCENE``