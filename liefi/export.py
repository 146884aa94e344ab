"""Exports of a :class:`~liefi.schemes.Solution`: a pandas ``DataFrame`` and an xarray ``Dataset``.

``Solution.to_dataframe()`` and ``Solution.to_xarray()`` call these.  pandas and
xarray are optional (``pip install liefi[export]``) and imported only here, when
an export is asked for.  The invariants come from the integrator that made the
run (``solution.integrator``, set by :meth:`liefi.FeedbackIntegrator.run`):
:meth:`~liefi.FeedbackIntegrator.invariant_values` at every saved state, with
the integrator's targets (``J_i``: 0; the energy and user invariants: their
value at ``y0`` unless given) as attributes.
"""

from __future__ import annotations

import numpy as np


def _need(module, what):
    import importlib

    try:
        return importlib.import_module(module)
    except ImportError:
        raise ImportError(
            f"{what} needs {module}, which is not installed; install the export extra: "
            "pip install 'liefi[export]' (pandas and xarray)"
        ) from None


def _names(sol):
    n = sol.y.shape[-2]
    names = tuple(sol.names)
    return names if len(names) == n else tuple(f"y{i}" for i in range(n))


def invariant_series(sol):
    """``{name: array (..., n_t)}``: the monitored invariants along the run (needs ``sol.integrator``)."""
    fi = getattr(sol, "integrator", None)
    if fi is None:
        raise ValueError("invariants: this solution does not know its integrator (solution.integrator is None); "
                         "pass invariants=False, or set solution.integrator = fi")
    if sol.y.shape[-2] != fi.n:
        raise ValueError(f"invariants: the solution has {sol.y.shape[-2]} components, its integrator {fi.n}")
    with np.errstate(all="ignore"):
        vals = fi.invariant_values(np.moveaxis(sol.y, -1, 0))  # time-major: an ensemble's members last
    return {k: np.broadcast_to(np.moveaxis(np.asarray(v, dtype=float), 0, -1) if np.ndim(v) else v,
                               sol.y.shape[:-2] + sol.t.shape) for k, v in vals.items()}


def invariant_targets(sol):
    """``{name: target}`` of the monitored invariants: the integrator's targets, else the value at the start."""
    fi = sol.integrator
    series = invariant_series(sol)
    out = {}
    for k, v in series.items():
        if k in fi.targets:
            out[k] = float(fi.targets[k])
        elif k == "penalty" or k.startswith("J_"):
            out[k] = 0.0
        else:
            out[k] = float(np.mean(v[..., 0]))
    return out


def to_dataframe(sol, *, invariants=False):
    """See :meth:`liefi.schemes.Solution.to_dataframe`."""
    pd = _need("pandas", "Solution.to_dataframe()")
    names = _names(sol)
    batch = sol.y.shape[:-2]
    cols = {nm: sol.y[..., i, :] for i, nm in enumerate(names)}
    if invariants:
        cols.update({k: v for k, v in invariant_series(sol).items() if k not in cols})
    t = np.asarray(sol.t, dtype=float)
    if not batch:
        return pd.DataFrame({k: np.asarray(v) for k, v in cols.items()}, index=pd.Index(t, name="t"))
    m = int(np.prod(batch))
    index = pd.MultiIndex.from_product([np.arange(m), t], names=["member", "t"])
    return pd.DataFrame({k: np.asarray(v).reshape(m * t.size) for k, v in cols.items()}, index=index)


def to_xarray(sol, *, invariants=True):
    """See :meth:`liefi.schemes.Solution.to_xarray`."""
    xr = _need("xarray", "Solution.to_xarray()")
    names = _names(sol)
    batch = sol.y.shape[:-2]
    t = np.asarray(sol.t, dtype=float)
    if batch:
        m = int(np.prod(batch))
        dims = ("member", "t")
        shape = (m, t.size)
        coords = {"t": t, "member": np.arange(m)}
    else:
        dims, shape, coords = ("t",), (t.size,), {"t": t}
    data = {nm: (dims, sol.y[..., i, :].reshape(shape), {"kind": "state", "index": i}) for i, nm in enumerate(names)}
    if invariants and getattr(sol, "integrator", None) is not None:
        targets = invariant_targets(sol)
        for k, v in invariant_series(sol).items():
            if k not in data:
                data[k] = (dims, np.asarray(v).reshape(shape), {"kind": "invariant", "target": targets[k]})
    attrs = {"scheme": str(sol.scheme), "dt": float(sol.dt), "steps": int(sol.steps), "status": int(sol.status),
             "message": str(sol.message), "state_names": ",".join(names)}
    if batch:
        attrs["batch_shape"] = ",".join(str(b) for b in batch)
    ds = xr.Dataset(data, coords=coords, attrs=attrs)
    ds["t"].attrs["long_name"] = "time"
    return ds
