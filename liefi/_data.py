"""System data as batch-first functions of the shape coordinates, with derivatives."""

from __future__ import annotations

import numpy as np

from . import _diff


def as_float_array(value, name, what="an array of real numbers"):
    """``np.array(value, dtype=float)``, or a ``ValueError`` naming ``name`` and ``what`` it expects
    (strings, complex numbers, ragged lists ...).  The one check of users' numbers: :func:`as_float`
    and :func:`as_state` call it."""
    try:
        raw = np.asarray(value)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: expected {what}, got {value!r} ({exc})") from None
    if np.iscomplexobj(raw) and np.any(raw.imag != 0):
        raise ValueError(
            f"{name}: complex values (largest imaginary part {np.max(np.abs(raw.imag)):.3g}), expected {what}; "
            "liefi needs real data -- pass the real numbers you meant (liefi does not drop imaginary parts)"
        )
    try:
        with np.errstate(all="ignore"):
            return np.array(raw.real if np.iscomplexobj(raw) else value, dtype=float)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{name}: expected {what}, got {value!r} ({exc})") from None


def as_float(value, name, what="a real number"):
    """``float(value)`` for one real number (not a bool), or a ``ValueError`` naming ``name`` and ``what``.

    ``"abc"``, ``1 + 2j``, ``[1, 2]`` and ``True`` are refused by name rather than with
    Python's ``could not convert string to float`` or ``float() argument ... not 'complex'``.
    """
    if isinstance(value, (bool, np.bool_)):
        raise ValueError(f"{name}: expected {what}, got {value!r} (a bool is not a number)")
    x = as_float_array(value, name, what)
    if x.ndim:
        raise ValueError(f"{name}: expected {what}, got {value!r} (shape {x.shape})")
    return float(x)


def as_state(value, name, names):
    """``value`` as a float array of states ``(..., len(names))``, or a ``ValueError`` naming ``name``.

    Strings, complex numbers, a wrong last axis and non-finite entries are refused
    by name (a NaN would otherwise come back as NaN, silently); the message names
    the components that are not finite and their indices in the batch.
    """
    names = tuple(names)
    x = as_float_array(value, name, f"a state of {len(names)} real numbers {names}")
    if x.shape[-1:] != (len(names),):
        raise ValueError(f"{name}: expected a state of {len(names)} numbers {names} (or a batch of them, "
                         f"shape (..., {len(names)})), got shape {x.shape}")
    bad = ~np.isfinite(x)
    if np.any(bad):
        which = [names[i] for i in np.flatnonzero(bad.reshape(-1, len(names)).any(axis=0))]
        where = np.argwhere(bad.reshape(x.shape[:-1] + (-1,)).any(axis=-1))[:3].tolist() if x.ndim > 1 else None
        raise ValueError(f"{name}: contains non-finite numbers (nan or inf) in {which}"
                         + (f" of the states at batch index {where}" if where else "")
                         + "; pass finite numbers")
    return x


def check_real(value, name, x):
    """Raise a ``ValueError`` naming ``name`` if ``value``, computed at the real point(s) ``x``,
    has a nonzero imaginary part: liefi's data must be real for real input (complex input is for
    the complex-step derivative only)."""
    val = np.asarray(value)
    if np.iscomplexobj(val) and np.any(val.imag != 0):
        raise ValueError(
            f"{name}: returns complex values at real x = {np.asarray(x).tolist()} (largest imaginary part "
            f"{np.max(np.abs(val.imag)):.3g}); it must be real for real x"
        )


#: Random points (besides the sample point) at which complex-step safety is checked.
N_PROBES = 3


class DataFunction:
    """A datum of a system (metric, constraints, potential) as a function of ``x``.

    Constant data (an array, or any datum of a system with no shape space) is
    stored once; callable data is evaluated batch-first and differentiated by
    complex step unless an analytic ``derivative`` is supplied.

    Parameters
    ----------
    value : array_like or callable
        The constant value, or ``fun(x)`` mapping ``(..., n)`` to ``(..., *shape)``.
    shape : tuple
        Shape of one value.
    n : int
        Dimension of ``x``.
    name : str
        Name used in error messages (``"metric"``, ``"constraints"`` ...).
    derivative : callable, optional
        ``derivative(x)`` -> ``(..., n, *shape)``, ``d value / d x_k`` on axis ``-len(shape)-1``.
    """

    def __init__(self, value, shape, n, name, derivative=None, sample=None):
        self.shape = tuple(shape)
        self.n = n
        self.name = name
        self.constant = not callable(value)
        self._derivative = derivative
        if self.constant:
            v = as_float_array(value, name)
            if v.shape != self.shape:
                raise ValueError(f"{name}: expected shape {self.shape}, got {v.shape}")
            if not np.all(np.isfinite(v)):
                raise ValueError(f"{name}: contains non-finite numbers")
            v.setflags(write=False)
            self.value = v
            self.fun = None
            return
        self.value = None
        self.fun = self._batched(value, sample)

    def _batched(self, fun, sample):
        """Wrap ``fun`` so it accepts a batch; fall back to a loop for point-wise functions."""
        n = self.n
        xs = np.zeros((2, n)) if sample is None else np.broadcast_to(np.asarray(sample, float), (2, n))
        try:
            out = np.asarray(fun(xs))
            ok = out.shape == (2,) + self.shape
        except Exception:  # noqa: BLE001 -- any failure means "not batch-aware"
            ok = False
        if ok:
            return fun
        try:
            single = np.asarray(fun(xs[0]))
        except Exception as exc:
            raise ValueError(f"{self.name}: calling it at x = {xs[0]} failed: {exc!r}") from exc
        if single.shape != self.shape:
            raise ValueError(
                f"{self.name}: expected a value of shape {self.shape} for x of shape ({n},), got {single.shape}"
            )

        def looped(x):
            x = np.asarray(x)
            flat = x.reshape(-1, n)
            out = [np.asarray(fun(xi)) for xi in flat]
            dtype = np.result_type(*out) if out else float
            return np.array(out, dtype=dtype).reshape(x.shape[:-1] + self.shape)

        looped.pointwise = True
        return looped

    def __call__(self, x):
        if self.constant:
            return self.value
        return np.asarray(self.fun(x))

    def with_derivative(self, x):
        """``(value, d value/dx)`` with the derivative on the axis after the batch; ``None`` if constant."""
        if self.constant:
            return self.value, None
        if self._derivative is not None:
            return self(x), np.asarray(self._derivative(x))
        return _diff.jacobian(self.fun, x)

    def check_real(self, x):
        """Raise a named error if the datum returns complex values (nonzero imaginary part) at real ``x``."""
        if self.constant:
            return
        check_real(self.fun(np.asarray(x, dtype=float)), self.name, x)

    def check_differentiable(self, x):
        """Raise a named error if the derivative (complex-step or supplied) is wrong at ``x``.

        A single point is not enough: a function that drops the imaginary part (an
        in-place fill into a float array, ``np.real``, ``.astype(float)``) has a zero
        complex-step derivative, which passes wherever the true derivative also vanishes
        (``cos`` at ``x = 0``).  So the complex step is also run at :data:`N_PROBES`
        further points around ``x`` (fixed seed: reproducible), where a datum whose
        complex-step derivative is *exactly* zero while its finite difference is not
        has dropped the imaginary part.  Only that signature is an error there: a
        probe point may lie near a singularity of the user's data (a chart's gimbal
        lock), where finite differences themselves are poor; points where the datum
        is not finite are skipped.
        """
        if self.constant or not self.n:
            return
        x = np.asarray(x, dtype=float)
        self._check_differentiable_at(x)
        if x.ndim != 1 or self._derivative is not None:
            return
        rng = np.random.default_rng(20261122)
        scale = np.maximum(1.0, np.abs(x))
        probes = np.stack([x + 0.5 * scale * rng.uniform(-1.0, 1.0, size=x.shape) for _ in range(N_PROBES)])
        # the probes as one batch (three calls of the datum, not three per probe); a batch the datum raises on
        # (a probe outside its domain) is probed point by point, each raising point skipped
        try:
            batch = self._probe_derivatives(probes)
        except Exception:  # noqa: BLE001 -- see the point-by-point probes
            batch = None
        for i, p in enumerate(probes):
            if batch is None:
                try:
                    jc, jf = self._probe_derivatives(p)
                except Exception:  # noqa: BLE001 -- outside the datum's domain (or raising there): not a probe point
                    continue
            else:
                jc, jf = batch[0][i], batch[1][i]
            self._check_imaginary_part_kept(p, jc, jf)

    def _probe_derivatives(self, x):
        """``(complex step, central differences)`` of the datum at the point(s) ``x`` (``(n,)`` or ``(P, n)``):
        each ``(..., n, *out)``, the derivatives along ``e_k`` at ``[..., k]``."""
        with np.errstate(all="ignore"):
            _, jc = _diff.probe_jacobian(self.fun, x)
            h = 1e-6 * np.maximum(1.0, np.abs(x))
            dx = h[..., :, None] * np.eye(self.n)  # row k: h_k e_k; the 2n differences in two calls
            with _diff.directions_after(x):
                fp, fm = (np.asarray(self.fun(x[..., None, :] + s * dx), float) for s in (1.0, -1.0))
            jf = (fp - fm) / (2 * h.reshape(h.shape + (1,) * (fp.ndim - h.ndim)))
        if jc.shape != jf.shape:
            raise ValueError("the complex step and the differences disagree in shape")
        return jc, jf

    def _check_imaginary_part_kept(self, x, jc, jf):
        """Named error if the complex step ``jc`` of the datum at ``x`` is exactly zero where the finite
        differences ``jf`` are not."""
        if not (np.all(np.isfinite(jc)) and np.all(np.isfinite(jf))):
            return
        dropped = (jc == 0) & (np.abs(jf) > 1e-6 * max(1.0, float(np.max(np.abs(jf), initial=0.0))))
        if np.any(dropped):
            raise ValueError(
                f"{self.name}: its complex-step derivative is exactly zero at x = {x} where finite "
                f"differences give up to {np.max(np.abs(jf[dropped])):.3g}: the function drops the "
                "imaginary part of its argument (in-place assignment into a float array, np.real, "
                ".astype(float), abs(), comparisons ...). Write it with operations that accept complex "
                "input (np.sin, np.stack, +, * ...), or pass its derivative explicitly."
            )

    def _check_differentiable_at(self, x):
        if self._derivative is None:
            _diff.check_complex_step(self.fun, x, self.name)
            return
        x = np.asarray(x, dtype=float)
        given = np.asarray(self._derivative(x), float)
        h = 1e-6 * np.maximum(1.0, np.abs(x))
        cols = []
        for k in range(self.n):
            dx = np.zeros_like(x)
            dx[..., k] = h[..., k]
            cols.append((np.asarray(self.fun(x + dx), float) - np.asarray(self.fun(x - dx), float)) / (2 * h[..., k]))
        fd = np.stack(cols, axis=x.ndim - 1)
        scale = max(1.0, float(np.max(np.abs(fd), initial=0.0)))
        if given.shape != fd.shape or not np.allclose(given, fd, rtol=1e-5, atol=1e-5 * scale):
            raise ValueError(
                f"{'potential_gradient' if self.name == 'potential' else self.name + '_derivative'}: the supplied derivative disagrees with finite differences "
                f"at x = {x} (expected shape {fd.shape}, got {given.shape}); check it, or omit it "
                "to let liefi differentiate by complex step"
            )
