"""The ``cdpr`` command. Results go to stdout as JSON (so other tools can read them), logs to stderr.

An invalid file or argument prints one line ``cdpr: error: …`` on stderr and exits with code 2.
"""

from __future__ import annotations

import json
import sys
from typing import Any, NoReturn

import click

from cdpr.errors import InputError


def _fail(message: str) -> NoReturn:
    click.echo(f"cdpr: error: {message}", err=True)
    sys.exit(2)


def _emit(obj: Any) -> None:
    click.echo(json.dumps(obj))


class _Group(click.Group):
    """Turns InputError anywhere below into one line and exit code 2."""

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except InputError as exc:
            _fail(str(exc))


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="cdpr")
def cli() -> None:
    """cdpr: a networked simulator for cable-driven parallel robots.

    Physics on DART, services talking over Zenoh, everything logged to Rerun.
    """


def main(argv: list[str] | None = None) -> None:
    try:
        cli.main(args=argv, prog_name="cdpr", standalone_mode=True)
    except InputError as exc:  # raised outside a command's invoke (e.g. in a callback)
        _fail(str(exc))


# The commands, by job (each module adds its commands to the group above).
import cdpr.tools.cli.study  # noqa: E402, F401  (cdpr study, tune, study-bench: the study extra)
from cdpr.tools.cli import convert, results, robot, session  # noqa: E402

__all__ = ["cli", "convert", "main", "results", "robot", "session"]
