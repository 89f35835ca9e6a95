"""How long a physics settle takes against the number of blocks (issue 3).

Targets on two cores: a 75-block layout of ``mini`` settles 2 s of simulated
time in under 2 s of wall time, and the cost grows about linearly with the
block count.

Two kinds of layout, both at rest on the foundation:

* **reference**: what the optimizer builds and ``shoha settle`` confirms.
  10 and 75 blocks from ``mini``'s reference (``benchmarks/layouts/mini-75.json``:
  its first 10 in crane order, and all of it); 300 and 1000 from the
  full-scale reference (``benchmarks/layouts/full-1005.json``, one continuous
  165 m breakwater: the 300 blocks nearest the middle of the crest, and the
  first 1000 in crane order).
* **poured**: a jumbled pile like a trainee's, made by physics: blocks dropped
  in waves into ``mini`` (``settle.pour``, seed 0). Pouring 1000 blocks takes
  minutes, so ``make bench`` pours 10 and 75 only; ``--poured 10,75,300,1000``
  pours the rest into mini's section made longer (``benchmarks/scenes/``).

Each layout is settled twice: for the full 2 s (``early_stop=False``), which
gives the cost per step, and as the CLI does it, stopping early once every
block rests. Times are wall-clock and CPU seconds of this process; the
machine may be shared, so the load average is saved with the results.

Run::

    .venv/bin/python benchmarks/settle_speed.py
    .venv/bin/python benchmarks/settle_speed.py --counts 10,75 --poured 75

Writes ``benchmarks/results/settle_speed.csv``, ``settle_speed.json`` (the
machine, as every benchmark: ``common.Run``; the fitted exponent under
``params``) and ``settle_speed.png``.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from geometry.collision import collisions  # noqa: E402
from geometry.layout import read_layout  # noqa: E402
from geometry.scene import Scene, load_scene  # noqa: E402
from settle import MujocoBackend, settle  # noqa: E402
from settle.base import SettleBody  # noqa: E402
from settle.pour import pour  # noqa: E402

sys.path.insert(0, str(ROOT / "benchmarks"))
from common import LONG_COPIES, Run, long_scene  # noqa: E402

LAYOUTS = ROOT / "benchmarks" / "layouts"

def scene_for(n: int) -> Scene:
    """mini for up to 75 blocks; beyond, the shortest shipped long scene of mini's section that holds n."""
    copies = next((k for k in LONG_COPIES if k * 75 >= n), None)
    if copies is None:
        raise SystemExit(f"settle_speed: no shipped scene holds {n} poured blocks "
                         f"(at most {75 * LONG_COPIES[-1]})")
    return long_scene(copies)


def reference(n: int) -> tuple[Scene, list]:
    """``n`` blocks of a reference layout (module docstring), at rest as the optimizer left them."""
    if n <= 75:
        layout = read_layout(LAYOUTS / "mini-75.json")
        return load_scene("mini"), layout.placed()[:n]
    layout = read_layout(LAYOUTS / "full-1005.json")
    scene, placed = load_scene("full"), layout.placed()
    if n > len(placed):
        raise SystemExit(f"settle_speed: the full reference has {len(placed)} blocks, not {n}")
    if n >= 1000:
        return scene, placed[:n]
    # The crest runs along y: keep the n blocks nearest its middle, in crane order.
    y = np.array([p.position[1] for _, _, p in placed])
    keep = set(np.argsort(np.abs(y - (scene.design.y_start + scene.design.y_end) / 2), kind="stable")[:n])
    return scene, [b for i, b in enumerate(placed) if i in keep]


def timed_settle(scene: Scene, pile: list, seconds: float, early_stop: bool) -> dict:
    wall, cpu = time.perf_counter(), time.process_time()
    r = settle(scene, pile, seconds=seconds, seed=0, backend=MujocoBackend(), early_stop=early_stop)
    wall, cpu = time.perf_counter() - wall, time.process_time() - cpu
    return {"wall_s": wall, "cpu_s": cpu, "steps": r.steps, "simulated_s": r.simulated_seconds,
            "stable": r.stable, "at_rest": r.at_rest, "max_displacement_m": r.max_displacement_m,
            "max_rotation_deg": r.max_rotation_deg}


def poured(n: int) -> tuple[Scene, list, float]:
    """A pile of n blocks poured with seed 0, and the seconds pouring took."""
    scene = scene_for(n)
    t = time.perf_counter()
    pile = pour(scene, n, seed=0)
    return scene, pile, time.perf_counter() - t


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


def measure(kind: str, scene: Scene, pile: list, seconds: float, pour_s: float | None) -> dict:
    n = len(pile)
    full = timed_settle(scene, pile, seconds, early_stop=False)
    early = timed_settle(scene, pile, seconds, early_stop=True)
    row = {
        "layout": kind,
        "blocks": n,
        "scene": scene.name,
        "collisions": len(collisions(pile)),
        "pour_s": round(pour_s, 2) if pour_s is not None else "",
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
    print(", ".join(f"{k}={v}" for k, v in row.items()), flush=True)
    return row


def run_rows(counts: list[int], pour_counts: list[int], seconds: float) -> list[dict]:
    rows = []
    for n in counts:
        scene, pile = reference(n)
        rows.append(measure("reference", scene, pile, seconds, None))
    for n in pour_counts:
        scene, pile, t = poured(n)
        rows.append(measure("poured", scene, pile, seconds, t))
    return rows


def exponent(rows: list[dict], lo: int = 75) -> float | None:
    """Least-squares slope of log CPU time against log block count, from ``lo`` blocks up."""
    pts = [(r["blocks"], r["full_cpu_s"]) for r in rows if r["blocks"] >= lo]
    if len(pts) < 2:
        return None
    n, t = np.log(np.array(pts, float)).T
    return float(np.polyfit(n, t, 1)[0])


def chart(rows: list[dict]):
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, (a, b) = plt.subplots(1, 2, figsize=(10, 4))
    for kind, marker in (("reference", "o"), ("poured", "s")):
        sel = [r for r in rows if r["layout"] == kind]
        if not sel:
            continue
        n = np.array([r["blocks"] for r in sel], float)
        a.loglog(n, [r["full_cpu_s"] for r in sel], marker + "-", label=f"{kind}: full 2 s (CPU)")
        a.loglog(n, [r["early_wall_s"] for r in sel], marker + "--", mfc="none",
                 label=f"{kind}: early stop, as the CLI (wall)")
        b.semilogx(n, [r["us_per_step_per_block"] for r in sel], marker + "-", label=kind)
    ref = [r for r in rows if r["layout"] == "reference"] or rows
    n = np.array([r["blocks"] for r in ref], float)
    a.loglog(n, n * ref[-1]["full_cpu_s"] / n[-1], ":", color="grey", label="linear")
    a.axhline(2.0, color="red", lw=0.8, label="target for 75 blocks: 2 s")
    a.set_xlabel("blocks")
    a.set_ylabel("seconds for a 2 s settle")
    a.legend(fontsize=7)
    b.set_xlabel("blocks")
    b.set_ylabel("CPU µs per step per block")
    b.set_ylim(bottom=0)
    b.legend(fontsize=8)
    fig.suptitle("MuJoCo settle of shake-4t layouts (4 ms steps)")
    fig.tight_layout(rect=(0, 0, 1, 0.97))
    return fig


def counts_arg(text: str) -> list[int]:
    return [int(c) for c in text.split(",") if c.strip()]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--counts", default="10,75,300,1000", type=counts_arg,
                    help="reference layout block counts, comma-separated (at most 1005)")
    ap.add_argument("--poured", default="10,75", type=counts_arg,
                    help="poured pile block counts, comma-separated ('' for none)")
    ap.add_argument("--seconds", type=float, default=2.0, help="simulated seconds per settle")
    ap.add_argument("--no-png", action="store_true")
    args = ap.parse_args()
    run = Run("settle_speed", {"counts": args.counts, "poured": args.poured, "seconds": args.seconds,
                               "timestep_s": MujocoBackend().timestep, "seed": 0})
    rows = run_rows(args.counts, args.poured, args.seconds)
    slope = exponent([r for r in rows if r["layout"] == "reference"])
    if slope is not None:
        run.params["cost_exponent_reference_75_up"] = slope
        print(f"reference layouts: CPU time ~ blocks^{slope:.2f} from 75 blocks up (least squares)")
    run.csv("settle_speed", rows)
    if not args.no_png:
        run.figure("settle_speed", chart(rows))
    run.done()


if __name__ == "__main__":
    main()
