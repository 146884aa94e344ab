"""Derivatives to machine precision by complex-step differentiation.

For a real-analytic ``f`` the complex step

.. math:: f'(x) = \\operatorname{Im} f(x + i h) / h + O(h^2)

has no subtractive cancellation, so with ``h = 1e-30`` the truncation error
``O(h^2)`` is far below rounding and the result is exact to working precision
(Squire & Trapp 1998; Martins, Sturdza & Alonso 2003).  The price is that the
user's function must be written with operations that extend analytically to
complex arguments (``+ - * /``, ``**``, ``np.sin``, ``np.exp``, ``np.sqrt``,
``np.linalg.solve`` ...), and must not use ``abs``, ``np.real``, comparisons or
``np.maximum`` on the argument.  :func:`check_complex_step` detects functions
that break this and says so.
"""

from __future__ import annotations

import contextlib
import contextvars
import warnings

import numpy as np

#: numpy's warning for a complex value cast to real (``numpy.exceptions`` from numpy 1.25)
ComplexWarning = getattr(getattr(np, "exceptions", np), "ComplexWarning")

#: Complex step.  Any value below ~1e-20 gives the same result in double precision.
STEP = 1e-30

#: While :func:`jacobian` differentiates: how many leading axes of the argument of the
#: function being differentiated index *states* (the axis it appends before the last, one
#: direction ``e_k`` per slot, does not).  ``None`` outside a derivative.  A datum whose
#: values differ between the members of an ensemble (per-member constants,
#: :mod:`liefi.systems.mechanics`) reads it to align its members with the states, never the
#: direction axis, whatever the lengths.
STATE_AXES = contextvars.ContextVar("liefi_state_axes", default=None)


@contextlib.contextmanager
def directions_after(x):
    """While a derivative appends direction axes after the batch of the states ``x`` (``(..., n)``): declares
    that the first ``x.ndim - 1`` axes of a data function's argument index states (:data:`STATE_AXES`; an
    enclosing declaration is kept).  :func:`jacobian` uses it, and so do liefi's finite differences."""
    token = STATE_AXES.set(np.ndim(x) - 1) if STATE_AXES.get() is None else None
    try:
        yield
    finally:
        if token is not None:
            STATE_AXES.reset(token)


def state_batch(shape):
    """The states' batch of a data function's argument of shape ``shape`` (``(..., n)``): without the
    direction axis :func:`jacobian` appends (:data:`STATE_AXES`)."""
    k = STATE_AXES.get()
    batch = tuple(shape[:-1])
    return batch if k is None else batch[:k]


def jacobian(fun, x, *, step: float = STEP):
    """Value and Jacobian of a batch-first function by complex step.

    Parameters
    ----------
    fun : callable
        ``fun(x)`` maps an array of shape ``(..., n)`` to ``(..., *out)`` and
        accepts complex input (see module docstring).
    x : array_like, shape ``(..., n)``
        Points (real).

    Returns
    -------
    value : ndarray, shape ``(..., *out)``
        ``fun(x)``.
    jac : ndarray, shape ``(..., n, *out)``
        ``jac[..., k, ...] = d fun / d x_k``.

    Notes
    -----
    One call of ``fun`` on a batch of ``n`` complex points gives both: the real
    part of ``fun(x + i h e_k)`` equals ``fun(x)`` up to ``O(h^2)``.
    """
    x = np.asarray(x, dtype=float)
    n = x.shape[-1]
    xc = x[..., None, :] + (1j * step) * np.eye(n)
    with directions_after(x):
        fc = np.asarray(fun(xc))
    if not np.iscomplexobj(fc):
        # The function discarded the imaginary part (or is constant).
        fc = fc.astype(complex)
    if n == 0:
        return np.asarray(fun(x)), fc.imag
    return np.take(fc, 0, axis=x.ndim - 1).real, fc.imag / step


def gradient(fun, x, *, step: float = STEP):
    """Value and gradient of a scalar batch-first function ``(..., n) -> (...)``."""
    return jacobian(fun, x, step=step)


def probe_jacobian(fun, x):
    """:func:`jacobian` for a check of the user's function: numpy's ``ComplexWarning`` (the function
    cast its complex argument to real) is not shown, since the check finds and names the dropped
    imaginary part itself (:func:`check_complex_step`, ``DataFunction.check_differentiable``)."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", ComplexWarning)
        return jacobian(fun, x)


def check_complex_step(fun, x, name: str, *, rtol: float = 1e-5, step: float = 1e-6):
    """Compare the complex-step Jacobian of ``fun`` with central differences.

    ``step``: the relative step of the differences, ``h = step * max(1, |x|)``
    (smaller for a function that varies on a short scale, e.g. a nearly flat surface).

    Raises
    ------
    ValueError
        Naming ``name`` when the two disagree, which means ``fun`` is not
        complex-step safe (it used ``abs``, ``np.real``, a comparison, an
        in-place assignment into a real array, ...) and the user must either
        rewrite it or pass an analytic derivative.
    """
    x = np.asarray(x, dtype=float)
    try:
        _, jc = probe_jacobian(fun, x)
    except (TypeError, ValueError) as exc:  # e.g. assigning complex into a float array
        raise ValueError(
            f"{name}: complex-step differentiation failed ({exc}). Write {name} with "
            "operations that accept complex input (np.sin, np.sqrt, +, *, np.stack, "
            "...; no float() casts or float arrays filled in place), or pass its "
            "derivative explicitly."
        ) from exc
    n = x.shape[-1]
    h = step * np.maximum(1.0, np.abs(x))
    if n:  # the 2n differences in two calls on a batch of directions (one call per direction: N^2 calls)
        dx = h[..., None, :] * np.eye(n)  # (..., n, n): row k is h_k e_k
        with directions_after(x):
            fp, fm = (np.asarray(fun(x[..., None, :] + s * dx), float) for s in (1.0, -1.0))
        jf = (fp - fm) / (2 * h.reshape(h.shape + (1,) * (fp.ndim - h.ndim)))
    else:
        jf = jc
    scale = max(1.0, float(np.max(np.abs(jf), initial=0.0)))
    if not np.allclose(jc, jf, rtol=rtol, atol=rtol * scale):
        raise ValueError(
            f"{name}: its complex-step derivative disagrees with finite differences at "
            f"x = {x} (max difference {np.max(np.abs(jc - jf)):.3g}). The function is not "
            "complex-step safe: avoid abs(), np.real, comparisons and np.maximum on its "
            "argument, or pass its derivative explicitly."
        )
