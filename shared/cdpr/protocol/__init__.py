"""The wire protocol: every key expression and every message of a session, in one place.

Documented for people in ``docs/protocol.md``; keep the two in step (a test checks the key table).

Payloads are msgpack maps with string keys. Every message carries the protocol version ``v``, and
every step-stamped message the step number ``step`` (int ≥ 0) and the sim time ``t`` (s, = step·dt).
Decoding validates type, length and finiteness and raises :class:`ProtocolError` with a one-line message
that names the field; services log it, count it, and drop (or clamp, for tensions) as documented.
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any, ClassVar

import msgpack

PROTOCOL_VERSION = 1
SESSION_RE = re.compile(r"^[A-Za-z0-9_-]{1,64}$")

# Service names that can hold a liveliness token `cdpr/{session}/alive/{name}`.
SERVICES = ("clock", "sim", "trajectory", "controller", "recorder")


class ProtocolError(ValueError):
    """A payload that does not follow the protocol; the message names the offending field."""


def check_session(session: str) -> str:
    if not SESSION_RE.match(session):
        raise ValueError(f"session id {session!r} must be 1-64 characters of A-Z a-z 0-9 _ -")
    return session


@dataclass(frozen=True)
class Keys:
    """Key expressions of one session, ``cdpr/{session}/...``."""

    session: str = "default"
    prefix: str = field(init=False)

    def __post_init__(self) -> None:
        check_session(self.session)
        object.__setattr__(self, "prefix", f"cdpr/{self.session}")

    @property
    def tick(self) -> str:
        return f"{self.prefix}/clock/tick"

    @property
    def status(self) -> str:
        return f"{self.prefix}/clock/status"

    @property
    def state(self) -> str:
        return f"{self.prefix}/sim/state"

    @property
    def setpoint(self) -> str:
        return f"{self.prefix}/trajectory/setpoint"

    @property
    def command(self) -> str:
        return f"{self.prefix}/controller/command"

    @property
    def sensors(self) -> str:
        return f"{self.prefix}/sim/sensors"

    @property
    def info(self) -> str:
        return f"{self.prefix}/session/info"

    def stats(self, service: str) -> str:
        return f"{self.prefix}/stats/{service}"

    @property
    def stats_all(self) -> str:
        return f"{self.prefix}/stats/*"

    def alive(self, service: str) -> str:
        return f"{self.prefix}/alive/{service}"

    @property
    def alive_all(self) -> str:
        return f"{self.prefix}/alive/*"

    def topic(self, name: str, publisher: str | None = None) -> str:
        """The key of topic ``name`` (a :data:`cdpr.protocol.wiring.TOPICS` name): ``stats`` is
        ``stats/{publisher}`` to publish on, ``stats/*`` to subscribe to."""
        if name == "stats":
            return self.stats_all if publisher is None else self.stats(publisher)
        if name == "alive":
            return self.alive_all if publisher is None else self.alive(publisher)
        return getattr(self, name)  # type: ignore[no-any-return]

    def table(self) -> dict[str, str]:
        """Name → key expression, for documentation and tests."""
        return {
            "tick": self.tick,
            "status": self.status,
            "state": self.state,
            "setpoint": self.setpoint,
            "command": self.command,
            "sensors": self.sensors,
            "info": self.info,
            "alive": self.alive("{service}"),
            "stats": self.stats("{service}"),
        }


# --------------------------------------------------------------------------------------------------
# Field checks. Each returns the cleaned value or raises ProtocolError naming the field.


def _field(msg: dict[Any, Any], name: str) -> Any:
    if name not in msg:
        raise ProtocolError(f"{name}: missing")
    return msg[name]


def _int(msg: dict[Any, Any], name: str, minimum: int = 0) -> int:
    value = _field(msg, name)
    if isinstance(value, bool) or not isinstance(value, int):
        raise ProtocolError(f"{name}: expected an integer, got {type(value).__name__}")
    if value < minimum:
        raise ProtocolError(f"{name}: must be >= {minimum}, got {value}")
    return value


def _float(msg: dict[Any, Any], name: str) -> float:
    value = _field(msg, name)
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise ProtocolError(f"{name}: expected a number, got {type(value).__name__}")
    value = float(value)
    if not math.isfinite(value):
        raise ProtocolError(f"{name}: must be finite, got {value}")
    return value


_FLOAT = frozenset({float})


def _vector(msg: dict[Any, Any], name: str, length: int | None) -> tuple[float, ...]:
    value = _field(msg, name)
    # Fast path for what every well-behaved sender sends: a list of finite floats (a NaN or an
    # infinity makes the sum non-finite; so may an overflow, which the full check below then clears).
    if (
        type(value) is list
        and (length is None or len(value) == length)
        and _FLOAT.issuperset(map(type, value))
        and math.isfinite(sum(value))
    ):
        return tuple(value)
    if not isinstance(value, (list, tuple)):
        raise ProtocolError(f"{name}: expected an array of numbers, got {type(value).__name__}")
    if length is not None and len(value) != length:
        raise ProtocolError(f"{name}: expected {length} numbers, got {len(value)}")
    out = []
    for i, x in enumerate(value):
        if isinstance(x, bool) or not isinstance(x, (int, float)):
            raise ProtocolError(f"{name}[{i}]: expected a number, got {type(x).__name__}")
        x = float(x)
        if not math.isfinite(x):
            raise ProtocolError(f"{name}[{i}]: must be finite, got {x}")
        out.append(x)
    return tuple(out)


def unpack(payload: bytes | bytearray | memoryview) -> dict[Any, Any]:
    """msgpack bytes → map, checking the protocol version."""
    try:
        msg = msgpack.unpackb(bytes(payload), raw=False, strict_map_key=False)
    except Exception as exc:  # msgpack raises several unrelated types for garbage
        raise ProtocolError(f"payload: not valid msgpack ({type(exc).__name__})") from None
    if not isinstance(msg, dict):
        raise ProtocolError(f"payload: expected a msgpack map, got {type(msg).__name__}")
    v = _field(msg, "v")
    if v != PROTOCOL_VERSION:
        raise ProtocolError(f"v: unsupported protocol version {v!r} (this is version {PROTOCOL_VERSION})")
    return msg


def pack(msg: dict[str, Any]) -> bytes:
    return msgpack.packb({"v": PROTOCOL_VERSION, **msg}, use_bin_type=True)


def _floats(values: Sequence[float]) -> list[float]:
    return list(map(float, values))


# --------------------------------------------------------------------------------------------------
# Messages


@dataclass(frozen=True, slots=True)
class Tick:
    """``clock/tick``: step ``step`` (time ``t``) may be computed. Repeated when a step must be redone."""

    KEY: ClassVar[str] = "tick"
    step: int
    t: float

    def encode(self) -> bytes:
        return pack({"step": self.step, "t": self.t})

    @classmethod
    def decode(cls, payload: bytes) -> Tick:
        msg = unpack(payload)
        return cls(_int(msg, "step"), _float(msg, "t"))


@dataclass(frozen=True, slots=True)
class State:
    """``sim/state``: the platform at step ``step`` and what acted on it during the previous step."""

    KEY: ClassVar[str] = "state"
    step: int
    t: float
    pose: tuple[float, ...]  # x, y, z, qx, qy, qz, qw (centre of mass, world frame)
    twist: tuple[float, ...]  # vx, vy, vz, wx, wy, wz (world frame)
    cable_lengths: tuple[float, ...]
    tensions: tuple[float, ...]  # as applied over [t - dt, t] (zeros at step 0)
    clamped: int = 0  # commands clamped by the sim so far (optional on the wire, default 0)

    def encode(self) -> bytes:
        return pack(
            {
                "step": self.step,
                "t": self.t,
                "pose": _floats(self.pose),
                "twist": _floats(self.twist),
                "cable_lengths": _floats(self.cable_lengths),
                "tensions": _floats(self.tensions),
                "clamped": self.clamped,
            }
        )

    @classmethod
    def decode(cls, payload: bytes, cables: int | None = None) -> State:
        msg = unpack(payload)
        lengths = _vector(msg, "cable_lengths", cables)
        return cls(
            _int(msg, "step"),
            _float(msg, "t"),
            _vector(msg, "pose", 7),
            _vector(msg, "twist", 6),
            lengths,
            _vector(msg, "tensions", len(lengths)),
            _int(msg, "clamped") if "clamped" in msg else 0,
        )


@dataclass(frozen=True, slots=True)
class Setpoint:
    """``trajectory/setpoint``: the desired pose, twist and acceleration at step ``step``."""

    KEY: ClassVar[str] = "setpoint"
    step: int
    t: float
    pose: tuple[float, ...]
    twist: tuple[float, ...]
    accel: tuple[float, ...]

    def encode(self) -> bytes:
        return pack(
            {
                "step": self.step,
                "t": self.t,
                "pose": _floats(self.pose),
                "twist": _floats(self.twist),
                "accel": _floats(self.accel),
            }
        )

    @classmethod
    def decode(cls, payload: bytes) -> Setpoint:
        msg = unpack(payload)
        return cls(
            _int(msg, "step"),
            _float(msg, "t"),
            _vector(msg, "pose", 7),
            _vector(msg, "twist", 6),
            _vector(msg, "accel", 6),
        )


@dataclass(frozen=True, slots=True)
class Command:
    """``controller/command``: the cable tensions (N) — or the unstretched cable lengths (m) — to apply
    over [t_k, t_k + dt].

    Exactly one of ``tensions`` and ``lengths`` is on the wire. ``tensions`` must be finite; the sim
    clamps each to [0, tmax] (a cable only pulls) and counts the clamps. ``lengths`` (a session whose
    scenario has ``controller.output: lengths``: winch-driven cables) must be finite and > 0; in a
    Python ``Command`` of lengths, ``tensions`` is ``()``. Optional ``feasible``/``status`` report the
    controller's tension distribution outcome.
    """

    KEY: ClassVar[str] = "command"
    step: int
    t: float
    tensions: tuple[float, ...]
    feasible: bool = True
    status: str = "ok"
    lengths: tuple[float, ...] | None = None

    @property
    def kind(self) -> str:
        """``"lengths"`` or ``"tensions"``: which command this is."""
        return "tensions" if self.lengths is None else "lengths"

    @property
    def values(self) -> tuple[float, ...]:
        """The commanded numbers, tensions or lengths."""
        return self.tensions if self.lengths is None else self.lengths

    def encode(self) -> bytes:
        return pack(
            {
                "step": self.step,
                "t": self.t,
                self.kind: _floats(self.values),
                "feasible": bool(self.feasible),
                "status": self.status,
            }
        )

    @classmethod
    def decode(cls, payload: bytes, cables: int | None = None, expect: str | None = None) -> Command:
        """``expect`` (``"tensions"`` or ``"lengths"``): the kind the receiver takes (the other: an error)."""
        msg = unpack(payload)
        feasible = msg.get("feasible", True)
        status = msg.get("status", "ok")
        if not isinstance(feasible, bool):
            raise ProtocolError(f"feasible: expected true/false, got {type(feasible).__name__}")
        if not isinstance(status, str):
            raise ProtocolError(f"status: expected a string, got {type(status).__name__}")
        step, t = _int(msg, "step"), _float(msg, "t")
        if "lengths" not in msg:
            if expect == "lengths":
                raise ProtocolError("lengths: missing (this session's controller commands cable lengths)")
            return cls(step, t, _vector(msg, "tensions", cables), feasible, status)
        if "tensions" in msg:
            raise ProtocolError("lengths: a command carries tensions or lengths, not both")
        if expect == "tensions":
            raise ProtocolError("lengths: this session's controller commands tensions, not lengths")
        lengths = _vector(msg, "lengths", cables)
        for i, x in enumerate(lengths):
            if x <= 0.0:
                raise ProtocolError(f"lengths[{i}]: must be > 0, got {x}")
        return cls(step, t, (), feasible, status, lengths)


@dataclass(frozen=True, slots=True)
class Sensors:
    """``sim/sensors``: what the simulated sensors read at step ``step`` (noisy, biased, quantised).

    ``encoders`` (m, m): the cable lengths the winch encoders measure; ``load_cells`` (m, N): the cable
    tensions at the winches; ``accel`` (m/s²) and ``gyro`` (rad/s): the platform IMU's specific force
    (acceleration minus gravity: +9.81 up at rest) and angular velocity, both in the platform frame.
    The ground truth stays in ``sim/state``.
    """

    KEY: ClassVar[str] = "sensors"
    step: int
    t: float
    encoders: tuple[float, ...]
    load_cells: tuple[float, ...]
    accel: tuple[float, ...]
    gyro: tuple[float, ...]

    def encode(self) -> bytes:
        return pack(
            {
                "step": self.step,
                "t": self.t,
                "encoders": _floats(self.encoders),
                "load_cells": _floats(self.load_cells),
                "accel": _floats(self.accel),
                "gyro": _floats(self.gyro),
            }
        )

    @classmethod
    def decode(cls, payload: bytes, cables: int | None = None) -> Sensors:
        msg = unpack(payload)
        encoders = _vector(msg, "encoders", cables)
        return cls(
            _int(msg, "step"),
            _float(msg, "t"),
            encoders,
            _vector(msg, "load_cells", len(encoders)),
            _vector(msg, "accel", 3),
            _vector(msg, "gyro", 3),
        )


@dataclass(frozen=True, slots=True)
class ServiceStats:
    """``stats/{service}``: a service's fault counters (dropped, clamped, … messages), about once a second
    while they change and once when the service stops. The clock gathers them into its status."""

    KEY: ClassVar[str] = "stats"
    service: str
    counters: dict[str, int]

    def encode(self) -> bytes:
        return pack({"service": self.service, "counters": dict(self.counters)})

    @classmethod
    def decode(cls, payload: bytes) -> ServiceStats:
        msg = unpack(payload)
        service = _field(msg, "service")
        if not isinstance(service, str) or service not in SERVICES:
            raise ProtocolError(f"service: expected one of {', '.join(SERVICES)}, got {service!r}")
        counters = _field(msg, "counters")
        if not isinstance(counters, dict) or not all(
            isinstance(k, str) and isinstance(v, int) and not isinstance(v, bool) and v >= 0
            for k, v in counters.items()
        ):
            raise ProtocolError("counters: expected a map of names to non-negative integers")
        return cls(service, counters)


CLOCK_STATES = ("waiting", "running", "paused", "finished", "aborted")


@dataclass(frozen=True, slots=True)
class Status:
    """``clock/status``: the session's state, published on every change and about once a second.

    ``state`` is one of waiting | running | paused | finished | aborted; ``missing`` lists the expected
    participants without a liveliness token; ``stats`` holds the clock's counters (documented).
    """

    KEY: ClassVar[str] = "status"
    state: str
    step: int
    t: float
    total_steps: int
    missing: tuple[str, ...] = ()
    reason: str = ""
    stats: dict[str, Any] = field(default_factory=dict)

    def encode(self) -> bytes:
        return pack(
            {
                "state": self.state,
                "step": self.step,
                "t": self.t,
                "total_steps": self.total_steps,
                "missing": list(self.missing),
                "reason": self.reason,
                "stats": self.stats,
            }
        )

    @classmethod
    def decode(cls, payload: bytes) -> Status:
        msg = unpack(payload)
        state = _field(msg, "state")
        if state not in CLOCK_STATES:
            raise ProtocolError(f"state: expected one of {', '.join(CLOCK_STATES)}, got {state!r}")
        missing = msg.get("missing", [])
        if not isinstance(missing, list) or not all(isinstance(x, str) for x in missing):
            raise ProtocolError("missing: expected a list of service names")
        stats = msg.get("stats", {})
        if not isinstance(stats, dict):
            raise ProtocolError("stats: expected a map")
        reason = msg.get("reason", "")
        return cls(
            state, _int(msg, "step"), _float(msg, "t"), _int(msg, "total_steps"), tuple(missing), str(reason), stats
        )
