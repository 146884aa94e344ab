"""Checks of the harness's arguments: every bad number is a ``ValueError`` that names the parameter."""

from __future__ import annotations

import math


def positive(name, value):
    """``float(value)`` if it is a finite number > 0, else a ``ValueError`` naming ``name``."""
    if isinstance(value, bool) or value is None:
        raise ValueError(f"{name}: expected a finite number > 0, got {value!r}")
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise ValueError(f"{name}: expected a finite number > 0, got {value!r}") from None
    if not math.isfinite(x) or x <= 0:
        raise ValueError(f"{name}: must be a finite number > 0, got {value!r}")
    return x


def check_grid(t_final, dts, rtols, gains):
    """``(t_final, dts, rtols, gains)`` checked: finite and positive (a gain may be ``None``: the scene's).

    A zero gain is refused: it is the ``no-feedback`` method, not a feedback integrator.
    """
    t_final = positive("t_final", t_final)
    dts = None if dts is None else [positive("dt", d) for d in dts]
    rtols = None if rtols is None else [positive("rtol", r) for r in rtols]
    out = []
    for k in gains:
        if k is None:
            out.append(None)
            continue
        if isinstance(k, (int, float)) and not isinstance(k, bool) and k == 0:
            raise ValueError("gains: 0 is the 'no-feedback' method, not a feedback integrator; give gains > 0")
        out.append(positive("gains", k))
    return t_final, dts, rtols, tuple(out)
