"""Batches: many saves scored against one reference, or many optimizer runs (``shoha batch``).

One batch is a list of items, each with a key that names it in the output
file. Every finished item becomes one row of a CSV or JSON Lines file
(chosen by the suffix), appended with a single ``write`` on a file opened
with ``O_APPEND`` and flushed to disk, so a row is in the file whole or not
at all. A re-run reads the rows already there and skips their items: a batch
that was stopped resumes where it stopped. A bad save gives an error row of
its own and the batch goes on.

The work runs in a local process pool (``workers`` processes), or on a Dask
distributed cluster (``scheduler``, the address of its scheduler). Both call
the same task functions with the same arguments, so they give the same rows
(bar the ``seconds`` column). If a worker dies, Dask runs its tasks again on
another worker; the local pool is rebuilt and the lost items are run again,
up to ``MAX_ATTEMPTS`` times each.

Task functions are module-level and import heavy modules lazily, so that a
Dask worker needs only ``shoha`` installed.
"""

from __future__ import annotations

import csv
import glob
import hashlib
import io
import json
import math
import os
import re
import socket
import time
import uuid
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from geometry.blocks import plain_number
from geometry.errors import InputError, one_line

#: Times an item is run before a worker crash is recorded as its error.
MAX_ATTEMPTS = 3

FORMATS = (".csv", ".jsonl")

#: The score's penalties (optimizer/score/scoring.py), one column each.
PENALTIES = ("tolerance", "collisions", "stability", "porosity", "interlock", "coverage", "time")

SCORE_COLUMNS = (
    "item", "status", "error", "save", "save_sha256", "reference_sha256", "score",
    "progress_percent", "quality", "penalty_points",
    "porosity_percent", "reference_porosity_percent", "porosity_gap_to_target_percent",
    "porosity_gap_to_reference_percent", "blocks", "required_blocks", "remaining_blocks",
    "out_of_tolerance", "collisions", "stable", "unstable_blocks", "poorly_interlocked",
    "bare_share_percent", "finished_porosity_percent", "finished_poorly_interlocked",
    "finished_bare_share_percent", "elapsed_s", "completion_time_s", "blocks_per_hour",
    *(f"penalty_{name}" for name in PENALTIES), "seconds",
)

OPTIMIZE_COLUMNS = (
    "item", "status", "error", "scene", "seed", "time_limit_s", "porosity_percent", "blocks",
    "required_blocks", "collisions", "out_of_tolerance", "stable", "valid", "path", "seconds",
)

#: Keys of ``shoha score --json`` copied as they are into a score row.
COPIED_KEYS = ("score", "progress_percent", "quality", "penalty_points", "porosity_percent",
               "reference_porosity_percent", "porosity_gap_to_target_percent",
               "porosity_gap_to_reference_percent", "blocks", "required_blocks", "remaining_blocks", "stable",
               "elapsed_s", "completion_time_s", "blocks_per_hour")

#: Columns that measure time, and so differ from run to run.
TIMING_COLUMNS = ("seconds",)


@dataclass(frozen=True)
class Item:
    """One unit of work.

    Attributes
    ----------
    key : str
        Names the item in the output; unique within a batch.
    args : dict
        Keyword arguments of the task function (plain data, picklable).
    """

    key: str
    args: dict[str, Any]


@dataclass
class BatchSummary:
    """What a batch did.

    Attributes
    ----------
    items : int
        Items in the batch.
    skipped : int
        Items already in the output file (done by an earlier run).
    ran : int
        Items run now.
    errors : int
        Of those, items whose row is an error row.
    path : str
    seconds : float
    """

    items: int
    skipped: int
    ran: int = 0
    errors: int = 0
    path: str = ""
    seconds: float = 0.0
    runner: str = ""
    rows: list[dict[str, Any]] = field(default_factory=list, repr=False)

    def to_dict(self) -> dict[str, Any]:
        return {"items": self.items, "skipped": self.skipped, "ran": self.ran, "errors": self.errors,
                "path": self.path, "seconds": self.seconds, "runner": self.runner}


# --- tasks (run in workers) ----------------------------------------------------------------------

_REFERENCES: dict[tuple[Any, ...], Any] = {}


def sha256_file(path: str | os.PathLike) -> str:
    """Hex SHA-256 of a file's bytes ("" if it cannot be read)."""
    try:
        return hashlib.sha256(Path(path).read_bytes()).hexdigest()
    except OSError:
        return ""


def _reference(path: str, slices: int, layers: int) -> tuple[Any, Any, Any]:
    """(layout, scene, Reference) of a reference file, computed once per process."""
    from geometry.layout import read_layout

    from .score import Reference

    stat = os.stat(path)
    key = (os.path.abspath(path), stat.st_mtime_ns, stat.st_size, slices, layers)
    cached = _REFERENCES.get(key)
    if cached is None:
        layout = read_layout(path)
        scene = layout.load_scene()
        cached = (layout, scene, Reference.of(scene, layout.placed(), slices, layers))
        _REFERENCES.clear()
        _REFERENCES[key] = cached
    return cached


def load_save(path: str, source: str, scene_ref: str, reference_scene: Any, block: str = "shake-4t",
              origin: tuple[float, float, float] = (0.0, 0.0, 0.0), scene_name: str | None = None
              ) -> tuple[Any, Any]:
    """A trainee's save as (Layout, Scene).

    Parameters
    ----------
    path : str
    source : {"auto", "layout", "unity"}
        ``auto`` tells the two apart by content: a ``format`` key means a
        ``shoha-layout/1`` file, blocks with ``{"x", "y", "z"}`` positions a
        simulator save.
    scene_ref, reference_scene
        A Unity save names no scene: it takes this one (a layout's ``scene``
        reference, and the scene it loads to), or ``scene_name``.
    block, origin
        As in ``shoha convert``: the block type of saved blocks that name none,
        and the world position (m) of Unity's origin.
    scene_name : str, optional
        Scene instead of the save's (or the reference's) own.
    """
    from geometry.fileio import read_json
    from geometry.layout import layout_from_dict
    from geometry.scene import load_scene
    from geometry.unity import read_unity_save

    if source not in ("auto", "layout", "unity"):
        raise InputError(f"--from {source!r}: use auto, layout or unity")
    if source == "auto":
        data = read_json(path)
        source = _detect(data, path)
        if source == "layout":
            layout = layout_from_dict(data, str(path), str(Path(path).resolve().parent))
    elif source == "layout":
        data = read_json(path)
        layout = layout_from_dict(data, str(path), str(Path(path).resolve().parent))
    if source == "unity":
        layout = read_unity_save(path, scene=scene_ref, block=block, origin=origin)
        if scene_name is not None:
            return layout, load_scene(scene_name)
        return layout, reference_scene
    return layout, layout.load_scene(scene_name)


def _detect(data: Any, path: str) -> str:
    if isinstance(data, dict) and "format" in data:
        return "layout"
    if isinstance(data, dict) and isinstance(data.get("blocks"), list):
        blocks = data["blocks"]
        if not blocks or isinstance(blocks[0], dict) and isinstance(blocks[0].get("position"), dict):
            return "unity"
    raise InputError(f"{path}: neither a shoha-layout/1 file nor a simulator save; name it with --from")


def _error_row(row: dict[str, Any], exc: Exception, start: float) -> dict[str, Any]:
    """The row of an item that failed: bad input in its one line, anything else as internal."""
    if isinstance(exc, InputError):
        error = one_line(str(exc)) if str(exc) else "bad input"
    else:
        # One line, as every row's error is: a CSV record over two lines, torn in its quoted
        # field, took the rows appended after it into that field.
        error = one_line(f"internal error: {type(exc).__name__}: {exc}")
    return {**row, "status": "error", "error": error, "seconds": time.perf_counter() - start}


def score_task(save: str, reference: str, source: str = "auto", block: str = "shake-4t",
               origin: tuple[float, float, float] = (0.0, 0.0, 0.0), scene: str | None = None,
               seconds: float = 2.0, slices: int = 4, layers: int = 2) -> dict[str, Any]:
    """Score one save against a reference; a row of the batch output.

    Never raises for a bad save: the row's ``status`` is ``error`` and
    ``error`` says why.
    """
    from .score import check_same_scene, score

    start = time.perf_counter()
    row: dict[str, Any] = {"save": save, "save_sha256": sha256_file(save),
                           "reference_sha256": sha256_file(reference)}
    try:
        ref_layout, ref_scene, ref = _reference(reference, slices, layers)
        layout, scn = load_save(save, source, ref_layout.scene, ref_scene, block, tuple(origin), scene)
        check_same_scene(scn, ref_scene, save)
        result = score(scn, layout.placed(), ref, seconds=seconds,
                       elapsed_s=layout.session_seconds()).to_dict()
    except Exception as exc:  # noqa: BLE001 - one bad item must not stop the batch
        return _error_row(row, exc, start)
    pens = {p["name"]: p["points"] for p in result["penalties"]}
    finished = result["finished"]
    row.update({
        "status": "ok", "error": "",
        **{k: result[k] for k in COPIED_KEYS},
        "out_of_tolerance": len(result["out_of_tolerance"]), "collisions": len(result["collisions"]),
        "unstable_blocks": len(result["unstable_blocks"]),
        "poorly_interlocked": len(result["interlock"]["flagged"]),
        "bare_share_percent": result["coverage"]["bare_share_percent"],
        "finished_porosity_percent": finished["porosity_percent"],
        "finished_poorly_interlocked": finished["poorly_interlocked"],
        "finished_bare_share_percent": finished["bare_share_percent"],
        **{f"penalty_{name}": pens[name] for name in PENALTIES},
        "result": result,
        "seconds": time.perf_counter() - start,
    })
    return row


def optimize_task(scene: str, seed: int, time_limit: float | None, layouts: str) -> dict[str, Any]:
    """One optimizer run; writes its layout into the folder ``layouts``; a row of the batch output."""
    from geometry.layout import write_layout
    from geometry.scene import load_scene

    from .api import optimize

    start = time.perf_counter()
    row: dict[str, Any] = {"scene": scene, "seed": seed, "time_limit_s": time_limit}
    try:
        scn = load_scene(scene)
        result = optimize(scn, seed=seed, time_limit=time_limit)
        path = Path(layouts) / f"{Path(scene).stem}-seed{seed}.json"
        write_layout(result.layout, path)
    except Exception as exc:  # noqa: BLE001 - one bad item must not stop the batch
        return _error_row(row, exc, start)
    d = result.to_dict()
    row.update({"status": "ok", "error": "", "porosity_percent": d["porosity_percent"],
                "blocks": d["blocks"], "required_blocks": d["required_blocks"],
                "collisions": d["collisions"], "out_of_tolerance": d["out_of_tolerance"],
                "stable": d["stable"], "valid": d["valid"], "path": str(path),
                "seconds": time.perf_counter() - start})
    return row


def _call(task: Callable[..., dict[str, Any]], key: str, args: dict[str, Any]) -> dict[str, Any]:
    """Run a task and put the item key first in its row."""
    return {"item": key, **task(**args)}


# --- items ----------------------------------------------------------------------------------------


def expand_saves(patterns: Sequence[str], exclude: Iterable[str | os.PathLike] = ()) -> list[str]:
    """Save files named by files, folders (their ``*.json``) and glob patterns, sorted, once each.

    Raises
    ------
    InputError
        If a pattern matches nothing.
    """
    skip = {os.path.abspath(p) for p in exclude}
    out: list[str] = []
    seen: set[str] = set()
    for pattern in patterns:
        if os.path.isdir(pattern):
            matches = sorted(glob.glob(os.path.join(glob.escape(pattern), "*.json")))
        elif glob.has_magic(pattern):
            matches = sorted(p for p in glob.glob(pattern, recursive=True) if os.path.isfile(p))
        else:
            matches = [pattern]
        if not matches:
            raise InputError(f"{pattern}: no saves match")
        for m in matches:
            a = os.path.abspath(m)
            if a in skip or a in seen:
                continue
            seen.add(a)
            out.append(m)
    return out


#: Seeds one batch may name at most.
MAX_SEEDS = 100_000
#: The largest seed, as ``shoha optimize --seed`` takes.
MAX_SEED = 2**31 - 1


def parse_seeds(text: str) -> list[int]:
    """Seeds from ``"0-9"``, ``"1,4,7"`` or ``"0-3,10"``."""
    too_many = InputError(f"--seeds {text!r}: seeds are non-negative, at most {MAX_SEEDS} of them")
    seeds: list[int] = []
    for part in text.split(","):
        part = part.strip()
        try:
            if not plain_number(part):
                raise ValueError
            if "-" in part[1:]:
                lo, hi = part.split("-", 1) if not part.startswith("-") else ("", part)
                a, b = int(lo), int(hi)
                if b < a:
                    raise ValueError
            else:
                a = b = int(part)
        except ValueError:
            raise InputError(f"--seeds {text!r}: expected seeds like 0-9 or 1,4,7") from None
        if a < 0 or len(seeds) + b - a + 1 > MAX_SEEDS:  # counted before a range is made
            raise too_many
        if b > MAX_SEED:
            raise InputError(f"--seeds {text!r}: a seed is at most {MAX_SEED}, as for shoha optimize --seed")
        seeds.extend(range(a, b + 1))
    return list(dict.fromkeys(seeds))


# --- output ---------------------------------------------------------------------------------------


class RowFile:
    """A CSV or JSON Lines file that rows are appended to, one whole row per write.

    Parameters
    ----------
    path : str or PathLike
        ``.csv`` or ``.jsonl``.
    columns : sequence of str
        The CSV header; JSON Lines rows hold these keys first, then any others.
    """

    def __init__(self, path: str | os.PathLike, columns: Sequence[str]):
        self.path = Path(path)
        self.columns = tuple(columns)
        suffix = self.path.suffix.lower()
        if suffix not in FORMATS:
            raise InputError(f"{path}: output must end in .csv or .jsonl")
        self.format = suffix[1:]

    def read(self) -> list[dict[str, Any]]:
        """Rows already in the file, dropping a torn last line left by a killed run.

        The file is cut only once what comes before that line reads as this
        batch's output; a torn first line is cut only if it is the start of what
        this batch writes first (the CSV header, or a JSON Lines row). Any other
        file, one line of notes without its newline too, is left as it is.

        Raises
        ------
        InputError
            If the file is not a batch output of the same kind.
        """
        if not self.path.exists():
            return []
        data = self.path.read_bytes()
        cut = data.rfind(b"\n") + 1 if data and not data.endswith(b"\n") else len(data)
        rows = self._rows(data[:cut])
        if cut < len(data):
            # A row is written in one write(); a line without its newline is
            # the remains of a run killed mid-write (or a full disk).
            first = self._first_write()
            if not cut and not first.startswith(data[:len(first)]):
                raise InputError(f"{self.path}: is not the output of a batch like this one; use a new --out")
            with open(self.path, "r+b") as fh:
                fh.truncate(cut)
        return rows

    def _first_write(self) -> bytes:
        """How the file this batch writes begins: its CSV header, or the start of a JSON Lines row."""
        if self.format == "csv":
            buf = io.StringIO()
            csv.writer(buf, lineterminator="\n").writerow(self.columns)
            return buf.getvalue().encode()
        return f'{{"{self.columns[0]}":'.encode()  # ``line`` writes the first column first

    def _rows(self, data: bytes) -> list[dict[str, Any]]:
        """The rows of whole lines, refused unless they are this batch's output."""
        text = data.decode("utf-8", errors="replace")
        if not text:
            return []
        if self.format == "csv":
            reader = csv.DictReader(io.StringIO(text))
            if tuple(reader.fieldnames or ()) != self.columns:
                raise InputError(f"{self.path}: its columns are not those of this batch; use a new --out")
            return list(reader)
        rows = []
        for n, line in enumerate(text.splitlines(), 1):
            try:
                row = json.loads(line)
            except (json.JSONDecodeError, RecursionError):  # a line of 100 000 "[" is the second
                raise InputError(f"{self.path}: line {n} is not JSON; use a new --out") from None
            # Rows are written with this batch's columns first, in order (``line``): a row of
            # the other kind of batch (score rows in an optimize's file) is not one of these.
            if (not isinstance(row, dict) or not isinstance(row.get("item"), str)
                    or tuple(row)[:len(self.columns)] != self.columns):
                raise InputError(f"{self.path}: line {n} is not a row of this batch; use a new --out")
            rows.append(row)
        return rows

    def line(self, row: dict[str, Any]) -> bytes:
        """The bytes of one row, newline included."""
        if self.format == "csv":
            buf = io.StringIO()
            writer = csv.writer(buf, lineterminator="\n")
            writer.writerow([_cell(row.get(c)) for c in self.columns])
            return buf.getvalue().encode()
        ordered = {c: row.get(c) for c in self.columns}
        ordered.update({k: v for k, v in row.items() if k not in ordered})
        return (json.dumps(ordered, allow_nan=False, default=_json_default) + "\n").encode()

    def append(self, row: dict[str, Any]) -> None:
        """Append one row with a single write (O_APPEND), then fsync."""
        data = self.line(row)
        if self.format == "csv" and (not self.path.exists() or self.path.stat().st_size == 0):
            buf = io.StringIO()
            csv.writer(buf, lineterminator="\n").writerow(self.columns)
            data = buf.getvalue().encode() + data
        fd = os.open(self.path, os.O_WRONLY | os.O_APPEND | os.O_CREAT, 0o644)
        try:
            written = os.write(fd, data)
            if written != len(data):
                raise OSError(f"short write ({written} of {len(data)} bytes)")
            os.fsync(fd)
        except OSError as exc:
            raise InputError(f"{self.path}: cannot append a row ({exc})") from exc
        finally:
            os.close(fd)


def _cell(value: Any) -> str:
    if value is None:
        return ""
    if isinstance(value, bool):
        return "true" if value else "false"
    if isinstance(value, float):
        return repr(value) if math.isfinite(value) else ""
    return str(value)


def _json_default(value: Any) -> Any:
    if hasattr(value, "tolist"):
        return value.tolist()
    raise TypeError(f"{type(value).__name__} is not JSON")


# --- running --------------------------------------------------------------------------------------


#: Called after each item with (rows done, rows total, the row).
Progress = Callable[[int, int, dict[str, Any]], None]


def run_batch(
    items: Sequence[Item],
    task: Callable[..., dict[str, Any]],
    out: RowFile,
    workers: int = 1,
    scheduler: str | None = None,
    done: Callable[[dict[str, Any]], bool] | None = None,
    progress: Progress | None = None,
    on_start: Callable[[int, int], None] | None = None,
) -> BatchSummary:
    """Run the items not yet in ``out`` and append a row for each.

    Parameters
    ----------
    items : sequence of Item
    task : callable
        A module-level function ``task(**item.args) -> row``.
    out : RowFile
    workers : int
        Processes of the local pool (1: run in this process).
    scheduler : str, optional
        Address of a Dask scheduler (``tcp://host:8786``); runs there instead.
    done : callable, optional
        ``done(row) -> bool``: whether an existing row finishes its item
        (by default every row does).
    progress : callable, optional
        Called after each item with (finished, to run, row).
    on_start : callable, optional
        Called once with (items to run, items skipped).
    """
    start = time.perf_counter()
    keys = [it.key for it in items]
    if len(set(keys)) != len(keys):
        twice = next(k for i, k in enumerate(keys) if k in keys[:i])
        raise InputError(f"batch: {twice} is given twice")
    finished = {str(r.get("item")) for r in out.read() if done is None or done(r)}
    todo = [it for it in items if it.key not in finished]
    summary = BatchSummary(items=len(items), skipped=len(items) - len(todo), path=str(out.path))
    # Connect before any progress shows: a wrong address is bad usage.
    client = _connect(scheduler) if scheduler is not None and todo else None
    if on_start is not None:
        on_start(len(todo), summary.skipped)

    def record(row: dict[str, Any]) -> None:
        out.append(row)
        summary.ran += 1
        summary.errors += row.get("status") != "ok"
        if progress is not None:
            progress(summary.ran, len(todo), row)

    if not todo:
        summary.runner = "none"
    elif client is not None:
        summary.runner = f"dask {scheduler}"
        _run_dask(todo, task, client, record)
    elif workers <= 1:
        summary.runner = "this process"
        for it in todo:
            record(_call(task, it.key, it.args))
    else:
        summary.runner = f"{workers} processes"
        _run_pool(todo, task, workers, record)
    summary.seconds = time.perf_counter() - start
    return summary


def _crash_row(item: Item, what: str) -> dict[str, Any]:
    return {"item": item.key, "status": "error", "error": one_line(f"internal error: {what}")}


def _run_pool(todo: Sequence[Item], task: Callable[..., dict[str, Any]], workers: int,
              record: Callable[[dict[str, Any]], None]) -> None:
    """A local process pool; rebuilt if a worker dies, its lost items run again."""
    import multiprocessing
    from concurrent.futures import FIRST_COMPLETED, ProcessPoolExecutor, wait
    from concurrent.futures.process import BrokenProcessPool

    # spawn, not fork: MuJoCo, FCL and manifold3d hold threads and state
    # that a forked child must not inherit.
    context = multiprocessing.get_context("spawn")
    attempts = {it.key: 0 for it in todo}
    pending = list(todo)
    while pending:
        broken = False
        with ProcessPoolExecutor(max_workers=workers, mp_context=context) as pool:
            running = {}
            queue = list(pending)
            pending = []
            try:
                # Keep a few items in flight per worker, not the whole batch.
                while queue or running:
                    while queue and len(running) < 2 * workers:
                        it = queue.pop(0)
                        attempts[it.key] += 1
                        running[pool.submit(_call, task, it.key, it.args)] = it
                    finished, _ = wait(running, return_when=FIRST_COMPLETED)
                    for fut in finished:
                        it = running.pop(fut)
                        record(fut.result())
            except BrokenProcessPool:
                broken = True
                for fut, it in running.items():
                    if fut.done() and not fut.exception():
                        record(fut.result())
                    elif attempts[it.key] >= MAX_ATTEMPTS:
                        record(_crash_row(it, "a worker process died on this item"))
                    else:
                        pending.append(it)
                pending.extend(queue)
            except BaseException:
                for fut in running:
                    fut.cancel()
                raise
        if not broken:
            break


def check_scheduler(scheduler: str | None) -> None:
    """Refuse a ``--scheduler`` that is no address (None is none given). An address that is
    none (``garbage``) is refused before a client is made: Dask's own refusal came with a
    traceback from the half-made client, 20 s later, at exit."""
    # HOST:PORT, with a scheme or none; an IPv6 host in brackets ([::1]:8786).
    if scheduler is not None and not re.fullmatch(
            r"(?:[A-Za-z][A-Za-z0-9+.-]*://)?(?:\[[0-9A-Fa-f:.]+\]|[^\s/:\[\]]+):\d{1,5}", scheduler):
        raise InputError(f"--scheduler {scheduler}: not a scheduler address (tcp://HOST:PORT)")


#: Schemes whose address is probed before Dask connects: plain TCP (none is tcp). The others
#: are left to Dask: a bare connection to a TLS scheduler is logged there as a failed handshake.
PROBED_SCHEMES = ("", "tcp")


def _reachable(scheduler: str, timeout: float = 10.0) -> None:
    """Refuse a TCP address nothing listens at, at once: Dask retries a refused connection
    until its timeout (11 s to say that nothing listens at ``tcp://127.0.0.1:9``). The
    scheduler logs the probe as a comm closed before its handshake."""
    scheme, _, rest = scheduler.rpartition("://")
    if scheme.lower() not in PROBED_SCHEMES:
        return
    host, _, port = rest.rpartition(":")
    try:
        socket.create_connection((host.strip("[]"), int(port)), timeout=timeout).close()
    except (OSError, OverflowError, ValueError) as exc:  # ValueError: a name IDNA refuses (a..b)
        raise InputError(f"--scheduler {scheduler}: cannot connect ({exc})") from None


def _connect(scheduler: str) -> Any:
    """A Dask client of the scheduler at ``scheduler``."""
    check_scheduler(scheduler)
    try:
        from distributed import Client
    except ImportError:
        raise InputError("--scheduler needs Dask: pip install 'shoha[dask]'") from None
    _reachable(scheduler)
    try:
        return Client(scheduler, timeout="10s", set_as_default=False)
    except (OSError, TimeoutError, ValueError) as exc:
        raise InputError(f"--scheduler {scheduler}: cannot connect ({exc})") from None


def _run_dask(todo: Sequence[Item], task: Callable[..., dict[str, Any]], client: Any,
              record: Callable[[dict[str, Any]], None]) -> None:
    """The items on a Dask cluster; a task whose workers kept dying is run again."""
    from distributed import as_completed

    try:
        # Task keys are unique per run, so that two batches on one cluster never share a result.
        run = uuid.uuid4().hex[:12]
        by_key: dict[str, Item] = {it.key: it for it in todo}
        attempts = {it.key: 1 for it in todo}
        futures = {}
        for it in todo:
            fut = client.submit(_call, task, it.key, it.args, pure=False,
                                key=f"shoha-{run}-{_token(it.key)}-1")
            futures[fut] = it.key
        queue = as_completed(list(futures), loop=client.loop)
        for fut in queue:
            key = futures.pop(fut)
            if fut.status == "finished":
                record(fut.result())
                continue
            # The scheduler gave up on the task (its workers died while
            # running it, more than allowed-failures times): try again.
            if attempts[key] < MAX_ATTEMPTS:
                attempts[key] += 1
                it = by_key[key]
                again = client.submit(_call, task, it.key, it.args, pure=False,
                                      key=f"shoha-{run}-{_token(key)}-{attempts[key]}")
                futures[again] = key
                queue.add(again)
            else:
                record(_crash_row(by_key[key], f"Dask could not run it: {fut.exception()!r}"))
    finally:
        client.close()


def _token(key: str) -> str:
    return hashlib.sha1(key.encode()).hexdigest()[:16]
