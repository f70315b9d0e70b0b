"""How a column of a per-step stream is declared: its width, unit and meaning, where a recording plots it (Rerun
time series) and where an MCAP file carries it (Foxglove JSON channels). The state's columns
(:data:`cdpr.protocol.streams.STATE_COLUMNS`) and the sensors' (:mod:`cdpr.sensors`) are declared with these."""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any


@dataclass(frozen=True)
class Series:
    """A Rerun Scalars time series showing part ``[first, end)`` of a column's row (``end`` None: to its end).
    A ``path`` with ``{i}`` is one entity per number of the part (``tension/cable_0``, …)."""

    path: str
    first: int = 0
    end: int | None = None

    @property
    def split(self) -> bool:
        return "{i}" in self.path


@dataclass(frozen=True)
class ChannelField:
    """Part ``[first, end)`` of a column's row as the field ``name`` of the messages of the JSON ``channel``."""

    channel: str
    name: str
    first: int = 0
    end: int | None = None


@dataclass(frozen=True)
class Column:
    """One field of a per-step stream."""

    name: str  # on the wire and as the message's attribute
    width: int | None  # numbers per step; None: one per cable (m)
    unit: str
    doc: str
    integer: bool = False  # a count: one whole number (width 1), an int on the wire and in the message
    default: Any = None  # its value when a ``sim/state`` leaves it out (None: the field is required)
    since: int = 0  # the first step with a value to record (tensions: those applied over the step before)
    series: tuple[Series, ...] = ()
    fields: tuple[ChannelField, ...] = ()

    def size(self, m: int) -> int:
        """Numbers per step for a robot of ``m`` cables."""
        return m if self.width is None else self.width
