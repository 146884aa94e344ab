r"""Reverse mode (the discrete adjoint) of a fixed-step run: ``w . dy / d(y0, theta)`` for one cotangent ``w``.

For a scalar loss ``L`` of the saved states, ``W[:, t] = dL / dy(t_t)`` (shape ``(n, n_t)``), :func:`vjp`
gives ``dL / dy0`` and ``dL / dtheta`` (the system's parameters, :mod:`liefi.integrator.sensitivity`) at
the cost of one run that keeps its states and one backward sweep, whatever the number of parameters;
forward mode costs about one to two runs per parameter (docs/gradients.md, "Reverse mode").

The run is ``y_{s+1} = Phi(y_s; p, theta)``, ``p`` the feedback parameters with the targets taken at the
start (``p = p(y0, theta)``).  The adjoint recursion is

.. math:: \lambda_N = W_N, \qquad \lambda_s = W_s + \partial_y\Phi(y_s)^T \lambda_{s+1}, \qquad
          \bar p = \sum_s \partial_p\Phi(y_s)^T \lambda_{s+1}, \quad
          \bar\theta = \sum_s \partial_\theta\Phi(y_s)^T \lambda_{s+1},

(``W_s = 0`` at steps not saved), then ``dL/dy0 = lambda_0 + (d p / d y0)^T pbar`` and
``dL/dtheta = thetabar + (d p / d theta)^T pbar`` through the targets that follow the start.  One
backward step of a split scheme (the tableau ``(A, b)`` on ``X``, then the feedback step ``F``):
``zbar = dF(y_*)^T lambda``; ``kbar_i = dt b_i zbar``; for ``i`` from the last stage down,
``Ybar_i = dX(Y_i)^T kbar_i``, ``ybar += Ybar_i``, ``kbar_j += dt a_ij Ybar_i`` (``j < i``); then
``lambda_s = ybar``.  The transposed products are generated from the same trace as the forward
tangents, by reverse accumulation over the graph (:func:`liefi.integrator._tangent_loop.vjp_graph`),
and printed as scalar code: the step's nodes are recomputed from the kept state ``y_s``.
"""

from __future__ import annotations

import numpy as np

from . import _tangent_loop as tl
from . import sensitivity as _sens

__all__ = ["vjp"]


def _source(f_vjp, g_vjp, f, tab, n, size, P, split):
    """Source of ``adjoint_forward(y0, p, c, dt, n_steps, Yall)`` and
    ``adjoint_backward(Yall, p, c, dt, n_steps, W, wsteps, out)`` (``out``: ``lambda_0, pbar, cbar``)."""
    I1, I2, I3 = "    ", "        ", "            "
    coeff = tl._coeff_source(tab)

    def stage_inputs(i, L, ind):
        coeffs = [(l, a) for l, a in enumerate(tab.A[i][:i]) if a]
        if not coeffs:
            return "y"
        for r in range(n):
            L.append(f"{ind}yi{i}_{r} = y_{r} + " + " + ".join(f"c{i}_{l} * k{l}_{r}" for l, _ in coeffs))
        return f"yi{i}"

    def primal_stages(L, ind, refs):
        for i in range(tab.stages):
            ys = stage_inputs(i, L, ind)
            ref = {}
            lines, outs = tl.emit_plain(f, lambda nm, idx, ys=ys: f"{ys}_{idx}" if nm == "y" else f"{nm}_{idx}",
                                        f"f{i}", ind, ref)
            L += lines
            L += [f"{ind}k{i}_{r} = {outs[r]}" for r in range(n)]
            refs.append((ys, ref))
        for r in range(n):
            L.append(f"{ind}z_{r} = y_{r} + " + tl._update_terms(tab, lambda l: f"k{l}_{r}"))

    L = ["@njit(cache=CACHE, error_model='numpy')", "def adjoint_forward(y0, p, c, dt, n_steps, Yall):"]
    L += [f"{I1}y_{r} = y0[{r}]" for r in range(n)] + [f"{I1}p_{q} = p[{q}]" for q in range(size)]
    L += [f"{I1}c_{q} = c[{q}]" for q in range(P)] + coeff
    L += [f"{I1}Yall[{r}, 0] = y_{r}" for r in range(n)] + [f"{I1}for step in range(1, n_steps + 1):"]
    primal_stages(L, I2, [])
    if split:
        lines, outs = tl.emit_plain(g_vjp[1], lambda nm, idx: f"z_{idx}" if nm == "y" else
                                    ("dt" if nm == "hh" else f"{nm}_{idx}"), "g", I2)
        L += lines + [f"{I2}y_{r} = {outs[r]}" for r in range(n)]
    else:
        L += [f"{I2}y_{r} = z_{r}" for r in range(n)]
    L += [f"{I2}Yall[{r}, step] = y_{r}" for r in range(n)] + [f"{I1}return 0", "", ""]

    L += ["@njit(cache=CACHE, error_model='numpy')", "def adjoint_backward(Yall, p, c, dt, n_steps, W, wsteps, out):"]
    L += [f"{I1}p_{q} = p[{q}]" for q in range(size)] + [f"{I1}c_{q} = c[{q}]" for q in range(P)] + coeff
    L += [f"{I1}l_{r} = 0.0" for r in range(n)] + [f"{I1}pb_{q} = 0.0" for q in range(size)]
    L += [f"{I1}cb_{q} = 0.0" for q in range(P)]
    L += [f"{I1}js = wsteps.size - 1", f"{I1}for step in range(n_steps, 0, -1):",
          f"{I2}if js >= 0 and wsteps[js] == step:"]
    L += [f"{I3}l_{r} += W[{r}, js]" for r in range(n)] + [f"{I3}js -= 1"]
    L += [f"{I2}y_{r} = Yall[{r}, step - 1]" for r in range(n)]
    refs = []
    primal_stages(L, I2, refs)
    if split:
        gv, _ = g_vjp
        lines, outs = tl.emit_plain(gv, lambda nm, idx: f"z_{idx}" if nm == "y" else
                                    ("dt" if nm == "hh" else (f"l_{idx}" if nm == "lam" else f"{nm}_{idx}")), "g", I2)
        L += lines
        L += [f"{I2}zb_{r} = {outs[r]}" for r in range(n)]
        L += [f"{I2}pb_{q} += {outs[n + q]}" for q in range(size)]
        L += [f"{I2}cb_{q} += {outs[n + size + q]}" for q in range(P)]
    else:
        L += [f"{I2}zb_{r} = l_{r}" for r in range(n)]
    L += [f"{I2}yb_{r} = zb_{r}" for r in range(n)]
    for i in range(tab.stages):
        bi = tab.b[i]
        L += [f"{I2}kb{i}_{r} = {(f'(dt * {float(bi)!r}) * zb_{r}') if bi else '0.0'}" for r in range(n)]
    for i in reversed(range(tab.stages)):
        ys, ref = refs[i]
        lines, outs = tl.emit_plain(f_vjp, lambda nm, idx, ys=ys, i=i: f"{ys}_{idx}" if nm == "y" else
                                    (f"kb{i}_{idx}" if nm == "lam" else f"{nm}_{idx}"), f"f{i}", I2, ref)
        L += lines
        L += [f"{I2}Yb_{r} = {outs[r]}" for r in range(n)]
        L += [f"{I2}pb_{q} += {outs[n + q]}" for q in range(size)]
        L += [f"{I2}cb_{q} += {outs[n + size + q]}" for q in range(P)]
        L += [f"{I2}yb_{r} += Yb_{r}" for r in range(n)]
        for l, a in enumerate(tab.A[i][:i]):
            if a:
                L += [f"{I2}kb{l}_{r} += c{i}_{l} * Yb_{r}" for r in range(n)]
    L += [f"{I2}l_{r} = yb_{r}" for r in range(n)]
    L += [f"{I1}if js >= 0 and wsteps[js] == 0:"] + [f"{I2}l_{r} += W[{r}, js]" for r in range(n)]
    L += [f"{I1}out[{r}] = l_{r}" for r in range(n)] + [f"{I1}out[{n + q}] = pb_{q}" for q in range(size)]
    L += [f"{I1}out[{n + size + q}] = cb_{q}" for q in range(P)] + [f"{I1}return 0"]
    return "\n".join(L) + "\n"


def adjoint_kernel(fi, sch, *, engine="numba"):
    """The generated forward (states kept) and backward loops of :func:`vjp` for ``fi`` and scheme ``sch``."""
    from ..engine.trace import TRACED_DATA, traced_call
    from ..schemes.split import feedback_step

    n, size, P = fi.n, fi.parameter_layout.size, _sens._constants(fi.system).size
    split = sch.kind == "split"
    tab = sch.explicit if split else sch

    def make(tr):
        y, p, c = tr.symbols("y", n), tr.symbols("p", size), tr.symbols("c", P)
        lam = tr.symbols("lam", n)
        inputs = [*y, *p, *c]
        field = fi.unforced_vector_field if split else fi.vector_field
        with _sens._SwappedConstants(fi.system, c):
            f = [tl.as_sym(v) for v in np.asarray(traced_call("the field", field, y, p, data=TRACED_DATA),
                                                    dtype=object).reshape(-1)]
            g_vjp = None
            if split:
                h = tr.symbols("hh", 1)[0]
                g = [tl.as_sym(v) for v in np.asarray(traced_call("the feedback step", feedback_step, fi, y, h, p,
                                                                  data=TRACED_DATA), dtype=object).reshape(-1)]
                g_vjp = (tl.vjp_graph(g, inputs, list(lam)), g)
        f_vjp = tl.vjp_graph(f, inputs, list(lam))
        return _source(f_vjp, g_vjp, f, tab, n, size, P, split), size, "adjoint", 0

    return _sens._kept(fi, ("adjoint", sch.name), engine, make)


def vjp(fi, sch, y0, dt, n_steps, saved_steps, W, *, engine="python", schedule=None):
    """``(dL/dy0, dL/dtheta)`` for the cotangents ``W`` (``(n, n_t)``, ``dL/dy`` at ``saved_steps``).

    Arguments as :func:`liefi.integrator.sensitivity.tangents` (``fi`` holding the run's gains,
    ``schedule`` an adaptive run's updates); ``theta`` the system's parameters in the order of
    :func:`~liefi.integrator.sensitivity.parameter_names`.  It equals
    ``sum_t S_t^T W[:, t]`` of the forward tangents, at the cost of two runs and a backward sweep
    whatever the number of parameters.  ``engine="numba"`` compiles the loops.
    """
    if isinstance(sch, str):
        from ..schemes import registry

        sch = registry.get(sch)
    y0 = np.ascontiguousarray(y0, dtype=float)
    n = fi.n
    c = np.ascontiguousarray(_sens._constants(fi.system), dtype=float)
    P = c.size
    saved_steps = np.asarray(saved_steps, dtype=np.int64)
    W = np.asarray(W, float)
    if W.shape != (n, saved_steps.size):
        raise ValueError(f"W: expected dL/dy at the saved steps, shape (n, n_t) = ({n}, {saved_steps.size}), got "
                         f"{W.shape}")
    if np.any(np.diff(saved_steps) <= 0) or (saved_steps.size and (saved_steps[0] < 0 or saved_steps[-1] > n_steps)):
        raise ValueError(f"saved_steps: expected increasing steps in 0..{n_steps}, got {saved_steps.tolist()}")
    if schedule is None:
        schedule = [(0, fi.parameters())]
    schedule = [(int(a), np.ascontiguousarray(q, dtype=float)) for a, q in schedule]
    size = schedule[0][1].size
    mod = adjoint_kernel(fi, sch, engine=engine).kernel.module
    buf = np.empty(size + size * (n + P))
    _sens.targets_kernel(fi).kernel.module.ptargets(y0, schedule[0][1], c, buf)
    p_at, Jp = buf[:size], buf[size:].reshape(size, n + P)
    follow = np.abs(p_at - schedule[0][1]) <= 1e-14 * np.maximum(1.0, np.abs(schedule[0][1]))
    segments, y = [], y0
    with np.errstate(all="ignore"):
        for i, (a, q) in enumerate(schedule):  # forward: the states of every step, segment by segment
            b = schedule[i + 1][0] if i + 1 < len(schedule) else int(n_steps)
            if b <= a:
                continue
            Yall = np.empty((n, b - a + 1))
            mod.adjoint_forward(y, q, c, float(dt), b - a, Yall)
            segments.append((a, b, q, Yall))
            y = np.ascontiguousarray(Yall[:, -1])
        lam, pbar, cbar = np.zeros(n), np.zeros(size), np.zeros(P)
        out = np.empty(n + size + P)
        for a, b, q, Yall in reversed(segments):  # backward: lambda carried across the segments
            inside = (saved_steps > a) & (saved_steps <= b)
            Ws = W[:, inside].copy()
            Ws[:, -1:] += lam[:, None] if inside.any() and saved_steps[inside][-1] == b else 0.0
            ws = saved_steps[inside] - a
            if not (inside.any() and saved_steps[inside][-1] == b):  # the carried adjoint enters at the end
                Ws = np.concatenate([Ws, lam[:, None]], 1)
                ws = np.r_[ws, b - a]
            mod.adjoint_backward(Yall, q, c, float(dt), b - a, np.ascontiguousarray(Ws), ws.astype(np.int64), out)
            lam, pbar, cbar = out[:n].copy(), pbar + out[n:n + size], cbar + out[n + size:]
    lam = lam + (W[:, saved_steps == 0].sum(1) if np.any(saved_steps == 0) and segments else 0.0)
    pb = pbar * follow
    return lam + Jp[:, :n].T @ pb, cbar + Jp[:, n:].T @ pb
