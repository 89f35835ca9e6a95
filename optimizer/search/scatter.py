"""A poor layout on purpose: blocks dropped at random, each where it comes to rest.

What an untrained crane operator might lay: the crane's hangings (crown,
level, horizontal, or a mesh block's rest poses) at any yaw, anywhere over the
mound, no pattern. Every block is valid as it lands (no collision, inside the
tolerance zone, at rest among its neighbours), so the layout is valid but loose.
``shoha optimize --keep`` is measured on completing such a start
(``benchmarks/keep.py``), beside a reference cut short.
"""

from __future__ import annotations

import numpy as np

from geometry.scene import Scene
from settle import settle

from .build import Build, search_window
from .drop import Shape
from .hangings import families, hanging_of
from .patterns import lattice_for
from .physics import ROUNDS, carried_closure, settle_in
from .problem import Problem


def scatter(scene: Scene, n: int, seed: int = 0, tries: int = 5000) -> Build:
    """Up to ``n`` blocks dropped at random over the tolerance zone's footprint, hung at random.

    Each is lowered until it touches and let go among the blocks already
    there (:func:`optimizer.search.physics.settle_in`); one that would not
    rest, or ends out of the zone, is drawn again. Then the whole layout is
    settled: blocks that fail, with what rests on them, are taken out and
    drawn again, for up to ``ROUNDS`` rounds. Stops after ``tries`` draws
    even if short of ``n``; the last round's verdict is not checked again.
    """
    rng = np.random.default_rng(seed)
    problem = Problem(scene=scene, required=n, target=scene.target_porosity,
                      lattice=lattice_for(scene.block, scene.block_type), families=families(scene.block))
    build = Build(scene)
    left = tries
    for _ in range(ROUNDS):
        left = _drop(problem, build, rng, n, left)
        result = settle(scene, build.placed(), seed=0)
        if result.stable or result.diverged:
            break
        for k in sorted(carried_closure(build, set(result.unstable_ids)), key=build.order.index,
                        reverse=True):
            build.remove(k)
    return build


def _drop(problem: Problem, build: Build, rng: np.random.Generator, n: int, tries: int) -> int:
    """Drop blocks until ``n`` rest or ``tries`` run out; returns the tries left."""
    (x_start, x_end), (y_start, y_end) = search_window(problem.scene)
    while len(build) < n and tries > 0:
        tries -= 1
        family = problem.families[int(rng.integers(len(problem.families)))]
        shape = Shape.of(problem.scene.block, hanging_of(problem.scene.block, family,
                                                         float(rng.uniform(0, 2 * np.pi))))
        x = rng.uniform(x_start, x_end)
        y = rng.uniform(y_start, y_end)
        c = build.lower(shape, float(x), float(y))
        c = settle_in(problem, build, c) if c is not None else None
        if c is not None:
            build.place(c)
    return tries
