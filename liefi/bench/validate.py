"""Checks of the harness's arguments: every bad number is a ``ValueError`` that names the parameter."""

from __future__ import annotations

from ..schemes import positive_number


def positive(name, value):
    """``float(value)`` if it is a finite number > 0, else a ``ValueError`` naming ``name``
    (the one run-argument validator, :func:`liefi.schemes.positive_number`)."""
    return positive_number(value, name, "must be a finite number > 0")


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


def positive_int(name, value):
    """``int(value)`` if it is a whole number >= 1, else a ``ValueError`` naming ``name``
    (:func:`liefi.schemes.positive_int`, the one validator of counts)."""
    from ..schemes import positive_int as _positive_int

    return _positive_int(value, name)
