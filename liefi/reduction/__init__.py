"""Extension and reduction of nonholonomic systems, derived from the data.

:mod:`liefi.reduction.core` computes ``h~``, ``J``, ``lambda``, ``lambda~``, the
constrained and extended fields on the reduced phase space and the
reconstruction; :mod:`liefi.reduction.lift` builds the *unreduced* canonical
system on ``T*Q`` in coordinates from a reduced one, which is how the test
suite checks that extension commutes with reduction.
"""

from .core import (
    Terms,
    constrained_vector_field,
    constraint_momenta,
    evaluate,
    extended_hamiltonian,
    extended_multipliers,
    extended_vector_field,
    full_vector_field,
    gram_matrix,
    group_velocity,
    hamiltonian,
    multipliers,
    poisson_bracket,
    project,
    projected_vector_field,
    reconstruction,
)
from .lift import LeftTrivialization, unreduce

__all__ = [
    "Terms",
    "evaluate",
    "hamiltonian",
    "extended_hamiltonian",
    "constraint_momenta",
    "gram_matrix",
    "multipliers",
    "extended_multipliers",
    "constrained_vector_field",
    "extended_vector_field",
    "full_vector_field",
    "project",
    "projected_vector_field",
    "group_velocity",
    "reconstruction",
    "poisson_bracket",
    "LeftTrivialization",
    "unreduce",
]
