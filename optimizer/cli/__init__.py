"""The ``shoha`` command line (docs/contract.md, "CLI").

Every command takes ``--json`` and then prints exactly one JSON object on
stdout; progress and messages go to stderr. Bad input or usage exits with
status 2 and one line on stderr naming the file and the problem, with no
traceback and no output file written. Any other failure is a bug (status 1).

Each verb, or group of verbs, is a module of this package whose commands sit
at module level; this module only gathers them. Heavy modules are imported
inside the commands, so ``shoha --help`` is quick. The CLI is the only place
where method, backend and strategy names map to classes.
"""

from __future__ import annotations

import sys
import warnings

import click

from geometry.errors import InputError, one_line

from .batch import batch
from .block import block
from .check import check
from .common import Group
from .convert import convert
from .optimize import optimize_cmd
from .porosity import porosity
from .render import render_cmd
from .scene import scene
from .score import score_cmd
from .serve import serve_cmd
from .settle import settle_cmd


@click.group(cls=Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="shoha")
def cli() -> None:
    """shoha: compute and check wave-dissipating block placement in breakwaters."""


for _command in (block, scene, convert, porosity, check, settle_cmd, optimize_cmd, score_cmd, batch,
                 render_cmd, serve_cmd):
    cli.add_command(_command)


def main(argv: list[str] | None = None) -> int:
    """Run the CLI; returns the exit status (0 done, 2 bad input, 1 bug)."""
    # A number that overflows on the way to a refusal (a voxel of 1e-320 m, a mesh 1e12 m
    # across) made numpy and trimesh print their warnings, with source lines, above the one
    # line the refusal is: the checks that follow say what is wrong, in the user's terms.
    warnings.simplefilter("ignore", RuntimeWarning)
    try:
        cli.main(args=argv, prog_name="shoha", standalone_mode=False)
    except click.exceptions.Exit as exc:
        return int(exc.exit_code)
    except click.exceptions.Abort:
        click.echo("shoha: aborted", err=True)
        return 130
    except click.exceptions.ClickException as exc:
        # Usage errors: one line, as for bad files (click prints three).
        ctx = getattr(exc, "ctx", None)
        where = f"{ctx.command_path}: " if ctx is not None else "shoha: "
        click.echo(one_line(where + exc.format_message().replace("\n", " ")), err=True)
        return 2
    except InputError as exc:
        click.echo(one_line(f"shoha: {exc or 'bad input'}"), err=True)
        return 2
    except OSError as exc:
        # A path the system itself refuses: a name too long, no permission, a loop of links.
        where = f"{exc.filename}: " if exc.filename else ""
        click.echo(one_line(f"shoha: {where}{exc.strerror or exc}"), err=True)
        return 2
    except RuntimeError as exc:
        if not str(exc).startswith("Symlink loop"):  # pathlib's word for ELOOP (Python 3.11)
            raise
        click.echo(one_line(f"shoha: {exc}"), err=True)
        return 2
    except KeyboardInterrupt:
        click.echo("shoha: interrupted", err=True)
        return 130
    return 0


if __name__ == "__main__":
    sys.exit(main())
