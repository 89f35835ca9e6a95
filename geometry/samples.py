"""Sample layouts for tests, benchmarks and the paper's experiment.

:func:`random_inside` places blocks at random poses wholly inside a prism,
without collisions, by rejection: the setting of the reference paper's
Fig. 16 (blocks "assuming no protrusions", whose exact porosity eq. (1) gives).
It is not a placement algorithm; the optimizer is.
"""

from __future__ import annotations

import numpy as np
from scipy.spatial.transform import Rotation

from .blocks import Block
from .collision import CollisionWorld
from .constants import tol
from .pose import Pose, quat_to_matrix
from .tolerance import TrapezoidalPrism


def random_quaternion(rng: np.random.Generator) -> np.ndarray:
    """A uniformly random unit quaternion ``[w, x, y, z]`` with ``w >= 0`` (scipy's ``Rotation.random``)."""
    return Rotation.random(rng=rng).as_quat(canonical=True, scalar_first=True)


def random_inside(
    block: Block, prism: TrapezoidalPrism, n: int, seed: int = 0, max_tries: int = 200_000,
) -> list[tuple[int, Block, Pose]]:
    """``n`` blocks at random poses, each wholly inside ``prism``, none colliding.

    Raises
    ------
    RuntimeError
        If ``max_tries`` random poses do not yield ``n`` blocks.
    """
    rng = np.random.default_rng(seed)
    poly = prism.polytope
    lo, hi = prism.bounds
    world = CollisionWorld(cell=2 * block.bounding_radius)
    placed: list[tuple[int, Block, Pose]] = []
    batch = 512
    for _ in range(0, max_tries, batch):
        # Draw a batch of poses and test containment for all of them at once.
        positions = rng.uniform(lo, hi, (batch, 3))
        quats = np.array([random_quaternion(rng) for _ in range(batch)])
        world_vertices = np.einsum("bij,vj->bvi", quat_to_matrix(quats), block.vertices) + positions[:, None]
        ok = np.all(world_vertices @ poly.normals.T <= poly.offsets + tol.distance, axis=(1, 2))
        for i in np.flatnonzero(ok):
            pose = Pose(positions[i], quats[i])
            if world.query(block, pose, threshold=-1.0, first=True):
                continue
            world.add(len(placed), block, pose)
            placed.append((len(placed), block, pose))
            if len(placed) == n:
                return placed
    if len(placed) < n:
        raise RuntimeError(f"placed only {len(placed)} of {n} blocks in {max_tries} tries")
    return placed
