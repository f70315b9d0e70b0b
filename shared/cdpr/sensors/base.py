"""What a sensor kind declares (:class:`SensorKind`), what every sensor measures from (:class:`Truth`), and what
every kind's scenario entry has (:data:`COMMON`: rate, latency, dropout). Pure: no I/O, and no pydantic (the
protocol, which a remote controller's base install imports, reads the kinds' channels): a kind declares its
parameters as data (:class:`Param`), from which :mod:`cdpr.config.scenario` builds the entry's model."""

from __future__ import annotations

import functools
import zlib
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike

from cdpr.columns import Column
from cdpr.mechanics.rotation import Array


@dataclass(frozen=True)
class Param:
    """One key of a kind's scenario entry: ``kind`` ``number`` (a finite number within the bounds given), ``vec3``
    (3 finite numbers), ``bias`` (one number, or one per cable: the kind's ``check`` says how many) or ``bias3``
    (one number or 3, ``[x, y, z]``)."""

    name: str
    default: Any
    doc: str
    kind: Literal["number", "vec3", "bias", "bias3"] = "number"
    ge: float | None = None
    gt: float | None = None
    le: float | None = None
    lt: float | None = None


COMMON: tuple[Param, ...] = (  # every kind's: when it reads, how late its readings come, how many are lost
    Param("rate", 0.0, "readings per second (0: every step)", ge=0.0),
    Param("latency", 0.0, "s from the measurement to its delivery (rounded to steps)", ge=0.0, le=10.0),
    Param("dropout", 0.0, "probability that a reading is lost", ge=0.0, lt=1.0),
)


def period(spec: Any, dt: float) -> int:
    """Steps between two readings of an entry (``rate`` 0: every step, else every ``round(1 / (rate · dt))``)."""
    return 1 if spec.rate <= 0.0 else max(1, round(1.0 / (spec.rate * dt)))


def latency_steps(spec: Any, dt: float) -> int:
    """Steps from a reading's measurement to its delivery."""
    return round(spec.latency / dt)


@dataclass(frozen=True)
class Truth:
    """What the sensors measure, exactly, at one step (world frame unless said otherwise)."""

    step: int
    t: float
    position: Array  # (3,) the centre of mass
    rotation: Array  # (3, 3) platform → world
    twist: Array  # (6,) [v; ω] at the centre of mass
    acceleration: Array  # (3,) the centre of mass's mean acceleration over the last step
    encoder_lengths: Array  # (m,) what the winches paid out (or the cable lengths) + the robot's encoder_offsets, m
    load_cell_tensions: Array  # (m,) the tensions at the winches, N
    com_offset: Array = field(default_factory=lambda: np.zeros(3))  # (3,) the COM in the platform frame

    def point(self, b: ArrayLike) -> Array:
        """The world position of the platform-frame point ``b`` (the robot file's platform frame)."""
        return self.position + self.rotation @ (np.asarray(b, dtype=float) - self.com_offset)


def truth(step: int, t: float, rotation: ArrayLike, twist: ArrayLike, acceleration: ArrayLike,
          encoder_lengths: ArrayLike, load_cell_tensions: ArrayLike, position: ArrayLike = (0.0, 0.0, 0.0),
          com_offset: ArrayLike = (0.0, 0.0, 0.0)) -> Truth:
    """A :class:`Truth` from array-likes (for tests and offline use)."""
    def f(x: ArrayLike) -> Array:
        return np.asarray(x, dtype=float)

    return Truth(step, t, f(position), f(rotation), f(twist), f(acceleration), f(encoder_lengths),
                 f(load_cell_tensions), f(com_offset))


Measure = Callable[[Truth, Any, Array], tuple[Array, ...]]


@dataclass(frozen=True)
class Ros2Topic:
    """A ROS 2 topic the ros2 node publishes a kind's readings on: ``name`` under the namespace, a standard
    message ``type`` (one :mod:`cdpr.ros2.messages` writes), and ``fields``: the message's fields from the
    readings (channel name → values), e.g. ``{"point": readings["laser_tracker"]}``; the header's stamp is the
    measurement's time, its frame ``frame``."""

    name: str
    type: str
    fields: Callable[[Mapping[str, Sequence[float]]], dict[str, Any]]
    frame: str = "world"


@dataclass(frozen=True)
class SensorKind:
    """One kind of sensor, declared once (its module in :mod:`cdpr.sensors`, a row of ``SENSOR_KINDS``).

    ``name``: its key under ``sim.sensors`` and the name of its noise stream; ``params``: its scenario entry's own
    keys (beside :data:`COMMON`'s); ``channels``: its fields in ``sim/sensors`` and ``sim/telemetry`` (in order),
    each with its Rerun series and Foxglove channel; ``draws(spec, m)``: the standard normal numbers one reading
    takes; ``measure(truth, spec, normals)``: the readings, one array per channel, a pure function (``spec``: the
    validated entry, its keys as attributes); ``default``: a scenario with ``sim.sensors`` has this kind unless it
    says ``null`` (otherwise only when its entry is given); ``ros2``: the ROS 2 topics of its readings;
    ``check(spec, m)``: a problem with the entry for a robot of m cables (one line), or None."""

    name: str
    params: tuple[Param, ...]
    channels: tuple[Column, ...]
    draws: Callable[[Any, int], int]
    measure: Measure
    doc: str
    default: bool = True
    ros2: tuple[Ros2Topic, ...] = ()
    check: Callable[[Any, int], str | None] = lambda spec, m: None

    @property
    def stream(self) -> int:
        """The noise stream's number, crc32 of the name: a function of the name only, so that adding a kind, or
        configuring one, never changes another's draws."""
        return _crc32(self.name)


@functools.cache
def _crc32(name: str) -> int:
    return zlib.crc32(name.encode())


def per_cable_bias(bias: float | list[float], m: int, name: str) -> str | None:
    """The problem with a bias of one number or one per cable, for m cables (None: none)."""
    if isinstance(bias, list) and len(bias) != m:
        return f"{name}: expected one number or {m} (one per cable), got {len(bias)}"
    return None


def vector(bias: float | Sequence[float], n: int) -> Array:
    """A bias of one number or n numbers, as n numbers."""
    raw = np.asarray(bias, dtype=float)
    return np.full(n, float(raw)) if raw.ndim == 0 else raw
