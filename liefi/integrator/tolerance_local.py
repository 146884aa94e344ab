r"""The local estimate of a step chosen for a tolerance: the pilot, its step-doubling error, the local model.

Steps 1--4 of :mod:`liefi.integrator.tolerance` (the module docstring there has the maths): an error scale
per component (:func:`_size`), a first step and a pilot of the scheme's tableau on ``X`` with a
step-doubling estimate ``e = C h^{p+1}`` (:func:`_local_estimate`), and the local model's step
``dt_0 = (1/(T C))^{1/p}`` (:func:`_local_step`).  Re-exported by :mod:`liefi.integrator.tolerance`.
"""

from __future__ import annotations

import math

import numpy as np

from .._members import MembersError

#: Steps of the pilot (each with a step-doubling error estimate).
PILOT_STEPS = 24
#: ... where the measured check follows (a compiled backend, one trajectory): the pilot then only plans the
#: check's coarse step and ranks the orders, and the check's runs set the step (a third of the pilot's work:
#: 10--40 ms of a short run's choice, the same steps on Suslov, Kepler, the rigid body, the Chaplygin ball).
PILOT_STEPS_CHECKED = 8
#: A component's error scale is at least this fraction of the largest size of its part.
PART_FLOOR = 1e-2
#: The first pilot step is the largest ``T / 4^k`` whose relative local error is below this.
FIRST_ERROR = 1e-5
#: The chosen step aims its estimated global error at this fraction of the tolerance (``solve_ivp``'s
#: achieved error is of the order of ``rtol``; a default run's should not exceed it).
TARGET = 1.0 / 3.0


def _tableau(sch):
    """The explicit tableau that steps ``X`` in ``sch`` (the split scheme's, or ``sch`` itself)."""
    return getattr(sch, "explicit", sch)


def _parts(fi):
    """The slices of the state whose components share units: the group element, ``x``, the momenta."""
    nc, nx = fi.nc, fi.system.space.n
    cuts = [0, nc, nc + nx, fi.n]
    return [slice(a, b) for a, b in zip(cuts, cuts[1:]) if b > a]


def unforced_field(fi, Y, backend):
    """``f(y)``: ``X`` at a batch ``y`` of shape ``(k, n)``, compiled when ``backend`` allows and the
    system compiles (the split kernel's ``xrhs_s``, the function the run's loop calls: no entry point
    compiled for the step choice alone), else numpy."""
    if backend != "numpy" and Y.shape[0] == 1:
        try:
            import warnings

            from ..engine.kernels import compile_split
            from ..engine.trace import NotCompilable

            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                cf = compile_split(fi)
                p = [float(v) for v in fi.parameters()]
                cf._first_call("xrhs_s", "xrhs_s", *[float(v) for v in Y[0]], *p)
            xrhs = cf.module.xrhs_s

            def f(y):
                return np.array([xrhs(*y[0].tolist(), *p)])

            return f
        except (NotCompilable, ImportError, RuntimeError, AttributeError, TypeError, ValueError):
            pass
    return fi.unforced_vector_field


def _local_estimate(fi, tab, Y, T, rtol, atol, f=None, steps=None):
    """``(C, h, mag)``: the local error constant of ``tab`` on ``X`` from the step-doubling pilot.

    ``C`` the largest ``e / h^{p+1}`` over ``steps`` (default :data:`PILOT_STEPS`) steps of ``h`` (steps 1--3
    of the module docstring), in the scaled norm; ``mag`` the componentwise largest ``|y|`` seen.  ``f``: ``X``
    (default: numpy's, :func:`unforced_field`).
    """
    p = int(tab.order)
    if f is None:
        f = fi.unforced_vector_field

    with np.errstate(all="ignore"):
        mag = np.abs(Y)

        def first_error(hh):
            try:
                y1 = tab.step(f, Y, hh)
                yh = tab.step(f, tab.step(f, Y, hh / 2), hh / 2)
            except MembersError:  # states not the ensemble's: never a step out of the data's domain
                raise
            except (ArithmeticError, np.linalg.LinAlgError, ValueError):
                # a trial step so long that its stages leave the data's domain (a singular metric or
                # constraint there, e.g. a rolling body's stage far from the plane): too long, not an error
                return math.inf
            e = float(np.max(np.abs(y1 - yh) / _size(fi, np.maximum(mag, np.abs(yh)))))
            return e if math.isfinite(e) else math.inf

        # the first pilot step: the largest T / 4^k in the asymptotic regime (its error small, and a quarter
        # of it has an error 4^(p+1) times smaller, so that no step aliases with a period of the motion)
        h, e_h = T, first_error(T)
        for _ in range(60):
            e_q = first_error(h / 4)
            if (e_h <= FIRST_ERROR and (e_q <= 1e3 * np.finfo(float).eps or e_q * 4 ** (p + 1) / 8 <= e_h)
                    or h < 1e-12 * T):
                break
            h, e_h = h / 4, e_q
        C, hC = 0.0, h
        for _ in range(12):  # enlarge the pilot step until its error is well above rounding
            y, big, c, m = Y, 0.0, 0.0, mag
            for _k in range(PILOT_STEPS if steps is None else steps):
                try:
                    y1 = tab.step(f, y, h)
                    yh = tab.step(f, tab.step(f, y, h / 2), h / 2)
                except MembersError:
                    raise
                except (ArithmeticError, np.linalg.LinAlgError, ValueError):  # out of the data's domain
                    e = math.inf
                    break
                m = np.maximum(m, np.abs(yh))
                err = np.abs(y1 - yh) / (1.0 - 2.0 ** -p)
                e = float(np.max(err / (atol + rtol * _size(fi, m))))
                if not math.isfinite(e):
                    break
                big = max(big, float(np.max(err / (np.finfo(float).eps * _size(fi, m)))))
                hp = h ** (p + 1)
                if hp > 0:  # a step so short that h^(p+1) underflows (a horizon of 1e-200) has no error to measure
                    c = max(c, e / hp)
                y = yh
            if not math.isfinite(e):
                break  # past the tableau's stability: keep the last estimate
            C, hC, mag = c, h, m
            if big > 1e4 or h >= T:
                break
            h = min(8.0 * h, T)
    return C, hC, mag


def _size(fi, m, floor_fraction=PART_FLOOR):
    """Each component's size ``m``, floored at :data:`PART_FLOOR` times the largest of its part (group
    element, ``x``, momenta).

    A component that stays near zero is measured against its neighbours of the same units, so that the
    error scale never vanishes; a small component beside a large one (a position beside an angle that
    winds up over the run) keeps its own scale.
    """
    parts = _parts(fi)
    floor = np.empty_like(m)
    for sl in parts:
        floor[..., sl] = np.max(m[..., sl], axis=-1, keepdims=True)
    return np.maximum(np.maximum(m, floor_fraction * floor), 1e-300)


def _local_step(C, T, p, h):
    """The step of the local model, ``(1 / (T C))^{1/p}`` (``T`` if ``X`` is exact at the pilot's step)."""
    if not (C > 0 and math.isfinite(C)):
        return T  # X is (numerically) exact at any step here, e.g. a state at rest
    return (1.0 / (max(T, h) * C)) ** (1.0 / p)
