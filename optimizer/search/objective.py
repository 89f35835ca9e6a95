"""What makes one valid layout better than another.

Validity (count, no collisions, tolerance, stability) is not scored: the
search keeps it or rejects a move. Among builds, the energy is, in order of
weight:

1. ``MISSING`` per block short of the required count: a missing block costs
   more than any porosity difference can repay;
2. the porosity error ``|porosity - target|`` in points, porosity from the
   shared module (exact);
3. ``EVEN`` times the spread (standard deviation, points) of porosity over
   slices of the prism: an even void distribution, no holes and no clumps;
4. ``SUPPORT`` per block resting on fewer than three others or the ground:
   well-supported blocks.

The slice spread is kept incrementally from block centroids binned into
slices of the design prism (six along the crest, lower and upper half): a
cheap proxy for the slice porosity the report shows exactly.
"""

from __future__ import annotations

import numpy as np

from geometry.scene import Scene

MISSING = 10.0
EVEN = 0.05
SUPPORT = 0.02

#: Slices of the prism for the evenness term: along the crest, and in height.
SLICES_ALONG = 6
SLICES_UP = 2


def slice_index(scene: Scene, position: np.ndarray) -> int:
    """The evenness slice of a block centroid (along-crest index, lower/upper half)."""
    i = int(np.clip(position[1] / scene.length * SLICES_ALONG, 0, SLICES_ALONG - 1))
    j = int(np.clip(position[2] / scene.height * SLICES_UP, 0, SLICES_UP - 1))
    return i * SLICES_UP + j


class Energy:
    """The energy of a build, kept up to date per block.

    Parameters
    ----------
    scene : Scene
    required : int
    target : float, percent
    """

    def __init__(self, scene: Scene, required: int, target: float):
        self.scene = scene
        self.required = required
        self.target = target
        self.v_block = scene.block.volume
        # Design-prism volume of each slice (slice_index order), for turning block volume into porosity.
        self.slice_volume = np.array([p.volume for p in scene.design.cut(SLICES_ALONG, SLICES_UP)])
        self.filled = np.zeros(SLICES_ALONG * SLICES_UP)

    def total(self, count: int, porosity: float, weak: int) -> float:
        """Energy of a build with ``count`` blocks, ``porosity`` percent, ``weak`` poorly supported blocks."""
        missing = max(0, self.required - count)
        return MISSING * missing + abs(porosity - self.target) + EVEN * self.spread() + SUPPORT * weak

    def spread(self) -> float:
        """Standard deviation of slice porosity, points."""
        p = 100.0 * (1.0 - self.filled / self.slice_volume)
        return float(np.std(p))

    def add(self, position: np.ndarray) -> None:
        self.filled[slice_index(self.scene, position)] += self.v_block

    def remove(self, position: np.ndarray) -> None:
        self.filled[slice_index(self.scene, position)] -= self.v_block

    def copy(self) -> Energy:
        other = Energy.__new__(Energy)
        other.__dict__.update(self.__dict__)
        other.filled = self.filled.copy()
        return other
