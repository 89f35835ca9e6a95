"""Reading and writing user files safely.

Output files are written whole or not at all (docs/contract.md: on bad input no
output file is written, "not even a partial one"). JSON input is parsed
strictly: NaN and Infinity, which Python's json accepts by default, are
rejected, as are files too large to be a layout.
"""

from __future__ import annotations

import contextlib
import json
import os
import stat
from pathlib import Path
from typing import Any

from .errors import InputError

#: Largest JSON input read, in bytes. A 100 000-block layout is about 15 MB.
MAX_JSON_BYTES = 64 * 1024 * 1024


def check_replaceable(path: str | os.PathLike) -> None:
    """Refuse an output path that a file cannot replace: a folder, or anything but a regular
    file (a device such as ``/dev/null``, a named pipe, a socket).

    Output files are written by a rename over the path, which would put a
    regular file in place of a device node (as root, ``--out /dev/null``
    replaced the machine's ``/dev/null``). A path that does not exist yet is fine.
    """
    try:
        st = os.stat(path)
    except OSError:
        return  # missing, or unreachable: the write itself says so
    _refuse_other_kinds(path, st, "; output files are written whole, in place of what is there")


def _temporary(path: Path) -> Path:
    """The file :func:`atomic_write` writes first, beside ``path``."""
    return path.with_name(f".{path.name}.{os.getpid()}.tmp")


def check_writable(path: str | os.PathLike) -> None:
    """Refuse, before any work, an output path whose folder takes no file of its name: the
    temporary file :func:`atomic_write` would write is made and removed at once (``path``
    itself is not touched). ``--out /proc/x.json`` and a name too long for the file system
    were refused only once a run had spent its whole limit (stop 77's probe)."""
    tmp = _temporary(Path(path))
    try:
        fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
    except FileExistsError:
        return  # this process's own temporary file: the write replaces it
    except OSError as exc:
        raise InputError(f"{path}: cannot write ({exc.strerror or exc})") from None
    os.close(fd)
    with contextlib.suppress(OSError):
        os.unlink(tmp)


def atomic_write(path: str | os.PathLike, data: bytes | str) -> None:
    """Write ``data`` to ``path`` through a temporary file and an atomic rename."""
    path = Path(path)
    check_replaceable(path)
    if isinstance(data, str):
        data = data.encode()
    tmp = _temporary(path)
    try:
        with open(tmp, "wb") as fh:
            fh.write(data)
            fh.flush()
            os.fsync(fh.fileno())
        os.replace(tmp, path)
    except OSError as exc:
        raise InputError(f"{path}: cannot write ({exc.strerror or exc})") from exc
    finally:
        # Not ``tmp.exists()``: that raises too where the name is too long for the system.
        with contextlib.suppress(OSError):
            tmp.unlink()


def reject_constant(name: str) -> Any:
    """``json.loads``' ``parse_constant``: NaN and Infinity refused."""
    raise ValueError(f"{name} is not a number JSON allows")


class DuplicateKey(ValueError):
    """A JSON object names one key twice."""


def unique_keys(pairs: list[tuple[str, Any]]) -> dict[str, Any]:
    """``json.loads``' ``object_pairs_hook``: an object that names a key twice is refused.
    ``json`` keeps the last, so a save with ``"blocks"`` twice silently lost the first list
    (stop 77's probe)."""
    out = dict(pairs)
    if len(out) < len(pairs):
        seen: set[str] = set()
        twice = next(k for k, _ in pairs if k in seen or seen.add(k))
        raise DuplicateKey(f"the key {twice[:40]!r} appears twice in one object")
    return out


#: Most digits of an integer read from JSON: more than any float holds (1e308 has 309).
MAX_INT_DIGITS = 309


def ascii_digits(text: str) -> bool:
    """Whether ``text`` is one or more of 0-9 (``str.isdigit`` and ``int`` also take other
    scripts' digits: ``int("٣")`` is 3)."""
    return text.isascii() and text.isdigit()


def bounded_int(text: str) -> int:
    """A JSON integer, refused where no float can hold it (``10**400`` would pass every
    type check as an int and then fail in float arithmetic)."""
    digits = len(text.lstrip("-"))
    if digits > MAX_INT_DIGITS:
        raise ValueError(f"an integer of {digits} digits is too large")
    value = int(text)
    try:
        float(value)  # 309 digits may still be past the largest float, 1.8e308
    except OverflowError:
        raise ValueError(f"an integer of {digits} digits is too large for a float") from None
    return value


def regular_file(path: Path) -> os.stat_result:
    """``path``'s status, if it is a regular file; else :class:`InputError` naming it.

    A device (``/dev/zero``) or a named pipe reports no size, or blocks its
    reader for ever: neither is read.
    """
    try:
        st = path.stat()
    except FileNotFoundError:
        raise InputError(f"{path}: file not found") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    _refuse_other_kinds(path, st)
    return st


def _refuse_other_kinds(path: str | os.PathLike, st: os.stat_result, why: str = "") -> None:
    """InputError unless ``st`` (``path``'s status) is a regular file's: a folder, a device,
    a pipe or a socket is neither read nor written over."""
    if stat.S_ISDIR(st.st_mode):
        raise InputError(f"{path}: is a folder, not a file")
    if not stat.S_ISREG(st.st_mode):
        raise InputError(f"{path}: not a regular file (a device, pipe or socket){why}")


def read_json(path: str | os.PathLike) -> Any:
    """Parse a JSON file strictly; raise :class:`InputError` naming the file."""
    path = Path(path)
    size = regular_file(path).st_size
    if size > MAX_JSON_BYTES:
        raise InputError(f"{path}: file is {size} bytes, more than {MAX_JSON_BYTES}")
    try:
        text = path.read_text(encoding="utf-8-sig")
    except UnicodeDecodeError:
        raise InputError(f"{path}: not UTF-8 text") from None
    except OSError as exc:
        raise InputError(f"{path}: cannot read ({exc.strerror or exc})") from None
    try:
        return json.loads(text, parse_constant=reject_constant, parse_int=bounded_int,
                          object_pairs_hook=unique_keys)
    except json.JSONDecodeError as exc:
        where = f"line {exc.lineno} column {exc.colno}"
        raise InputError(f"{path}: malformed JSON at {where}: {exc.msg}") from None
    except ValueError as exc:
        raise InputError(f"{path}: {exc}") from None
    except RecursionError:
        raise InputError(f"{path}: JSON nested too deeply") from None
