"""Lie groups: algebra structure (derived from hat/vee) and configuration embeddings.

Concrete groups: :class:`SO3`, :class:`SE3`, :class:`SE2` (rotation as matrix or angle),
:class:`SO2` (the circle as a 2x2 matrix), :class:`S1` (the circle as an
angle), :class:`Rn`; direct products with ``G * H`` or :class:`ProductGroup`; the representation
of a group by (a block of) its matrix, where advected vectors live: :class:`Representation`.
"""

from .base import LieGroup, MatrixLieGroup
from .product import ProductGroup
from .representation import Representation
from .rn import Rn
from .se2 import SE2
from .se3 import SE3
from .so2 import S1, SO2
from .so3 import SO3

__all__ = ["LieGroup", "MatrixLieGroup", "ProductGroup", "Representation", "Rn", "SE2", "SE3", "SO2", "S1", "SO3"]
