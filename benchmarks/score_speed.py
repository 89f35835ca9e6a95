"""How long ``shoha score`` takes on a 75-block save, settle included (issue 5).

Target on two cores: under 3 s for a 75-block save of ``mini``.

Three saves of the 75-block reference (``benchmarks/layouts/mini-75.json``):

``reference``
    the reference itself, as the optimizer wrote it (blocks a hair apart);
``settled``
    the reference after a physics settle, as a simulator saves a pile at rest:
    blocks in contact, touching groups that the exact porosity must union;
``three-faults``
    one block lifted out of tolerance, one on a leg tip, two pushed into each
    other (optimizer/perturb.py): the settle cannot stop early.

Each is timed three ways:

* ``score()``: the library call, the reference's own analysis done once
  before (as a batch does), median of ``REPEATS`` after a warm-up;
* ``cli_seconds``: the ``seconds`` that ``shoha score --json`` reports, its own
  work from reading the files to the result (reference analysis included);
* ``cli_wall``: the whole ``shoha score`` process, Python start-up included.

Run::

    .venv/bin/python benchmarks/score_speed.py

Writes ``benchmarks/results/score_speed.csv`` and ``score_speed.json`` (the
machine: cores, CPU model, library versions, load average).
"""

from __future__ import annotations

import json
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import MINI_75, Run, timed

from geometry.layout import Layout, Placement, read_layout, write_layout
from optimizer.score import Reference, score
from settle import settle
from tests.perturb import three_faults

REPEATS = 5
TARGET_SECONDS = 3.0


def saves(reference: Layout) -> dict[str, Layout]:
    scene = reference.load_scene()
    result = settle(scene, reference.placed(), seed=7)
    settled = Layout("mini", [Placement(p.id, p.type, result.poses[p.id]) for p in reference.blocks])
    faulty = three_faults(scene, reference)
    faulty.scene = "mini"
    plain = Layout("mini", list(reference.blocks), dict(reference.extra))
    return {"reference": plain, "settled": settled, "three-faults": faulty}


def main() -> int:
    run = Run("score_speed", {"layout": str(MINI_75.name), "repeats": REPEATS, "target_s": TARGET_SECONDS})
    reference = read_layout(MINI_75)
    scene = reference.load_scene()
    ref = Reference.of(scene, reference.placed())
    shoha = str(Path(sys.executable).parent / "shoha")
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for name, layout in saves(reference).items():
            placed = layout.placed()
            timing, result = timed(lambda placed=placed: score(scene, placed, ref), repeats=REPEATS)
            path = Path(tmp) / f"{name}.json"
            write_layout(layout, path)
            t = time.perf_counter()
            proc = subprocess.run([shoha, "score", str(path), "--reference", str(MINI_75), "--json"],
                                  capture_output=True, text=True, check=True)
            wall = time.perf_counter() - t
            cli = json.loads(proc.stdout)
            assert cli["score"] == result.score, (cli["score"], result.score)
            rows.append({
                "save": name, "blocks": len(placed), "score": result.score,
                "score_median_s": timing.median, "score_best_s": timing.best, "score_worst_s": timing.worst,
                "settle_s": result.settle.seconds, "settle_simulated_s": result.settle.simulated_seconds,
                "cli_seconds": cli["seconds"], "cli_wall_s": wall,
                "under_target": timing.median < TARGET_SECONDS and cli["seconds"] < TARGET_SECONDS,
                "cores": run.start["cores"], "cpu_model": run.start["cpu_model"],
            })
            print(f"{name:13s} {len(placed)} blocks, score {result.score:5.1f}: score() median "
                  f"{timing.median:.2f} s (best {timing.best:.2f}, worst {timing.worst:.2f}; settle "
                  f"{result.settle.seconds:.2f} s for {result.settle.simulated_seconds:.2f} s simulated), "
                  f"CLI {cli['seconds']:.2f} s own work, {wall:.2f} s with start-up", flush=True)
    run.csv("score_speed", rows)
    worst = max(max(r["score_median_s"], r["cli_seconds"]) for r in rows)
    print(f"slowest: {worst:.2f} s against a target of {TARGET_SECONDS:g} s on {run.start['cores']} cores: "
          f"{'PASS' if worst < TARGET_SECONDS else 'FAIL'}")
    run.done()
    return 0 if worst < TARGET_SECONDS else 1


if __name__ == "__main__":
    sys.exit(main())
