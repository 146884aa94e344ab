"""The user's gains and targets, parsed and checked: one parser for the API's ``gains=`` and the CLI's ``--gains``.

Part of :mod:`liefi.integrator.feedback` (which re-exports every function here).  A gain
or a target is a number, or for an ensemble one number per member (an array of
the ensemble's shape ``y0.shape[:-1]``, :func:`per_member`).
"""

from __future__ import annotations

import numpy as np


def gain_number(v, what="the gain"):
    """A finite non-negative gain: ``float(v)``, or a float array for gains that differ between members.

    A ``ValueError`` naming it otherwise (a bool is not a number).  An array
    (one gain per member of an ensemble) is checked entry by entry; its shape is
    checked against the batch by :class:`FeedbackIntegrator`.
    """
    if isinstance(v, (bool, np.bool_)):
        raise ValueError(f"gains: {what} must be a number (or gains='auto'), got {v!r} (a bool is not a gain)")
    if np.ndim(v) and not isinstance(v, str):
        try:
            x = np.array(v, dtype=float)
        except (TypeError, ValueError):
            raise ValueError(f"gains: {what} must be a number or an array of numbers (one per member), "
                             f"got {v!r}") from None
        if np.asarray(v).dtype == bool or not np.all(np.isfinite(x)) or np.any(x < 0):
            raise ValueError(f"gains: {what} must hold finite non-negative numbers, got {v!r}")
        return x
    try:
        x = float(v)
    except (TypeError, ValueError):
        raise ValueError(f"gains: {what} must be a number (or gains='auto'), got {v!r}") from None
    if not np.isfinite(x) or x < 0:
        raise ValueError(f"gains: {what} must be a finite non-negative number, got {v!r}")
    return x


def parse_gains(gains, names, *, defaults=None):
    """The one gain parser (the API's ``gains=`` and the CLI's ``--gains``) -> ``{name: k}`` over ``names``, or ``"auto"``.

    ``gains`` is a number (every gain), ``"auto"``, a dict ``{name: k}``
    (``"constraints"`` sets every ``J_i``), or text: ``"K"``, ``"K1,K2,..."``
    (in the order of ``names``), ``"name=K,..."``.  A dict or ``name=K`` text
    sets the named gains over ``defaults`` (``{name: k}``; without them every
    gain must be given).
    """
    names = tuple(names)
    order = ",".join(names) or "(none)"
    Js = [n for n in names if n.startswith("J_")]

    def named(pairs):
        out = dict(defaults or {})
        for k, v in pairs:
            if k == "constraints":
                out.update({n: gain_number(v, "the gain of 'constraints'") for n in Js})
            elif k in names:
                out[k] = gain_number(v, f"the gain of {k!r}")
            else:
                raise ValueError(f"gains: unknown name {k!r}; the gains are {order}")
        missing = [k for k in names if k not in out]
        if missing:
            raise ValueError(f"gains: no gain given for {missing} (the gains are {order})")
        return {k: out[k] for k in names}

    if isinstance(gains, str):
        text = gains.strip()
        if text == "auto":
            return "auto"
        parts = [p.strip() for p in text.split(",")]
        if not text or any(not p for p in parts):
            raise ValueError(f"gains: empty entry in {gains!r}; give K, K1,K2,... (order {order}) or name=K,...")
        if all("=" in p for p in parts):
            return named(tuple(x.strip() for x in p.split("=", 1)) for p in parts)
        if any("=" in p for p in parts):
            raise ValueError(f"gains: mix of name=K and plain numbers in {gains!r}; use one form")
        if len(parts) == 1:
            k = gain_number(parts[0], f"the gain {parts[0]!r} (order {order})")
            return {n: k for n in names}
        if len(parts) != len(names):
            raise ValueError(f"gains: expected 1 or {len(names)} gains in the order {order}, got {len(parts)}")
        return {n: gain_number(p, f"the gain of {n!r}") for n, p in zip(names, parts)}
    if isinstance(gains, dict):
        return named(gains.items())
    if np.ndim(gains) == 0:
        k = gain_number(gains)
        return {n: k for n in names}
    raise TypeError(f"gains: expected a number, a dict {{name: gain}} or 'auto', got {gains!r}")


def target_number(name, v):
    """A target value ``I_j0``: a finite real number, else a ``ValueError`` naming it."""
    x = target_value(name, v, ())
    return float(x)


def target_value(name, v, batch):
    """A target ``I_j0`` for an ensemble of shape ``batch``: a float, or one finite number per member.

    An array must broadcast to ``batch`` (it is returned broadcast to it); a
    ``ValueError`` naming the target otherwise.
    """
    if isinstance(v, (bool, np.bool_)):
        raise ValueError(f"targets: the target of {name!r} must be a finite number, got {v!r}")
    try:
        x = np.asarray(v, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"targets: the target of {name!r} must be a finite number, got {v!r}") from None
    if np.asarray(v).dtype == bool or not np.all(np.isfinite(x)):
        raise ValueError(f"targets: the target of {name!r} must be a finite number, got {v!r}")
    return per_member(x, batch, f"targets: the target of {name!r}")


def per_member(x, batch, what):
    """``x`` (a number or an array) as a float (``x`` a number) or a float array of shape ``batch``.

    A ``ValueError`` naming ``what`` when ``x`` does not broadcast to ``batch``
    (the shape of the ensemble, ``y0.shape[:-1]``).
    """
    x = np.asarray(x, dtype=float)
    if x.ndim == 0:
        return float(x)
    try:
        return np.array(np.broadcast_to(x, batch), dtype=float)
    except ValueError:
        raise ValueError(
            f"{what} has shape {x.shape}, which does not match the ensemble: y0 holds {batch or 'one state'} "
            f"(shape {batch + ('n',)}); give one value, or one value per member (shape {batch})"
        ) from None
