"""What every benchmark in ``benchmarks/`` shares: the machine, timing, saving, layouts.

Nothing here computes porosity: the benchmarks call ``geometry.porosity``, the
one porosity module (STYLE.md). This module only says where results go, what
machine made them, how a time is taken, and which fixed-seed layouts are
measured.

Results go to ``benchmarks/results/``. Each ``NAME.csv`` has a ``NAME.json``
beside it with the machine (core count, CPU model, library versions, load
average at start and end) and the run's parameters; markdown results carry the
same machine block at their foot.
"""

from __future__ import annotations

import csv
import gc
import json
import os
import platform
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from geometry.blocks import Block
from geometry.collision import CollisionWorld
from geometry.constants import tol
from geometry.layout import read_layout
from geometry.pose import Pose, axis_angle_quat, quat_multiply, quat_to_matrix
from geometry.samples import random_inside, random_quaternion
from geometry.scene import Scene, load_scene

ROOT = Path(__file__).resolve().parents[1]
BENCH = ROOT / "benchmarks"
RESULTS = BENCH / "results"

# The benchmarks make trainee saves with the test helpers (tests/perturb.py), which
# are not installed with shoha: import them from the repository's root.
if str(ROOT) not in sys.path:
    sys.path.insert(0, str(ROOT))

#: The 75-block reference layout of ``mini`` (benchmarks/layouts/README.md).
MINI_75 = BENCH / "layouts" / "mini-75.json"

#: Seed of every random layout in the benchmarks: re-runs measure the same layouts.
SEED = 0

Placed = list[tuple[int, Block, Pose]]

# --- the reference paper's Tables V and VI ------------------------------------------

#: Table V of the reference paper: porosity (%) by blocks and gridDivisionCount,
#: Unity's Physics.OverlapBox rule (our ``voxel-any``).
PAPER_POROSITY = {
    9: {50: 89.52, 100: 92.40, 150: 93.25, 200: 93.60},
    17: {50: 80.50, 100: 85.58, 150: 87.12, 200: 87.82},
    25: {50: 71.93, 100: 79.03, 150: 81.10, 200: 82.16},
}

#: Table V's "correct value" column, eq. (1) with no protrusion. The paper
#: prints "9.68" for 9 blocks; 1 - 9 * 1.735 / 293.3 = 94.68 %, and 9.68 would
#: mean 26 m^3 of blocks out of 15.6 m^3, so it is a typo for 94.68.
PAPER_CORRECT = {9: 94.68, 17: 89.94, 25: 85.21}

#: Table VI of the reference paper: processing time (s), Unity on a PC whose
#: hardware the paper does not give.
PAPER_SECONDS = {
    9: {50: 0.56, 100: 4.75, 150: 13.55, 200: 31.13},
    17: {50: 0.64, 100: 5.11, 150: 13.92, 200: 32.02},
    25: {50: 0.66, 100: 5.22, 150: 14.51, 200: 32.89},
}

PAPER_DIVISIONS = (50, 100, 150, 200)
PAPER_BLOCKS = (9, 17, 25)

# --- the machine ----------------------------------------------------------------------

_DISTRIBUTIONS = ("numpy", "scipy", "trimesh", "manifold3d", "python-fcl", "mujoco", "rtree",
                  "matplotlib", "shoha", "pymunk")


def cpu_model() -> str:
    """The CPU model name from /proc/cpuinfo, or the platform's processor string."""
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                return line.split(":", 1)[1].strip()
    except OSError:
        pass
    return platform.processor() or "unknown"


def git_commit() -> str:
    """The repository's HEAD commit, with ``+dirty`` when the tree has changes."""
    try:
        head = subprocess.run(["git", "rev-parse", "--short", "HEAD"], cwd=ROOT, capture_output=True,
                              text=True, check=True).stdout.strip()
        dirty = subprocess.run(["git", "status", "--porcelain", "--untracked-files=no"], cwd=ROOT,
                               capture_output=True, text=True, check=True).stdout.strip()
    except (OSError, subprocess.CalledProcessError):
        return "unknown"
    return head + ("+dirty" if dirty else "")


def machine_info() -> dict[str, Any]:
    """Core count, CPU model, library versions and the load average, now.

    The machine is shared with other work, so the 1-minute load average is
    saved with every result: a figure taken at load 3 on 2 cores is slower
    than the same figure on an idle machine.
    """
    versions = {}
    for dist in _DISTRIBUTIONS:
        try:
            versions[dist] = metadata.version(dist)
        except metadata.PackageNotFoundError:
            versions[dist] = None
    return {
        "cores": os.cpu_count(),
        "cpu_model": cpu_model(),
        "platform": platform.platform(),
        "python": platform.python_version(),
        "versions": versions,
        "load_average": [round(v, 2) for v in os.getloadavg()],
        "date": time.strftime("%Y-%m-%d %H:%M:%S %z"),
        "commit": git_commit(),
    }


class Run:
    """One benchmark run: its machine at start and end, its parameters, its files.

    Parameters
    ----------
    name : str
        The script's stem; results are ``results/NAME*.{csv,json,md,png}``.
    params : dict
        What the run measured with (seeds, counts, repeats), saved beside.
    """

    def __init__(self, name: str, params: dict[str, Any] | None = None):
        self.name = name
        self.params = dict(params or {})
        self.start = machine_info()
        self._t0 = time.perf_counter()
        self.files: list[Path] = []
        RESULTS.mkdir(parents=True, exist_ok=True)

    def meta(self) -> dict[str, Any]:
        """Machine at start, load average at end, parameters and wall time."""
        return {
            "benchmark": self.name,
            "machine": self.start,
            "load_average_end": [round(v, 2) for v in os.getloadavg()],
            "wall_seconds": round(time.perf_counter() - self._t0, 2),
            "params": self.params,
        }

    def csv(self, stem: str, rows: Sequence[dict[str, Any]]) -> Path:
        """Write ``rows`` to ``results/STEM.csv`` and the machine to ``results/STEM.json``."""
        path = RESULTS / f"{stem}.csv"
        fields: list[str] = []
        for row in rows:
            fields.extend(k for k in row if k not in fields)
        with path.open("w", newline="") as f:
            writer = csv.DictWriter(f, fieldnames=fields)
            writer.writeheader()
            for row in rows:
                writer.writerow({k: _cell(v) for k, v in row.items()})
        (RESULTS / f"{stem}.json").write_text(json.dumps(self.meta(), indent=2) + "\n")
        self.files += [path, RESULTS / f"{stem}.json"]
        return path

    def markdown(self, stem: str, text: str) -> Path:
        """Write ``results/STEM.md``: ``text`` and the machine block."""
        path = RESULTS / f"{stem}.md"
        path.write_text(text.rstrip() + "\n\n" + machine_markdown(self.meta()) + "\n")
        self.files.append(path)
        return path

    def figure(self, stem: str, fig: Any) -> Path:
        """Save a matplotlib figure as ``results/STEM.png``, its caption naming the machine."""
        m = self.start
        fig.text(0.995, 0.995, f"{m['cpu_model']}, {m['cores']} cores, load {m['load_average'][0]}, "
                 f"shoha {m['commit']}, {m['date'][:10]}", ha="right", va="top", fontsize=7,
                 color="0.4")
        path = RESULTS / f"{stem}.png"
        fig.savefig(path, dpi=130)
        self.files.append(path)
        return path

    def done(self) -> None:
        """Print the files written and the run's wall time."""
        for p in self.files:
            print(f"wrote {p.relative_to(ROOT)}")
        print(f"{self.name}: {time.perf_counter() - self._t0:.1f} s wall")


def _cell(v: Any) -> Any:
    if isinstance(v, float | np.floating):
        return f"{float(v):.6g}"
    return v


def machine_markdown(meta: dict[str, Any]) -> str:
    """The machine block at the foot of every markdown result."""
    m = meta["machine"]
    libs = ", ".join(f"{k} {v}" for k, v in m["versions"].items() if v)
    return (
        f"Machine: {m['cpu_model']}, {m['cores']} cores, {m['platform']}, Python {m['python']}. "
        f"Libraries: {libs}. Load average (1, 5, 15 min) at start {m['load_average']}, "
        f"1-min at end {meta['load_average_end'][0]}. shoha {m['commit']}, {m['date']}; "
        f"this run took {meta['wall_seconds']} s."
    )


# --- timing ---------------------------------------------------------------------------


@dataclass(frozen=True)
class Timing:
    """Seconds of repeated calls: the median is the figure quoted, the rest shows spread.

    ``cpu_median`` is the median CPU time of this process over the same calls:
    on a shared machine it moves less with the load than wall time does.
    """

    median: float
    best: float
    worst: float
    repeats: int
    cpu_median: float = float("nan")

    @property
    def ms(self) -> float:
        return 1e3 * self.median


def timed(fn: Callable[[], Any], repeats: int = 7, warmup: int = 1) -> tuple[Timing, Any]:
    """Time ``fn()``: ``warmup`` untimed calls, then the median of ``repeats``.

    Returns
    -------
    (Timing, value of the last call)

    Notes
    -----
    Warm-up calls keep first-call costs out of the figure: imports, the
    block's cached mesh and convex pieces, FCL's geometry. A garbage
    collection before each timed call keeps another call's garbage out of it.
    """
    value = None
    for _ in range(warmup):
        value = fn()
    times, cpu = [], []
    for _ in range(max(1, repeats)):
        gc.collect()
        c = time.process_time()
        t = time.perf_counter()
        value = fn()
        times.append(time.perf_counter() - t)
        cpu.append(time.process_time() - c)
    return Timing(float(np.median(times)), min(times), max(times), len(times), float(np.median(cpu))), value


def move_times(tracker: Any, placed: Placed, moves: Placed, rounds: int = 3) -> np.ndarray:
    """Seconds of each ``tracker.move``: every block to its pose in ``moves``, then back.

    ``tracker`` holds ``placed`` (a ``PorosityTracker``). One untimed round
    first, then ``rounds`` timed ones. Returns (moves, 2): wall and CPU
    seconds of each move (CPU time has a coarse clock: use its median over
    many moves only).
    """
    times = []
    for r in range(rounds + 1):
        for (key, _, pose), (_, _, moved) in zip(placed, moves, strict=True):
            for target in (moved, pose):
                c = time.process_time()
                t = time.perf_counter()
                tracker.move(key, target)
                if r:
                    times.append((time.perf_counter() - t, time.process_time() - c))
    return np.array(times).reshape(-1, 2)


def repeats_for(seconds: float, budget: float = 3.0, lo: int = 1, hi: int = 21) -> int:
    """How many repeats fit ``budget`` seconds for a call that took ``seconds`` once."""
    return int(np.clip(budget / max(seconds, 1e-6), lo, hi))


# --- layouts --------------------------------------------------------------------------


def mini() -> Scene:
    return load_scene("mini")


def mini_reference() -> Placed:
    """The 75-block reference layout of ``mini``: collision-free, in tolerance, stable.

    Made by ``optimize(load_scene("mini"), seed=1, time_limit=120)``
    (benchmarks/layouts/README.md). About half its blocks stick out of the
    design prism into the tolerance zone, as a full layout's outer blocks do.
    """
    return read_layout(MINI_75).placed()


def paper_layout(n: int, seed: int = SEED) -> Placed:
    """``n`` blocks wholly inside ``mini``, collision-free: the paper's Fig. 16 setting."""
    scene = mini()
    return random_inside(scene.block, scene.design, n, seed=seed)


def long_scene(copies: int) -> Scene:
    """mini's cross-section, ``copies`` times its length (``benchmarks/scenes/``)."""
    if copies == 1:
        return mini()
    return load_scene(BENCH / "scenes" / f"mini-x{copies}.toml")


#: Lengths, in minis, of the long scenes shipped in benchmarks/scenes/.
LONG_COPIES = (1, 4, 14, 40)


def tiled(n: int) -> tuple[Scene, Placed]:
    """``n`` blocks: copies of the mini reference layout laid end to end along the crest.

    Copy ``j`` is shifted by ``j`` mini lengths along +y, in the shortest
    shipped long scene that holds them; the first ``n`` blocks in
    installation order are kept. The copies neither collide nor touch
    (checked by ``scaling.py``), since the reference layout keeps inside
    0.52 m < y < 11.36 m of mini's 12.22 m.
    """
    ref = mini_reference()
    copies = next(k for k in LONG_COPIES if k * len(ref) >= n)
    scene = long_scene(copies)
    step = np.array([0.0, mini().length, 0.0])
    placed = []
    for j in range(copies):
        for k, block, pose in ref:
            if len(placed) == n:
                break
            placed.append((j * len(ref) + k, block, Pose(pose.position + j * step, pose.quaternion)))
    return scene, placed


def protruding_layout(n: int, seed: int = SEED) -> Placed:
    """``n`` blocks that each stick out of ``mini``'s design prism, none colliding.

    Centres are drawn in the design prism's bounding box; a pose is kept when
    some but not all of the block's vertices are inside the prism, so each
    block is clipped by the prism's faces: the case eq. (1) with whole block
    volumes gets wrong and the paper's Table V leaves out.
    """
    scene = mini()
    block, poly = scene.block, scene.design.polytope
    rng = np.random.default_rng(seed)
    lo, hi = scene.design.bounds
    world = CollisionWorld(cell=2 * block.bounding_radius)
    placed: Placed = []
    while len(placed) < n:
        pose = Pose(rng.uniform(lo, hi), random_quaternion(rng))
        inside = np.all(pose.apply(block.vertices) @ poly.normals.T <= poly.offsets + tol.distance, axis=1)
        if inside.all() or not inside.any():
            continue
        if world.query(block, pose, threshold=-1.0, first=True):
            continue
        world.add(len(placed), block, pose)
        placed.append((len(placed), block, pose))
    return placed


def overlapping_layout(n: int, overlaps: int, seed: int = SEED) -> Placed:
    """``n`` blocks, ``overlaps`` of them pushed into another block, as in a trainee's save.

    The first ``n - overlaps`` blocks are :func:`paper_layout`'s; each of the
    last ``overlaps`` is a copy of one of those, moved 0.4 m in a random
    direction and turned by up to 30 degrees, so it interpenetrates the block
    it was copied from (and may stick out of the prism).
    """
    base = paper_layout(n - overlaps, seed)
    rng = np.random.default_rng(seed + 1)
    placed = list(base)
    for i in range(overlaps):
        _, block, pose = base[i]
        direction = rng.normal(size=3)
        direction /= np.linalg.norm(direction)
        turn = axis_angle_quat(rng.normal(size=3), np.radians(rng.uniform(-30, 30)))
        placed.append((len(placed), block,
                       Pose(pose.position + 0.4 * direction, quat_multiply(turn, pose.quaternion))))
    return placed


def jittered(placed: Placed, shift: float, degrees: float, seed: int = SEED) -> Placed:
    """Each block moved by up to ``shift`` m per axis and turned by up to ``degrees``.

    A packed layout jittered like this is what a trainee's hand makes of it:
    neighbours interpenetrate and outer blocks stick out further.
    """
    rng = np.random.default_rng(seed)
    out = []
    for key, block, pose in placed:
        turn = axis_angle_quat(rng.normal(size=3), np.radians(rng.uniform(-degrees, degrees)))
        out.append((key, block, Pose(pose.position + rng.uniform(-shift, shift, 3),
                                     quat_multiply(turn, pose.quaternion))))
    return out


def world_vertices(block: Block, pose: Pose) -> np.ndarray:
    """A posed block's mesh vertices, (n, 3) metres, world frame."""
    return block.vertices @ quat_to_matrix(pose.quaternion).T + pose.position


# --- a service in its own process ------------------------------------------------------


def free_port() -> int:
    """A TCP port on 127.0.0.1 that nothing listens on now."""
    import socket

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


class ServiceProcess:
    """A service started as a subprocess, ready once ``GET /healthz`` answers, stopped on exit.

    Parameters
    ----------
    argv : list of str
        The command; it must listen on ``port``.
    port : int
    timeout : float, seconds
        How long start-up may take.
    """

    def __init__(self, argv: list[str], port: int, timeout: float = 60.0):
        self.argv, self.port, self.timeout = argv, port, timeout
        self.url = f"http://127.0.0.1:{port}"
        self.proc: subprocess.Popen[bytes] | None = None

    def __enter__(self) -> ServiceProcess:
        import httpx

        self.proc = subprocess.Popen(self.argv, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        deadline = time.monotonic() + self.timeout
        while time.monotonic() < deadline:
            if self.proc.poll() is not None:
                raise RuntimeError(f"{self.argv[:3]} exited: {self.proc.stderr.read().decode()[-2000:]}")
            try:
                if httpx.get(self.url + "/healthz", timeout=1.0).status_code == 200:
                    return self
            except httpx.TransportError:
                pass
            time.sleep(0.1)
        self.__exit__(None, None, None)
        raise RuntimeError(f"{self.argv[:3]} did not answer within {self.timeout} s")

    def __exit__(self, *exc: object) -> None:
        if self.proc is not None and self.proc.poll() is None:
            self.proc.terminate()
            try:
                self.proc.wait(10)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait()


def percentiles(seconds: Sequence[float]) -> dict[str, float]:
    """p50, p90, p99 and max of request times, in milliseconds."""
    a = 1e3 * np.asarray(seconds, dtype=float)
    return {"n": int(len(a)), "p50_ms": float(np.percentile(a, 50)), "p90_ms": float(np.percentile(a, 90)),
            "p99_ms": float(np.percentile(a, 99)), "max_ms": float(a.max())}


def settled(layout_path: Path, seed: int = 7) -> tuple[Scene, Placed]:
    """A reference layout after a physics settle: blocks in contact, as a simulator saves a pile at rest."""
    from settle import settle

    layout = read_layout(layout_path)
    scene = layout.load_scene()
    placed = layout.placed()
    result = settle(scene, placed, seed=seed)
    return scene, [(k, b, result.poses[k]) for k, b, _ in placed]
