"""What limits the optimizer on the built-in ``tetrapod`` scene (issue 4).

The scene asks for 81 tetrapods (H = 2 m) at 50 % porosity in a 3.5 m
mound. With the count fixed at N, porosity is ``1 - N V f / V_B``, where
``f`` is the share of the blocks' volume inside the design prism; so 81
blocks come within 1 point of 50 % only if ``f`` is at least
``0.49 V_B / (81 V)``, about 97.4 %. This script measures, on the same
machine and code as everything else:

* ``shoha optimize tetrapod`` for seeds 1, 2 and 3 (the default pipeline
  and its 120 s limit): blocks placed, porosity, time, validity, CP-SAT
  gap, and ``f``, split between blocks on the foundation and blocks resting
  on other blocks; and the porosity the required count would give at the
  same ``f``;
* the toe: the farthest from the axis a tetrapod's centroid can be when it
  rests on the foundation inside the tolerance zone, over random
  orientations, and the largest ``f`` of a block resting there with its
  centroid at a given distance from the axis. The design prism reaches
  further out than any tetrapod can;
* where the volume outside the prism goes: for each layout, the volume
  past the crest, past the slopes and past the ends, against the most the
  required count may lose and still come within 1 point of the target;
* where the blocks' volume is inside the prism: the solid share of the
  prism in bands of ``|x|`` (distance from the axis) and height, for seed 1
  (the shared module's voxel grid, 5 cm voxels). The toe and the wedge
  under the slopes above the first layer hold little; the interior makes up
  for them only in part;
* with ``--variants``, the design: the same pipeline (seed 1) on copies of
  the scene 3.75 m, 4 m and 6 m high, and 4 m high with a wider crest,
  each with a time limit scaled by its required count. A 4 m mound takes
  the second layer under its crest, but its slopes then hold fewer blocks
  than it requires, and a wider crest adds about as many blocks as it
  requires; the 6 m mound, with layers laid on the first two, falls
  further short. ``make bench`` leaves this out for time (about 12
  minutes more: the copies, the one-layer scene's among them, took 738 s
  of a 1143 s run);
* the second layer: random drops, in each hanging with a random yaw and in
  free orientation, onto a patch of the tuned first layer (the crown/level
  lattice the optimizer lays on the foundation), as the crane lowers them.
  For each family, the lowest top reached, and the largest share of such a
  block under the design crest (the block moved to the middle of the crest,
  where only the crest plane cuts it);
* the pattern's packing density away from the slopes and ends: the tuned
  first layer and its upper layer laid in crane order on a patch of
  lattice cells, and the solid share of a window of whole cells at its
  middle, up to the design crest and up to the upper layer's top
  (``interior_rows``). The block packs denser there than the target asks;
* ``shoha optimize tetrapod-layer`` for the same seeds: one layer of the
  same tetrapods in a 2 m mound with a 10 m crest, where the interior makes
  up for the slopes and toes; with ``--variants``, seed 1 on copies of it
  with narrower crests;
* the same crane drops released: each is lowered until it first touches,
  then MuJoCo settles it for a few seconds with only it free and the blocks
  under it held fixed, as a block slides into a pocket after the crane lets
  go. Over the crest onto seed 1's blocks on the foundation, and at the toes
  onto seed 1's whole layout: how many come to rest inside the tolerance
  zone, penetrating nothing, how low their tops end, and how much of them is
  inside the design prism where they rest; and a second layer of such
  blocks on seed 1's blocks on the foundation, each the released drop of
  ``GREEDY_CANDIDATES`` with the most volume inside, settled whole at the end;
* with ``--bound``, CP-SAT's bound on the blocks over seed 1's first layer:
  over a grid of candidates lowered onto its blocks on the foundation, the
  most their mean share inside can be (``upper_bound_row``), against the
  share they need. ``make bench`` leaves it out for time (264 s more, which
  would take the run past its 30-minute cap).

Writes ``results/tetrapod_limit.{csv,json}`` (the runs),
``results/tetrapod_solid.csv`` (the solid share by band),
``results/tetrapod_variants.csv`` and ``results/tetrapod_variants_solid.csv``
(the copies and the 4 m copy's map, with ``--variants``),
``results/tetrapod_toe.csv`` (the toe), ``results/tetrapod_nest.csv``
(the second layer), ``results/tetrapod_interior.csv`` (the pattern's own
density), ``results/tetrapod_release.csv`` (the drops released),
``results/tetrapod_release_greedy.csv`` (the second layer they make),
``results/tetrapod_layer.csv`` and ``results/tetrapod_layer_variants.csv`` (the one-layer
scene, and its copies with ``--variants``) and
``results/tetrapod_upper_bound.csv`` (the bound, with ``--bound``).

Run::

    .venv/bin/python benchmarks/studies/tetrapod_limit.py [--variants] [--bound]

It is a study, not a benchmark: ``make bench`` does not run it. Its findings
are written up in docs/tetrapod-study.md.
"""

from __future__ import annotations

import argparse
import sys
import time
import tomllib
from importlib import resources
from pathlib import Path
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))  # benchmarks/common.py
from common import Run  # noqa: E402

from geometry.clip import volume_inside, volumes_inside  # noqa: I001
from geometry.collision import world_of
from geometry.constants import tol
from geometry.polytope import ConvexPolytope
from geometry.porosity import PorosityTracker
from geometry.pose import Pose
from geometry.samples import random_quaternion
from geometry.scene import load_scene, parse_scene
from optimizer.api import optimize
from optimizer.search.cpsat import CpSat, overlapping_pairs
from optimizer.search.drop import DropWorld, Shape
from optimizer.search.hangings import FAMILIES, hanging
from optimizer.search.patterns import first_layer, lattice_for, lay_upper
from settle import settle

SEEDS = (1, 2, 3)
LIMIT = 120.0
#: A block whose lowest point is this close to the foundation rests on it, m.
ON_GROUND = 0.05
TOE_SAMPLES = 20000
TOE_DISTANCES = (4.0, 4.2, 4.4, 4.6, 4.8)
NEST_SAMPLES = 1500
#: Released drops per place (``release_rows``), and the simulated seconds each settles.
RELEASE_SAMPLES = 400
RELEASE_SECONDS = 3.0
#: Where released drops fall, as ranges of x (m) on either side of the axis:
#: over the crest, and at the toes.
RELEASE_PLACES = {"crest": (0.0, 1.5), "toes": (3.6, 5.4)}
#: Released drops tried for each block of the greedy second layer.
GREEDY_CANDIDATES = 100
#: The bound on the blocks over the first layer (``upper_bound_row``): candidates on
#: a grid of this step (m), in each hanging at this many yaws plus this many free
#: orientations; a block less than ``BOUND_FLOOR`` inside counts as that share;
#: CP-SAT's deterministic time limit.
BOUND_STEP = 0.5
BOUND_YAWS = 8
BOUND_FREE = 8
BOUND_FLOOR = 0.90
BOUND_SECONDS = 120.0
#: The interior patch (``interior_rows``): lattice cells on every side of its centre cell,
#: and the side, in cells, of the window cut from its middle.
INTERIOR_RING = 3
INTERIOR_CELLS = 3
#: Copies of the scene run with seed 1 (``--variants``): design height and
#: crest width, m (None keeps the built-in crest). Each copy's time limit is
#: ``LIMIT`` scaled by its required count over the built-in scene's, so that
#: a larger copy is not cut short by the clock alone.
VARIANTS = ((3.75, None), (4.0, None), (4.0, 6.0), (4.0, 8.0), (6.0, None))
#: The one-layer scene, run for ``SEEDS``; with ``--variants``, copies of it as
#: ``VARIANTS`` (its height kept, these crest widths).
LAYER = "tetrapod-layer"
LAYER_VARIANTS = ((None, 4.0), (None, 6.0), (None, 8.0))
#: Bands of the solid-share map (m), and its voxel edge (m).
BAND = 1.0
VOXEL = 0.05
#: Faces of the design prism by outward normal: the volume past each group is a loss.
FACES = {"crest": lambda n: n[2] > 0.9, "ends": lambda n: abs(n[1]) > 0.9,
         "slopes": lambda n: abs(n[0]) > 0.1 and abs(n[2]) < 0.9}


def inside_share_needed(scene, within: float = 1.0) -> float:
    """Least inside share ``f`` for the required count to land within ``within`` points of target."""
    filled = (1 - (scene.target_porosity + within) / 100) * scene.design_volume
    return filled / (scene.required_blocks * scene.block.volume)


def rest_share_needed(scene, ground_inside: float, ground: int) -> float:
    """Mean share inside that the blocks the required count leaves over ``ground`` blocks on the
    foundation need, those holding ``ground_inside`` m^3 inside the design prism."""
    needed = inside_share_needed(scene) * scene.required_blocks * scene.block.volume  # m^3 inside
    return (needed - ground_inside) / (max(scene.required_blocks - ground, 1) * scene.block.volume)


def face_losses(scene, placed, inside: np.ndarray) -> dict:
    """Volume (m^3) of the blocks past each group of the design prism's faces.

    The volume inside the prism with that group's planes removed, less the
    volume inside the prism. Volume past two groups at once (beyond an edge
    of the prism) counts in neither: ``edges_loss_m3`` is the total outside
    less the three groups. ``loss_allowed_m3`` is the most the required
    count may have outside and still come within 1 point of the target.
    """
    prism = scene.design.polytope
    centre = prism.vertices.mean(axis=0)
    span = 10.0 * float(np.ptp(prism.vertices, axis=0).max())
    box_n, box_o = np.vstack([np.eye(3), -np.eye(3)]), np.concatenate([centre + span, span - centre])
    out = {}
    for name, in_group in FACES.items():
        keep = [i for i, n in enumerate(prism.normals) if not in_group(n)]
        if len(keep) == len(prism.normals):
            raise ValueError(f"no {name} face on the design prism")
        opened = ConvexPolytope.from_halfspaces(np.vstack([prism.normals[keep], box_n]),
                                                np.concatenate([prism.offsets[keep], box_o]), centre)
        # "+ 0.0" turns a rounded -0.0 (a loss of nothing, less rounding) into 0.0.
        out[f"{name}_loss_m3"] = round(float((volumes_inside(placed, opened) - inside).sum()), 3) + 0.0
    total = len(placed) * scene.block.volume - float(inside.sum())
    out["edges_loss_m3"] = round(total - sum(out.values()), 3) + 0.0
    out["total_loss_m3"] = round(total, 3)
    allowed = scene.required_blocks * scene.block.volume * (1 - inside_share_needed(scene))
    out["loss_allowed_m3"] = round(float(allowed), 3)
    return out


def _toml(data: dict[str, Any]) -> str:
    """A scene's parsed TOML written back: top-level values first, then one ``[table]`` each.

    Scene files hold strings, numbers, booleans, lists of numbers and tables of those,
    which is all this writes.
    """
    def value(v: Any) -> str:
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        if isinstance(v, list):
            return "[" + ", ".join(value(x) for x in v) + "]"
        return repr(v)

    lines = [f"{k} = {value(v)}" for k, v in data.items() if not isinstance(v, dict)]
    for k, table in data.items():
        if isinstance(table, dict):
            lines += ["", f"[{k}]"] + [f"{kk} = {value(vv)}" for kk, vv in table.items()]
    return "\n".join(lines) + "\n"


def variant(scene_text: str, height: float | None = None, crest: float | None = None):
    """A built-in scene's TOML with its design ``height`` and ``crest`` width (m) changed, where given;
    its required count follows. The copy is named after both."""
    data = tomllib.loads(scene_text)
    copy = data["name"]
    for key, value, tag in (("height_m", height, "{}m"), ("crest_width_m", crest, "crest-{}m")):
        if value is None:
            continue
        if key not in data["design"]:
            raise ValueError(f"{copy}: [design] has no {key} to change")
        data["design"][key] = value
        copy += "-" + tag.format(value)
    data["name"] = copy
    return parse_scene(_toml(data), copy, None)


def run_copies(base, edits) -> list[tuple]:
    """Seed 1 on copies of the built-in scene ``base``, one per ``(height, crest)`` of ``edits``
    (:func:`variant`; None keeps the scene's own).

    Each copy's time limit is ``LIMIT`` scaled by its required count over
    ``base``'s, so that a larger copy is not cut short by the clock alone.
    Returns ``(copy, row, placed)`` for each, ``row, placed`` from :func:`run_row`.
    """
    text = (resources.files("geometry") / "scenes" / f"{base.name}.toml").read_text()
    out = []
    for height, crest in edits:
        copy = variant(text, height, crest)
        row, placed = run_row(copy, 1, LIMIT * max(1.0, copy.required_blocks / base.required_blocks))
        print(row, flush=True)
        out.append((copy, row, placed))
    return out


def solid_rows(scene, placed) -> list[dict]:
    """Share of the design prism that the blocks fill, in bands of ``|x|`` and height.

    The shared porosity module's voxel tracker holds the layout (voxel
    centres in the prism, ``VOXEL`` edges); both sides of the axis fall in
    one band.
    """
    tracker = PorosityTracker(scene, "voxel", voxel_size=VOXEL)
    for key, block, pose in placed:
        tracker.add(key, block, pose)
    grid, solid = tracker.grid, tracker.occupied()
    bx = np.floor(np.abs(grid.centres[0]) / BAND).astype(int)
    bz = np.floor(grid.centres[2] / BAND).astype(int)
    prism_count = np.zeros((bx.max() + 1, bz.max() + 1))
    solid_count = np.zeros_like(prism_count)
    # Sum over y, then into the bands along x and z.
    np.add.at(prism_count, (bx[:, None], bz[None, :]), grid.prism_mask.sum(axis=1))
    np.add.at(solid_count, (bx[:, None], bz[None, :]), solid.sum(axis=1))
    rows = []
    for i, k in zip(*np.nonzero(prism_count), strict=True):
        rows.append({"scene": scene.name, "abs_x_from_m": i * BAND, "z_from_m": k * BAND,
                     "prism_m3": round(float(prism_count[i, k]) * grid.voxel_volume, 3),
                     "solid_percent": round(100 * float(solid_count[i, k] / prism_count[i, k]), 1)})
    return rows


def run_row(scene, seed: int, limit: float = LIMIT) -> tuple[dict, list]:
    """One ``optimize`` run with a ``limit`` s budget: its row, and the blocks it placed."""
    t0 = time.perf_counter()
    r = optimize(scene, seed=seed, time_limit=limit, bound=True)  # the run as issue 4 measured it
    wall = time.perf_counter() - t0
    placed = r.layout.placed()
    block = scene.block
    inside = volumes_inside(placed, scene.design.polytope)
    ground = on_ground(block, placed)

    def share(mask: np.ndarray) -> float:
        """Share of the volume of the blocks in ``mask`` inside the design prism."""
        return float(inside[mask].sum() / (max(1, mask.sum()) * block.volume))

    f = share(np.ones(len(placed), bool))
    rest_needed = rest_share_needed(scene, float(inside[ground].sum()), int(ground.sum()))
    projected = 100 * (1 - scene.required_blocks * block.volume * f / scene.design_volume)
    return {
        "scene": scene.name,
        "seed": seed,
        "height_m": scene.height,
        "crest_width_m": scene.crest_width,
        "required_blocks": scene.required_blocks,
        "blocks": r.blocks,
        "porosity_percent": round(r.porosity_percent, 3),
        "seconds": round(wall, 1),
        "time_limit_s": round(limit, 1),
        "collisions": r.collisions,
        "out_of_tolerance": r.out_of_tolerance,
        "stable": r.stable,
        "cpsat_gap_percent": round(r.gap.get("gap_percent", float("nan")), 6),
        "inside_share_percent": round(100 * f, 2),
        "ground_blocks": int(ground.sum()),
        "ground_inside_share_percent": round(100 * share(ground), 2),
        "upper_blocks": int((~ground).sum()),
        "upper_inside_share_percent": round(100 * share(~ground), 2),
        "porosity_at_required_count_percent": round(projected, 2),
        "inside_share_needed_percent": round(100 * inside_share_needed(scene), 2),
        "upper_inside_share_needed_percent": round(100 * float(rest_needed), 2),
        **face_losses(scene, placed, inside),
    }, placed


def toe_rows(scene) -> list[dict]:
    """How far out a tetrapod can rest on the foundation, and how much of it is then inside."""
    block = scene.block
    zone = scene.tolerance
    rng = np.random.default_rng(0)
    quats, lows, reach = [], [], []
    for _ in range(TOE_SAMPLES):
        q = random_quaternion(rng)
        pts = Pose(np.zeros(3), q).apply(block.vertices)
        low = float(pts[:, 2].min())
        quats.append(q)
        lows.append(low)
        # The furthest out the centroid goes with every vertex inside the zone's slope line.
        reach.append(float(np.min(zone.half_width(pts[:, 2] - low) - pts[:, 0])))
    reach = np.array(reach)
    rows = []
    for d in TOE_DISTANCES:
        # Each orientation that reaches d, with its centroid at d: further out is no more inside.
        far = np.flatnonzero(reach >= d)
        placed = [(i, block, Pose(np.array([d, scene.length / 2, -lows[i]]), quats[i])) for i in far]
        inside = volumes_inside(placed, scene.design.polytope) / block.volume if len(far) else np.zeros(0)
        rows.append({"centroid_at_least_m": d, "orientations": len(far),
                     "best_inside_share_percent": round(100 * float(inside.max()), 2) if len(far) else "",
                     "reach_m": round(float(reach.max()), 3),
                     "design_base_half_width_m": round(scene.design.bottom_half_width, 3)})
    return rows


def nest_rows(scene) -> list[dict]:
    """How low a tetrapod lowered onto the tuned first layer comes to rest, per family."""
    block = scene.block
    lattice = lattice_for(block, scene.block_type)
    world = first_layer(lattice, block)
    crest = scene.height
    rng = np.random.default_rng(0)
    rows = []
    for family in (*FAMILIES, "free"):
        tops, placed = [], []
        for i in range(NEST_SAMPLES):
            yaw = float(rng.uniform(0, 2 * np.pi))
            q = random_quaternion(rng) if family == "free" else hanging(family, yaw)
            shape = Shape.of(block, q)
            # Anywhere over the centre cell of the patch, which has three cells on every side.
            x, y = rng.uniform(0, lattice.w), rng.uniform(0, lattice.p)
            z, _, _ = world.drop(shape, float(x), float(y))
            tops.append(z + float(shape.highs.max()))
            # The same block, at the same height, over the middle of the crest.
            placed.append((i, block, Pose(np.array([0.0, scene.length / 2, z]), q)))
        inside = volumes_inside(placed, scene.design.polytope) / block.volume
        rows.append({"family": family, "drops": NEST_SAMPLES,
                     "first_layer_top_m": round(world.top(), 3),
                     "lowest_top_m": round(float(min(tops)), 3),
                     "median_top_m": round(float(np.median(tops)), 3),
                     "design_crest_m": round(float(crest), 3),
                     "median_inside_share_percent": round(100 * float(np.median(inside)), 2),
                     "p99_inside_share_percent": round(100 * float(np.quantile(inside, 0.99)), 2),
                     "best_inside_share_percent": round(100 * float(inside.max()), 2)})
    return rows


def interior_rows(scene) -> list[dict]:
    """How densely the optimizer's own pattern packs tetrapods away from slopes and ends.

    The tuned first layer and its upper layer, each over ``(2 INTERIOR_RING
    + 1)^2`` lattice cells, are lowered in crane order onto a flat foundation
    (as the beam search lays them, with nothing in the way). A window of
    ``INTERIOR_CELLS^2`` whole cells at the patch's centre, from the
    foundation up to a height, is then cut from the blocks (exact clipping,
    the shared module's): its solid share, up to the scene's design crest
    and up to the upper layer's top. A window of whole cells holds the same
    volume wherever it sits on the lattice, so the figure is the pattern's
    own, not the window's.
    """
    block = scene.block
    lattice = lattice_for(block, scene.block_type)
    world = first_layer(lattice, block, ring=INTERIOR_RING)
    tops = lay_upper(world, block, lattice, lattice.upper, ring=INTERIOR_RING)
    placed = [(k, block, pose) for k, pose in world.poses().items()]
    collisions = len(overlapping_pairs(block, [pose for _, _, pose in placed]))
    a, b = np.array([lattice.w, lattice.q]), np.array([0.0, lattice.p])
    half = INTERIOR_CELLS / 2
    rows = []
    for label, height in (("design crest", scene.height), ("upper layer's top", float(tops.max()))):
        corners = [[*(s * a + t * b), z] for s in (-half, half) for t in (-half, half) for z in (0.0, height)]
        window = ConvexPolytope.from_points(np.array(corners))
        solid = float(volumes_inside(placed, window).sum()) / window.volume
        rows.append({"up_to": label, "height_m": round(height, 3), "cells": INTERIOR_CELLS ** 2,
                     "patch_blocks": len(placed), "collisions": collisions,
                     "area_per_block_m2": round(lattice.area_per_block, 3),
                     "upper_tops_m": " / ".join(f"{t:.2f}" for t in tops),
                     "solid_percent": round(100 * solid, 2), "porosity_percent": round(100 * (1 - solid), 2)})
    return rows


class Release:
    """Crane drops onto fixed blocks, released and settled with only the dropped block free.

    Each drop is lowered until it first touches, as the optimizer lowers it,
    then settled for ``RELEASE_SECONDS`` with its neighbours held fixed. It
    counts when it comes to rest inside the tolerance zone and penetrates no
    block by more than ``tol.contact_depth``. Blocks that count can be kept
    (:meth:`keep`) for later drops to land on.
    """

    def __init__(self, scene, placed):
        self.scene, self.block = scene, scene.block
        self.zone = scene.tolerance.polytope
        self.drops = DropWorld.of(scene.foundation, placed)
        self.world = world_of(placed)

    def drop(self, q: np.ndarray, x: float, y: float) -> tuple[float, Pose | None]:
        """The top at first contact (m), and the pose it rests in, or None if it does not count."""
        block, shape = self.block, Shape.of(self.block, q)
        z, _, _ = self.drops.drop(shape, x, y)
        pose = Pose(np.array([x, y, z]), q)
        near = self.world.neighbours(pose.position, 2.5 * block.bounding_radius)
        result = settle(self.scene, [(k, block, self.world.pose(k)) for k in near] + [(-1, block, pose)],
                        seconds=RELEASE_SECONDS, seed=0, movable={-1})
        rest = result.poses[-1]
        valid = (result.at_rest and self.zone.contains(rest.apply(block.vertices)).all()
                 and not self.world.query(block, rest, threshold=tol.contact_depth, first=True))
        return z + float(shape.highs.max()), rest if valid else None

    def keep(self, key: int, pose: Pose) -> None:
        self.drops.add(key, Shape.of(self.block, pose.quaternion), pose.position)
        self.world.add(key, self.block, pose)


def random_hanging(rng: np.random.Generator, i: int) -> np.ndarray:
    """The ``i``-th drop's orientation: each hanging in turn with a random yaw, then a free one."""
    family = (*FAMILIES, "free")[i % (len(FAMILIES) + 1)]
    return random_quaternion(rng) if family == "free" else hanging(family, float(rng.uniform(0, 2 * np.pi)))


def on_ground(block, placed) -> np.ndarray:
    """Which of ``placed`` rest on the foundation (lowest point within ``ON_GROUND``), a bool mask."""
    return np.array([pose.apply(block.vertices)[:, 2].min() <= ON_GROUND for _, _, pose in placed], bool)


def ground_blocks(block, placed) -> list:
    return [b for b, g in zip(placed, on_ground(block, placed), strict=True) if g]


def release_rows(scene, placed) -> list[dict]:
    """Does a released tetrapod nest lower than where it first touches, and can it rest at the toes?

    Over the crest the drops fall onto ``placed``'s blocks on the foundation;
    at the toes, onto all of ``placed`` (see :class:`Release`).
    """
    block = scene.block
    rng = np.random.default_rng(0)
    rows = []
    for place, (lo, hi) in RELEASE_PLACES.items():
        release = Release(scene, ground_blocks(block, placed) if place == "crest" else placed)
        first_tops, tops, inside = [], [], []
        for i in range(RELEASE_SAMPLES):
            q = random_hanging(rng, i)
            x = float(rng.choice([-1.0, 1.0]) * rng.uniform(lo, hi))
            first, rest = release.drop(q, x, float(rng.uniform(1.0, scene.length - 1.0)))
            first_tops.append(first)
            if rest is not None:
                tops.append(float(rest.apply(block.vertices)[:, 2].max()))
                inside.append(volume_inside(block, rest, scene.design.polytope) / block.volume)

        def stat(values: list[float], f, scale: float = 1.0, digits: int = 3):
            return round(scale * float(f(values)), digits) if values else ""

        rows.append({"place": place, "x_from_m": lo, "x_to_m": hi, "drops": RELEASE_SAMPLES,
                     "on_blocks": len(release.world), "seconds_simulated": RELEASE_SECONDS,
                     "first_contact_lowest_top_m": stat(first_tops, min),
                     "at_rest_valid": len(tops),
                     "lowest_top_m": stat(tops, min), "median_top_m": stat(tops, np.median),
                     "design_crest_m": round(float(scene.height), 3),
                     "median_inside_share_percent": stat(inside, np.median, 100, 2),
                     "best_inside_share_percent": stat(inside, max, 100, 2)})
    return rows


def greedy_release_row(scene, placed) -> dict:
    """A second layer laid by released drops on ``placed``'s blocks on the foundation.

    Each block of the rest of the required count is the one of
    ``GREEDY_CANDIDATES`` released drops, anywhere over the design prism,
    with the most volume inside the prism; it stays for the next drops to
    land on. Then the whole layout is settled, every block free.
    """
    block = scene.block
    ground = ground_blocks(block, placed)
    release = Release(scene, ground)
    rng = np.random.default_rng(0)
    reach = scene.design.bottom_half_width
    tracker = PorosityTracker(scene, "exact")
    for key, _, pose in ground:
        tracker.add(key, block, pose)
    upper = []
    for slot in range(scene.required_blocks - len(ground)):
        best = None
        for i in range(GREEDY_CANDIDATES):
            q = random_hanging(rng, i)
            x, y = float(rng.uniform(-reach, reach)), float(rng.uniform(1.0, scene.length - 1.0))
            _, rest = release.drop(q, x, y)
            if rest is not None:
                v = tracker.gain(block, rest)
                if best is None or v > best[0]:
                    best = (v, rest)
        if best is not None:
            key = -2 - slot
            release.keep(key, best[1])
            tracker.add(key, block, best[1])
            upper.append(best[0] / block.volume)
    placed_now = [(k, block, release.world.pose(k)) for k in release.world.keys()]
    verdict = settle(scene, placed_now, seed=0)
    return {"ground_blocks": len(ground), "candidates_per_block": GREEDY_CANDIDATES,
            "required_blocks": scene.required_blocks, "blocks": len(placed_now),
            "porosity_percent": round(tracker.percent, 3),
            "upper_inside_share_percent": round(100 * float(np.mean(upper)), 2) if upper else "",
            "stable": bool(verdict.stable)}


def upper_bound_row(scene, placed) -> dict:
    """CP-SAT's bound on the share inside the design prism of the blocks over ``placed``'s first layer.

    ``placed``'s blocks on the foundation stay. Candidates are lowered onto
    them alone, at every point of a ``BOUND_STEP`` grid over the tolerance
    zone, in each hanging at ``BOUND_YAWS`` yaws and in ``BOUND_FREE`` free
    orientations; those wholly inside the zone count. CP-SAT (the
    optimizer's own selection model, :meth:`optimizer.search.cpsat.CpSat.solve`)
    chooses at most as many as the required count leaves, with no two
    interpenetrating (FCL), maximising their volume inside above
    ``BOUND_FLOOR``; every block it does not choose counts as
    ``BOUND_FLOOR`` inside. Its proven bound then bounds the mean share
    inside of the blocks the count leaves, over this candidate set. It is
    generous: the candidates need not stand or follow a crane order, and each
    is as low as the first layer alone lets it come, where blocks resting on
    other candidates would stand higher.
    """
    block, zone = scene.block, scene.tolerance
    ground = ground_blocks(block, placed)
    drops = DropWorld.of(scene.foundation, ground)
    rng = np.random.default_rng(0)
    quats = [hanging(f, yaw) for f in FAMILIES for yaw in np.arange(BOUND_YAWS) * 2 * np.pi / BOUND_YAWS]
    quats += [random_quaternion(rng) for _ in range(BOUND_FREE)]
    shapes = [Shape.of(block, q) for q in quats]
    t0 = time.perf_counter()
    cands = []
    for x in np.arange(-zone.bottom_half_width, zone.bottom_half_width + 1e-9, BOUND_STEP):
        for y in np.arange(zone.y_start, zone.y_end + 1e-9, BOUND_STEP):
            for q, shape in zip(quats, shapes, strict=True):
                z, _, _ = drops.drop(shape, float(x), float(y))
                pose = Pose(np.array([x, y, z]), q)
                if zone.polytope.contains(pose.apply(block.vertices)).all():
                    cands.append(pose)
    share = volumes_inside([(i, block, pose) for i, pose in enumerate(cands)], scene.design.polytope)
    share = share / block.volume
    keep = np.flatnonzero(share >= BOUND_FLOOR)
    conflicts = overlapping_pairs(block, [cands[i] for i in keep])
    rest = scene.required_blocks - len(ground)
    chosen, _, bound, status = CpSat(time_limit=BOUND_SECONDS).solve(
        [float(share[i] - BOUND_FLOOR) * block.volume for i in keep], conflicts, rest, seed=0)
    needed = rest_share_needed(scene, float(volumes_inside(ground, scene.design.polytope).sum()), len(ground))
    return {"ground_blocks": len(ground), "upper_blocks": rest, "grid_step_m": BOUND_STEP,
            "orientations": len(quats), "candidates_in_zone": len(cands),
            "candidates_at_least_floor": len(keep), "floor_percent": round(100 * BOUND_FLOOR, 1),
            "conflicts": len(conflicts), "cpsat_status": status, "chosen": len(chosen),
            "best_candidate_inside_percent": round(100 * float(share.max()), 2),
            "upper_inside_needed_percent": round(100 * needed, 2),
            "upper_inside_bound_percent": round(100 * (bound / (rest * block.volume) + BOUND_FLOOR), 2),
            "seconds": round(time.perf_counter() - t0, 1)}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--variants", action="store_true",
                        help="also run copies of the scenes with other designs (about 12 minutes more)")
    parser.add_argument("--bound", action="store_true",
                        help="also bound the blocks over seed 1's first layer with CP-SAT (about 5 minutes)")
    args = parser.parse_args()
    scene = load_scene("tetrapod")
    run = Run("tetrapod_limit", {"scene": scene.name, "seeds": list(SEEDS), "time_limit_s": LIMIT,
                                 "on_ground_m": ON_GROUND, "toe_samples": TOE_SAMPLES,
                                 "band_m": BAND, "voxel_m": VOXEL, "release_samples": RELEASE_SAMPLES,
                                 "release_seconds": RELEASE_SECONDS,
                                 "greedy_candidates": GREEDY_CANDIDATES, "bound_step_m": BOUND_STEP,
                                 "bound_floor": BOUND_FLOOR, "bound_cpsat_s": BOUND_SECONDS})
    rows, first = [], None
    for seed in SEEDS:
        row, placed = run_row(scene, seed)
        rows.append(row)
        first = first or placed
        print(row, flush=True)
    run.csv("tetrapod_limit", rows)
    run.csv("tetrapod_solid", solid_rows(scene, first))
    if args.variants:
        copies = run_copies(scene, VARIANTS)
        run.csv("tetrapod_variants", [rows[0]] + [row for _, row, _ in copies])
        copy, _, placed = copies[VARIANTS.index((4.0, None))]
        run.csv("tetrapod_variants_solid", solid_rows(copy, placed))
    layer = load_scene(LAYER)
    layer_rows = [run_row(layer, seed)[0] for seed in SEEDS]
    for r in layer_rows:
        print(r, flush=True)
    run.csv("tetrapod_layer", layer_rows)
    if args.variants:
        run.csv("tetrapod_layer_variants", [row for _, row, _ in run_copies(layer, LAYER_VARIANTS)])
    toe = toe_rows(scene)
    for r in toe:
        print(r)
    run.csv("tetrapod_toe", toe)
    nest = nest_rows(scene)
    for r in nest:
        print(r)
    run.csv("tetrapod_nest", nest)
    interior = interior_rows(scene)
    for r in interior:
        print(r)
    run.csv("tetrapod_interior", interior)
    release = release_rows(scene, first)
    for r in release:
        print(r)
    run.csv("tetrapod_release", release)
    greedy = greedy_release_row(scene, first)
    print(greedy)
    run.csv("tetrapod_release_greedy", [greedy])
    if args.bound:
        bound = upper_bound_row(scene, first)
        print(bound)
        run.csv("tetrapod_upper_bound", [bound])
    run.done()


if __name__ == "__main__":
    main()
