"""What every ``shoha`` command shares: output, path checks, option parsing."""

from __future__ import annotations

import json
import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import click

from geometry.errors import InputError
from geometry.fileio import check_replaceable, check_writable


def emit(payload: dict[str, Any], as_json: bool, human: str) -> None:
    """Print one JSON object (``--json``) or a line for people, on stdout."""
    if as_json:
        click.echo(json.dumps(payload, allow_nan=False))
    else:
        click.echo(human)


def check_out(path: str, suffixes: tuple[str, ...] | None = None, atomic: bool = True) -> Path:
    """Validate an output path before any work is done. ``atomic``: the output is written
    whole through a temporary file beside it (:func:`geometry.fileio.atomic_write`); else it is
    appended to in place (a batch's rows), and an existing file need only be writable."""
    p = Path(path)
    if suffixes and p.suffix.lower() not in suffixes:
        raise InputError(f"{path}: output must end in {' or '.join(suffixes)}")
    parent = p.parent if str(p.parent) else Path(".")
    if not parent.is_dir():
        raise InputError(f"{path}: folder {parent} does not exist")
    check_replaceable(p)
    if atomic or not p.exists():
        check_writable(p)
    elif not os.access(p, os.W_OK):
        raise InputError(f"{path}: cannot write (permission denied)")
    return p


def check_not_input(path: Path, inputs: Sequence[tuple[str | os.PathLike | None, str]]) -> None:
    """Refuse an output path that is one of the command's own input files (``inputs``: each
    path, or None, with what it is): writing there would destroy what was read."""
    for given, what in inputs:
        if given is None:
            continue
        try:
            same = os.path.samefile(Path(given).expanduser(), path)
        except OSError:  # one of them does not exist: no clash
            continue
        if same:
            raise InputError(f"{path}: is the {what}; write the output elsewhere")


def parse_origin(text: str) -> tuple[float, float, float]:
    """``--origin X,Y,Z``, metres."""
    from geometry.blocks import plain_number

    try:
        values = tuple(float(v) for v in text.split(",")) if plain_number(text) else ()
    except ValueError:
        values = ()
    if len(values) != 3 or not all(math.isfinite(v) for v in values):
        raise InputError(f"--origin {text!r}: expected three numbers X,Y,Z in metres")
    from geometry.layout import MAX_COORDINATE

    if max(abs(v) for v in values) > MAX_COORDINATE:
        raise InputError(f"--origin {text!r}: more than {MAX_COORDINATE:g} m from the world origin")
    return values  # type: ignore[return-value]


def json_option(f: Callable[..., Any]) -> Callable[..., Any]:
    """The ``--json`` flag every command takes."""
    return click.option("--json", "as_json", is_flag=True, help="Print one JSON object.")(f)


class Group(click.Group):
    """A click group that lists commands in the order they were added."""

    def list_commands(self, ctx: click.Context) -> list[str]:
        return list(self.commands)


SAVE_FORMATS = click.Choice(["auto", "layout", "unity"])


def block_from_cwd(ctx: click.Context, param: click.Parameter, value: str) -> str:
    """``--block``'s callback: a relative ``mesh:PATH`` on the command line is the working
    folder's (docs/contract.md), made absolute here; a save's own block types are resolved
    from the save's folder, and ``--block`` was too."""
    if value.startswith("mesh:") and not Path(value[5:]).expanduser().is_absolute():
        value = "mesh:" + str(Path.cwd() / Path(value[5:]).expanduser())
    # A bad --block is the option's fault, whatever the save holds. A mesh is only looked for
    # here: reading and cutting it is the command's work, within its time limit where it has one.
    from geometry.blocks import get_block, mesh_path

    path = mesh_path(value)
    try:
        if path is None:
            get_block(value)
        elif not path.is_file():
            raise InputError(f"{path}: no such file" if not path.exists() else f"{path}: not a file")
    except InputError as exc:
        raise InputError(f"{param.opts[0]} {value}: {exc}") from None
    return value


def save_options(f: Any) -> Any:
    """The options that say how to read a save (as in ``shoha convert``)."""
    f = click.option("--origin", default="0,0,0", show_default=True,
                     help="Unity saves: world position X,Y,Z (m) of Unity's origin.")(f)
    f = click.option("--block", "block_type", default="shake-4t", show_default=True, callback=block_from_cwd,
                     help="Unity saves: block type of saved blocks that name none.")(f)
    f = click.option("--from", "source", type=SAVE_FORMATS, default="auto", show_default=True,
                     help="Format of the save: shoha-layout/1, the simulator's Unity JSON, "
                          "or auto (told apart by content).")(f)
    return f


def check_time_limit(value: float | None) -> None:
    """``--time-limit``: a positive, finite number of seconds (``nan`` passes a range check)."""
    if value is not None and (not math.isfinite(value) or value <= 0):
        raise InputError(f"--time-limit {value}: must be a positive number of seconds")
