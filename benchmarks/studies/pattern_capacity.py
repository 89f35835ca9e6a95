"""How many blocks the placement pattern alone can lay in a scene: its capacity (issue 24).

``optimize`` lays the pattern's sites first (``optimizer.search.sites``); the
pocket fill adds what it can around them. Where the pattern holds fewer
blocks than the scene requires, the search ends short unless the fill finds
the rest. This study lays the pattern with no count to stop it
(``sites.pattern_pass``), from ``ORIGINS`` origins ((0, 0) and seeded random ones
over one lattice cell), and reports the most, the median and the fewest
blocks laid, against the required count. No physics, no fill: a quick measure of
the room the pattern leaves, not a layout. Each origin is laid twice: with its
later passes nested as tuned, and with each later pass shifted to where it lays
the most (``sites.fit_layers``, which ``optimize`` uses for origins whose pattern
falls short of the count).

Besides the scenes of issue 24's table it measures ``wall-rough``, written for
this study and not in any benchmark: ``wall-shake`` on the rubble of
``mini-rough``. The held-out scenes are left out: they are for results, not
for diagnosis.

Writes ``results/pattern_capacity.csv``. Run::

    python benchmarks/studies/pattern_capacity.py [SCENE ...]
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

from common import BENCH, Run  # noqa: E402
from generality import scene_arg, write_turned_mesh  # noqa: E402

from geometry.scene import load_scene  # noqa: E402
from optimizer.search.build import Build  # noqa: E402
from optimizer.search.hangings import families  # noqa: E402
from optimizer.search.patterns import lattice_for  # noqa: E402
from optimizer.search.problem import Problem  # noqa: E402
from optimizer.search.shapes import ShapeCache  # noqa: E402
from optimizer.search.sites import fit_layers, pattern_pass  # noqa: E402

SCENES = ("mini", "mini-mesh", "mini-rough", "wall-shake", "wall-rough", "tetrapod-big", "cube",
          "shake-low-gentle")
ORIGINS = 12
#: A user's block with no tuned pattern is tuned first, for at most this long.
TUNE_SECONDS = 60.0

WALL_ROUGH = """name = "wall-rough"
block = "shake-4t"
target_porosity_percent = 56.0

[design]
crest_width_m = 3.0
height_m = 3.5
slope_rise_run = [3.0, 4.0]
length_m = 15.0
wall = true

[foundation]
kind = "rough"
amplitude_m = 0.15
cell_m = 0.5
seed = 3
"""


def scene_of(name: str):
    if name == "wall-rough":
        path = Path(tempfile.mkdtemp()) / "wall-rough.toml"
        path.write_text(WALL_ROUGH)
        return load_scene(str(path))
    return load_scene(scene_arg(name))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("scenes", nargs="*", default=list(SCENES))
    args = parser.parse_args()
    write_turned_mesh(BENCH / "scenes" / "shake-turned.stl")
    run = Run("pattern_capacity", {"scenes": args.scenes, "origins": ORIGINS})
    rows = []
    for name in args.scenes:
        scene = scene_of(name)
        lattice = lattice_for(scene.block, scene.block_type, TUNE_SECONDS, time.perf_counter)
        problem = Problem(scene=scene, required=10**9, target=scene.target_porosity, lattice=lattice,
                          families=families(scene.block), deadline=float("inf"))
        shapes = ShapeCache(scene.block)
        rng = np.random.default_rng(0)
        t0 = time.perf_counter()
        laid, fitted = [], []
        origins = [(0.0, 0.0)] + [(float(rng.uniform(0, lattice.w)), float(rng.uniform(0, lattice.p)))
                                  for _ in range(ORIGINS - 1)]
        for origin in origins:
            laid.append(len(pattern_pass(problem, shapes, Build(scene), origin)))
        nested_seconds = time.perf_counter() - t0
        for origin in origins:
            shifted = fit_layers(problem, shapes, Build(scene), origin, float("inf"))
            fitted.append(len(pattern_pass(problem, shapes, Build(scene), shifted)))
        laid.sort()
        fitted.sort()
        rows.append({"scene": name, "block": scene.block.name, "required": scene.required_blocks,
                     "capacity_most": laid[-1], "capacity_median": laid[len(laid) // 2],
                     "capacity_fewest": laid[0],
                     "most_over_required": round(laid[-1] / scene.required_blocks, 3),
                     "fitted_most": fitted[-1], "fitted_median": fitted[len(fitted) // 2],
                     "fitted_fewest": fitted[0],
                     "seconds": round(nested_seconds, 1),
                     "fit_seconds": round(time.perf_counter() - t0 - nested_seconds, 1)})
        print(rows[-1], flush=True)
    run.csv("pattern_capacity", rows)


if __name__ == "__main__":
    main()
