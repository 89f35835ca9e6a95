"""Layouts: which blocks stand where, in installation order.

The file format is ``shoha-layout/1`` (docs/contract.md, "Layout file")::

    {"format": "shoha-layout/1",
     "scene": "mini",
     "blocks": [{"id": 0, "type": "shake-4t",
                 "position": [0.0, 1.2, 0.9], "quaternion": [1.0, 0.0, 0.0, 0.0]}]}

Reading validates everything at this boundary, and the rest of shoha trusts
the result. Unknown top-level keys are kept and written back; unknown block
keys are errors. Floats are written with Python's shortest round-trip repr,
so writing what was read is lossless.

A save from a training session may carry times (docs/contract.md): each
block an optional ``time_s``, when it was laid, and the file an optional
``elapsed_s``, when it was saved, both in seconds since the session began.
They are read, checked and written back; ``shoha score`` reports the
completion time and blocks per hour from them.
"""

from __future__ import annotations

import json
import os
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Any

import numpy as np

from .blocks import Block, get_block
from .constants import MAX_BLOCKS, tol
from .errors import InputError, finite_number, shown
from .fileio import atomic_write, read_json
from .pose import Pose
from .scene import Scene, load_scene

FORMAT = "shoha-layout/1"

#: The largest block id: JSON readers hold integers exactly up to 2**53.
MAX_ID = 2**53
#: Coordinates beyond this many metres from the origin are not a breakwater.
MAX_COORDINATE = 1e6

_BLOCK_KEYS = ("id", "type", "position", "quaternion")
#: Block keys a file may leave out.
_OPTIONAL_BLOCK_KEYS = ("time_s",)


@dataclass(frozen=True)
class Placement:
    """One block of a layout.

    Attributes
    ----------
    id : int
        Non-negative, unique within the layout.
    type : str
        Block type name, as written in the file.
    pose : Pose
        Block frame to world frame.
    time_s : float or None, seconds
        When the block was laid, since the session began (a simulator's
        save); None where the file gives no time.
    """

    id: int
    type: str
    pose: Pose
    time_s: float | None = None


@dataclass
class Layout:
    """A layout: a scene reference and blocks in installation order.

    Attributes
    ----------
    scene : str
        Built-in scene name or a scene file path (relative to ``base_dir``).
    blocks : list of Placement
    extra : dict
        Unknown top-level keys of the file, kept for writing back.
    base_dir : str or None
        Folder of the file it was read from; relative paths resolve here.
    source : str or None
        The file it was read from, named in messages about it.
    """

    scene: str
    blocks: list[Placement] = field(default_factory=list)
    extra: dict[str, Any] = field(default_factory=dict)
    base_dir: str | None = None
    source: str | None = field(default=None, compare=False)

    def load_scene(self, override: str | None = None) -> Scene:
        """The layout's scene, or ``override`` (a ``--scene`` option) when given.

        A scene the file names that does not load is reported as the file's fault, naming it.
        """
        if override is not None:
            return load_scene(override, self.base_dir)
        try:
            return load_scene(self.scene, self.base_dir)
        except InputError as exc:
            if self.source is None:
                raise
            raise InputError(f"{self.source}: {exc}") from None

    def placed(self) -> list[tuple[int, Block, Pose]]:
        """``(id, Block, Pose)`` for every block, in installation order."""
        return [(p.id, get_block(p.type, self.base_dir), p.pose) for p in self.blocks]

    def session_seconds(self) -> float | None:
        """Seconds from the session's start to this save, or None where the file has no times.

        The save's ``elapsed_s`` where it has one, else the latest ``time_s``
        of its blocks.
        """
        elapsed = self.extra.get("elapsed_s")
        if elapsed is not None:
            return float(elapsed)
        times = [p.time_s for p in self.blocks if p.time_s is not None]
        return max(times) if times else None

    def to_dict(self) -> dict[str, Any]:
        out: dict[str, Any] = {"format": FORMAT, "scene": self.scene}
        out.update(self.extra)
        out["blocks"] = [
            {
                "id": p.id,
                "type": p.type,
                "position": [float(v) for v in p.pose.position],
                "quaternion": [float(v) for v in p.pose.quaternion],
                **({"time_s": p.time_s} if p.time_s is not None else {}),
            }
            for p in self.blocks
        ]
        return out

    def dumps(self) -> str:
        """The layout as ``shoha-layout/1`` JSON text, one block per line."""
        d = self.to_dict()
        blocks = d.pop("blocks")
        head = json.dumps(d, allow_nan=False)[:-1]
        lines = ",\n".join("  " + json.dumps(b, allow_nan=False) for b in blocks)
        sep = ", " if len(d) else ""
        return f'{head}{sep}"blocks": [\n{lines}\n]}}\n' if blocks else f'{head}{sep}"blocks": []}}\n'


def read_layout(path: str | os.PathLike) -> Layout:
    """Read and validate a ``shoha-layout/1`` file.

    Raises
    ------
    InputError
        Naming the file, and the block where there is one, for: a missing or
        unreadable file, malformed JSON, NaN or infinite numbers, a wrong
        format tag, wrong types, a quaternion whose norm is not within 1e-6 of
        1, an unknown block type or block key, duplicate ids, more than
        ``MAX_BLOCKS`` blocks, or a ``time_s`` or ``elapsed_s`` that is not a
        finite, non-negative number of seconds (or an ``elapsed_s`` before a
        block's ``time_s``).
    """
    path = Path(path)
    data = read_json(path)
    return layout_from_dict(data, str(path), str(path.resolve().parent))


def layout_from_dict(data: Any, source: str, base_dir: str | None) -> Layout:
    """Validate parsed JSON as a layout; ``source`` names it in messages."""
    if not isinstance(data, dict):
        raise InputError(f"{source}: a layout must be a JSON object")
    fmt = data.get("format")
    if fmt != FORMAT:
        raise InputError(f"{source}: format must be {FORMAT!r}, not {fmt!r}")
    scene = data.get("scene")
    if not isinstance(scene, str) or not scene:
        raise InputError(f"{source}: scene must be a scene name or path")
    blocks = data.get("blocks")
    if not isinstance(blocks, list):
        raise InputError(f"{source}: blocks must be a list")
    if len(blocks) > MAX_BLOCKS:
        raise InputError(f"{source}: {len(blocks)} blocks is more than {MAX_BLOCKS}")
    extra = {k: v for k, v in data.items() if k not in ("format", "scene", "blocks")}
    check_type_count((raw.get("type") for raw in blocks if isinstance(raw, dict)), source)
    seen: set[int] = set()
    placements = []
    for index, raw in enumerate(blocks):
        p = _placement(raw, index, source, base_dir)
        if p.id in seen:
            raise InputError(f"{source}: block {p.id}: duplicate id")
        seen.add(p.id)
        placements.append(p)
    if "elapsed_s" in extra:
        check_elapsed(extra["elapsed_s"], placements, source)
    refuse_crowded(placements, base_dir, source)
    return Layout(scene, placements, extra, base_dir, source)


#: Most block types (names) in one layout or save: a breakwater's are one or two.
MAX_BLOCK_TYPES = 16


def check_type_count(kinds: Any, source: str) -> None:
    """Raise InputError where ``kinds`` (type names, strings among them counted) are more than
    ``MAX_BLOCK_TYPES``: each is a model built when it is first read, and 1500 tetrapod sizes
    took 7 s to read before any check refused them."""
    count = len({k for k in kinds if isinstance(k, str)})
    if count > MAX_BLOCK_TYPES:
        raise InputError(f"{source}: {count} block types, more than {MAX_BLOCK_TYPES}")


def refuse_crowded(placements: list[Placement], base_dir: str | None, source: str) -> None:
    """Raise InputError for blocks one inside another by the dozen (``checks.check_not_crowded``,
    for each block shape, then ``check_not_crowded_across`` the shapes): every check of such a
    file grows with the square of its count (300 copies of one pose took ``shoha check`` 13 s,
    and 100 000 ran it out of memory). Callers count the types first (:func:`check_type_count`),
    before any is built."""
    kinds = list(dict.fromkeys(p.type for p in placements))  # counted by the caller (check_type_count)
    blocks = {kind: get_block(kind, base_dir) for kind in kinds}
    refuse_crowded_blocks([(p.id, blocks[p.type], p.pose.position) for p in placements], source)


def refuse_crowded_blocks(blocks: list[tuple[int, Any, np.ndarray]], source: str) -> None:
    """:func:`refuse_crowded` of blocks already built: ``(id, block, position)`` each."""
    from .checks import check_not_crowded, check_not_crowded_across  # they pull in FCL and manifold3d

    # Grouped by shape, not by name: tetrapod:2 and tetrapod:02 are one block.
    shapes: dict[tuple[float, float], tuple[Any, list[tuple[int, np.ndarray]]]] = {}
    for key, block, position in blocks:
        shape = (round(block.volume, 9), round(block.bounding_radius, 9))
        shapes.setdefault(shape, (block, []))[1].append((key, position))
    groups = [(block, np.array([pos for _, pos in group]).reshape(-1, 3), [key for key, _ in group])
              for block, group in shapes.values()]
    for group in groups:
        check_not_crowded(*group, source)
    if len(groups) > 1:
        check_not_crowded_across(groups, source)


def check_seconds(value: Any, what: str, where: str) -> float:
    """``value`` as seconds since the session began: a finite, non-negative number, else an error."""
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        raise InputError(f"{where}: {what} must be a number of seconds, not {shown(value)}")
    if not finite_number(value) or value < 0:
        raise InputError(f"{where}: {what} must be a finite, non-negative number of seconds, "
                         f"not {shown(value)}")
    return float(value)


def check_elapsed(value: Any, placements: list[Placement], source: str) -> float:
    """A save's ``elapsed_s``: seconds (:func:`check_seconds`), and no earlier than any block's ``time_s``."""
    elapsed = check_seconds(value, "elapsed_s", source)
    for p in placements:
        if p.time_s is not None and p.time_s > elapsed:
            raise InputError(f"{source}: elapsed_s {elapsed:g} is earlier than block {p.id}'s "
                             f"time_s {p.time_s:g}")
    return elapsed


def _placement(raw: Any, index: int, source: str, base_dir: str | None) -> Placement:
    where = f"{source}: block #{index}"
    if not isinstance(raw, dict):
        raise InputError(f"{where}: must be a JSON object")
    allowed = _BLOCK_KEYS + _OPTIONAL_BLOCK_KEYS
    unknown = [k for k in raw if k not in allowed]
    if unknown:
        raise InputError(f"{where}: unknown key {unknown[0]!r} (allowed: {', '.join(allowed)})")
    missing = [k for k in _BLOCK_KEYS if k not in raw]
    if missing:
        raise InputError(f"{where}: missing {missing[0]!r}")
    key = raw["id"]
    if not isinstance(key, int) or isinstance(key, bool) or key < 0 or key > MAX_ID:
        raise InputError(f"{where}: id must be an integer from 0 to 2**53 (JSON's exact integers), "
                         f"not {key!r}")
    where = f"{source}: block {key}"
    kind = raw["type"]
    if not isinstance(kind, str):
        raise InputError(f"{where}: type must be a string")
    try:
        get_block(kind, base_dir)
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None
    position = _vector(raw["position"], 3, "position", where)
    check_position(position, where)
    q = _vector(raw["quaternion"], 4, "quaternion", where)
    time_s = check_seconds(raw["time_s"], "time_s", where) if "time_s" in raw else None
    return Placement(key, kind, Pose(position, normalised_quaternion(q, where)), time_s)


def check_position(position: np.ndarray, where: str, frame: str = "") -> None:
    """Refuse a position more than :data:`MAX_COORDINATE` from the origin: not a breakwater's."""
    if np.abs(position).max() > MAX_COORDINATE:
        raise InputError(f"{where}: position is more than {MAX_COORDINATE:g} m from the origin{frame}")


def normalised_quaternion(q: np.ndarray, where: str) -> np.ndarray:
    """``q`` normalised if its norm is within ``tol.quaternion_norm`` of 1, else an error."""
    with np.errstate(over="ignore"):  # a norm of 1e200s is inf, and refused below
        norm = float(np.linalg.norm(q))
    if abs(norm - 1.0) > tol.quaternion_norm:
        raise InputError(f"{where}: quaternion norm {norm:.6g} is not 1")
    return q


def _vector(value: Any, n: int, name: str, where: str) -> np.ndarray:
    if (not isinstance(value, list) or len(value) != n
            or not all(isinstance(v, (int, float)) and not isinstance(v, bool) for v in value)):
        raise InputError(f"{where}: {name} must be a list of {n} numbers")
    if not all(finite_number(v) for v in value):
        raise InputError(f"{where}: {name} has a non-finite number")
    return np.array(value, dtype=float)


def write_layout(layout: Layout, path: str | os.PathLike) -> None:
    """Write a layout atomically (whole, or not at all).

    A ``mesh:`` block type with a relative path is written relative to the
    file's own folder, where a reader resolves it (docs/contract.md), not to
    the folder it was relative to in memory (``layout.base_dir``, or the
    working folder when that is None): a layout of a scene in one folder
    written to another still finds its mesh.
    """
    folder = Path(path).expanduser().resolve().parent
    blocks = [replace(p, type=_rebased(p.type, layout.base_dir, folder)) for p in layout.blocks]
    atomic_write(path, replace(layout, blocks=blocks).dumps())


def _rebased(block_type: str, base_dir: str | None, folder: Path) -> str:
    """``block_type`` with a relative ``mesh:`` path made relative to ``folder`` instead of ``base_dir``."""
    if not block_type.startswith("mesh:"):
        return block_type
    mesh = Path(block_type[5:]).expanduser()
    if mesh.is_absolute():
        return block_type
    where = (Path(base_dir) if base_dir is not None else Path.cwd()) / mesh
    return "mesh:" + Path(os.path.relpath(where.resolve(), folder)).as_posix()
