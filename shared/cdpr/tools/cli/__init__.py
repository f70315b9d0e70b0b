"""The ``cdpr`` command. Results go to stdout as JSON (so other tools can read them), logs to stderr.

An invalid file or argument prints one line ``cdpr: error: …`` on stderr and exits with code 2.
"""

from __future__ import annotations

from cdpr.errors import InputError

# The commands, by job (each module adds its commands to the group of cdpr.tools.cli.group).
from cdpr.tools.cli import convert, results, robot, session, study
from cdpr.tools.cli.group import cli, fail


def main(argv: list[str] | None = None) -> None:
    try:
        cli.main(args=argv, prog_name="cdpr", standalone_mode=True)
    except InputError as exc:  # raised outside a command's invoke (e.g. in a callback)
        fail(str(exc))


__all__ = ["cli", "convert", "main", "results", "robot", "session", "study"]
