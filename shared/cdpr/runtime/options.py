"""Command-line options that a service (argparse, ``python -m cdpr_<name>``) and the ``cdpr`` command (click,
``cdpr run``/``cdpr up``: :func:`cdpr.tools.cli.group.click_options`) share: declared once here, added to either
parser, and turned back into the argv with which the launcher starts the service.
"""

from __future__ import annotations

import argparse
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Option:
    """One option: ``--flag VALUE`` (``type``), a bare ``--flag`` (``is_flag``), or ``--flag [VALUE]`` whose
    value may be left out (``const``: the value of the bare flag)."""

    flag: str
    help: str
    type: type = str
    default: Any = None
    metavar: str | None = None
    is_flag: bool = False
    const: Any = None
    dest_name: str | None = None  # the parsed value's name, if not the flag's (--session: session_id)
    bounds: tuple[int, int] | None = None  # an integer's least and greatest values

    def _parse(self, text: str) -> Any:
        try:
            value = self.type(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"invalid {self.type.__name__} value: {text!r}") from None
        if self.bounds is not None and not self.bounds[0] <= value <= self.bounds[1]:
            raise argparse.ArgumentTypeError(f"{value} is not in the range {self.bounds[0]}-{self.bounds[1]}")
        return value

    @property
    def dest(self) -> str:
        return self.dest_name or self.flag.lstrip("-").replace("-", "_")

    def add_to(self, parser: argparse.ArgumentParser | argparse._ArgumentGroup) -> None:
        shown = f"{self.help} (default: %(default)s)" if self.default not in (None, False) else self.help
        if self.is_flag:
            parser.add_argument(self.flag, dest=self.dest, action="store_true", help=self.help)
        elif self.const is not None:
            parser.add_argument(self.flag, dest=self.dest, type=self._parse, nargs="?", const=self.const,
                                default=self.default, metavar=self.metavar, help=shown)
        else:
            parser.add_argument(self.flag, dest=self.dest, type=self._parse, default=self.default,
                                metavar=self.metavar, help=shown)

    def argv(self, value: Any) -> list[str]:
        """The arguments that give this option ``value`` (none for its default)."""
        if value is None or value is False or (value == self.default and not self.is_flag):
            return []
        return [self.flag] if self.is_flag else [self.flag, str(value)]


def add_options(parser: argparse.ArgumentParser | argparse._ArgumentGroup, options: Iterable[Option]) -> None:
    for option in options:
        option.add_to(parser)


def options_argv(options: Iterable[Option], values: Mapping[str, Any] | Any) -> list[str]:
    """The argv that gives each option its value in ``values`` (a mapping, or an object with the dests as
    attributes)."""
    get = values.get if isinstance(values, Mapping) else (lambda name: getattr(values, name, None))
    return [arg for option in options for arg in option.argv(get(option.dest))]


# The session a service or a launcher joins (besides the scenario argument).
SESSION_OPTIONS = (
    Option("--session", "session id", default="default", dest_name="session_id"),
    Option("--duration", "override the scenario's duration (s)", type=float),
)
RT_PRIORITY = Option("--rt-priority", "run under SCHED_FIFO at this priority (realtime mode on a busy machine; "
                     "needs CAP_SYS_NICE)", type=int, metavar="1-99")  # (the range is checked where it is set)
CPU_LATENCY = Option("--cpu-latency", "hold Linux's CPU wake-up latency limit (PM QoS, /dev/cpu_dma_latency) at US "
                     "microseconds while this runs: 0 keeps idle CPUs polling instead of sleeping, so a message wakes "
                     "its receiver at once (realtime at 1-2 kHz; as cyclictest does; needs root or write access to "
                     "the device)", type=int, metavar="US", bounds=(0, 2_000_000_000))
REALTIME_OPTIONS = (RT_PRIORITY, CPU_LATENCY)
# Where the recorder writes or streams the session (cdpr_recorder; cdpr run/up pass them on).
RECORDER_OPTIONS = (
    Option("--rrd", "write the recording to this .rrd file", metavar="FILE"),
    Option("--spawn", "stream the recording to a new Rerun viewer", is_flag=True),
    Option("--connect-viewer", "stream the recording to the Rerun viewer at this gRPC URL", metavar="URL"),
    Option("--mcap", "write the session to this .mcap file (Foxglove schemas, log time = sim time; also with --rrd)",
           metavar="FILE"),
    Option("--foxglove", "serve the session live on a Foxglove WebSocket server (default port 8765; 0: a free one)",
           type=int, metavar="PORT", const=8765, bounds=(0, 65535)),
    Option("--foxglove-host", "address the Foxglove server listens on", default="127.0.0.1", metavar="HOST"),
)
