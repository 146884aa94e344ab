r"""A peer for gradients: liefi's discrete sensitivities against JAX + diffrax, on the Chaplygin ball.

Run (from the repository root)::

    python benchmarks/gradient_peer.py                                   # liefi's side only, a note for JAX
    LIEFI_JAX_PYTHON=JAXENV/bin/python python benchmarks/gradient_peer.py  # both sides
    python benchmarks/gradient_peer.py --jax-python JAXENV/bin/python --t-final 5 --reps 3

where ``JAXENV`` is a virtual environment of its own with ``pip install jax jaxlib diffrax``
(JAX is not a dependency of liefi and nothing in ``liefi/`` imports it).  The JAX side runs in
that interpreter, in a subprocess (this file with ``--jax-side``, which imports only numpy and
JAX); without it the benchmark says so and prints liefi's side alone.

**The run.**  liefi's scene ``chaplygin-ball`` (``m = 1, a = 1, I = (0.3, 0.4, 0.5)``, its tilted
start ``R0``), started with the spin ``Omega0``.  The loss is a fit of the attitude to samples:

.. math:: L(\Omega_0) = \tfrac12 \sum_i |\Gamma(t_i; \Omega_0) - \hat\Gamma_i|^2, \qquad t_i = i\,\Delta t_s,

``Gamma = R^T e_3`` the vertical in the body, ``hat Gamma_i`` the reference trajectory from
another spin ``Omega0 + (0.05, -0.03, 0.02)``; the gradient ``dL / dOmega0`` (three numbers).

* **liefi**: the whole ball on ``SO(3) x R^2`` (25 states, the no-slip rows held by feedback), the
  split scheme ``imex-rk4`` at fixed ``dt`` with the scene's gains; the gradient from three
  forward tangents (:func:`liefi.integrator.sensitivity.tangents`, compiled, ``engine="numba"``)
  along ``d y0 / d Omega0`` (``rolling_start`` is linear in ``Omega``), then
  ``sum_i (Gamma_i - hat Gamma_i) . S_i``.
* **JAX/diffrax**: the eliminated equations (the oracle of ``liefi.scenes.chaplygin_ball``),
  an unconstrained ODE in ``(M, Gamma)``:

  .. math:: \dot M = M \times \Omega, \quad \dot\Gamma = \Gamma \times \Omega, \quad
            \Omega = (I + m a^2 (|\Gamma|^2 1 - \Gamma\Gamma^T))^{-1} M,

  ``M0 = I Omega0 + m a^2 Gamma0 x (Omega0 x Gamma0)``; ``diffrax.diffeqsolve`` with ``Tsit5``
  (diffrax's recommended general solver) or ``Dopri8`` and a ``PIDController``, the default
  adjoint ``RecursiveCheckpointAdjoint`` (reverse mode through the solver's steps, exact for
  the discrete solution), float64, the loss and its gradient under one ``jax.jit(jax.value_and_grad)``.

**Timing.**  CPU seconds (``time.process_time``) of one call returning the loss and the gradient:
*first* (trace and compile included: JAX's jit, liefi's tangent kernel -- numba's disk cache
serves it after the first process ever) and *repeated* (best of ``--reps``).

**Accuracy.**  Against a reference gradient: the complex step ``Im L(Omega0 + i h e_k) / h``
(``h = 1e-30``) of the same ODE in ``(M, Gamma)`` solved by scipy's DOP853 at ``rtol = atol =
1e-13`` (complex-safe numpy, the step sequence held by the real part): exact to the
solver's tolerance.  Each side's error is that of its trajectory (liefi: its step ``dt``; diffrax:
its tolerance), not of the differentiation -- both differentiate their own discrete solution exactly.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
import time

import numpy as np

HERE = os.path.dirname(os.path.abspath(__file__))

#: the perturbation of the spin that made the samples (the loss is not at its minimum)
DATA_SHIFT = np.array([0.05, -0.03, 0.02])


# --- the eliminated equations in (M, Gamma): numpy (complex-safe), for the reference ---------------------
def rates(inertia, ma2):
    """``fun(t, y)``, ``y = (M, Gamma)``: Chaplygin's equations without the attitude and the path."""
    I = np.diag(np.asarray(inertia, float))

    def fun(t, y):
        M, G = y[:3], y[3:6]
        W = np.linalg.solve(I + ma2 * (np.dot(G, G) * np.eye(3) - np.outer(G, G)), M)
        return np.concatenate([np.cross(M, W), np.cross(G, W)])

    return fun


def start(inertia, ma2, G0, W0):
    """``(M0, Gamma0)``: the contact point's angular momentum at the spin ``W0``."""
    return np.concatenate([np.asarray(inertia) * W0 + ma2 * np.cross(G0, np.cross(W0, G0)), G0])


def reference(case, W0, rtol=1e-13):
    """``Gamma(t_i)`` ``(n_t, 3)`` by DOP853 at ``rtol`` (complex ``W0`` gives the complex step)."""
    from scipy.integrate import solve_ivp

    ts = np.asarray(case["ts"])
    y0 = start(case["inertia"], case["ma2"], np.asarray(case["G0"]), W0)
    sol = solve_ivp(rates(case["inertia"], case["ma2"]), (0.0, ts[-1]), y0, method="DOP853", rtol=rtol,
                    atol=rtol, t_eval=ts)
    return sol.y[3:6].T


def loss_of(G, Ghat):
    return 0.5 * float(np.sum(np.abs(G - Ghat) ** 2)) if not np.iscomplexobj(G) else 0.5 * np.sum((G - Ghat) ** 2)


def reference_gradient(case, h=1e-30):
    """``(L, dL/dOmega0)`` by the complex step of the tight reference."""
    W0, Ghat = np.asarray(case["W0"]), np.asarray(case["Ghat"])
    L = loss_of(reference(case, W0), Ghat)
    g = np.array([np.imag(loss_of(reference(case, W0 + 1j * h * e), Ghat)) / h for e in np.eye(3)])
    return L, g


# --- the JAX side (runs in the JAX interpreter: numpy and JAX only) ---------------------------------------
def jax_side(path):
    """Read the case from ``path`` (JSON), time ``jit(value_and_grad(loss))`` per setting, print JSON rows."""
    import jax

    jax.config.update("jax_enable_x64", True)
    import diffrax
    import jax.numpy as jnp

    with open(path) as fh:
        case = json.load(fh)
    inertia, ma2 = jnp.asarray(case["inertia"]), case["ma2"]
    G0, W0, Ghat, ts = (jnp.asarray(case[k]) for k in ("G0", "W0", "Ghat", "ts"))
    Id = jnp.diag(inertia)

    def field(t, y, args):
        M, G = y[:3], y[3:6]
        W = jnp.linalg.solve(Id + ma2 * (jnp.dot(G, G) * jnp.eye(3) - jnp.outer(G, G)), M)
        return jnp.concatenate([jnp.cross(M, W), jnp.cross(G, W)])

    term = diffrax.ODETerm(field)
    rows = []
    for solver_name, rtol in case["jax_settings"]:
        solver = {"Tsit5": diffrax.Tsit5(), "Dopri8": diffrax.Dopri8(), "Dopri5": diffrax.Dopri5()}[solver_name]

        def loss(W, solver=solver, rtol=rtol):
            y0 = jnp.concatenate([inertia * W + ma2 * jnp.cross(G0, jnp.cross(W, G0)), G0])
            sol = diffrax.diffeqsolve(term, solver, t0=0.0, t1=ts[-1], dt0=1e-3, y0=y0,
                                      saveat=diffrax.SaveAt(ts=ts),
                                      stepsize_controller=diffrax.PIDController(rtol=rtol, atol=rtol),
                                      adjoint=diffrax.RecursiveCheckpointAdjoint(), max_steps=1_000_000)
            return 0.5 * jnp.sum((sol.ys[:, 3:6] - Ghat) ** 2), sol.stats["num_steps"]

        f = jax.jit(jax.value_and_grad(loss, has_aux=True))
        t0 = time.process_time()
        (L, steps), g = f(W0)
        g = np.asarray(jax.block_until_ready(g))
        first = time.process_time() - t0
        best = np.inf
        for _ in range(case["reps"]):
            t0 = time.process_time()
            (L, steps), g = f(W0)
            g = np.asarray(jax.block_until_ready(g))
            best = min(best, time.process_time() - t0)
        rows.append(dict(side="JAX/diffrax", setting=f"{solver_name}, rtol = atol = {rtol:g}", steps=int(steps),
                         first=first, repeated=best, loss=float(L), grad=[float(x) for x in g]))
    print(json.dumps(dict(rows=rows, versions=dict(jax=jax.__version__, diffrax=diffrax.__version__))))


# --- liefi's side -------------------------------------------------------------------------------------------
def liefi_rows(case, dts, reps, engine):
    """liefi's gradient at each step ``dt``: rows as the JAX side's."""
    sys.path.insert(0, os.path.join(HERE, ".."))
    from liefi.integrator.sensitivity import tangents
    from liefi.systems.rolling import rolling_start

    fi, R0 = case["_fi"], case["_R0"]
    W0, Ghat, ts = np.asarray(case["W0"]), np.asarray(case["Ghat"]), np.asarray(case["ts"])
    y0 = rolling_start(fi.system, R0, W0)
    V = np.stack([rolling_start(fi.system, R0, W0 + e) - y0 for e in np.eye(3)])  # linear in Omega: exact
    rows = []
    for dt in dts:
        n_steps = int(round(ts[-1] / dt))
        every = int(round((ts[1] - ts[0]) / dt))
        saved = np.arange(ts.size) * every

        def grad():
            Y, S = tangents(fi, "imex-rk4", y0, dt, n_steps, saved, V, engine=engine)
            r = Y[17:20].T - Ghat  # Gamma = y[17:20] (R, x, y, rho_1, rho_2, Gamma, Pi, p)
            return 0.5 * float(np.sum(r**2)), np.einsum("ti,kit->k", r, S[:, 17:20, :]), Y

        t0 = time.process_time()
        L, g, Y = grad()
        first = time.process_time() - t0
        best = np.inf
        for _ in range(reps):
            t0 = time.process_time()
            L, g, Y = grad()
            best = min(best, time.process_time() - t0)
        J = fi.invariant_values(Y.T)
        drift = max(float(np.max(np.abs(J[k]))) for k in J if k.startswith("J_"))
        rows.append(dict(side="liefi", setting=f"imex-rk4, dt = {dt:g} ({engine})", steps=n_steps, first=first,
                         repeated=best, loss=L, grad=[float(x) for x in g], drift=drift))
    return rows


def run_jax(python, case, reps, settings):
    """The JAX side's rows from the interpreter ``python``, or ``(None, why)``."""
    if not python:
        return None, ("JAX/diffrax side skipped: no JAX interpreter given (set LIEFI_JAX_PYTHON or --jax-python to "
                      "the python of a virtual environment with jax, jaxlib and diffrax)")
    if not os.path.exists(python):
        return None, f"JAX/diffrax side skipped: the interpreter {python!r} does not exist"
    data = {k: (v.tolist() if isinstance(v, np.ndarray) else v) for k, v in case.items() if not k.startswith("_")}
    data.update(reps=reps, jax_settings=settings)
    with tempfile.NamedTemporaryFile("w", suffix=".json", delete=False) as fh:
        json.dump(data, fh)
    try:
        out = subprocess.run([python, os.path.abspath(__file__), "--jax-side", fh.name], capture_output=True,
                             text=True, env=dict(os.environ, JAX_PLATFORMS="cpu"))
    finally:
        os.unlink(fh.name)
    if out.returncode != 0:
        tail = out.stderr.strip().splitlines()[-1:] or ["(no message)"]
        return None, f"JAX/diffrax side skipped: {python} failed ({tail[0]})"
    return json.loads(out.stdout.strip().splitlines()[-1]), None


def make_case(t_final, sample):
    sys.path.insert(0, os.path.join(HERE, ".."))
    import liefi
    from liefi.groups import SO3
    from liefi.scenes import get

    sc = get("chaplygin-ball")
    fi = sc.integrator(gains=sc.gains)
    R0 = SO3().exp(sc.R0_axis)
    y0 = np.asarray(fi.y0)
    case = dict(inertia=np.asarray(sc.inertia, float), ma2=sc.mass * sc.radius**2, G0=y0[17:20],
                W0=np.asarray(sc.Omega0, float), ts=np.linspace(0.0, t_final, int(round(t_final / sample)) + 1),
                _fi=fi, _R0=R0, _liefi=liefi)
    case["Ghat"] = reference(case, case["W0"] + DATA_SHIFT)
    return case


def table(rows, ref_grad, ref_loss):
    lines = ["| side | setting | steps | first (s CPU) | repeated (s CPU) | loss rel. error | gradient rel. error |",
             "|---|---|---|---|---|---|---|"]
    for r in rows:
        eg = np.max(np.abs(np.asarray(r["grad"]) - ref_grad)) / np.max(np.abs(ref_grad))
        el = abs(r["loss"] - ref_loss) / abs(ref_loss)
        lines.append(f"| {r['side']} | {r['setting']} | {r['steps']} | {r['first']:.3g} | {r['repeated']:.3g} | "
                     f"{el:.1e} | {eg:.1e} |")
    return "\n".join(lines)


def main(argv=None):
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--jax-side", metavar="CASE.json", help=argparse.SUPPRESS)
    ap.add_argument("--jax-python", default=os.environ.get("LIEFI_JAX_PYTHON"),
                    help="the python of an environment with jax and diffrax (default: $LIEFI_JAX_PYTHON)")
    ap.add_argument("--t-final", type=float, default=10.0)
    ap.add_argument("--sample", type=float, default=0.1, help="spacing of the samples of Gamma")
    ap.add_argument("--dts", type=float, nargs="+", default=[1e-2, 1e-3])
    ap.add_argument("--rtols", type=float, nargs="+", default=[1e-6, 1e-8, 1e-10])
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("--engine", default="numba", choices=["numba", "python"])
    args = ap.parse_args(argv)
    if args.jax_side:
        return jax_side(args.jax_side)
    sys.path.insert(0, HERE)
    from _machine import cpu_model

    case = make_case(args.t_final, args.sample)
    for dt in args.dts:
        if abs(args.sample / dt - round(args.sample / dt)) > 1e-9:
            ap.error(f"--dts: each step must divide --sample ({args.sample:g}); {dt:g} does not")
    t0 = time.process_time()
    ref_loss, ref_grad = reference_gradient(case)
    print(f"reference: complex step of DOP853 at 1e-13 on (M, Gamma), {time.process_time() - t0:.1f} s CPU; "
          f"L = {ref_loss:.12g}, dL/dOmega0 = {np.array2string(ref_grad, precision=10)}")
    settings = [("Tsit5", r) for r in args.rtols] + [("Dopri8", min(args.rtols))]
    jax, why = run_jax(args.jax_python, case, args.reps, settings)
    rows = liefi_rows(case, args.dts, args.reps, args.engine)
    print(f"Chaplygin ball, T = {args.t_final:g}, {len(case['ts'])} samples of Gamma, dL/dOmega0; CPU: {cpu_model()}")
    if jax is None:
        print(why)
    else:
        rows = jax["rows"] + rows
        print(f"jax {jax['versions']['jax']}, diffrax {jax['versions']['diffrax']} (CPU, float64)")
    print(table(rows, ref_grad, ref_loss))
    for r in rows:
        if "drift" in r:
            print(f"liefi {r['setting']}: largest no-slip constraint |J| along the run {r['drift']:.1e}")
    return rows


if __name__ == "__main__":
    main()
