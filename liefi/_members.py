"""Which members of an ensemble liefi is evaluating: per-member data read by the members they belong to.

An ensemble of states ``(*B, n)`` may carry per-member data: the constants ``(*B, P)`` of a
:func:`liefi.from_mechanics` system (one mass per member of a mass sweep), as the per-member gains and
targets of a :class:`~liefi.FeedbackIntegrator`.  A data function evaluated at the ensemble's states
(``(*B, n)``, or liefi's time-major stacks ``(T, *B, n)``) reads member ``b``'s row for the states of
member ``b``.  Where liefi evaluates only *some* members -- a few standing for the ensemble in the
stability pilot, the members due for their adaptation of the gains, one member's states in a check at
its start -- the states are ``(k, n)`` or ``(n,)`` and cannot say whose they are; :func:`selected`
declares it (:meth:`liefi.FeedbackIntegrator.members` records the members, and
:meth:`~liefi.FeedbackIntegrator.selection` enters this context), and :func:`rows` gives the data of
those members.  Outside such a declaration, states that are not the ensemble's are refused by the data
(a ``ValueError`` naming ``constants``), never read with another member's values.
"""

from __future__ import annotations

import contextlib
import contextvars

import numpy as np

class MembersError(ValueError):
    """States that are not those of the ensemble whose per-member data a system holds (never read with
    another member's data).  A ``ValueError``; the loops that take a ``ValueError`` for a step out of the data's
    domain (the step choice's pilots and checks) let it through."""


#: ``(batch, index)`` while liefi evaluates some members of an ensemble of shape ``batch``: ``index``
#: ``None`` (every member, flattened to ``(prod(batch),)``), an int (one member) or an int array (those
#: members, flat indices into ``batch``); ``None`` outside.
SELECTED = contextvars.ContextVar("liefi_members", default=None)


@contextlib.contextmanager
def selected(batch, index):
    """While liefi evaluates the members ``index`` (flat indices into the ensemble's shape ``batch``)."""
    token = SELECTED.set((tuple(batch), index))
    try:
        yield
    finally:
        SELECTED.reset(token)


def rows(values, what="constants"):
    """The per-member ``values`` (``(*B, P)``) of the members selected now (:data:`SELECTED`).

    Outside a selection, ``values`` itself.  Inside, ``values`` broadcast to the ensemble's shape and
    flattened (``(prod(batch), P)``), then the selected rows (``(k, P)``, or ``(P,)`` for one member);
    a ``ValueError`` naming ``what`` when ``values`` do not broadcast to the ensemble.
    """
    sel = SELECTED.get()
    if sel is None:
        return values
    batch, index = sel
    try:
        flat = np.broadcast_to(values, batch + values.shape[-1:]).reshape(-1, values.shape[-1])
    except ValueError:
        raise MembersError(f"{what}: per-member values of shape {values.shape[:-1]} do not match the ensemble of "
                         f"shape {batch} being run; give one value per member (shape {batch}) or one value") from None
    return flat if index is None else flat[index]
