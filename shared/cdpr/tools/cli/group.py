"""The ``cdpr`` command group that every command module adds its commands to, and its output helpers."""

from __future__ import annotations

import json
import sys
from collections.abc import Callable, Sequence
from typing import Any, NoReturn

import click

from cdpr.errors import InputError
from cdpr.runtime.options import Option


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


def click_option(option: Option) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """The click form of a shared option (:mod:`cdpr.runtime.options`)."""
    if option.is_flag:
        return click.option(option.flag, option.dest, is_flag=True, help=option.help)
    show = option.default not in (None, False)
    kind: Any = option.type if option.bounds is None else click.IntRange(*option.bounds)
    if option.const is not None:
        return click.option(option.flag, option.dest, type=kind, is_flag=False, flag_value=option.const,
                            default=option.default, metavar=f"[{option.metavar}]", help=option.help, show_default=show)
    return click.option(option.flag, option.dest, type=kind, default=option.default, metavar=option.metavar,
                        help=option.help, show_default=show)


def click_options(options: Sequence[Option]) -> Callable[[Callable[..., Any]], Callable[..., Any]]:
    """A decorator adding ``options`` to a click command (in their order in ``--help``)."""

    def decorate(f: Callable[..., Any]) -> Callable[..., Any]:
        for option in reversed(options):
            f = click_option(option)(f)
        return f

    return decorate
