"""Lowering a block until it first touches: the compiled contact loop against numpy.

``DropWorld.drop`` (``optimizer/search/drop.py``) is the search's most called
step: every candidate, pattern pass and fill drop lowers a block among the
placed ones. For each pair of a moving piece and a placed piece whose
footprints meet, ``rest_height`` finds the first-contact height from the
breakpoints of their top and bottom surfaces. Until 2026-11-28 that was numpy
on arrays of a few dozen rows; it is now a loop compiled by numba
(``optimizer/search/_contact.py``). This measures, in one process, on the
``mini`` reference layout (75 blocks) and on ``tetrapod`` blocks:

* microseconds per drop, ``DropWorld.drop`` as it is, over ``DROPS`` random
  drops (random hanging, random place over the layout);
* microseconds per ``rest_height`` call, the compiled one against the numpy
  one below (the code that was replaced, kept here as the reference);
* the largest difference between their heights over every pair, and whether
  every drop lands on the same blocks with either;
* microseconds to turn the block to a new orientation (``Shape.of``), which the
  search does for every new yaw.

The first compiled call (numba's compile, or its load from the disk cache) is
timed on its own.

On a rubble underlayer each drop also finds where the block clears the ground
(``DropWorld.ground_height``), compiled since 2026-11-28 too: over ``DROPS``
random places and hangings on the foundations of ``mini-rough`` and
``tetrapod-big``, microseconds a call, compiled against the numpy code it
replaced (below), and their largest difference (``ground_speed.csv``).

Run::

    .venv/bin/python benchmarks/drop_speed.py

Writes ``benchmarks/results/drop_speed.csv``, ``ground_speed.csv`` and ``.json``.
"""

from __future__ import annotations

import time

import numpy as np
from common import ROOT, SEED, Run, mini_reference

import optimizer.search.drop as drop
from geometry.blocks import get_block
from geometry.constants import tol
from geometry.polytope import column_intervals
from geometry.pose import Pose
from geometry.samples import random_quaternion
from geometry.scene import Foundation, load_scene
from optimizer.search.drop import DropWorld, Shape
from optimizer.search.hangings import families, hanging_of

DROPS = 2000


def numpy_rest_height(moving, moving_lower, fixed, fixed_upper, offset_xy) -> float:
    """``rest_height`` as it was in numpy (to 9327b59): the reference."""
    if len(moving.normals) + len(fixed.normals) > drop.MANY_PLANES:
        return drop._rest_height_lp(moving, fixed, offset_xy)
    me, mvert = moving_lower
    fe, fvert = fixed_upper
    pts = np.concatenate([mvert[:, :2] + offset_xy, fvert[:, :2],
                          _crossings(me[:, :, :2] + offset_xy, fe[:, :, :2])])
    q_lo, q_hi = column_intervals(fixed.normals, fixed.offsets, pts)
    p_lo, p_hi = column_intervals(moving.normals, moving.offsets, pts - offset_xy)
    ok = (q_hi >= q_lo - tol.distance) & (p_hi >= p_lo - tol.distance)
    return float(np.max(q_hi[ok] - p_lo[ok])) if ok.any() else -np.inf


def _crossings(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    p, r = a[:, None, 0, :], (a[:, 1] - a[:, 0])[:, None, :]
    q, s = b[None, :, 0, :], (b[:, 1] - b[:, 0])[None, :, :]
    denom = r[..., 0] * s[..., 1] - r[..., 1] * s[..., 0]
    qp = q - p
    with np.errstate(divide="ignore", invalid="ignore"):
        t = (qp[..., 0] * s[..., 1] - qp[..., 1] * s[..., 0]) / denom
        u = (qp[..., 0] * r[..., 1] - qp[..., 1] * r[..., 0]) / denom
    ok = (np.abs(denom) > tol.parallel) & (t >= 0) & (t <= 1) & (u >= 0) & (u <= 1)
    ii, jj = np.nonzero(ok)
    return p[ii, 0] + t[ii, jj, None] * r[ii, 0]


def case(name: str, placed: list, rng: np.random.Generator) -> dict:
    block = placed[0][1]
    world = DropWorld.of(Foundation(), placed)
    xy = np.array([pose.position[:2] for _, _, pose in placed])
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    turns = [random_quaternion(rng) for _ in range(DROPS)]
    t0 = time.perf_counter()
    for q in turns:
        Shape.of(block, q)
    per_shape = (time.perf_counter() - t0) / len(turns)
    shapes = [Shape.of(block, random_quaternion(rng)) for _ in range(16)]
    drops = [(shapes[int(rng.integers(len(shapes)))], *rng.uniform(lo, hi)) for _ in range(DROPS)]

    pairs = []
    compiled = drop.rest_height

    def recording(*args):
        pairs.append(args)
        return compiled(*args)

    t0 = time.perf_counter()
    compiled(*_one_pair(world, shapes[0], placed))
    first = time.perf_counter() - t0
    drop.rest_height = recording
    try:
        landed = [world.drop(s, float(x), float(y)) for s, x, y in drops]
    finally:
        drop.rest_height = compiled
    t0 = time.perf_counter()
    for s, x, y in drops:
        world.drop(s, float(x), float(y))
    per_drop = (time.perf_counter() - t0) / len(drops)
    t0 = time.perf_counter()
    fast = [compiled(*a) for a in pairs]
    per_pair = (time.perf_counter() - t0) / len(pairs)
    t0 = time.perf_counter()
    slow = [numpy_rest_height(*a) for a in pairs]
    per_pair_numpy = (time.perf_counter() - t0) / len(pairs)
    drop.rest_height = numpy_rest_height
    try:
        again = [world.drop(s, float(x), float(y)) for s, x, y in drops]
    finally:
        drop.rest_height = compiled
    finite = [(a, b) for a, b in zip(fast, slow, strict=True) if np.isfinite(a) or np.isfinite(b)]
    return {
        "case": name, "blocks": len(placed), "drops": len(drops), "pairs": len(pairs),
        "drop_us": round(per_drop * 1e6, 1), "shape_us": round(per_shape * 1e6, 1),
        "pair_us": round(per_pair * 1e6, 2), "pair_numpy_us": round(per_pair_numpy * 1e6, 2),
        "speedup": round(per_pair_numpy / per_pair, 1),
        "max_height_diff_m": max((abs(a - b) for a, b in finite), default=0.0),
        "same_misses": all(np.isfinite(a) == np.isfinite(b) for a, b in zip(fast, slow, strict=True)),
        "same_supports": all(a[1] == b[1] and a[2] == b[2] for a, b in zip(landed, again, strict=True)),
        "first_call_s": round(first, 3),
    }


def _one_pair(world: DropWorld, shape: Shape, placed: list) -> tuple:
    """The arguments of one ``rest_height`` call: the shape over the first placed block."""
    key = placed[0][0]
    _, position, pieces, upper, _ = world._placed[key]
    return shape.pieces[0], shape.lower[0], pieces[0], upper[0], np.asarray(position[:2], float)


def tetrapods(n: int, rng: np.random.Generator) -> list:
    """``n`` tetrapods of 2 m laid as a crane lays them, at random places over 8 x 8 m."""
    block = get_block("tetrapod:2")
    world = DropWorld(Foundation(), cell=2 * block.bounding_radius)
    placed = []
    for k in range(n):
        shape = Shape.of(block, random_quaternion(rng))
        x, y = rng.uniform(0, 8, 2)
        z, _, _ = world.drop(shape, float(x), float(y))
        world.add(k, shape, np.array([x, y, z]))
        placed.append((k, block, Pose([x, y, z], shape.quaternion)))
    return placed


def numpy_ground_height(world: DropWorld, shape: Shape, x: float, y: float) -> float:
    """``DropWorld.ground_height`` on rough ground as it was in numpy (to fa12b4b): the reference."""
    f = world.foundation
    xs, ys, _ = f.grid
    offset = np.array([x, y])
    lo_xy, hi_xy = shape.xy_boxes[:, 0].min(axis=0) + offset, shape.xy_boxes[:, 1].max(axis=0) + offset
    i0, i1 = np.searchsorted(xs, lo_xy[0]), np.searchsorted(xs, hi_xy[0], side="right")
    j0, j1 = np.searchsorted(ys, lo_xy[1]), np.searchsorted(ys, hi_xy[1], side="right")
    gx, gy = np.meshgrid(xs[i0:i1], ys[j0:j1], indexing="ij")
    local = np.concatenate([shape.vertices_xy, np.column_stack([gx.ravel(), gy.ravel()]) - offset])
    ground = f.height_at(local + offset)
    best = -np.inf
    for p in shape.pieces:
        lo, hi = column_intervals(p.normals, p.offsets, local)
        ok = hi >= lo - tol.distance
        if ok.any():
            best = max(best, float(np.max(ground[ok] - lo[ok])))
    return best


def ground_case(name: str, rng: np.random.Generator) -> dict:
    """``ground_height`` on a scene's rubble, compiled and numpy, over ``DROPS`` random calls."""
    scene = load_scene(ROOT / "benchmarks" / "scenes" / f"{name}.toml")
    world = DropWorld(scene.foundation)
    kinds = families(scene.block)
    shapes = [Shape.of(scene.block, hanging_of(scene.block, kinds[i % len(kinds)], rng.uniform(0, 2 * np.pi)))
              for i in range(16)]
    z = scene.tolerance
    half = z.bottom_half_width
    calls = [(shapes[int(rng.integers(len(shapes)))], float(rng.uniform(-half, half)),
              float(rng.uniform(z.y_start, z.y_end))) for _ in range(DROPS)]
    t0 = time.perf_counter()
    world.ground_height(*calls[0])
    first = time.perf_counter() - t0
    t0 = time.perf_counter()
    fast = [world.ground_height(*c) for c in calls]
    per_call = (time.perf_counter() - t0) / len(calls)
    t0 = time.perf_counter()
    slow = [numpy_ground_height(world, *c) for c in calls]
    per_call_numpy = (time.perf_counter() - t0) / len(calls)
    return {"case": f"{name} ({scene.block_type}, rubble {scene.foundation.amplitude:g} m)",
            "calls": len(calls),
            "call_us": round(per_call * 1e6, 1), "call_numpy_us": round(per_call_numpy * 1e6, 1),
            "speedup": round(per_call_numpy / per_call, 1),
            "max_height_diff_m": max(abs(a - b) for a, b in zip(fast, slow, strict=True)),
            "first_call_s": round(first, 3)}


def main() -> None:
    run = Run("drop_speed", {"drops": DROPS, "seed": SEED})
    rng = np.random.default_rng(SEED)
    rows = [case("mini reference (shake-4t)", mini_reference(), rng),
            case("60 tetrapods of 2 m", tetrapods(60, rng), rng)]
    for r in rows:
        print(f"{r['case']}: {r['drop_us']} us a drop; rest_height {r['pair_us']} us compiled, "
              f"{r['pair_numpy_us']} us numpy ({r['speedup']}x), largest height difference "
              f"{r['max_height_diff_m']:.1e} m, same supports {r['same_supports']}; first call "
              f"{r['first_call_s']} s; a new orientation {r['shape_us']} us")
    run.csv("drop_speed", rows)
    grounds = [ground_case(name, rng) for name in ("mini-rough", "tetrapod-big")]
    for r in grounds:
        print(f"ground under a block, {r['case']}: {r['call_us']} us compiled, {r['call_numpy_us']} us numpy "
              f"({r['speedup']}x), largest difference {r['max_height_diff_m']:.1e} m; first call "
              f"{r['first_call_s']} s")
    run.csv("ground_speed", grounds)
    run.done()


if __name__ == "__main__":
    main()
