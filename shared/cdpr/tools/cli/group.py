"""The ``cdpr`` command group that every command module adds its commands to, and its output helpers."""

from __future__ import annotations

import json
import sys
from typing import Any, NoReturn

import click

from cdpr.errors import InputError


def fail(message: str) -> NoReturn:
    click.echo(f"cdpr: error: {message}", err=True)
    sys.exit(2)


def emit(obj: Any) -> None:
    click.echo(json.dumps(obj))


class _Group(click.Group):
    """Turns InputError anywhere below into one line and exit code 2."""

    def invoke(self, ctx: click.Context) -> Any:
        try:
            return super().invoke(ctx)
        except InputError as exc:
            fail(str(exc))


@click.group(cls=_Group, context_settings={"help_option_names": ["-h", "--help"]})
@click.version_option(package_name="cdpr")
def cli() -> None:
    """cdpr: a networked simulator for cable-driven parallel robots.

    Physics on DART, services talking over Zenoh, everything logged to Rerun.
    """
