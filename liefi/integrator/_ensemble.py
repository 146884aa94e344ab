"""An ensemble's members: some of them standing for it, the per-member data of their system, stale constants.

Part of :mod:`liefi.integrator.feedback` (the methods :meth:`~liefi.FeedbackIntegrator.members`,
:meth:`~liefi.FeedbackIntegrator.selection` and the checks of the constructor call these).  An ensemble
``(*B, n)`` carries per-member gains and targets, and its system may carry per-member constants
(:func:`liefi.from_mechanics`, shape ``(*B, P)``).  Where liefi evaluates a few members standing for the
ensemble (the stability pilot, the members due for adaptation, the step choice's flattened states), the
integrator of :func:`members` holds their gains and targets and names which members they are; inside
:func:`selection` the system's data read those members' constants (:mod:`liefi._members`).  Outside it
the system refuses states that are not the whole ensemble's: never another member's constants.  And
:func:`check_data`: a run after the constants changed retakes what the integrator took at its start.
"""

from __future__ import annotations

import contextlib
import copy

import numpy as np

from .. import _members
from .._parameters import per_member


def data_state(system):
    """The current values of ``system``'s changeable data (its ``data_key``: the constants of
    :func:`~liefi.from_mechanics`, declared parameters' values), or ``None`` (none, or symbols while traced)."""
    key = getattr(system, "data_key", None)
    try:
        return key.parameters.data_key if hasattr(key, "parameters") else key
    except (TypeError, ValueError):  # the values replaced by symbols (a trace of the sensitivities)
        return None


def member_states(system, batch, what):
    """Check that states of batch shape ``batch`` carry the members of ``system``'s per-member data.

    A system with per-member constants (:attr:`liefi.systems.mechanics.MechanicsSystem.member_shape` ``B``
    not empty) runs an ensemble whose last axes are ``B`` (``(..., *B, n)``); anything else -- one
    state, a batch of another shape -- is refused with a ``ValueError`` naming ``what`` and ``constants``.
    """
    B = tuple(getattr(system, "member_shape", ()))
    batch = tuple(batch)
    if B and batch[len(batch) - len(B):] != B:
        raise ValueError(
            f"{what}: the system holds per-member constants for an ensemble of shape {B} (system.constants of "
            f"shape {B + (len(system.constant_names),)}), but {what} holds "
            f"{'one state' if not batch else f'states of shape {batch}'}; give one state per member "
            f"(shape ({', '.join(map(str, B))}, n)), or set one value of each constant to run one trajectory "
            "(system.constants = system.constants[k] for member k)")


def members(fi, index=None):
    """``fi`` restricted to some members of its ensemble: their own targets, gains and (inside
    :func:`selection`) per-member constants.

    ``index``: ``None``, the whole ensemble flattened to ``(B,)``; an int,
    that member alone (one trajectory); an integer array, those members
    (flat indices into ``fi.batch``).  Without per-member values (one
    trajectory) the integrator itself.  Used where a few members stand for
    the ensemble (the stability pilot) or its states are flattened.  The result records which members of
    the whole ensemble it holds (``_selected``: the ensemble's shape and their flat indices; restricting it
    again composes them).
    """
    if not fi.batch:
        return fi
    B = int(np.prod(fi.batch, dtype=int))

    def pick(v):
        if np.ndim(v) == 0:
            return v
        a = np.asarray(v, dtype=float).reshape(B)
        if index is None:
            return a
        return float(a[index]) if np.ndim(index) == 0 else a[np.asarray(index)]

    new = copy.copy(fi)
    Y = np.broadcast_to(fi.y0, fi.batch + (fi.n,)).reshape(B, fi.n)  # (one y0 after for_batch)
    new.y0 = Y if index is None else Y[index]
    new.batch = new.y0.shape[:-1]
    # which members of the whole ensemble these are: the per-member data of the system (from_mechanics
    # constants) are read for them inside selection() (liefi._members)
    whole, own = fi._selected if fi._selected is not None else (fi.batch, None)
    own = np.arange(B) if own is None else np.asarray(own).reshape(B)
    new._selected = (whole, own if index is None else (int(own[index]) if np.ndim(index) == 0 else
                                                       own[np.asarray(index)]))
    new.targets = {k: pick(v) for k, v in fi.targets.items()}
    new.energy_target = new.targets.get("energy", 0.0)
    new.user_targets = [new.targets[u.name] for u in new.user]
    new._set_gains({k: pick(v) for k, v in fi.gains.items()})
    return new


def selection(fi):
    """The context in which the system's per-member data are those of this integrator's members.

    An integrator of :func:`members` (some members of an ensemble) evaluates its system inside it: the
    constants of a :func:`~liefi.from_mechanics` system with per-member constants are then the rows of
    these members (:mod:`liefi._members`); outside it the system refuses states that are not the
    whole ensemble's.  The whole integrator: no selection (a no-op).
    """
    if fi._selected is None:
        return contextlib.nullcontext()
    return _members.selected(*fi._selected)


def check_data(fi):
    """Before a run: what ``fi`` took at ``y0`` retaken when its system's constants changed since it was built.

    The targets taken at ``y0`` (the energy's ``h~_0``, a user invariant's value; not those given) and the
    unit-rate gains of ``gains="auto"`` hold the system's constants at the construction: a run after
    ``system.constants = ...`` (or a declared parameter set) would steer to the old system's energy.  They
    are taken again at ``y0`` with the new constants, as a new ``FeedbackIntegrator(system, y0)`` takes them,
    so the run is the one of the new system.
    """
    if fi._data_key is None:
        return
    now = data_state(fi.system)
    if now is None or now == fi._data_key:
        return
    member_states(fi.system, fi.batch, "y0")  # constants now per member of another ensemble: refused by name
    if fi._y0_targets:
        values = fi.invariant_values(fi.y0)
        for k in fi._y0_targets:
            fi.targets[k] = per_member(values[k], fi.batch, f"the value of {k!r} at y0")
        fi.energy_target = fi.targets.get("energy", 0.0)
        fi.user_targets = [fi.targets[u.name] for u in fi.user]
        fi._parameters = None
    if fi.gains_mode == "auto":
        from .gains import unit_rate_gains

        fi._set_gains(unit_rate_gains(fi, fi.y0))
    fi._data_key = now
