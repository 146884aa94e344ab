"""The runtime constants of a :func:`liefi.from_mechanics` system: one set, or one per member of an ensemble.

Part of :mod:`liefi.systems.mechanics`.  The generated data functions read the constants ``values``
(``(P,)``, or ``(*B, P)`` per member of an ensemble of shape ``B``) each time they are evaluated, aligned
with the states they are evaluated at (:meth:`_Constants.aligned`): member ``b``'s row for member ``b``'s
states, never another's (:mod:`liefi._members`).
"""

from __future__ import annotations

import numpy as np


class _Constants:
    """The runtime constants shared by the data functions of one system: ``values`` of shape ``(..., P)``."""

    def __init__(self, symbols, values):
        self.symbols = tuple(symbols)
        self.names = tuple(str(s) for s in symbols)
        self.values = values
        #: the inputs of every data function bound so far (:func:`_bound`): the system's fingerprint
        self.bound = []

    def parse(self, constants):
        """An array ``(..., P)`` from a mapping ``{symbol or name: value(s)}`` or an array."""
        from .. import _data

        P = len(self.symbols)
        if isinstance(constants, dict):
            given = {}
            for key, val in constants.items():
                name = key if isinstance(key, str) else str(key)
                if name not in self.names:
                    raise ValueError(f"constants: {name!r} is not a parameter of the model; its parameters are {list(self.names)}")
                given[name] = _data.as_float_array(val, f"constants[{name!r}]", "a real number (or one per member)")
            missing = [s for s in self.names if s not in given and self.values is None]
            if missing:
                raise ValueError(f"constants: no value for {missing}; pass constants={{{', '.join(f'{s}: ...' for s in missing)}}}")
            old = self.values
            cols = [given[s] if s in given else old[..., k] for k, s in enumerate(self.names)]
            try:
                cols = np.broadcast_arrays(*cols) if cols else []
            except ValueError:
                raise ValueError("constants: the values have shapes that do not broadcast "
                                 f"({[np.shape(c) for c in cols]})") from None
            arr = np.stack(cols, -1) if cols else np.zeros((0,))
        else:
            from .._data import as_float_array

            arr = as_float_array(constants, "constants")
            if arr.shape[-1:] != (P,):
                raise ValueError(f"constants: expected {P} values {list(self.names)} on the last axis, got shape {arr.shape}")
        if not np.all(np.isfinite(arr)):
            raise ValueError("constants: contains non-finite numbers")
        return arr

    def aligned(self, batch):
        """The constants shaped to broadcast against a data function's argument of batch shape ``batch``.

        The member axes are explicit, never matched by length: per-member constants
        ``(*B, P)`` belong to the *last* axes of the states' batch, as the per-member gains
        and targets of a :class:`~liefi.FeedbackIntegrator` do (numpy broadcasting): an
        ensemble's states ``(*B, n)``, and liefi's time-major stacks of saved states
        ``(T, *B, n)``.  The axis a complex-step derivative appends to the states
        (:data:`liefi._diff.STATE_AXES`) is not a state axis.  Where liefi evaluates some
        members only (a few standing for the ensemble in a stiffness estimate, one member at
        its start) it declares which (:mod:`liefi._members`), and they get their own rows.
        Any other states -- a single state, a batch that does not end in ``B``, a
        member-major stack ``(*B, T, n)`` -- get a ``ValueError`` naming ``constants``:
        never another member's constants.
        """
        from .. import _members
        from .._diff import state_batch

        c = self.values
        if c.ndim < 2:
            return c
        c = _members.rows(c)  # the members liefi evaluates now (all of them outside a selection)
        cb = c.shape[:-1]
        if not cb:  # one member selected: its constants for any of its states
            return c
        batch = tuple(batch)
        states, k = state_batch(batch + (0,)), len(cb)
        if len(states) >= k and states[len(states) - k :] == cb:
            lead = len(states) - k
            return c.reshape((1,) * lead + cb + (1,) * (len(batch) - len(states)) + c.shape[-1:])
        if any(states[i : i + k] == cb for i in range(len(states) - k + 1)):
            raise _members.MembersError(
                f"constants: per-member constants for an ensemble of shape {cb}, but states of batch shape {states} "
                f"hold its members on other than their last axes; stack the states time-major, shape (T, *{cb}, n) "
                "(the members last, as liefi's own stacks)"
            )
        got = f"states of batch shape {states}" if states else "a single state"
        raise _members.MembersError(
            f"constants: the system holds per-member constants for an ensemble of shape {cb} (constants of shape "
            f"{self.values.shape}), but it was evaluated at {got}; give one state per member (shape {_shape(cb + ('n',))}, "
            f"or time-major {_shape(('T',) + cb + ('n',))}), or set one value of each constant for a single state "
            "(system.constants = system.constants[k] for member k)"
        )


def _shape(parts):
    """``(3, n)``: a shape with named axes, as text."""
    return "(" + ", ".join(str(p) for p in parts) + ")"
