"""Piles made by physics: blocks poured onto a scene's foundation.

:func:`pour` drops blocks in batches at random orientations over the design
prism's footprint and lets each batch come to rest on what is already there,
which stays fixed, so that the cost of a batch does not grow with the pile.
The result is a pile at rest on the ground, the kind of layout a settle is
asked about, for tests and benchmarks (``benchmarks/settle_speed.py``). It
is not a placement algorithm; the optimizer is.
"""

from __future__ import annotations

import numpy as np

from geometry.blocks import Block
from geometry.pose import Pose, axis_angle_quat
from geometry.samples import random_quaternion
from geometry.scene import Scene

from .base import SettleBackend
from .run import settle

#: Gap between a dropped block's lowest possible point and the pile top, m.
DROP_GAP = 0.05

#: Simulated seconds a batch is given to come to rest.
BATCH_SECONDS = 2.0

#: Most times the whole pile is released at the end, BATCH_SECONDS each.
MAX_RELEASES = 6

#: A pile counts as settled when no block moved more than this in a
#: release, metres.
SETTLED_MOTION = 0.01


def pour(
    scene: Scene,
    n: int,
    seed: int = 0,
    batch: int | None = None,
    backend: SettleBackend | None = None,
) -> list[tuple[int, Block, Pose]]:
    """Pour ``n`` of the scene's blocks onto its foundation.

    In a section scene the blocks turn about y only and fill the slice.

    Parameters
    ----------
    scene : Scene
    n : int
        Number of blocks.
    seed : int
        The same seed gives the same pile.
    batch : int, optional
        Blocks dropped at once; by default enough to cover the footprint
        sparsely (one per 12 m^2).
    backend : SettleBackend, optional
        The physics engine; by default the scene's.

    Returns
    -------
    list of (id, Block, Pose)
        Ids 0 to n-1 in the order poured (installation order).
    """
    rng = np.random.default_rng(seed)
    block = scene.block
    prism = scene.design
    r = block.bounding_radius
    if batch is None:
        footprint = 2 * prism.bottom_half_width * prism.length
        batch = max(4, int(footprint / 12.0))
    placed: list[tuple[int, Block, Pose]] = []
    tops = np.zeros((0, 3))  # (x, y, highest z) of each placed block
    while len(placed) < n:
        wave: list[tuple[int, Block, Pose]] = []
        centres: list[np.ndarray] = []
        for _ in range(50 * batch):
            if len(wave) == min(batch, n - len(placed)):
                break
            if scene.kind == "section":
                y = (prism.y_start + prism.y_end) / 2  # a section's blocks fill the slice
            else:
                y = rng.uniform(prism.y_start + r, prism.y_end - r)
            x = rng.uniform(-prism.bottom_half_width, prism.bottom_half_width)
            near = tops[np.hypot(tops[:, 0] - x, tops[:, 1] - y) < 2 * r] if len(tops) else tops
            ground = float(scene.foundation.height_at(np.array([[x, y]]))[0])
            z_top = max([ground, *near[:, 2]]) if len(near) else ground
            # Keep the pile inside the prism's slopes: the half-width shrinks
            # linearly from the bottom to the crest.
            frac = min(max(z_top / prism.height, 0.0), 1.0)
            half = prism.bottom_half_width + frac * (prism.top_half_width - prism.bottom_half_width)
            if abs(x) > max(half - 0.5 * r, 0.0):
                continue
            if scene.kind == "section":
                q = axis_angle_quat(np.array([0.0, 1.0, 0.0]), rng.uniform(-np.pi, np.pi))
            else:
                q = random_quaternion(rng)
            pose = Pose([x, y, 0.0], q)
            low = pose.apply(block.vertices)[:, 2].min()
            centre = np.array([x, y, z_top + DROP_GAP - low])
            if any(np.linalg.norm(centre - c) < 2 * r for c in centres):
                continue
            centres.append(centre)
            wave.append((len(placed) + len(wave), block, Pose(centre, q)))
        if not wave:
            raise RuntimeError(f"pour: no room for more blocks after {len(placed)} of {n}")
        # The wave falls onto the pile, and the blocks it lands among may give
        # way; the rest of the pile is held fixed, so that a wave costs about
        # the same however large the pile has grown.
        xy = np.array([c[:2] for c in centres])
        nearby = [k for k, _, p in placed if np.min(np.hypot(*(xy - p.position[:2]).T)) < 2 * r]
        result = settle(scene, placed + wave, seconds=BATCH_SECONDS, seed=int(rng.integers(2**31)),
                        backend=backend, movable=nearby + [k for k, _, _ in wave])
        placed = [(k, b, result.poses[k]) for k, b, _ in placed + wave]
        tops = np.array([(*p.position[:2], p.apply(b.vertices)[:, 2].max()) for _, b, p in placed])
    # Release the whole pile until no block moves more than SETTLED_MOTION in
    # a release (a few may go on rocking in place on a leg for longer).
    for _ in range(MAX_RELEASES):
        result = settle(scene, placed, seconds=BATCH_SECONDS, seed=int(rng.integers(2**31)), backend=backend)
        placed = [(k, b, result.poses[k]) for k, b, _ in placed]
        if result.at_rest or result.max_displacement_m <= SETTLED_MOTION:
            break
    return placed
