"""Sensitivities against a complex step of the whole run, for the start and for two parameters.

A complex step ``Im y(p + i h e_k) / h`` (``h = 1e-30``) of the numpy step map differentiates a whole run
exactly to rounding: no subtraction, no step to tune.  It needs data that a complex state does not push
through a second complex step of their own:

* constant data, or data that carry their analytic derivatives (``metric_derivative=``,
  ``constraints_derivative=``, ``potential_gradient=``): the hand-built sleigh and Suslov's body under a
  declared weight; the complex step is then exact;
* data without them (a ``from_mechanics`` model, the Chaplygin ball of ``rolling_body``): inside the
  reference only, each such datum's derivative is its 8th-order central difference
  (``liefi.integrator._forced_sensitivity.differentiated_data``, relative step 1e-2, about 1e-13 off the
  true derivative), which is linear in the datum and so carries the outer complex step exactly.  The
  reference is then the exact derivative of a run whose field differs from liefi's by about 1e-13.

Each run goes through the split scheme with ``gains="auto"`` (the resolved gains held, as the
sensitivities hold them).
"""

import contextlib

import numpy as np
import pytest

import liefi
from liefi.integrator._forced_sensitivity import differentiated_data
from liefi.integrator.sensitivity import _holder
from liefi.schemes import registry

from test_sensitivity import rel
from test_sensitivity_parameters import declared_ball, hand_sleigh, step_map_run, weighted_suslov

H = 1e-30
RTOL = 1e-10


def _complex_step_reference(fr, sch, par, y0, T, dt, gains):
    """``{"y0": (n, n, n_t), name: (n, n_t)}``: complex steps of the whole numpy run of ``fr``."""
    n = y0.size
    out = {"y0": np.stack([step_map_run(fr, sch, y0 + 1j * H * np.eye(n)[j], T, dt, gains).imag / H
                           for j in range(n)], 1)}
    base = par.values.copy()
    for k, name in enumerate(par.names):
        par.values = base + 1j * H * np.eye(len(base))[k]  # the data read the complex value
        try:
            out[name] = step_map_run(fr, sch, y0.astype(complex), T, dt, gains).imag / H
        finally:
            par.values = base
    return out


def _check(system, par, y0, scheme, T=0.2, reference=contextlib.nullcontext, **kw):
    """liefi's sensitivities against the complex steps of the whole run, made inside ``reference()``."""
    fi = liefi.FeedbackIntegrator(system, y0, **kw)  # gains="auto"
    dt = 0.01
    sol = fi.run(T, dt=dt, scheme=scheme, backend="numpy", sensitivities=("y0",) + par.names)
    fr = liefi.FeedbackIntegrator(system, y0, gains=sol.stability.gains, **kw)
    if sol.dropped:  # the invariants the run left out of V (kept exactly by the scheme)
        fr = fr.without({d["name"]: d["reason"] for d in sol.dropped})
    sch = registry.get(scheme)
    with reference():
        replay = step_map_run(fr, sch, y0.astype(complex), T, dt, sol.stability.gains)
        assert np.max(np.abs(replay.imag)) == 0.0
        assert np.allclose(replay.real, sol.y, rtol=0, atol=1e-13)  # the reference steps the run that was returned
        ref = _complex_step_reference(fr, sch, par, y0, T, dt, sol.stability.gains)
    for name in ("y0",) + par.names:
        assert np.max(np.abs(ref[name])) > 1e-3, name  # the direction moves the run
        assert rel(sol.sensitivities[name], ref[name]) < RTOL, name
    return sol


@pytest.mark.parametrize("scheme", ["imex-rk4", "rk4"])
def test_hand_built_sleigh_y0_and_two_parameters_match_a_complex_step_of_the_whole_run(scheme):
    system, par = hand_sleigh()
    _check(system, par, np.array([0.0, 0.0, 0.1, 0.3, 0.2, 0.5]), scheme, configuration=False)


def test_weighted_suslov_y0_and_two_parameters_match_a_complex_step_of_the_whole_run():
    system, par, y0 = weighted_suslov(gradient=True)
    sol = _check(system, par, y0, "imex-rk4")
    assert sol.stability.gains  # gains="auto" resolved numbers, held by the sensitivities and the reference


def test_from_mechanics_sleigh_y0_and_two_constants_match_a_complex_step_of_the_whole_run():
    from models import sleigh_model

    LM, (m, I, a) = sleigh_model()
    sleigh = liefi.from_mechanics(LM, {m: 1.0, I: 0.5, a: 0.3})
    holder = _holder(sleigh)  # the model's constants, in the order of sleigh.parameters

    class Constants:  # the step map reads holder.values: a complex step moves one constant
        names = ("m", "a")

        def __init__(self):
            self.base = holder.values.copy()
            self.index = [list(map(str, sleigh.parameters)).index(n) for n in self.names]

        @property
        def values(self):
            return holder.values[self.index]

        @values.setter
        def values(self, v):
            c = self.base.astype(np.result_type(v, float))
            c[..., self.index] = v
            holder.values = c

    y0 = np.array([0.0, 0.0, 0.1, 0.3, 0.2, 0.5])
    assert not sleigh.metric.constant and sleigh.metric._derivative is None  # the case this test is about
    _check(sleigh, Constants(), y0, "imex-rk4", reference=lambda: differentiated_data(sleigh), configuration=False)
    assert sleigh.metric._derivative is None  # restored


@pytest.mark.slow  # ~40 s: the ball's 25 states, 25 complex runs of the reference
def test_chaplygin_ball_y0_and_two_declared_parameters_match_a_complex_step_of_the_whole_run():
    ball, par, y0 = declared_ball()
    _check(ball, par, y0, "imex-rk4", T=0.05, reference=lambda: differentiated_data(ball))
