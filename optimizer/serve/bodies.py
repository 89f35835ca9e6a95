"""Request bodies of ``shoha serve``: parsed strictly, checked whole, before anything changes.

Every body is untrusted. It must be JSON of at most :data:`MAX_BODY_BYTES`
(413 above), with no NaN or Infinity and no number that overflows to one; a
field of the wrong type or out of range is a 422 naming the field. Nothing in
a body can make the service read a file: block types are limited to the
names the service knows (:class:`Catalogue`), and a layout's ``scene`` is
compared with the session's, never loaded.

Poses come in the session's frame (docs/contract.md, "Simulator saves"):

``unity``
    ``{"position": {"x", "y", "z"}, "rotation": {"x", "y", "z", "w"}}``,
    converted by :func:`geometry.unity.unity_to_world` with the session's
    ``origin``, exactly as ``shoha convert`` converts a save.
``world``
    ``{"position": [x, y, z], "quaternion": [w, x, y, z]}``, as in layout files.
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from geometry.blocks import Block, get_block, size_key
from geometry.errors import InputError, finite_number
from geometry.fileio import DuplicateKey, ascii_digits, bounded_int, reject_constant, unique_keys
from geometry.layout import (
    FORMAT,
    MAX_COORDINATE,
    layout_from_dict,
    normalised_quaternion,
    refuse_crowded_blocks,
)
from geometry.pose import Pose
from geometry.scene import Scene
from geometry.unity import unity_to_world

#: Largest request body, bytes. A 5000-block simulator save is about 1 MB.
MAX_BODY_BYTES = 4 * 1024 * 1024

#: Most blocks one session holds: five times the 1005 of the built-in ``full`` scene.
MAX_SESSION_BLOCKS = 5000

#: Largest block id, as in layout files (docs/contract.md): a JSON number any client reads exactly.
MAX_BLOCK_ID = 2**53

#: Latest time a block may carry, seconds since the session began (a year).
MAX_TIME_S = 366 * 24 * 3600.0

FRAMES = ("unity", "world")


class BodyError(InputError):
    """A request the service refuses, with its HTTP status and a one-line reason.

    Attributes
    ----------
    status : int
        400 for a body that is not JSON, 404 for something that does not
        exist, 413 for a body too large, 422 for JSON that is not what the
        endpoint takes.
    """

    def __init__(self, status: int, message: str):
        super().__init__(message.splitlines()[0] if message else "bad request")
        self.status = status


def parse_json(raw: bytes) -> Any:
    """The JSON value of a request body; a :class:`BodyError` for anything else.

    NaN, Infinity and numbers too large for a float are refused (Python's
    ``json`` accepts the first two by default and turns ``1e400`` into
    infinity).
    """
    if len(raw) > MAX_BODY_BYTES:
        raise BodyError(413, f"body is {len(raw)} bytes, more than {MAX_BODY_BYTES}")
    if not raw.strip():
        raise BodyError(400, "body is empty: send a JSON object")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError:
        raise BodyError(400, "body is not UTF-8 text") from None
    try:
        value = json.loads(text, parse_constant=reject_constant, parse_float=_finite_float,
                           parse_int=bounded_int, object_pairs_hook=unique_keys)
    except json.JSONDecodeError as exc:
        raise BodyError(400, f"malformed JSON at line {exc.lineno} column {exc.colno}: {exc.msg}") from None
    except RecursionError:
        raise BodyError(400, "JSON nested too deeply") from None
    except DuplicateKey as exc:
        raise BodyError(400, str(exc)) from None
    except ValueError as exc:
        raise BodyError(400, f"bad JSON number: {exc}") from None
    return value


def _finite_float(text: str) -> float:
    v = float(text)
    if not math.isfinite(v):
        raise ValueError(f"{text[:40]} is too large for a float")
    return v


# --- fields -----------------------------------------------------------------------


def _object(value: Any, where: str) -> dict[str, Any]:
    if not isinstance(value, dict):
        raise BodyError(422, f"{where} must be a JSON object")
    return value


def _only(value: dict[str, Any], allowed: Iterable[str], where: str) -> None:
    allowed = tuple(allowed)
    unknown = [k for k in value if k not in allowed]
    if unknown:
        raise BodyError(422, f"{where}: unknown key {unknown[0][:40]!r} (allowed: {', '.join(allowed)})")


def _number(value: Any, where: str) -> float:
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        raise BodyError(422, f"{where} must be a number")
    if not finite_number(value):
        raise BodyError(422, f"{where} is not a finite number")
    return float(value)


def _numbers(value: Any, n: int, where: str) -> np.ndarray:
    if not isinstance(value, list) or len(value) != n:
        raise BodyError(422, f"{where} must be a list of {n} numbers")
    return np.array([_number(v, f"{where}[{i}]") for i, v in enumerate(value)])


def _fields(value: Any, names: str, where: str) -> dict[str, float]:
    """A Unity ``Vector3`` or ``Quaternion`` object: numbers named by the letters of ``names``."""
    if not isinstance(value, dict):
        raise BodyError(422, f"{where} must be an object with {', '.join(names)}")
    out = {}
    for c in names:
        if c not in value:
            raise BodyError(422, f"{where}.{c} is missing")
        out[c] = _number(value[c], f"{where}.{c}")
    return out


def _position(p: np.ndarray, where: str) -> np.ndarray:
    if np.abs(p).max() > MAX_COORDINATE:
        raise BodyError(422, f"{where} is more than {MAX_COORDINATE:g} m from the origin")
    return p


def _quaternion(q: np.ndarray, where: str) -> np.ndarray:
    try:
        return normalised_quaternion(q, where)
    except InputError as exc:
        raise BodyError(422, str(exc)) from None


def time_value(value: Any, where: str) -> float | None:
    """An optional time in seconds since the session began: None, or a number in [0, a year]."""
    if value is None:
        return None
    t = _number(value, where)
    if not 0.0 <= t <= MAX_TIME_S:
        raise BodyError(422, f"{where} = {t:g} s must be from 0 to {MAX_TIME_S:g}")
    return t


def block_id(text: str) -> int:
    """A block id from a URL path: a non-negative integer, as in layout files."""
    if not ascii_digits(text) or len(text) > 16 or int(text) > MAX_BLOCK_ID:
        raise BodyError(422, f"block id {text[:40]!r} must be an integer from 0 to {MAX_BLOCK_ID}")
    return int(text)


def origin_value(value: Any) -> np.ndarray:
    """A session's ``origin``: where Unity's origin lies in the world frame, metres."""
    if value is None:
        return np.zeros(3)
    return _position(_numbers(value, 3, "origin"), "origin")


def frame_value(value: Any) -> str:
    if value is None:
        return "unity"
    if value not in FRAMES:
        raise BodyError(422, f"frame must be \"unity\" or \"world\", not {str(value)[:40]!r}")
    return value


# --- block types ----------------------------------------------------------------------


@dataclass(frozen=True)
class Catalogue:
    """The block types a client may name: those of the served scenes, and the built-in ones.

    A client never names a ``mesh:PATH`` of its own (that would read a file of
    its choosing) nor a new parametric size (each is built and cached): a
    ``mesh:`` or sized type is allowed only where a served scene uses it.
    """

    names: frozenset[str]
    base_dirs: tuple[tuple[str, str | None], ...]

    @classmethod
    def of(cls, scenes: Iterable[Scene]) -> Catalogue:
        names = {"shake-4t", "tetrapod"}
        dirs: dict[str, str | None] = {}
        for s in scenes:
            names.add(s.block_type)
            dirs.setdefault(s.block_type, s.base_dir)
        return cls(frozenset(names), tuple(sorted(dirs.items(), key=lambda kv: kv[0])))

    def spelled(self, name: Any, where: str) -> str:
        """``name`` as the served scenes spell it: ``tetrapod:2`` is ``tetrapod:2.0`` where a
        scene names that one (the same size, parsed), and any name outside them is refused."""
        if not isinstance(name, str):
            raise BodyError(422, f"{where}: type must be a string")
        if name in self.names:
            return name
        size = size_key(name)
        served = dict(self.base_dirs)  # the scenes' own types: their spelling first
        same = sorted((known for known in self.names if size is not None and size_key(known) == size),
                      key=lambda known: (known not in served, known))
        if not same:
            raise BodyError(422, f"{where}: unknown block type {name[:60]!r} "
                                 f"(this service knows {', '.join(sorted(self.names))})")
        return same[0]

    def block(self, name: Any, where: str) -> Block:
        name = self.spelled(name, where)
        return get_block(name, dict(self.base_dirs).get(name))


# --- blocks ---------------------------------------------------------------------------


@dataclass(frozen=True)
class BlockBody:
    """One block as a request gives it, in the world frame.

    Attributes
    ----------
    type : str
    block : Block
    pose : Pose
        World frame.
    time_s : float or None, seconds since the session began
    """

    type: str
    block: Block
    pose: Pose
    time_s: float | None


def block_body(value: Any, frame: str, origin: np.ndarray, default_type: str, catalogue: Catalogue,
               where: str = "body") -> BlockBody:
    """``PUT /sessions/{id}/blocks/{block}``'s body, in the session's frame."""
    value = _object(value, where)
    pose_keys = ("position", "rotation") if frame == "unity" else ("position", "quaternion")
    _only(value, (*pose_keys, "type", "time_s"), where)
    for k in pose_keys:
        if k not in value:
            other = "quaternion" if frame == "unity" else "rotation"
            hint = f" (a {frame}-frame session takes {k}, not {other})" if other in value else ""
            raise BodyError(422, f"{where}: missing {k!r}{hint}")
    kind = catalogue.spelled(value.get("type", default_type), where)
    block = catalogue.block(kind, where)
    if frame == "unity":
        position = _fields(value["position"], "xyz", f"{where}: position")
        rotation = _fields(value["rotation"], "xyzw", f"{where}: rotation")
        _quaternion(np.array([rotation[c] for c in "xyzw"]), f"{where}: rotation")
        pose = unity_to_world(position, rotation, origin)
    else:
        q = _quaternion(_numbers(value["quaternion"], 4, f"{where}: quaternion"), f"{where}: quaternion")
        pose = Pose(_numbers(value["position"], 3, f"{where}: position"), q)
    _position(pose.position, f"{where}: position")
    return BlockBody(kind, block, pose, time_value(value.get("time_s"), f"{where}: time_s"))


@dataclass(frozen=True)
class LayoutBody:
    """``PUT /sessions/{id}/layout``'s body: every block, world frame, ids in installation order.

    Attributes
    ----------
    blocks : list of (id, BlockBody)
    elapsed_s : float or None
        The save's ``elapsed_s``, seconds.
    """

    blocks: list[tuple[int, BlockBody]]
    elapsed_s: float | None


def layout_body(value: Any, scene: Scene, origin: np.ndarray, catalogue: Catalogue) -> LayoutBody:
    """A whole simulator save (Unity frame) or a ``shoha-layout/1`` object (world frame).

    They are told apart as ``shoha score --from auto`` tells them: a
    ``format`` key means a layout file's object. A save's blocks take the ids
    0, 1, 2, ... in order and the session's ``origin``, and one without a
    ``type`` is of the scene's block, as ``shoha convert`` reads a save.
    """
    value = _object(value, "layout")
    blocks = value.get("blocks")
    if not isinstance(blocks, list):
        raise BodyError(422, "layout: blocks must be a list")
    if len(blocks) > MAX_SESSION_BLOCKS:
        raise BodyError(422, f"layout: {len(blocks)} blocks is more than a session holds "
                             f"({MAX_SESSION_BLOCKS})")
    elapsed = time_value(value.get("elapsed_s"), "layout: elapsed_s")
    if "format" in value:
        out = _layout_file(value, scene, catalogue)
    else:
        out = []
        for index, raw in enumerate(blocks):
            where = f"layout: block #{index}"
            raw = _object(raw, where)
            # A save block's other keys are ignored, as shoha convert ignores them.
            picked = {k: raw[k] for k in ("position", "rotation", "type", "time_s") if k in raw}
            out.append((index, block_body(picked, "unity", origin, scene.block_type, catalogue, where)))
        # As a layout file is refused (layout_from_dict), before any block is laid: laid one by one,
        # 100 copies of one pose met every other copy up to the crowding check's 84th, and held the
        # worker 16 s.
        try:
            refuse_crowded_blocks([(key, b.block, b.pose.position) for key, b in out], "layout")
        except InputError as e:
            raise BodyError(422, str(e)) from None
    for key, b in out:
        if elapsed is not None and b.time_s is not None and b.time_s > elapsed:
            raise BodyError(422, f"layout: elapsed_s {elapsed:g} is earlier than block {key}'s time_s "
                                 f"{b.time_s:g}")
    return LayoutBody(out, elapsed)


def _layout_file(value: dict[str, Any], scene: Scene, catalogue: Catalogue) -> list[tuple[int, BlockBody]]:
    if value.get("format") != FORMAT:
        raise BodyError(422, f"layout: format must be {FORMAT!r}, not {str(value.get('format'))[:40]!r}")
    named = value.get("scene")
    if not isinstance(named, str) or (named not in (scene.name, scene.source)
                                      and Path(named).stem != scene.name):
        raise BodyError(422, f"layout: scene {str(named)[:60]!r} is not the session's scene {scene.name!r}")
    times: list[float | None] = []
    stripped = []
    for index, raw in enumerate(value["blocks"]):
        where = f"layout: block #{index}"
        raw = _object(raw, where)
        # Types are checked here, before geometry.layout builds any block from them.
        catalogue.spelled(raw.get("type"), where)
        times.append(time_value(raw.get("time_s"), f"{where}: time_s"))
        stripped.append({k: v for k, v in raw.items() if k != "time_s"})
    data = {"format": FORMAT, "scene": scene.name, "blocks": stripped}
    try:
        layout = layout_from_dict(data, "layout", None)
    except InputError as exc:
        raise BodyError(422, str(exc)) from None
    out = []
    for p, t in zip(layout.blocks, times, strict=True):
        _position(p.pose.position, f"layout: block {p.id}: position")
        kind = catalogue.spelled(p.type, f"layout: block {p.id}")
        out.append((p.id, BlockBody(kind, catalogue.block(kind, f"layout: block {p.id}"), p.pose, t)))
    return out
