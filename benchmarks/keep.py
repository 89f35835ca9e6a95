"""``shoha optimize --keep`` on ``mini``: completing a layout already begun (issue 24, item 4).

Two starts, each the first 30 blocks of a layout:

* ``reference``: the seed-1 reference that ``optimize`` makes now (a site
  re-planning after a survey of a good start);
* ``scatter``: 30 random valid drops (``optimizer.search.scatter``: crane
  hangings at random yaws, anywhere over the mound, each at rest where it
  landed, the whole settled), a deliberately poor start.

Each is completed by ``optimize(keep=...)`` at the default time limit, seeds 1,
2 and 3, and checked as ``shoha optimize`` checks: count, collisions, out of
tolerance, the settle, porosity against the 56 % target (within 1 point is the
acceptance), the coverage, and whether the kept blocks are where they were to
the last bit.

Writes ``results/keep.csv`` (and ``keep.json``, the machine).
"""

from __future__ import annotations

import argparse

from common import Run, mini

from optimizer.api import optimize
from optimizer.search.scatter import scatter

KEPT = 30
SEEDS = (1, 2, 3)


def starts(scene) -> dict:
    """The two partial layouts, as lists of placements."""
    reference = optimize(scene, seed=1).layout.blocks[:KEPT]
    poor = scatter(scene, KEPT, seed=1).layout({}).blocks
    return {"reference": reference, "scatter": poor}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--seeds", type=int, nargs="+", default=list(SEEDS))
    args = parser.parse_args()
    scene = mini()
    run = Run("keep", {"scene": "mini", "kept": KEPT, "seeds": args.seeds})
    rows = []
    for start, keep in starts(scene).items():
        for seed in args.seeds:
            r = optimize(scene, seed=seed, keep=keep)
            same = all(p.id == q.id and p.pose.position.tobytes() == q.pose.position.tobytes()
                       and p.pose.quaternion.tobytes() == q.pose.quaternion.tobytes()
                       for p, q in zip(r.layout.blocks, keep, strict=False))
            cov = r.coverage or {}
            row = {
                "start": start, "seed": seed, "kept": len(keep), "blocks": r.blocks,
                "required": r.required_blocks, "porosity_percent": round(r.porosity_percent, 3),
                "points_off": round(abs(r.porosity_percent - r.target_porosity_percent), 3),
                "collisions": r.collisions, "out_of_tolerance": r.out_of_tolerance, "stable": r.stable,
                "valid": r.valid,
                "within_1_point": r.valid and abs(r.porosity_percent - r.target_porosity_percent) <= 1.0,
                "kept_unchanged": same,
                "kept_faults": sum(len(v) for k, v in r.kept.items() if k != "blocks"),
                "bare_share_percent": round(cov.get("bare_share_percent", float("nan")), 2),
                "seconds": round(r.seconds, 1),
                "phases": " ".join(f"{p['strategy']}:{p['blocks']}" for p in r.phases
                                   if p["strategy"] != "attempts"),
                "repaired": r.settle.get("repaired"),
            }
            rows.append(row)
            print(row, flush=True)
    run.csv("keep", rows)
    run.done()


if __name__ == "__main__":
    main()
