"""Exports of a :class:`~liefi.schemes.Solution`: a pandas ``DataFrame`` and an xarray ``Dataset``.

``Solution.to_dataframe()`` and ``Solution.to_xarray()`` call these.  pandas and
xarray are optional (``pip install liefi[export]``) and imported only here, when
an export is asked for.  The invariants come from the integrator that made the
run (``solution.integrator``, set by :meth:`liefi.FeedbackIntegrator.run`):
:meth:`~liefi.FeedbackIntegrator.invariant_values` at every saved state, with
the integrator's targets (``J_i``: 0; the energy and user invariants: their
value at ``y0`` unless given) as attributes.

One column (variable) per quantity, under its own name:

* the penalized ``energy`` is ``h~`` (or ``h`` with ``energy="original"``), so it
  is not repeated; the dataset's attribute ``energy`` names it;
* a name that is taken is not hidden but suffixed: an invariant named as a
  component (``h``, ``J_1`` ...) becomes ``h_invariant``, a component named as
  the index or a coordinate (``t``, ``member``) ``t_state``; the variable's
  attribute ``name`` (xarray) and the attribute ``renamed`` (``"h->h_invariant"``)
  say so;
* two components of the same name are refused (their columns could not be told apart);
* an ensemble's per-member targets are an array attribute (one per member, flat);
* in the ``Dataset`` the characters of a name outside Latin-1 (``θ``), which a
  netCDF3 file (``engine="scipy"``) cannot hold in a variable's name, are
  written as Python escapes (``\\u03b8``), so the dataset round-trips; the
  attribute ``name`` keeps the name as given (the ``DataFrame`` keeps it too).
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
    """The components' names, refused when two are the same (one column per component)."""
    n = sol.y.shape[-2]
    names = tuple(sol.names)
    names = names if len(names) == n else tuple(f"y{i}" for i in range(n))
    twice = sorted({nm for nm in names if names.count(nm) > 1})
    if twice:
        where = "; ".join(f"{nm!r} at {[i for i, m in enumerate(names) if m == nm]}" for nm in twice)
        raise ValueError(f"names: the components' names repeat ({where}), so their columns cannot be told apart; "
                         "give the system's coordinates distinct names, or export the states as an array (sol.y)")
    return names


def energy_name(fi):
    """The quantity that the invariant ``energy`` of ``fi`` is: ``"h~"`` (``energy="extended"``) or ``"h"``."""
    return "h~" if getattr(fi, "energy", "extended") == "extended" else "h"


def invariant_series(sol):
    """``{name: array (..., n_t)}``: the monitored invariants along the run (needs ``sol.integrator``).

    One entry per quantity: ``energy`` (the penalized energy) is ``h~`` or ``h``
    (:func:`energy_name`), so it is not repeated under its own name.
    """
    fi = getattr(sol, "integrator", None)
    if fi is None:
        raise ValueError("invariants: this solution does not know its integrator (solution.integrator is None); "
                         "pass invariants=False, or set solution.integrator = fi")
    if sol.y.shape[-2] != fi.n:
        raise ValueError(f"invariants: the solution has {sol.y.shape[-2]} components, its integrator {fi.n}")
    with np.errstate(all="ignore"):
        vals = fi.invariant_values(np.moveaxis(sol.y, -1, 0))  # time-major: an ensemble's members last
    if energy_name(fi) in vals:
        vals.pop("energy", None)
    return {k: np.broadcast_to(np.moveaxis(np.asarray(v, dtype=float), 0, -1) if np.ndim(v) else v,
                               sol.y.shape[:-2] + sol.t.shape) for k, v in vals.items()}


def invariant_targets(sol):
    """``{name: target}`` of the monitored invariants (keys of :func:`invariant_series`).

    The integrator's targets (``energy``'s is that of :func:`energy_name`), else
    ``0`` for ``J_i`` and the penalty, else the value at the start.  A target
    is a float, or for an ensemble whose members have their own targets an
    array of the batch's shape.
    """
    fi = sol.integrator
    series = invariant_series(sol)
    given = dict(fi.targets)
    if "energy" in given:
        given.setdefault(energy_name(fi), given.pop("energy"))
    out = {}
    for k, v in series.items():
        if k in given:
            x = np.asarray(given[k], dtype=float)
        elif k == "penalty" or k.startswith("J_"):
            x = np.zeros(())
        else:
            x = np.asarray(v[..., 0], dtype=float)
        out[k] = float(x.flat[0]) if x.size == 1 or np.all(x == x.flat[0]) else np.array(x, dtype=float)
    return out


def _columns(sol, invariants, reserved, spelled=str):
    """``[(key, name, kind, values (..., n_t))]``: the states, then the invariants, one per quantity.

    ``key`` is the column's name: the quantity's ``name`` (as ``spelled``), with ``_state`` added
    to a component named as one of ``reserved`` (the index or the coordinates)
    and ``_invariant`` to an invariant named as a component, so that nothing is
    hidden; every renaming is recorded by the caller.  An invariant that *is*
    the component of its name (equal values: the knife edge's ``p_phi``) is one
    column, the component's.
    """
    names = _names(sol)
    taken = set(reserved)
    cols = []

    def key(name, suffix):
        k = spelled(name)
        while k in taken:
            k = f"{k}_{suffix}"
        taken.add(k)
        return k

    for i, nm in enumerate(names):
        cols.append((key(nm, "state"), nm, "state", sol.y[..., i, :]))
    if invariants:
        for k, v in invariant_series(sol).items():
            if k in names and np.array_equal(v, sol.y[..., names.index(k), :]):
                continue  # a component that is also monitored (the knife edge's p_phi): one quantity
            cols.append((key(k, "invariant"), k, "invariant", v))
    return cols


def _netcdf_name(name):
    """``name`` with the characters netCDF3 cannot hold in a name (outside Latin-1) written as ``\\uXXXX``."""
    return "".join(c if ord(c) < 256 else c.encode("ascii", "backslashreplace").decode() for c in name)


def _renamed(cols):
    """``"name->key,..."`` of the columns exported under another name than their quantity's, or ``""``."""
    return ",".join(f"{nm}->{k}" for k, nm, _, _ in cols if k != nm)


def to_dataframe(sol, *, invariants=False):
    """See :meth:`liefi.schemes.Solution.to_dataframe`."""
    pd = _need("pandas", "Solution.to_dataframe()")
    batch = sol.y.shape[:-2]
    cols = _columns(sol, invariants, ("t", "member") if batch else ("t",))
    t = np.asarray(sol.t, dtype=float)
    if not batch:
        df = pd.DataFrame({k: np.asarray(v) for k, _, _, v in cols}, index=pd.Index(t, name="t"))
    else:
        m = int(np.prod(batch))
        index = pd.MultiIndex.from_product([np.arange(m), t], names=["member", "t"])
        df = pd.DataFrame({k: np.asarray(v).reshape(m * t.size) for k, _, _, v in cols}, index=index)
    if _renamed(cols):
        df.attrs["renamed"] = _renamed(cols)
    return df


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
    invariants = invariants and getattr(sol, "integrator", None) is not None
    cols = _columns(sol, invariants, tuple(coords), _netcdf_name)
    targets = invariant_targets(sol) if invariants else {}
    data = {}
    for i, (k, nm, kind, v) in enumerate(cols):
        attrs = {"kind": kind, "index": i} if kind == "state" else {"kind": kind}
        if nm in targets and (kind == "invariant" or nm not in {c[1] for c in cols if c[2] == "invariant"}):
            tg = targets[nm]  # also of a component that is monitored; per member: an array over the flat members
            attrs["target"] = tg if np.ndim(tg) == 0 else np.asarray(tg).reshape(-1)
        if k != nm:
            attrs["name"] = nm
        data[k] = (dims, np.asarray(v).reshape(shape), attrs)
    attrs = {"scheme": str(sol.scheme), "dt": float(sol.dt), "steps": int(sol.steps), "status": int(sol.status),
             "message": str(sol.message), "state_names": ",".join(names)}
    if invariants:
        attrs["energy"] = energy_name(sol.integrator)
    if _renamed(cols):
        attrs["renamed"] = _renamed(cols)
    if batch:
        attrs["batch_shape"] = ",".join(str(b) for b in batch)
    ds = xr.Dataset(data, coords=coords, attrs=attrs)
    ds["t"].attrs["long_name"] = "time"
    return ds
