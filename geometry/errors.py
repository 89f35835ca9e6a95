"""The error raised for bad input.

The CLI turns an :class:`InputError` into one line on stderr and exit status 2
(docs/contract.md, "Exit codes and errors"). Anything else escaping the CLI is a bug.
"""

from __future__ import annotations


class InputError(ValueError):
    """Bad input from a user: a file, a name or an argument.

    The message names the file or object and the problem, in words a person
    can act on, e.g. ``"layout.json: block 17: quaternion norm 0.82 is not 1"``.
    """


def one_line(message: str) -> str:
    """``message`` as one line of printable text: a newline or other control character in a
    name the user gave (a file called ``"a\\nb"``) is shown escaped, not cut or sent raw."""
    return "".join(c if c.isprintable() else repr(c)[1:-1] for c in message)
