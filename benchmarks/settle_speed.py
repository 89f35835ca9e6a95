"""How long a physics settle takes against the number of blocks (issue 3).

Targets on two cores: a 75-block layout of ``mini`` settles 2 s of simulated
time in under 2 s of wall time, and the cost grows about linearly with the
block count.

The layouts are piles at rest on the ground, made by physics: blocks poured
in waves onto the foundation (``settle.pour``), not a floating lattice. 10 and
75 blocks go into ``mini``; 300 and 1000 into a breakwater of mini's cross
section, made long enough for them (4 and 13.3 times mini's 12.2 m), so that
the pile has the same height and width and grows along the crest.

Each pile is settled twice: for the full 2 s (``early_stop=False``), which
gives the cost per step, and as the CLI does it, stopping early once every
block rests. Times are wall-clock and CPU seconds of this process; the
machine may be shared, so the load average is saved with the results.

Run::

    .venv/bin/python benchmarks/settle_speed.py            # 10, 75, 300, 1000
    .venv/bin/python benchmarks/settle_speed.py --counts 10,75

Writes ``benchmarks/results/settle_speed.csv``, ``settle_speed.json`` (the
machine: cores, CPU model, library versions, load) and ``settle_speed.png``.
"""

from __future__ import annotations

import argparse
import csv
import json
import math
import os
import platform
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from geometry.collision import collisions  # noqa: E402
from geometry.layout import Layout, Placement, read_layout, write_layout  # noqa: E402
from geometry.scene import Scene, load_scene, parse_scene  # noqa: E402
from settle import MujocoBackend, settle  # noqa: E402
from settle.base import SettleBody  # noqa: E402
from settle.pour import pour  # noqa: E402

RESULTS = ROOT / "benchmarks" / "results"

#: mini's cross-section (geometry/scenes/mini.toml), any length.
LONG_SCENE = """
name = "long-{n}"
kind = "3d"
block = "shake-4t"
target_porosity_percent = 56.0
[design]
crest_width_m = 4.0
height_m = 3.0
slope_rise_run = [3.0, 4.0]
length_m = {length!r}
"""


def scene_for(n: int) -> Scene:
    """mini for up to 75 blocks; beyond, mini's section stretched to hold n."""
    mini = load_scene("mini")
    if n <= mini.required_blocks:
        return mini
    text = LONG_SCENE.format(n=n, length=mini.length * n / mini.required_blocks)
    return parse_scene(text, source=f"long-{n}", base_dir=None)


def machine() -> dict:
    import mujoco
    import pymunk
    import scipy

    model = "unknown"
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                model = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    return {
        "cpu_model": model,
        "cores": os.cpu_count(),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "mujoco": mujoco.__version__,
        "pymunk": pymunk.version,
        "numpy": np.__version__,
        "scipy": scipy.__version__,
        "load_average_start": os.getloadavg(),
        "date": time.strftime("%Y-%m-%d %H:%M:%S %z"),
    }


def timed_settle(scene: Scene, pile: list, seconds: float, early_stop: bool) -> dict:
    wall, cpu = time.perf_counter(), time.process_time()
    r = settle(scene, pile, seconds=seconds, seed=0, backend=MujocoBackend(), early_stop=early_stop)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    return {"wall_s": wall, "cpu_s": cpu, "steps": r.steps, "simulated_s": r.simulated_seconds,
            "stable": r.stable, "at_rest": r.at_rest, "max_displacement_m": r.max_displacement_m,
            "max_rotation_deg": r.max_rotation_deg}


def load_or_pour(scene: Scene, n: int, piles: Path | None) -> tuple[list, float]:
    """The poured pile of n blocks, and the seconds pouring took (NaN if read from ``piles``).

    With ``piles``, a pile is kept there as ``pile-N.json`` (a shoha-layout/1
    file that ``shoha settle`` reads, with its scene file beside it) and
    reused on the next run.
    """
    path = piles / f"pile-{n}.json" if piles is not None else None
    if path is not None and path.is_file():
        return read_layout(path).placed(), math.nan
    t = time.perf_counter()
    pile = pour(scene, n, seed=0)
    poured = time.perf_counter() - t
    if path is not None:
        path.parent.mkdir(parents=True, exist_ok=True)
        ref = scene.name
        if ref != "mini":
            ref = f"{scene.name}.toml"
            (path.parent / ref).write_text(LONG_SCENE.format(n=n, length=scene.length))
        write_layout(Layout(ref, [Placement(k, b.name, p) for k, b, p in pile]), path)
    return pile, poured


def profile(scene: Scene, pile: list, steps: int = 100) -> dict:
    """Where a step's time goes: MuJoCo's own timers over ``steps`` steps of the pile."""
    bodies = [SettleBody(k, b, p, True, np.zeros(3), np.zeros(3)) for k, b, p in pile]
    model = MujocoBackend().build(scene, bodies)
    data = mujoco.MjData(model)
    iterations, contacts = [], []
    for _ in range(steps):
        mujoco.mj_step(model, data)
        iterations.append(data.solver_niter[:max(data.nisland, 1)].max())
        contacts.append(data.ncon)

    def ms(timer: str) -> float:
        return round(1e3 * data.timer[getattr(mujoco.mjtTimer, timer)].duration / steps, 3)

    return {
        "collision_ms": ms("mjTIMER_POS_COLLISION"),
        "solver_ms": ms("mjTIMER_CONSTRAINT"),
        "newton_iterations": round(float(np.mean(iterations)), 2),
        "contacts": round(float(np.mean(contacts)), 1),
        "arena_kb_per_block": round(data.maxuse_arena / 1024 / max(len(pile), 1), 1),
    }


def run(counts: list[int], seconds: float, piles: Path | None = None) -> list[dict]:
    rows = []
    for n in counts:
        scene = scene_for(n)
        pile, poured = load_or_pour(scene, n, piles)
        top = max(p.position[2] for _, _, p in pile)
        overlaps = collisions(pile)
        full = timed_settle(scene, pile, seconds, early_stop=False)
        early = timed_settle(scene, pile, seconds, early_stop=True)
        row = {
            "blocks": n,
            "scene": scene.name,
            "pile_top_centroid_m": round(top, 3),
            "collisions": len(overlaps),
            "pour_s": round(poured, 2) if math.isfinite(poured) else "",
            "full_wall_s": round(full["wall_s"], 3),
            "full_cpu_s": round(full["cpu_s"], 3),
            "steps": full["steps"],
            "ms_per_step": round(1e3 * full["cpu_s"] / full["steps"], 3),
            "us_per_step_per_block": round(1e6 * full["cpu_s"] / full["steps"] / n, 2),
            **profile(scene, pile),
            "early_wall_s": round(early["wall_s"], 3),
            "early_simulated_s": early["simulated_s"],
            "early_at_rest": early["at_rest"],
            "stable": full["stable"],
            "max_displacement_m": round(full["max_displacement_m"], 5),
            "max_rotation_deg": round(full["max_rotation_deg"], 3),
        }
        rows.append(row)
        print(", ".join(f"{k}={v}" for k, v in row.items()), flush=True)
    return rows


def plot(rows: list[dict], path: Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    n = np.array([r["blocks"] for r in rows], float)
    fig, (a, b) = plt.subplots(1, 2, figsize=(9, 3.6))
    a.loglog(n, [r["full_cpu_s"] for r in rows], "o-", label="full 2 s (CPU)")
    a.loglog(n, [r["early_wall_s"] for r in rows], "s--", label="early stop (wall)")
    a.loglog(n, n * rows[0]["full_cpu_s"] / n[0], ":", color="grey", label="linear")
    a.axhline(2.0, color="red", lw=0.8)
    a.set_xlabel("blocks")
    a.set_ylabel("seconds for a 2 s settle")
    a.legend(fontsize=8)
    b.semilogx(n, [r["us_per_step_per_block"] for r in rows], "o-")
    b.set_xlabel("blocks")
    b.set_ylabel("µs per step per block")
    b.set_ylim(bottom=0)
    fig.suptitle("MuJoCo settle of poured shake-4t piles")
    fig.tight_layout()
    fig.savefig(path, dpi=120)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--counts", default="10,75,300,1000", help="block counts, comma-separated")
    ap.add_argument("--seconds", type=float, default=2.0, help="simulated seconds per settle")
    ap.add_argument("--no-png", action="store_true")
    ap.add_argument("--piles", type=Path, default=None,
                    help="folder to keep the poured piles in (as layouts) and to reuse them from")
    args = ap.parse_args()
    counts = [int(c) for c in args.counts.split(",")]
    info = machine()
    print(json.dumps(info))
    rows = run(counts, args.seconds, args.piles)
    info["load_average_end"] = os.getloadavg()
    if len(rows) >= 2:
        a, b = rows[1] if len(rows) > 2 else rows[0], rows[-1]
        ratio = b["full_cpu_s"] / a["full_cpu_s"]
        info["cost_exponent"] = math.log(ratio) / math.log(b["blocks"] / a["blocks"])
        print(f"cost ~ blocks^{info['cost_exponent']:.2f} between {a['blocks']} and {b['blocks']} blocks")
    RESULTS.mkdir(parents=True, exist_ok=True)
    with open(RESULTS / "settle_speed.csv", "w", newline="") as fh:
        w = csv.DictWriter(fh, fieldnames=list(rows[0]))
        w.writeheader()
        w.writerows(rows)
    (RESULTS / "settle_speed.json").write_text(json.dumps(info, indent=2) + "\n")
    if not args.no_png:
        plot(rows, RESULTS / "settle_speed.png")
    print(f"wrote {RESULTS / 'settle_speed.csv'}")


if __name__ == "__main__":
    main()
