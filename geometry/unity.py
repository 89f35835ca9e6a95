"""Simulator saves: Unity's left-handed, y-up frame to shoha's world frame.

docs/contract.md ("Simulator saves") fixes the conversion::

    p_world = (x_u, z_u, y_u) + origin
    R_world = P @ R_unity @ P          P swaps y and z

Conjugating a rotation by the reflection P keeps its angle's magnitude but
mirrors its axis and reverses its sense, so for a Unity quaternion
``(x, y, z, w)`` the world quaternion is ``[w, -x, -z, -y]`` (scalar first):
sign flips and a swap, exact in floating point.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from .blocks import get_block
from .constants import MAX_BLOCKS
from .errors import InputError, finite_number
from .fileio import read_json
from .layout import (
    Layout,
    Placement,
    check_elapsed,
    check_position,
    check_seconds,
    check_type_count,
    normalised_quaternion,
    refuse_crowded,
)
from .pose import Pose

#: The permutation matrix that swaps y and z.
SWAP_YZ = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])


def unity_to_world(position: dict[str, float], rotation: dict[str, float],
                   origin: np.ndarray) -> Pose:
    """World pose of a Unity ``Vector3`` position and ``Quaternion`` rotation."""
    p = np.array([position["x"], position["z"], position["y"]]) + origin
    q = np.array([rotation["w"], -rotation["x"], -rotation["z"], -rotation["y"]])
    return Pose(p, q)


def read_unity_save(
    path: str | os.PathLike,
    scene: str = "mini",
    block: str = "shake-4t",
    origin: tuple[float, float, float] = (0.0, 0.0, 0.0),
) -> Layout:
    """Convert a simulator save to a layout.

    Blocks get ids ``0..n-1`` in save order, which is their installation
    order. A block without ``type`` takes ``block``. A block's optional
    ``time_s`` and the save's optional ``elapsed_s`` (seconds since the
    session began) are kept: ``time_s`` on the block, ``elapsed_s`` among the
    layout's top-level keys, so that ``shoha convert`` writes both.

    Raises
    ------
    InputError
        For a malformed save: missing or non-numeric fields, NaN, a rotation
        whose norm is not 1, an unknown block type, too many blocks, or a
        ``time_s`` or ``elapsed_s`` that is not a finite, non-negative number
        of seconds (or an ``elapsed_s`` before a block's ``time_s``).
    """
    path = Path(path)
    data = read_json(path)
    source = str(path)
    if not isinstance(data, dict) or not isinstance(data.get("blocks"), list):
        raise InputError(f"{source}: a simulator save is an object with a 'blocks' list")
    raw_blocks = data["blocks"]
    if len(raw_blocks) > MAX_BLOCKS:
        raise InputError(f"{source}: {len(raw_blocks)} blocks is more than {MAX_BLOCKS}")
    origin_arr = np.asarray(origin, dtype=float)
    base_dir = str(path.resolve().parent)
    get_block(block, base_dir)
    check_type_count((raw.get("type", block) for raw in raw_blocks if isinstance(raw, dict)), source)
    placements = []
    for index, raw in enumerate(raw_blocks):
        where = f"{source}: block #{index}"
        if not isinstance(raw, dict):
            raise InputError(f"{where}: must be a JSON object")
        kind = raw.get("type", block)
        if not isinstance(kind, str):
            raise InputError(f"{where}: type must be a string")
        try:
            get_block(kind, base_dir)
        except InputError as exc:
            raise InputError(f"{where}: {exc}") from None
        position = _fields(raw.get("position"), "xyz", "position", where)
        check_position(np.array(list(position.values())), where)  # before --origin is added to it
        rotation = _fields(raw.get("rotation"), "xyzw", "rotation", where)
        q = np.array([rotation[c] for c in "xyzw"])
        normalised_quaternion(q, where)
        time_s = check_seconds(raw["time_s"], "time_s", where) if "time_s" in raw else None
        placement = Placement(index, kind, unity_to_world(position, rotation, origin_arr), time_s)
        check_position(placement.pose.position, where, " in the world frame (after --origin)")
        placements.append(placement)
    extra = {}
    if "elapsed_s" in data:
        check_elapsed(data["elapsed_s"], placements, source)
        extra["elapsed_s"] = data["elapsed_s"]
    refuse_crowded(placements, base_dir, source)
    return Layout(scene, placements, extra, base_dir, source)


def _fields(value: Any, names: str, what: str, where: str) -> dict[str, float]:
    if not isinstance(value, dict):
        raise InputError(f"{where}: {what} must be an object with {', '.join(names)}")
    out = {}
    for c in names:
        v = value.get(c)
        if not isinstance(v, (int, float)) or isinstance(v, bool):
            raise InputError(f"{where}: {what}.{c} must be a number")
        if not finite_number(v):
            raise InputError(f"{where}: {what}.{c} is not finite")
        out[c] = float(v)
    return out
