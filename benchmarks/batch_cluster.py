"""A batch of 200 saves: local pool against a 2-worker Dask LocalCluster, interrupted and resumed (issue 5).

Target: on two cores, ``shoha batch score`` of 200 saves on a 2-worker
``distributed.LocalCluster`` finishes, resumes correctly after it is
interrupted, and gives the same rows as ``--workers 2``.

The saves are made from the 75-block reference (``benchmarks/layouts/mini-75.json``)
by ``tests.perturb.trainee_saves`` with seed 0: a few blocks nudged in each,
sometimes the last few missing, every tenth with a named fault. The same
seed gives the same 200 saves.

Phases, each a ``shoha batch score`` process, as a user runs it:

1. ``pool``: ``--workers 2``;
2. ``dask-interrupted``: ``--scheduler`` on a LocalCluster of 2 worker
   processes (1 thread each), killed with SIGKILL once half the rows are in;
3. ``dask-resumed``: the same command again, which skips the rows already
   written and runs the rest.

Then the rows of 3 are compared with those of 1, every column but ``seconds``.

Run::

    .venv/bin/python benchmarks/batch_cluster.py [--count 200]

Writes ``benchmarks/results/batch_cluster.csv`` and ``batch_cluster.json``.
"""

from __future__ import annotations

import argparse
import json
import os
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

from common import MINI_75, Run

from geometry.layout import read_layout, write_layout
from optimizer.batch import SCORE_COLUMNS, TIMING_COLUMNS, RowFile
from tests.perturb import trainee_saves

SHOHA = str(Path(sys.executable).parent / "shoha")


def make_saves(folder: Path, count: int) -> None:
    reference = read_layout(MINI_75)
    for name, layout in trainee_saves(reference.load_scene(), reference, count, seed=0):
        layout.scene = "mini"
        write_layout(layout, folder / f"{name}.json")


def rows_of(path: Path) -> tuple[dict[str, dict], int]:
    """Rows by item without timing columns, and how many items appear more than once."""
    out: dict[str, dict] = {}
    repeated = 0
    for row in RowFile(path, SCORE_COLUMNS).read():
        repeated += row["item"] in out
        out[row["item"]] = {k: v for k, v in row.items() if k not in TIMING_COLUMNS}
    return out, repeated


def batch(args: list[str], stop_after: int | None = None, out: Path | None = None) -> tuple[dict, float]:
    """Run ``shoha batch score``; with ``stop_after``, SIGKILL it once that many rows are written."""
    t = time.perf_counter()
    proc = subprocess.Popen([SHOHA, "batch", "score", *args, "--json"], stdout=subprocess.PIPE,
                            stderr=subprocess.DEVNULL, text=True, start_new_session=True)
    if stop_after is None:
        stdout, _ = proc.communicate()
        if proc.returncode != 0:
            raise RuntimeError(f"shoha batch exited with {proc.returncode}")
        return json.loads(stdout), time.perf_counter() - t
    assert out is not None
    while proc.poll() is None:
        if out.exists() and len(out.read_bytes().splitlines()) - 1 >= stop_after:
            os.killpg(proc.pid, signal.SIGKILL)
            break
        time.sleep(0.1)
    proc.wait()
    return {"killed": proc.returncode == -signal.SIGKILL}, time.perf_counter() - t


def main() -> int:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--count", type=int, default=200, help="saves in the batch")
    args = parser.parse_args()
    run = Run("batch_cluster", {"saves": args.count, "seed": 0, "workers": 2, "threads_per_worker": 1,
                                "reference": MINI_75.name})
    from distributed import LocalCluster

    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp) / "saves"
        folder.mkdir()
        t = time.perf_counter()
        make_saves(folder, args.count)
        print(f"made {args.count} saves in {time.perf_counter() - t:.1f} s", flush=True)
        common = [str(folder), "--reference", str(MINI_75)]

        pool_out = Path(tmp) / "pool.csv"
        summary, wall = batch([*common, "--out", str(pool_out), "--workers", "2"])
        rows.append({"phase": "pool", "runner": summary["runner"], "ran": summary["ran"],
                     "skipped": summary["skipped"], "errors": summary["errors"], "wall_s": wall,
                     "saves_per_s": summary["ran"] / wall})
        print(f"pool: {summary['ran']} saves in {wall:.1f} s", flush=True)

        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True,
                          dashboard_address=None) as cluster:
            dask_out = Path(tmp) / "dask.csv"
            dask_args = [*common, "--out", str(dask_out), "--scheduler", cluster.scheduler_address]
            killed, wall = batch(dask_args, stop_after=args.count // 2, out=dask_out)
            before, repeated = rows_of(dask_out)
            rows.append({"phase": "dask-interrupted", "runner": "dask LocalCluster", "ran": len(before),
                         "skipped": 0, "errors": sum(r["status"] != "ok" for r in before.values()),
                         "wall_s": wall, "saves_per_s": len(before) / wall, "killed": killed["killed"]})
            print(f"dask, killed after {len(before)} rows: {wall:.1f} s", flush=True)
            summary, wall = batch(dask_args)
            rows.append({"phase": "dask-resumed", "runner": summary["runner"], "ran": summary["ran"],
                         "skipped": summary["skipped"], "errors": summary["errors"], "wall_s": wall,
                         "saves_per_s": summary["ran"] / wall})
            print(f"dask resumed: {summary['ran']} more saves in {wall:.1f} s "
                  f"({summary['skipped']} skipped)", flush=True)

        pool_rows, pool_repeated = rows_of(pool_out)
        dask_rows, dask_repeated = rows_of(dask_out)
        resumed_ok = (summary["skipped"] == len(before) and summary["ran"] == args.count - len(before)
                      and len(dask_rows) == args.count and dask_repeated == 0)
        same = dask_rows == pool_rows
        differ = sorted(k for k in pool_rows if dask_rows.get(k) != pool_rows[k])
        rows.append({"phase": "compare", "runner": "", "ran": len(dask_rows), "skipped": "", "errors": "",
                     "wall_s": "", "saves_per_s": "", "resumed_ok": resumed_ok, "rows_match_pool": same,
                     "rows_differing": len(differ), "repeated_items": pool_repeated + dask_repeated})
        print(f"resume correct: {resumed_ok}; rows match the pool: {same} ({len(differ)} differ)")
    run.csv("batch_cluster", rows)
    run.done()
    return 0 if resumed_ok and same else 1


if __name__ == "__main__":
    sys.exit(main())
