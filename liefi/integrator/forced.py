r"""A feedback integrator under external forces and controls: the energy balance ``h~ - W`` is the held invariant.

With a generalized force ``F(t, q, v; u)`` (:mod:`liefi.systems.forcing`) the
Lagrange--d'Alembert equations read, in the reduced variables,

.. math:: \dot z = B\, dH + \sum_i \lambda_i e_i^\flat + (0, F), \qquad
          \lambda = C^{-1} (\{H, J\} - E F)

(:func:`liefi.reduction.core.field_terms`, the one place where the force
enters): the constraint forces absorb the part of ``F`` along the forbidden
directions, the constraints ``J_i`` stay first integrals of the extended
field (``E (F - E^{\flat T} C^{-1} E F) = 0``), and the feedback term is
unchanged.  Energy is no longer conserved:

.. math:: \frac{d\tilde h}{dt} = \langle d\tilde h/dP, F \rangle = F \cdot v
          \quad (\text{on } J = 0),

exactly, off the constraint set too, since ``E^flat dh~/dP = J - C C^{-1} J = 0``.
The state therefore carries **one** extra number, the work done,

.. math:: \dot W = \langle d\tilde h/dP, F \rangle, \qquad W(t_0) = 0,

and the held invariant is the **energy balance** ``h~ - W`` (or ``h - W`` with
``energy="original"``), a first integral of the extended forced field; ``V``
penalizes ``(h~ - W - c)^2`` in place of ``(h~ - c)^2``, with gradient
``(dh~, -1)`` in ``(z, W)``.  The schemes step an autonomous field, so the time
the force reads is carried by a clock ``time' = 1`` after ``W`` (every
Runge--Kutta tableau integrates it exactly: a stage sees ``t_n + c_i dt``); the
clock is no invariant and the feedback never moves it.  The state is
``y = (g, z, W, time)`` (:attr:`FeedbackIntegrator.names` ends in ``"W", "time"``);
a conservative system's runs are untouched (no force: no extra states).

**Piecewise-constant inputs are held over whole steps** (a zero-order hold): every
stage of a step reads such an input at the step's midpoint ``t_n + dt/2``, not at its
own time, so the step integrates a field that is smooth in time and the balance and
the constraints stay at rounding across a switch.  (Read per stage, a switch at a step
end ``t_{n+1}`` would be seen by that step's last stage, ``c = 1``, and the step would
be first order in the jump.)  The step tells the field its start and size through
:meth:`ForcedFeedbackIntegrator.holding`, which the Runge--Kutta step enters around its
stages.  A switch that is not a step end ``t0 + k dt`` then acts at the step end nearest
to it (the midpoint decides); the run warns (:class:`InputGridWarning`), naming the input and the
switch: choose a ``dt`` that divides the switch times' offsets from the start, or give
the input as a spline.  Splines, callables and constants are read per stage, at each
stage's own time ``t_n + c_i dt``.  A run that goes past a spline's nodes warns too
(:class:`InputGridWarning`): outside them the end cubics extrapolate, and grow as ``t^3``.

Forced runs use the numpy path (``backend="numpy"``; the compiled engine cannot
trace a user's force): ``backend="numba"`` gets a ``ValueError`` saying so.  Their
sensitivities are those with respect to the values of an input over its grid
(``sensitivities=("tau",)``), to the start (``"y0"``) and to the system's constants
(:mod:`liefi.integrator._forced_sensitivity`).
"""

from __future__ import annotations

import contextlib
import warnings

import numpy as np

from .._data import as_float_array
from ..reduction import core as _core
from ..systems.forcing import as_force_law, bind_inputs
from .feedback import FeedbackIntegrator, per_member

#: the names of the two states a forced run appends: the work done and the clock
EXTRA_NAMES = ("W", "time")
#: a switch of a piecewise-constant input is a step end when within this fraction of dt of one
SWITCH_RTOL = 1e-9


class InputGridWarning(UserWarning):
    """A switch of a piecewise-constant input falls between the steps of a forced run, or a run goes past a
    spline input's nodes, where its end cubics extrapolate (module docstring)."""


class ForcedFeedbackIntegrator(FeedbackIntegrator):
    """:class:`~liefi.FeedbackIntegrator` with an external force (module docstring); built by
    ``FeedbackIntegrator(system, y0, force=..., inputs=...)``.

    ``y0``: the state ``(g, z)`` (then ``W = 0`` and the clock at the run's start) or
    ``(g, z, W, time)``.
    """

    def __init__(self, system, y0, *, force=None, inputs=None, field="extended", configuration=True,
                 targets=None, **kw):
        law = as_force_law(force if force is not None else getattr(system, "force", None))
        if field != "extended":
            raise ValueError(f"field: a forced system runs the extended field (the force enters it), got {field!r}")
        self.force_law = law
        self.signals = bind_inputs(law, inputs)
        #: the inputs held over whole steps (the piecewise-constant ones) and the running step's midpoint
        self.held_inputs = frozenset(s for s, sig in self.signals.items() if getattr(sig, "grid_kind", None)
                                     == "piecewise")
        self._hold_time = None
        sp = system.space
        nb = (sp.group.config_dim if configuration and sp.group.config_dim > 0 else 0) + sp.nz
        y0 = as_float_array(y0, "y0")
        extras = np.zeros(y0.shape[:-1] + (2,))
        if y0.shape[-1:] == (nb + 2,):
            y0, extras = y0[..., :nb], y0[..., nb:]
            if not np.all(np.isfinite(extras)):
                raise ValueError("y0: contains non-finite numbers")
        self.nb = nb  # the state without W and the clock
        super().__init__(system, y0, field=field, configuration=configuration, targets=targets, **kw)
        self.n = self.nb + 2
        self.names = tuple(self.names) + EXTRA_NAMES
        self.y0 = np.concatenate([self.y0, extras], -1)
        self.generalized_force(self.y0)  # a wrong shape or NaN from the force is named now, not mid-run
        if self.use_energy and "energy" not in (targets or {}):  # the balance h~ - W at the start
            self.targets["energy"] = per_member(self.invariant_values(self.y0)["energy"], self.batch, "h~ - W at y0")
            self.energy_target = self.targets["energy"]
            self._parameters = None

    # --- the force -------------------------------------------------------------------------
    def input_values(self, t):
        """The inputs at the times ``t`` (any shape): ``(..., m)`` in the order of ``force_law.inputs``.

        Inside a step (:meth:`holding`) the piecewise-constant inputs are read at the step's midpoint.
        """
        t = np.asarray(t)
        if not self.signals:
            return np.zeros(t.shape + (0,))
        mid = self._hold_time
        return np.stack([np.broadcast_to(s(mid if mid is not None and name in self.held_inputs else t), t.shape)
                         for name, s in self.signals.items()], -1)

    @contextlib.contextmanager
    def holding(self, y, dt):
        """The context of one step from the states ``y`` (``(..., n)``) of size ``dt`` (a number, or one per
        state shaped as the Runge--Kutta step broadcasts it): inside, the piecewise-constant inputs read the
        step's midpoint ``t_n + dt/2`` (module docstring).  Without such inputs, nothing changes."""
        if not self.held_inputs:
            yield
            return
        h = np.asarray(dt, float)
        if h.ndim:  # (m, ..., 1): one step size per state, against the state's last axis
            h = h[..., 0]
        previous = self._hold_time
        self._hold_time = np.real(np.asarray(y)[..., self.n - 1]) + 0.5 * h
        try:
            yield
        finally:
            self._hold_time = previous

    def warn_off_grid_switches(self, t0, t_final, dt, stacklevel=3):
        """Warn (:class:`InputGridWarning`) for each held input with a switch inside ``(t0, t_final)`` that is
        not a step end ``t0 + k dt``; returns the ``[(name, switch time)]`` warned about."""
        out = []
        for name in sorted(self.held_inputs):
            sig = self.signals[name]
            N = np.asarray(sig.values).shape[0]
            switches = np.asarray(sig.t_grid, float)[1:N]  # the starts of the intervals after the first
            inside = switches[(switches > t0) & (switches < t_final)]
            k = (inside - t0) / dt
            bad = inside[np.abs(k - np.rint(k)) > SWITCH_RTOL * np.maximum(1.0, np.abs(k))]
            if bad.size:
                spacing = np.diff(switches).min() if switches.size > 1 else float(switches[0] - t0)
                out.append((name, float(bad[0])))
                warnings.warn(
                    f"inputs: the piecewise-constant input {name!r} switches at t = {bad[0]:.6g}"
                    f"{f' (and {bad.size - 1} more)' if bad.size > 1 else ''}, which is not a step end "
                    f"t0 + k dt (t0 = {t0:g}, dt = {dt:.6g}); a forced run holds it over each step at its value at "
                    "the step's midpoint, so the switch acts at the step end nearest to it. Choose a dt "
                    f"that divides the switch times' offsets from t0 (e.g. a divisor of the switch spacing "
                    f"{spacing:.6g}), or give the input as a spline", InputGridWarning, stacklevel=stacklevel)
        return out

    def warn_extrapolated_splines(self, t0, t_final, stacklevel=3):
        """Warn (:class:`InputGridWarning`) for each spline input whose nodes do not span ``[t0, t_final]``.

        Outside its nodes a cubic spline is its end cubic, extrapolated: values ``[1, 2, 30]`` at
        ``t = 0, 0.01, 0.02`` read 5151 at ``t = 0.2``, silently.  A span within one part in ``1e9`` of the
        nodes' is inside.  Returns the names warned about.
        """
        out = []
        for name in sorted(self.signals):
            sig = self.signals[name]
            if getattr(sig, "grid_kind", None) != "spline":
                continue
            a, b = float(sig.t_grid[0]), float(sig.t_grid[-1])
            tol = 1e-9 * max(1.0, abs(a), abs(b))
            if t0 < a - tol or t_final > b + tol:
                out.append(name)
                far = t_final if t_final - b >= a - t0 else t0  # the run's time farthest outside the nodes
                warnings.warn(
                    f"inputs: the run spans [{t0:g}, {t_final:g}] but the spline input {name!r} has nodes over "
                    f"[{a:g}, {b:g}] only; outside them its end cubics extrapolate (its value at t = {far:g} is "
                    f"{np.array2string(np.asarray(sig(np.array(far))), precision=4)}). Give nodes over the whole "
                    "run, or shorten the run", InputGridWarning, stacklevel=stacklevel)
        return out

    def generalized_force(self, y, v=None):
        """The force ``F(t, q, v, u)`` at full states ``y`` (``(..., n)``), shape ``(..., D)``.

        ``v``: the velocities ``dh~/dP`` if already at hand.  A force of the wrong shape or
        non-finite at a finite state is a ``ValueError`` naming ``force``.
        """
        y = _core.as_real(y)
        sp = self.system.space
        g, z = y[..., : self.nc], y[..., self.nc : self.nb]
        if v is None:
            v = _core.evaluate(self.system, z).dht[..., sp.data_dim :]
        return self._force(y[..., self.nb + 1], np.concatenate([g, z[..., : sp.data_dim]], -1), v)

    def _force(self, t, q, v):
        D = self.system.space.D
        u = self.input_values(t)  # a failing signal names itself (liefi.systems.forcing.as_signal)
        try:
            F = np.asarray(self.force_law(t, q, v, u))
        except (ValueError, TypeError, IndexError) as exc:
            raise ValueError(f"force: calling it with t {np.shape(t)}, q {np.shape(q)}, v {np.shape(v)} "
                             f"(and inputs u) failed: {exc!r}") from exc
        if F.shape[-1:] != (D,) or np.broadcast_shapes(F.shape, v.shape) != v.shape:
            raise ValueError(f"force: expected a generalized force of shape (..., {D}) (one component per "
                             f"velocity {self.system.space.momentum_names}), got shape {F.shape}")
        if F.dtype.kind not in "fciu":
            raise ValueError(f"force: expected numbers, got dtype {F.dtype}")
        if not np.all(np.isfinite(F)) and np.all(np.isfinite(q)) and np.all(np.isfinite(v)):
            raise ValueError(f"force: non-finite values (NaN or inf) at the finite state with t = "
                             f"{np.asarray(t).real.ravel()[:3]}; check the force and its inputs")
        return np.broadcast_to(F, v.shape)

    # --- the field and the invariants ---------------------------------------------------------
    def _reduced_field(self, g, z, data):
        """The extended field with the force, then ``W' = <dh~/dP, F>`` and ``time' = 1`` (module docstring)."""
        if _core.is_traced(z) or _core.is_traced(g):
            raise ValueError("force: a forced run is not compiled (the engine cannot trace the force); "
                             "use backend='numpy'")
        sp = self.system.space
        nz, n = sp.nz, sp.data_dim
        zb, tail = z[..., :nz], z.shape[-1] > nz
        t = _core.evaluate(self.system, zb, data=data)
        v = t.dht[..., n:]  # dh~/dP: the velocity, equal to dh/dP on J = 0
        clock = z[..., nz + 1] if tail else np.zeros(z.shape[:-1])
        F = self._force(clock, np.concatenate([g, zb[..., :n]], -1), v)
        zdot, xi, t = _core.field_terms(self.system, zb, kind="extended", terms=t, data=data, force=F)
        if tail:
            power = np.einsum("...i,...i->...", v, F)
            zdot = np.concatenate([zdot, power[..., None], np.ones_like(power)[..., None]], -1)
        return zdot, xi, t

    def invariant_terms(self, z, t, params, data=_core.NUMPY_DATA):
        """The terms of :meth:`FeedbackIntegrator.invariant_terms` with the energy balance ``h~ - W``: its
        residual less ``W`` and its gradient ``(dh~, -1, 0)`` in ``(z, W, time)``; the others' gradients padded."""
        nz = self.system.space.nz
        pad = z.shape[-1] - nz
        out = super().invariant_terms(z[..., :nz], t, params, data)
        if not pad:
            return out
        batch = z.shape[:-1]
        W = z[..., nz]
        tail = np.zeros(batch + (pad,))
        res = []
        for name, r, grad, k in out:
            if name == "energy":
                r = r - W
            if grad is not None:
                extra = tail
                if name == "energy":
                    extra = tail.copy()
                    extra[..., 0] = -1.0
                grad = np.concatenate([np.broadcast_to(grad, batch + (nz,)), extra], -1)
            res.append((name, r, grad, k))
        return res

    def invariant_values(self, y):
        """:meth:`FeedbackIntegrator.invariant_values` with ``energy`` the balance ``h~ - W`` and ``W`` itself."""
        y = np.asarray(y, float)
        out = super().invariant_values(y[..., : self.nb])
        if y.shape[-1] > self.nb:
            W = y[..., self.nb]
            out["energy"] = out["energy"] - W
            out["W"] = W
        return out

    # --- running ------------------------------------------------------------------------------
    def run(self, t_span=None, *more, backend=None, sensitivities=None, y0=None, **kw):
        """:meth:`FeedbackIntegrator.run` on the numpy path, the clock started at the span's start.

        ``sensitivities=("tau", "y0", "m", ...)``: names of inputs given as ``piecewise_constant`` or ``spline``
        (``sol.sensitivities[name]`` of shape ``(n, N, n_t)``: ``d y_i(t_k) / d values_j``), ``"y0"``
        (``(n, n, n_t)``, rows ``y``, columns ``y0``) and the system's constants (``(n, n_t)``); ``dt=``
        required (:mod:`liefi.integrator._forced_sensitivity`).
        """
        from .run import positional_span

        if backend not in (None, "auto", "numpy"):
            raise ValueError(f"backend: a forced run (force=, inputs=) runs on the numpy path only, got "
                             f"{backend!r}; use backend='numpy' (or leave it out)")
        names = ()
        if sensitivities is not None:  # d y / d (an input's values): liefi.integrator._forced_sensitivity
            from . import _forced_sensitivity as _fs

            names = _fs.check(self, sensitivities, t_eval=kw.get("t_eval"), events=kw.get("events"),
                              dense_output=kw.get("dense_output", False))
            if kw.get("dt") is None:
                raise ValueError("sensitivities: give the step (dt=): the sensitivities of a forced run are those of "
                                 "its fixed steps")
        span = positional_span(t_span, more, scheme=kw.get("scheme"))
        t0 = float(span[0]) if np.ndim(span) == 1 and len(span) == 2 else 0.0
        y = self.y0 if y0 is None else as_float_array(y0, "y0")
        if y.shape[-1:] == (self.nb,):
            y = np.concatenate([y, np.zeros(y.shape[:-1] + (2,))], -1)
        if y.shape[-1:] == (self.n,):
            y = y.copy()
            y[..., self.n - 1] = t0
        sol = super().run(span, backend="numpy", y0=y, **kw)
        if self.held_inputs and len(sol.t):
            self.warn_off_grid_switches(t0, float(sol.t[-1]), float(sol.dt))
        if len(sol.t):
            self.warn_extrapolated_splines(t0, float(sol.t[-1]))
        if names:
            from . import _forced_sensitivity as _fs

            _fs.attach(sol, self, names, scheme=sol.scheme, dt=float(kw["dt"]), t0=t0)
        return sol


def force_contribution(system, force, z, u, t=0.0):
    """``(XF, DXF, BF)``: the force's part of the reduced constrained field at ``z`` with inputs ``u`` (``(m,)``).

    ``XF`` (``(nz,)``) is :func:`liefi.reduction.core.field_terms` with the force less without it (the
    projected force on the momentum slots), ``DXF`` (``(nz, nz)``) its ``z``-Jacobian by central differences
    (to about 1e-9 relative) and ``BF`` (``(nz, m)``) its ``u``-Jacobian by complex step (exact to rounding).
    The force is read as ``force(t, x, v, u)`` with ``x`` the data point (no group element) and ``v = dh/dP``.
    Used by :func:`liefi.integrator.linearize.linearize` for its ``B``.
    """
    from .. import _diff

    law = as_force_law(force)
    n = system.space.data_dim
    z = np.asarray(z, float)
    u = np.asarray(u, float)

    def XF(zz, uu):
        terms = _core.evaluate(system, zz)
        F = np.asarray(law(t, zz[..., :n], terms.dh[..., n:], uu))
        F = np.broadcast_to(F, terms.dh[..., n:].shape[:-1] + F.shape[-1:])
        with_force = _core.field_terms(system, zz, kind="constrained", terms=terms, force=F)[0]
        return with_force - _core.field_terms(system, zz, kind="constrained", terms=terms)[0]

    X0 = np.asarray(XF(z, u)).real
    h = 1e-6 * np.maximum(1.0, np.abs(z))
    E = np.diag(h)
    DXF = ((XF(z + E, u) - XF(z - E, u)).real / (2 * h[:, None])).T
    if u.size:
        BF = np.swapaxes(_diff.jacobian(lambda uu: XF(np.broadcast_to(z, uu.shape[:-1] + z.shape), uu), u)[1],
                         -1, -2)
    else:
        BF = np.zeros((z.size, 0))
    return X0, DXF, np.asarray(BF, float)
