"""A trainee who lays every live hint exactly as given: do the blocks stand? (stop 77)

``shoha serve``'s hint (``optimizer.serve.hint.first_fitting``) names the next
reference block that fits. This follows it in one process, as a client of the
service would but without HTTP: ask for a hint, lay it as given, and so on,
until no reference block fits (the service would then start a re-plan). Every
5 blocks the blocks laid are settled (``settle.settle``, seed 0, as ``shoha
score`` settles a save) and the blocks that do not stand are counted.

Two ways of hinting, side by side:

* ``as-lowered``: the block where the crane's drop leaves it (before stop 77);
* ``let-go``: then let go among the laid blocks, held still, and given where it
  comes to rest (``first_fitting(let_go_hints=True)``, the service's now).

Beside them, the reference's own crane order: how many of its prefixes (its
first n blocks, for every n) do not stand when settled alone.

Layouts: the ``mini`` and ``mini-rough`` references of ``tests/data``, and any
``--layout PATH --scene SCENE`` pair more. Writes ``results/hint_follow.csv``
(``.json``: the machine): per layout and way, the hints laid before none fit,
the blocks not standing at each settle (the largest count and the last), and
the time of a hint (median and largest).

Run::

    .venv/bin/python benchmarks/hint_follow.py [--layout L --scene S ...]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import numpy as np
from common import BENCH, Run

from geometry.layout import read_layout
from geometry.scene import load_scene
from optimizer.serve.hint import PlanBlock, first_fitting
from optimizer.serve.live import LiveLayout
from settle import settle

DATA = BENCH.parent / "tests" / "data"
LAYOUTS = [("mini", DATA / "mini-reference.json", "mini"),
           ("mini-rough", DATA / "mini-rough-seed1.json", str(BENCH / "scenes" / "mini-rough.toml"))]
#: Blocks laid between two settles.
EVERY = 5


def follow(scene, plan: list[PlanBlock], let_go: bool) -> dict:
    live = LiveLayout(scene)
    times, unstable = [], []
    while True:
        t = time.perf_counter()
        hint = first_fitting(scene, live, plan, let_go_hints=let_go)
        times.append(time.perf_counter() - t)
        if hint is None:
            break
        live.put(len(live), hint.type, scene.block, hint.pose)
        if len(live) % EVERY == 0:
            result = settle(scene, live.placed(), seed=0)
            unstable.append(sum(not b.stable for b in result.blocks))
    return {"hints_laid": len(live), "settles": len(unstable), "most_unstable": max(unstable, default=0),
            "unstable_at_end": unstable[-1] if unstable else 0,
            "settles_with_unstable": sum(n > 0 for n in unstable),
            "hint_p50_ms": round(1e3 * float(np.median(times)), 2), "hint_max_ms": round(1e3 * max(times), 1)}


def prefixes_unstable(scene, placed: list) -> int:
    """How many prefixes of ``placed`` (crane order) do not stand, each settled alone."""
    return sum(not settle(scene, placed[:n], seed=0).stable for n in range(1, len(placed) + 1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--layout", action="append", default=[], help="a reference layout more")
    parser.add_argument("--scene", action="append", default=[], help="its scene (one per --layout)")
    args = parser.parse_args()
    if len(args.layout) != len(args.scene):
        parser.error("give one --scene for each --layout")
    cases = LAYOUTS + [(Path(p).stem, Path(p), s) for p, s in zip(args.layout, args.scene, strict=True)]
    run = Run("hint_follow", {"every": EVERY, "layouts": [str(p) for _, p, _ in cases]})
    rows = []
    for name, path, source in cases:
        scene = load_scene(source)
        layout = read_layout(path)
        plan = [PlanBlock(p.id, p.type, scene.block, p.pose) for p in layout.blocks]
        prefixes = prefixes_unstable(scene, [(p.id, p.block, p.pose) for p in plan])
        print(f"{name:12s} {prefixes} of {len(plan)} prefixes of the reference do not stand", flush=True)
        for way, let_go in (("as-lowered", False), ("let-go", True)):
            row = {"layout": name, "blocks": len(plan), "prefixes_unstable": prefixes, "way": way,
                   **follow(scene, plan, let_go)}
            rows.append(row)
            print(f"{name:12s} {way:10s} {row['hints_laid']:3d} of {len(plan)} hints laid; not standing: "
                  f"at most {row['most_unstable']} ({row['settles_with_unstable']} of {row['settles']} "
                  f"settles), {row['unstable_at_end']} at the end; hint {row['hint_p50_ms']} ms median, "
                  f"{row['hint_max_ms']} ms largest", flush=True)
    run.csv("hint_follow", rows)
    run.done()


if __name__ == "__main__":
    main()
