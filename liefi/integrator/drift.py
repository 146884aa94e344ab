"""Drift of the invariants: their scales, the largest relative residual, and the first-integral check.

Part of :mod:`liefi.integrator.stability` (which re-exports every function here): the
guard of a run (:mod:`liefi.integrator.guard`) measures with them how far a run has left
the invariant set.
"""

from __future__ import annotations

import math
from types import SimpleNamespace

import numpy as np

from ..reduction import core as _core


def drift_scales(fi, y=None, values=None):
    """The scale of each penalized invariant, for relative drifts (``{name: s}``).

    ``J_i``: ``sqrt(2 E C_ii)``, the largest ``|<P, e_i>|`` at kinetic energy
    ``E`` (so ``J_i / s`` is a cosine); energy: ``E = max(|h|, T, |U|)``; a user
    invariant: ``max(|I_0|, sqrt(E))``; the penalty: 1 (for ``||R^T R - I||``).
    ``values``: :func:`liefi.reduction.core.evaluate` at ``y`` without derivatives, when the caller has it
    (:func:`drift`: the residuals at the same states read it too).
    """
    y = fi.y0 if y is None else np.asarray(y, float)
    _, z = fi.split(y)
    # values only: no Jacobian of the data
    t = _core.evaluate(fi.system, z, derivatives=False) if values is None else values
    n = fi.system.space.data_dim
    U = np.asarray(fi.system.potential(z[..., :n]), float)
    T = np.abs(t.h - U)
    E = float(max(np.max(np.abs(t.h)), np.max(T), np.max(np.abs(U)), 1e-12))
    out = {}
    if fi.use_constraints:
        C = np.asarray(_core.gram_matrix(fi.system, z[..., :n]), float)
        d = np.diagonal(C, axis1=-2, axis2=-1).reshape(-1, fi.system.K).max(axis=0)
        for i in range(fi.system.K):
            out[f"J_{i + 1}"] = math.sqrt(2 * E * max(float(d[i]), 1e-300))
    if fi.use_energy:
        out["energy"] = E
    for u in fi.user:
        out[u.name] = max(float(np.max(np.abs(np.asarray(fi.targets[u.name], float)))), math.sqrt(E), 1e-12)
    if fi.use_penalty:
        out["penalty"] = 1.0
    return out


def drift(fi, y, scales=None, jet=None):
    """``(delta, name)``: the largest relative residual ``|I_j - I_j0| / s_j`` at ``y`` (max over a batch).

    ``s_j`` is the larger of ``scales[name]`` (e.g. :func:`drift_scales` at the
    start) and the scale at ``y`` itself (the kinetic and potential energies
    exchange along a run: a start at rest must not make every later drift huge).
    """
    y = np.asarray(y, float)
    values = None
    if jet is None:  # the data's values at y evaluated once, for the residuals and the scales at y
        values = _core.evaluate(fi.system, fi.split(y)[1], derivatives=False)
        jet = residuals(fi, y, values)
    with np.errstate(all="ignore"):
        try:
            cur = drift_scales(fi, y, values)
        except Exception:  # noqa: BLE001 -- non-finite states: the start scales only
            cur = {}
    scales = {k: max((v for v in ((scales or {}).get(k, 0.0), cur.get(k, 0.0)) if np.isfinite(v)), default=0.0)
              or 1.0 for k in set(cur) | set(scales or {})}
    best, who = 0.0, ""
    for j, nm in enumerate(jet.names):
        v = float(np.max(np.abs(jet.residual[..., j]), initial=0.0)) / scales.get(nm, 1.0)
        if not v <= best:  # also catches nan
            best, who = v, nm
    if fi.use_penalty:
        P = fi.system.space.group.penalty(y[..., : fi.nc])
        v = float(np.max(2 * np.sqrt(np.maximum(P, 0.0)), initial=0.0))
        if not v <= best:
            best, who = v, "penalty"
    return best, who


def residuals(fi, y, values=None):
    """The penalized invariants' names and residuals ``I_j(y) - I_j0`` at ``y``, values only.

    The residuals of :meth:`liefi.FeedbackIntegrator.invariant_gradients` (same terms,
    :meth:`~liefi.FeedbackIntegrator.invariant_terms`) without differentiating the data.  Returns a
    namespace with ``names`` and ``residual`` (``(..., m)``), as the jet's.  ``values``: as
    :func:`drift_scales`'s.
    """
    _, z = fi.split(y)
    t = _core.evaluate(fi.system, z, derivatives=False) if values is None else values
    terms = fi.invariant_terms(z, t, fi.parameters())
    batch = y.shape[:-1]
    r = np.zeros(batch + (len(terms),))
    for j, term in enumerate(terms):
        r[..., j] = np.broadcast_to(term[1], batch)
    return SimpleNamespace(names=tuple(term[0] for term in terms), residual=r)


def first_integral_defect(fi, y, rtol=1e-6):
    """A warning text if a penalized invariant is not conserved by the extended field at ``y``, else ``""``.

    Assumption A1 of the theory: ``grad I_j . X = 0``.  A user invariant that is
    not a first integral (e.g. ``L_z`` once the metric is not isotropic) makes
    the feedback fight the dynamics: the run then drifts whatever the gains.

    Evaluated on the constraint set (``y`` projected onto ``{J = 0}`` at fixed
    ``x``, :func:`liefi.reduction.project`): a first integral of the constrained
    motion (the knife edge's ``p_phi``) is one of the extended field only there
    (off it its rate is ``O(J)``), so a state off the set would be a false alarm.
    """
    try:
        with np.errstate(all="ignore"):
            y = np.asarray(y, float)
            if fi.system.K:
                g, z = fi.split(y)
                y = np.concatenate([g, _core.project(fi.system, z)], -1)
            jet = fi.invariant_gradients(y)
            X = fi.unforced_vector_field(y)
            dI = np.einsum("...mn,...n->...m", jet.grad, X)
            scale = np.linalg.norm(jet.grad, axis=-1) * np.linalg.norm(X, axis=-1)[..., None]
            rel = np.abs(dI) / np.maximum(scale, 1e-300)
            rel = rel.reshape(-1, len(jet.names)).max(axis=0) if jet.names else rel
    except Exception:  # noqa: BLE001 -- a diagnostic only
        return ""
    bad = [(nm, float(r)) for nm, r in zip(jet.names, np.atleast_1d(rel)) if r > rtol]
    if not bad:
        return ""
    what = ", ".join(f"{nm} (relative dI/dt = {r:.2g})" for nm, r in bad)
    return (f"liefi: invariants: {what} not conserved by the extended field on the constraint set (at the "
            "start): V is not a first "
            "integral (assumption A1), so the feedback fights the dynamics and the run drifts whatever the "
            "gains; check that the invariant belongs to this system.")
