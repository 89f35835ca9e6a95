"""Block shapes by orientation, built once per orientation a search uses."""

from __future__ import annotations

import numpy as np

from geometry.blocks import Block

from .drop import Shape
from .hangings import hanging_of


class ShapeCache:
    """Shapes by quantised orientation, so repeated hangings are built once.

    Parameters
    ----------
    block : Block
    """

    def __init__(self, block: Block):
        self.block = block
        self._cache: dict[tuple, Shape] = {}

    def hung(self, family: str, yaw: float) -> Shape:
        """The shape of the block hung in ``family`` (``hangings.families``), turned by ``yaw`` radians."""
        return self.get(hanging_of(self.block, family, yaw))

    def get(self, q: np.ndarray) -> Shape:
        """The shape of the block turned by ``q`` (scalar first), rounded to 1e-12."""
        key = tuple(np.round(q, 12))
        s = self._cache.get(key)
        if s is None:
            s = self._cache[key] = Shape.of(self.block, q)
        return s
