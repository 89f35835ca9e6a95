"""How near the tolerance zone lets any block come to each point of the design surface (issue 24).

Issue 24's coverage aim asks that at most 5 % of the design prism's slopes and
crest lie more than H/2 from every block, and no point of them more than H.
A valid block lies wholly inside the tolerance zone. For each scene this
script measures, with :func:`geometry.reach.least_distances`, the least
distance at which any block of the scene's type, in any place inside the
zone, comes to each point of the design cross-section's slopes and crest: a
floor under that point's distance to the nearest block in every valid
layout (the relaxations and the orientations tried: ``geometry/reach.py``).
Points whose floor exceeds H/2 are bare in every valid layout; their share
is a floor under ``bare_share_percent``, and the largest floor one under
``max_bare_m``.

Two sets of orientations for each scene:

* ``crane``: every stable rest pose of the block at ``YAWS`` yaws, with no
  random turns and no local search: the orientations the crane lays a block
  in on the ground;
* ``any``: those, ``RANDOM`` random turns, and the local search over the turn
  for every point still over H/2. Blocks resting on others take such poses.

Writes ``results/surface_reach.csv`` (one row per scene and set) and
``results/surface_reach_profile.csv`` (the floor at each sample of the
section).

Run::

    python benchmarks/studies/surface_reach.py [SCENE ...]
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common import BENCH, Run  # noqa: E402
from generality import HELD_OUT_DIR, SCENES, scene_arg, write_turned_mesh  # noqa: E402

from geometry.coverage import AIM_BARE_PERCENT, AIM_MAX_BARE_H  # noqa: E402
from geometry.reach import floor_of, least_distances  # noqa: E402
from geometry.scene import load_scene  # noqa: E402

YAWS = 180
RANDOM = 20000


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    held_out = sorted(p.stem for p in HELD_OUT_DIR.glob("*.toml"))
    parser.add_argument("scenes", nargs="*", default=list(SCENES) + held_out)
    parser.add_argument("--random", type=int, default=RANDOM)
    args = parser.parse_args()
    write_turned_mesh(BENCH / "scenes" / "shake-turned.stl")
    run = Run("surface_reach", {"scenes": args.scenes, "yaws": YAWS, "random": args.random})
    rows, profile = [], []
    for name in args.scenes:
        scene = load_scene(scene_arg(name))
        h = scene.block.height
        floors = {}
        for kind, random, refine in (("crane", 0, 0), ("any", args.random, 4)):
            t0 = time.perf_counter()
            points, weights, least, tried = least_distances(scene, random, YAWS, refine)
            floors[kind] = least
            f = floor_of(scene, points, weights, least, tried)
            rows.append({
                "scene": name, "held_out": name in held_out, "block": scene.block.name,
                "orientations": kind, "tried": tried, "block_height_m": round(h, 4),
                "floor_bare_share_percent": round(f.bare_share_percent, 2),
                "aim_bare_share_percent": AIM_BARE_PERCENT,
                "floor_max_bare_m": round(f.max_bare_m, 3),
                "aim_max_bare_m": round(AIM_MAX_BARE_H * h, 3),
                "worst_x_m": round(f.worst_point[0], 3),
                "worst_z_m": round(f.worst_point[1], 3),
                "seconds": round(time.perf_counter() - t0, 1),
            })
            print(rows[-1], flush=True)
        profile += [{"scene": name, "x_m": round(float(p[0]), 3), "z_m": round(float(p[1]), 3),
                     "crane_m": round(float(c), 4), "any_m": round(float(a), 4)}
                    for p, c, a in zip(points, floors["crane"], floors["any"], strict=True)]
    run.csv("surface_reach", rows)
    run.csv("surface_reach_profile", profile)


if __name__ == "__main__":
    main()
