"""The error raised for bad input.

The CLI turns an :class:`InputError` into one line on stderr and exit status 2
(docs/contract.md, "Exit codes and errors"). Anything else escaping the CLI is a bug.
"""

from __future__ import annotations

import math
from typing import Any


class InputError(ValueError):
    """Bad input from a user: a file, a name or an argument.

    The message names the file or object and the problem, in words a person
    can act on, e.g. ``"layout.json: block 17: quaternion norm 0.82 is not 1"``.
    """


def one_line(message: str) -> str:
    """``message`` as one line of printable text: a newline or other control character in a
    name the user gave (a file called ``"a\\nb"``) is shown escaped, not cut or sent raw."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in message)


def shown(value: Any, width: int = 40) -> str:
    """``repr(value)`` for a message, cut to ``width`` characters: a number a user wrote with 300
    digits, or a 10 MB string, is named, not printed whole."""
    text = repr(value)
    return text if len(text) <= width else f"{text[:width - 3]}..."


def finite_number(value: Any) -> bool:
    """Whether ``value``, as a JSON or TOML reader gives it, is a number a float holds: not a
    bool, not NaN or infinite, and not an integer too large for a float (``1e400`` written
    out in digits, which ``math.isfinite`` refuses with an OverflowError)."""
    if not isinstance(value, (int, float)) or isinstance(value, bool):
        return False
    try:
        return math.isfinite(value)
    except OverflowError:
        return False
