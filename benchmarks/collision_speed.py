"""Collision checks: shoha's FCL path against naive pairwise ``fcl.collide`` on whole meshes.

shoha (``geometry.collision.collisions``) prunes pairs by bounding sphere
(a k-d tree) and by convex-piece bounding boxes, then runs FCL's GJK/EPA on
the convex pieces that remain. The obvious alternative is what the python-fcl
README shows: one ``fcl.BVHModel`` of the block's triangle mesh, one
``fcl.CollisionObject`` per block, and ``fcl.collide`` on every pair.

Both run in the same process on the same fixed layouts: the 75-block mini
reference (packed, collision-free), the same jittered (blocks pushed into
each other), and the reference tiled along the crest to 300 and 1000 blocks
(``common.tiled``), plain and jittered.

Measured per layout:

* shoha, as ``shoha check`` runs it (penetration deeper than
  ``tol.contact_depth`` = 5 mm, with depths), and as a boolean contact test
  (``threshold=-1``, like-for-like with the naive boolean);
* naive: building the objects, then ``fcl.collide`` on all n(n-1)/2 pairs
  (boolean, one contact);
* FCL's own broadphase, ``fcl.DynamicAABBTreeCollisionManager``, on the same
  convex pieces, with depths (the alternative to shoha's k-d tree and piece
  boxes): every piece gets its own ``fcl.Convex``, so that a contact's
  geometry names its block, and the deepest contact per block pair is kept.
  Building the manager is counted. Its colliding pairs must be shoha's.

The optimizer asks one question far more often: does this one block,
lowered here, touch any placed block? That is timed too, for 200 random
blocks against the 75 and 1000-block layouts: ``CollisionWorld.query``
(grid of cells by centre, bounding spheres, piece boxes, then FCL) against
the manager's one-to-many ``collide`` with each of the block's pieces.

"Pair checks per second" is n(n-1)/2 block pairs decided, over the total
time (objects built included for both). Colliding pair sets are compared:
the naive mesh test and shoha's contact test must agree.

Run::

    .venv/bin/python benchmarks/collision_speed.py

Writes ``benchmarks/results/collision_speed.csv`` and ``.json``.
"""

from __future__ import annotations

import itertools

import fcl
import numpy as np
from common import SEED, Placed, Run, jittered, mini_reference, tiled, timed

from geometry.collision import CollisionWorld, collisions
from geometry.constants import tol
from geometry.pose import Pose
from geometry.samples import random_quaternion

REPEATS = 5


def naive(placed: Placed) -> set[tuple[int, int]]:
    """Colliding pairs by ``fcl.collide`` on every pair of whole-mesh BVH models."""
    models = {}
    objects = []
    for key, block, pose in placed:
        model = models.get(id(block))
        if model is None:
            model = fcl.BVHModel()
            model.beginModel(len(block.vertices), len(block.faces))
            model.addSubModel(block.vertices, block.faces)
            model.endModel()
            models[id(block)] = model
        objects.append((key, fcl.CollisionObject(model, fcl.Transform(pose.rotation, pose.position))))
    request = fcl.CollisionRequest(num_max_contacts=1, enable_contact=False)
    hits = set()
    for (ka, a), (kb, b) in itertools.combinations(objects, 2):
        if fcl.collide(a, b, request, fcl.CollisionResult()):
            hits.add((min(ka, kb), max(ka, kb)))
    return hits


def _piece_objects(block, pose: Pose) -> tuple[list, list]:
    """Posed FCL objects of a block's pieces, each on its own copy of the piece's geometry."""
    tf = fcl.Transform(pose.rotation, pose.position)
    geoms = []
    for piece in block.pieces:
        faces = np.hstack([np.full((len(piece.faces), 1), 3), piece.faces]).ravel()
        geoms.append(fcl.Convex(np.ascontiguousarray(piece.vertices), len(piece.faces), faces))
    return geoms, [fcl.CollisionObject(g, tf) for g in geoms]


def manager_pairs(placed: Placed, threshold: float = tol.contact_depth) -> dict[tuple[int, int], float]:
    """Block pairs deeper than ``threshold`` by FCL's dynamic AABB tree, with their depths."""
    owner: dict[int, int] = {}
    objects = []
    for key, block, pose in placed:
        geoms, objs = _piece_objects(block, pose)
        owner.update({id(g): key for g in geoms})
        objects += objs
    manager = fcl.DynamicAABBTreeCollisionManager()
    manager.registerObjects(objects)
    manager.setup()
    request = fcl.CollisionRequest(num_max_contacts=100_000, enable_contact=True)
    data = fcl.CollisionData(request, fcl.CollisionResult())
    manager.collide(data, fcl.defaultCollisionCallback)
    out: dict[tuple[int, int], float] = {}
    for c in data.result.contacts:
        a, b = owner[id(c.o1)], owner[id(c.o2)]
        if a == b:
            continue
        pair = (min(a, b), max(a, b))
        out[pair] = max(out.get(pair, 0.0), c.penetration_depth)
    return {p: d for p, d in out.items() if d > threshold}


def query_times(placed: Placed, probes: int = 200) -> tuple[float, float, bool]:
    """Seconds per one-block query: shoha's world, and the manager; and whether they agree."""
    rng = np.random.default_rng(SEED)
    block = placed[0][1]
    lo = np.min([p.position for _, _, p in placed], axis=0)
    hi = np.max([p.position for _, _, p in placed], axis=0)
    poses = [Pose(rng.uniform(lo, hi), random_quaternion(rng)) for _ in range(probes)]
    world = CollisionWorld(cell=2.0 * block.bounding_radius)
    for key, b, pose in placed:
        world.add(key, b, pose)
    owner: dict[int, int] = {}
    manager = fcl.DynamicAABBTreeCollisionManager()
    for key, b, pose in placed:
        geoms, objs = _piece_objects(b, pose)
        owner.update({id(g): key for g in geoms})
        manager.registerObjects(objs)
    manager.setup()

    def ours() -> list[bool]:
        return [bool(world.query(block, p, threshold=-1.0, first=True)) for p in poses]

    def theirs() -> list[bool]:
        out = []
        for p in poses:
            hit = False
            for obj in _piece_objects(block, p)[1]:
                data = fcl.CollisionData(fcl.CollisionRequest(), fcl.CollisionResult())
                manager.collide(obj, data, fcl.defaultCollisionCallback)
                if data.result.is_collision:
                    hit = True
                    break
            out.append(hit)
        return out

    t_ours, a = timed(ours, repeats=3)
    t_theirs, b = timed(theirs, repeats=3)
    return t_ours.median / probes, t_theirs.median / probes, a == b


def layouts() -> list[tuple[str, Placed]]:
    ref = mini_reference()
    out = [("75 reference", ref), ("75 jittered", jittered(ref, 0.1, 5.0, seed=SEED))]
    for n in (300, 1000):
        _, placed = tiled(n)
        out += [(f"{n} tiled", placed), (f"{n} tiled jittered", jittered(placed, 0.1, 5.0, seed=SEED))]
    return out


def main() -> None:
    run = Run("collision_speed", {"repeats": REPEATS, "seed": SEED,
                                  "jitter": "0.1 m per axis, 5 degrees (common.jittered)"})
    naive(mini_reference()[:3])  # warm-up: FCL's code paths
    collisions(mini_reference()[:3])
    rows = []
    for name, placed in layouts():
        n = len(placed)
        pairs = n * (n - 1) // 2
        t_check, hits = timed(lambda p=placed: collisions(p), repeats=REPEATS)
        t_touch, touching = timed(lambda p=placed: collisions(p, threshold=-1.0), repeats=REPEATS)
        naive_repeats = REPEATS if n <= 300 else 1
        t_naive, naive_hits = timed(lambda p=placed: naive(p), repeats=naive_repeats, warmup=0)
        t_manager, managed = timed(lambda p=placed: manager_pairs(p), repeats=REPEATS)
        ours = {(c.a, c.b) for c in touching}
        row = {
            "layout": name, "blocks": n, "block_pairs": pairs,
            "colliding_pairs_over_5mm": len(hits), "touching_pairs_shoha": len(ours),
            "touching_pairs_naive": len(naive_hits), "same_pairs": ours == naive_hits,
            "shoha_check_s": t_check.median, "shoha_contact_s": t_touch.median, "naive_s": t_naive.median,
            "shoha_check_pairs_per_s": pairs / t_check.median,
            "shoha_contact_pairs_per_s": pairs / t_touch.median,
            "naive_pairs_per_s": pairs / t_naive.median,
            "speedup_contact": t_naive.median / t_touch.median,
            "speedup_check": t_naive.median / t_check.median,
            "naive_repeats": naive_repeats,
            "fcl_manager_check_s": t_manager.median,
            "fcl_manager_same_pairs": set(managed) == {(c.a, c.b) for c in hits},
            "shoha_over_manager": t_manager.median / t_check.median,
        }
        rows.append(row)
        print(f"{name:<20} {n:>5} blocks  shoha check {1e3 * t_check.median:8.1f} ms  "
              f"contact {1e3 * t_touch.median:8.1f} ms  naive {1e3 * t_naive.median:9.1f} ms  "
              f"({row['speedup_contact']:.0f}x; {row['naive_pairs_per_s']:.3g} vs "
              f"{row['shoha_contact_pairs_per_s']:.3g} pairs/s)  pairs {len(ours)}/{len(naive_hits)} "
              f"{'same' if row['same_pairs'] else 'DIFFER'}; FCL manager {1e3 * t_manager.median:8.1f} ms "
              f"({'same' if row['fcl_manager_same_pairs'] else 'DIFFERENT'} pairs)")
        if ours != naive_hits:
            print(f"  only shoha: {sorted(ours - naive_hits)[:5]}")
            print(f"  only naive: {sorted(naive_hits - ours)[:5]}")
    run.csv("collision_speed", rows)
    query_rows = []
    for name, placed in layouts():
        if "jittered" in name or name == "300 tiled":
            continue
        ours, theirs, same = query_times(placed)
        query_rows.append({"layout": name, "blocks": len(placed), "shoha_query_s": ours,
                           "fcl_manager_query_s": theirs, "same_answers": same,
                           "manager_over_shoha": theirs / ours})
        print(f"one-block query on {name}: shoha {1e6 * ours:.0f} us, FCL manager {1e6 * theirs:.0f} us "
              f"({'same' if same else 'DIFFERENT'} answers)")
    run.csv("collision_query_speed", query_rows)
    speedups = np.array([r["speedup_contact"] for r in rows])
    print(f"shoha's contact test: {speedups.min():.0f}x to {speedups.max():.0f}x faster than naive pairwise")
    run.done()


if __name__ == "__main__":
    main()
