"""Unknown keyword arguments of the public entry points, answered as the CLI answers an unknown flag.

``run(sheme="rk4")`` gets ``TypeError: run() got an unexpected keyword argument
'sheme'; did you mean 'scheme'?`` instead of Python's bare message, and a
keyword of ``scipy.integrate.solve_ivp`` that has no meaning here (``first_step=``,
``args=``, ...) gets a sentence saying what to write instead.  For
:meth:`liefi.FeedbackIntegrator.run`, :class:`liefi.FeedbackIntegrator` and
:meth:`liefi.scenes.Scene.run`: each takes ``**unknown`` (hidden from its
signature by :func:`keywords`) and refuses it with :func:`unknown_keyword`, with
no wrapper, so that their warnings keep pointing at the caller's line.
"""

from __future__ import annotations

import difflib
import inspect

#: Keywords of ``solve_ivp`` with no counterpart in liefi's fixed-step runs: the sentence that answers them.
IVP_ONLY = {
    "first_step": ("liefi steps with one fixed step over the whole run, so there is no first step to "
                   "guess; give dt= (every step), or rtol=/atol= (the step is chosen for the tolerance), and "
                   "max_step= to cap a chosen step"),
    "args": ("liefi's vector field takes no extra arguments; a model's constants belong to its system "
             "(constants= of liefi.from_mechanics / liefi.from_sympy, or system.constants = {...}): set them, "
             "then build the FeedbackIntegrator (its targets are taken at its start)"),
    "vectorized": ("liefi's field is always batch-first; pass an ensemble as y0 of shape "
                   "(..., n) instead"),
    "jac": "liefi has the Jacobian of its own field (fi.jac); the schemes of run() do not take one",
    "jac_sparsity": "liefi's schemes do not take a Jacobian's sparsity",
    "lband": "liefi's schemes do not take a banded Jacobian",
    "uband": "liefi's schemes do not take a banded Jacobian",
    "min_step": ("liefi steps with one fixed step; give dt=, or rtol=/atol= for a step chosen for "
                 "the tolerance"),
}

#: ... and those of :meth:`liefi.FeedbackIntegrator.run`: with the retired ``t_final=`` of the old form.
RUN_FOREIGN = dict(IVP_ONLY, t_final=(
    "the old form run(dt=..., t_final=...) is retired; write run(t_final, dt=...) (the run starts at 0) "
    "or run((t0, t_final), dt=...), as solve_ivp's t_span"))

#: ... and those of :meth:`liefi.scenes.Scene.run`, which names its method ``scheme=`` and has no ``max_step``.
SCENE_FOREIGN = dict(IVP_ONLY, method=(
    "Scene.run names its method scheme=: e.g. scheme='scipy:RK45' for solve_ivp's RK45, or a liefi "
    "scheme such as scheme='rk4'"), max_step=(
    "Scene.run takes dt= (a fixed step) or rtol=/atol= (the step chosen for the tolerance); "
    "FeedbackIntegrator.run(t_span, rtol=..., max_step=...) caps a chosen step"))


def unknown_keyword(where, unknown, fn, foreign=None):
    """The :class:`TypeError` for the first of the ``unknown`` keywords of ``fn`` (called ``where``).

    ``foreign``: ``{name: sentence}`` of known keywords of other libraries that
    liefi answers with a sentence; otherwise the closest accepted names
    (:func:`difflib.get_close_matches`), or the list of them.
    """
    name = next(iter(unknown))
    if foreign and name in foreign:
        return TypeError(f"{name}: {where}() does not take {name}=; {foreign[name]}")
    accepted = [p.name for p in inspect.signature(fn).parameters.values()
                if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY) and p.name != "self"]
    close = difflib.get_close_matches(name, accepted, n=1, cutoff=0.6)
    hint = f"did you mean {close[0]!r}?" if close else f"the keywords are {', '.join(sorted(accepted))}"
    return TypeError(f"{where}() got an unexpected keyword argument {name!r}; {hint}")


def keywords(fn):
    """Hide ``fn``'s ``**unknown`` from its signature (``inspect.signature``, the docs, ``help``).

    The function itself starts with ``if unknown: raise unknown_keyword(...)``:
    no wrapper, so that the warnings it gives keep pointing at the caller's line.
    """
    sig = inspect.signature(fn)
    fn.__signature__ = sig.replace(parameters=[p for p in sig.parameters.values() if p.kind is not p.VAR_KEYWORD])
    return fn
