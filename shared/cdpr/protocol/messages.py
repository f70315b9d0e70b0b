"""The wire protocol: every key expression and every message of a session, in one place.

Documented for people in ``docs/protocol.md``; keep the two in step (a test checks the key table).

Payloads are msgpack maps with string keys. Every message carries the protocol version ``v``, and
every step-stamped message the step number ``step`` (int ≥ 0) and the sim time ``t`` (s, = step·dt).
Decoding validates type, length and finiteness and raises :class:`ProtocolError` with a one-line message
that names the field; services log it, count it, and drop (or clamp, for tensions) as documented.

The per-step messages (:class:`Tick`, :class:`State`, :class:`Setpoint`, :class:`Command`, :class:`Sensors`)
are ``msgspec`` structs: msgspec encodes them and decodes a payload into a *wire type* (the message's fields
behind a required ``v``, each field's type and bounds — an integer ≥ 0, a finite number, n finite numbers —
checked in C), which is what a well-formed payload costs. A payload that fails there is decoded again by the
reference checks written out below (``_checked``), which give the documented one-line error naming the
field; they accept exactly what the protocol allows, so the fast path only ever takes payloads they take too,
with the same result (tested on mutated payloads).
"""

from __future__ import annotations

import itertools
import math
import re
import sys
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Annotated, Any, Literal, get_args

import msgpack
import msgspec
from msgspec import UNSET, UnsetType

from cdpr.mechanics.outputs import COMMAND_KINDS, CommandKind
from cdpr.protocol.streams import ESTIMATE_WIDTH, STATE_COLUMNS
from cdpr.protocol.wiring import TOPICS, WIRING
from cdpr.sensors import SENSOR_COLUMNS

PROTOCOL_VERSION = 2  # 2: ticks grant windows; setpoints and telemetry travel in blocks
TELEMETRY_EVERY = 50  # states per sim/telemetry block at most...
TELEMETRY_PERIOD = 0.2  # ...or seconds between two, whichever comes first: the clock hears of a slow loop too
SESSION_RE = re.compile(r"^[A-Za-z0-9_-]{1,64}$")

# Service names that can hold a liveliness token `cdpr/{session}/alive/{name}`: the nodes of the wiring table.
SERVICES = tuple(WIRING)
END_REASON_MAX = 200  # characters of a session/end's reason


_PLACEHOLDER = re.compile(r"\{(node|camera)\}")  # where a topic's key names its node, or a camera


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

    def __getattr__(self, name: str) -> str:
        """``keys.tick``, ``keys.state``, …: the key of each topic of :data:`cdpr.protocol.wiring.TOPICS` that
        has one key per session (``stats`` and ``alive`` have one per node: :meth:`stats`, :meth:`alive`)."""
        topic = TOPICS.get(name)
        if topic is None or "{" in topic.key or "prefix" not in self.__dict__:
            raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")
        return f"{self.prefix}/{topic.key}"

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
        """The key of topic ``name`` (a :data:`cdpr.protocol.wiring.TOPICS` name): a topic with one key per
        node (``stats``, ``alive``, ``ping``) or per camera (``camera``) is ``stats/{publisher}`` to publish on,
        ``stats/*`` to subscribe to."""
        key = TOPICS[name].key
        return f"{self.prefix}/{_PLACEHOLDER.sub(publisher or '*', key)}"

    def table(self) -> dict[str, str]:
        """Topic name → key expression (``{service}`` where a node's name goes), for documentation and tests."""
        return {name: f"{self.prefix}/{t.key.replace('{node}', '{service}')}" for name, t in TOPICS.items()}


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


def _flat(rows: Sequence[Sequence[float]]) -> list[float]:
    return [float(x) for row in rows for x in row]


def _ints(msg: dict[Any, Any], name: str, length: int | None = None) -> list[int]:
    value = _field(msg, name)
    if not isinstance(value, list) or any(isinstance(x, bool) or not isinstance(x, int) or x < 0 for x in value):
        raise ProtocolError(f"{name}: expected an array of integers >= 0")
    if length is not None and len(value) != length:
        raise ProtocolError(f"{name}: expected {length} integers, got {len(value)}")
    return value


def _rows(msg: dict[Any, Any], name: str, n: int, width: int | None) -> list[tuple[float, ...]]:
    """``n`` rows of ``width`` numbers from the flat array ``name`` (``width`` None: n rows of equal width)."""
    flat = _vector(msg, name, None if width is None else n * width)
    if width is None:
        if n == 0 or len(flat) % n:
            raise ProtocolError(f"{name}: expected {n} rows of equal length, got {len(flat)} numbers")
        width = len(flat) // n
    return [flat[i * width:(i + 1) * width] for i in range(n)]


# --------------------------------------------------------------------------------------------------
# The msgspec side: field types with their bounds, wire types, the encoder

_MAX = sys.float_info.max
Finite = Annotated[float, msgspec.Meta(ge=-_MAX, le=_MAX)]  # a finite number (NaN and ±inf fail the bounds)
Count = Annotated[int, msgspec.Meta(ge=0)]  # an integer >= 0 (not a bool)
Floats = tuple[Finite, ...]


def fixed(n: int) -> Any:
    """The type of exactly ``n`` finite numbers."""
    return Annotated[Floats, msgspec.Meta(min_length=n, max_length=n)]


def _enc_hook(obj: Any) -> Any:
    """What msgspec does not encode itself: numpy scalars and arrays (``.item()``, ``.tolist()``)."""
    for convert in ("tolist", "item"):
        if callable(method := getattr(obj, convert, None)):
            return method()
    raise NotImplementedError(f"cannot encode a {type(obj).__name__} in a message")


_ENCODER = msgspec.msgpack.Encoder(enc_hook=_enc_hook)
_WireField = tuple[str, Any] | tuple[str, Any, Any]
_STRUCT = {"frozen": True, "gc": False, "tag_field": "v", "tag": PROTOCOL_VERSION}  # encodes as {"v": 2, …}


def _wire(name: str, fields: Sequence[_WireField]) -> msgspec.msgpack.Decoder[Any]:
    """A decoder of the wire type ``name``: a required ``v`` (the protocol version), then ``fields``
    (``(name, type)`` or ``(name, type, default)``: a field with a default may be missing)."""
    wire = msgspec.defstruct(name, [("v", Literal[PROTOCOL_VERSION]), *fields], frozen=True, gc=False)
    return msgspec.msgpack.Decoder(wire)


def _fast(decoder: msgspec.msgpack.Decoder[Any], payload: bytes | bytearray | memoryview) -> tuple[Any, ...] | None:
    """The payload's fields after ``v`` as a tuple, or None if it is not a well-formed message of this type
    (the caller then runs its reference checks, which name the field)."""
    try:
        return msgspec.structs.astuple(decoder.decode(payload))[1:]
    except msgspec.MsgspecError:
        return None


# --------------------------------------------------------------------------------------------------
# Messages


class Tick(msgspec.Struct, **_STRUCT):
    """``clock/tick``: steps ``step`` … ``until`` (times ``t`` … ``until·dt``) may be computed.

    A tick grants a window of steps (in realtime mode marked ``paced``, at least 0.25 s ahead). ``resend``:
    the clock saw no progress (or a participant came back) and asks for the current state and the
    setpoints again, ``step`` then being the sim's current step. ``flush``: the clock will grant nothing
    more until it hears of progress, so the sim sends its telemetry once it has computed ``until``.
    ``free``: free-running realtime (``--sync free``): the sim integrates each granted step at its own
    wall-clock deadline, every ``dt`` from the first free grant, with the newest command it holds (it does
    not wait for one); without it, the sim integrates a step once its command has come (lock-step).
    ``paced``: realtime lock-step: the sim integrates each granted step once its command has come and not
    before its wall-clock deadline (the deadlines as with ``free``), and reports how late each one started.
    """

    step: Count
    t: Finite
    until: int = -1  # the last step granted (-1: ``step``; below ``step``: a ValueError)
    resend: bool = False
    flush: bool = False
    free: bool = False
    paced: bool = False

    def __post_init__(self) -> None:
        if self.until < self.step:
            if self.until != -1:
                raise ValueError(f"until: must be >= step ({self.step}), got {self.until}")
            msgspec.structs.force_setattr(self, "until", self.step)

    def encode(self) -> bytes:
        return _ENCODER.encode(self)

    @classmethod
    def decode(cls, payload: bytes) -> Tick:
        fields = _fast(_TICK, payload)
        if fields is not None and (fields[2] == -1 or fields[2] >= fields[0]):
            return cls(*fields)
        return cls._checked(payload)

    @classmethod
    def _checked(cls, payload: bytes) -> Tick:
        msg = unpack(payload)
        step = _int(msg, "step")
        until = _int(msg, "until") if "until" in msg else step
        if until < step:
            raise ProtocolError(f"until: must be >= step ({step}), got {until}")
        flags = [msg.get(name, False) for name in _TICK_FLAGS]
        if not all(isinstance(flag, bool) for flag in flags[:3]):
            raise ProtocolError("resend, flush, free: expected true/false")  # (the line of protocol 2's first flags)
        if not isinstance(flags[3], bool):
            raise ProtocolError(f"paced: expected true/false, got {type(flags[3]).__name__}")
        return cls(step, _float(msg, "t"), until, *flags)


_TICK_FLAGS = ("resend", "flush", "free", "paced")
_TICK = _wire("TickWire", [("step", Count), ("t", Finite), ("until", Count, -1),
                           *((name, bool, False) for name in _TICK_FLAGS)])


class State(msgspec.Struct, **_STRUCT):
    """``sim/state``: the platform at step ``step`` and what acted on it during the previous step.

    Its fields after ``step`` and ``t`` are the columns of :data:`cdpr.protocol.streams.STATE_COLUMNS`, in
    their order (the table says what each is); encoding and decoding follow the table.
    """

    step: int
    t: float
    pose: tuple[float, ...]  # x, y, z, qx, qy, qz, qw (centre of mass, world frame)
    twist: tuple[float, ...]  # vx, vy, vz, wx, wy, wz (world frame)
    cable_lengths: tuple[float, ...]
    tensions: tuple[float, ...]  # as applied over [t - dt, t] (zeros at step 0)
    clamped: int = 0  # commands clamped by the sim so far (optional on the wire, default 0)
    command_age: int = 0  # steps: the step before this state minus the one the acting command answered
    watchdog: int = 0  # 1 if the watchdog policy acted over the step before (instead of a command)

    def encode(self) -> bytes:
        return _ENCODER.encode(self)

    @classmethod
    def decode(cls, payload: bytes, cables: int | None = None) -> State:
        fields = _fast(_STATE, payload)
        if fields is not None:
            m = len(fields[_PER_CABLE[0]]) if cables is None else cables
            if all(len(fields[i]) == m for i in _PER_CABLE):
                return cls(*fields)
        return cls._checked(payload, cables)

    @classmethod
    def _checked(cls, payload: bytes, cables: int | None = None) -> State:
        msg = unpack(payload)
        step, t = _int(msg, "step"), _float(msg, "t")
        values: list[Any] = []
        for c in STATE_COLUMNS:
            if c.default is not None and c.name not in msg:
                values.append(c.default)
            elif c.integer:
                values.append(_int(msg, c.name))
            elif c.width == 1:
                values.append(_float(msg, c.name))
            else:
                v = _vector(msg, c.name, cables if c.width is None else c.width)
                if c.width is None:
                    cables = len(v)  # the first per-cable column tells the others their length
                values.append(v)
        return cls(step, t, *values)


def _column_type(c: Any) -> Any:
    """A state column's wire type: an integer >= 0, a finite number, or its width's finite numbers (any
    number for a per-cable column: they must agree with each other, checked after decoding)."""
    return Count if c.integer else Finite if c.width == 1 else Floats if c.width is None else fixed(c.width)


_STATE = _wire("StateWire", [("step", Count), ("t", Finite),
                             *((c.name, _column_type(c)) if c.default is None else (c.name, _column_type(c), c.default)
                               for c in STATE_COLUMNS)])
_PER_CABLE = tuple(2 + i for i, c in enumerate(STATE_COLUMNS) if c.width is None)  # their places in a State


def _state_block(msg: dict[Any, Any], n: int, cables: int | None) -> tuple[list[list[Any]], int | None]:
    """The state columns of a telemetry block of ``n`` states (flat arrays on the wire), and the cable count."""
    columns: list[list[Any]] = []
    for c in STATE_COLUMNS:
        if c.integer:
            columns.append(_ints(msg, c.name, n))
            continue
        if c.width == 1:
            columns.append(list(_vector(msg, c.name, n)))
            continue
        width = cables if c.width is None else c.width
        rows: list[tuple[float, ...]] = []
        if n:
            rows = _rows(msg, c.name, n, width)
        else:
            _vector(msg, c.name, 0)  # an empty block: an empty array
        if c.width is None and cables is None and rows:
            cables = len(rows[0])
        columns.append(rows)
    return columns, cables


class Setpoint(msgspec.Struct, **_STRUCT):
    """``trajectory/setpoint``: the desired pose, twist and acceleration at step ``step``."""

    step: int
    t: float
    pose: tuple[float, ...]
    twist: tuple[float, ...]
    accel: tuple[float, ...]

    def encode(self) -> bytes:
        return _ENCODER.encode(self)

    @classmethod
    def decode(cls, payload: bytes) -> Setpoint:
        fields = _fast(_SETPOINT, payload)
        return cls._checked(payload) if fields is None else cls(*fields)

    @classmethod
    def _checked(cls, payload: bytes) -> Setpoint:
        msg = unpack(payload)
        return cls(
            _int(msg, "step"),
            _float(msg, "t"),
            _vector(msg, "pose", 7),
            _vector(msg, "twist", 6),
            _vector(msg, "accel", 6),
        )


_SETPOINT = _wire("SetpointWire", [("step", Count), ("t", Finite), ("pose", fixed(7)), ("twist", fixed(6)),
                                   ("accel", fixed(6))])


class Command(msgspec.Struct, frozen=True, gc=False):
    """``controller/command``: the cable tensions (N) — or the unstretched cable lengths (m) — to apply
    over [t_k, t_k + dt].

    Exactly one of ``tensions`` and ``lengths`` is on the wire. ``tensions`` must be finite; the sim
    clamps each to [0, tmax] (a cable only pulls) and counts the clamps. ``lengths`` (a session whose
    scenario has ``controller.output: lengths``: winch-driven cables) must be finite and > 0; in a
    Python ``Command`` of lengths, ``tensions`` is ``()``. Optional ``feasible``/``status`` report the
    controller's tension distribution outcome. Optional ``estimate`` (a controller fed from the sensors:
    ``controller.feedback: sensors``): the pose and twist it estimated for state ``step`` and answered, the
    columns of :data:`cdpr.protocol.streams.ESTIMATE_COLUMNS` (13 numbers: x, y, z, qx, qy, qz, qw, vx, vy, vz,
    wx, wy, wz); the sim passes it on in its telemetry, for the recording and the summary.
    """

    step: int
    t: float
    tensions: tuple[float, ...]
    feasible: bool = True
    status: str = "ok"
    lengths: tuple[float, ...] | None = None
    solve_time: float | None = None  # s the controller spent on this step (optional)
    estimate: tuple[float, ...] | None = None  # the pose and twist the command answered (ESTIMATE_WIDTH numbers)

    @property
    def kind(self) -> CommandKind:
        """``"lengths"`` or ``"tensions"``: which command this is."""
        return "tensions" if self.lengths is None else "lengths"

    @property
    def values(self) -> tuple[float, ...]:
        """The commanded numbers, tensions or lengths."""
        return self.tensions if self.lengths is None else self.lengths

    def encode(self) -> bytes:
        lengths = self.lengths
        return _ENCODER.encode(_CommandOut(
            PROTOCOL_VERSION, self.step, self.t, self.tensions if lengths is None else UNSET,
            UNSET if lengths is None else lengths, bool(self.feasible), self.status,
            UNSET if self.solve_time is None else self.solve_time,
            UNSET if self.estimate is None else self.estimate))

    @classmethod
    def decode(cls, payload: bytes, cables: int | None = None, expect: CommandKind | None = None) -> Command:
        """``expect`` (``"tensions"`` or ``"lengths"``): the kind the receiver takes (the other: an error)."""
        f = _fast(_COMMAND, payload)
        if f is not None:
            step, t, tensions, lengths, feasible, status, solve_time, estimate = f
            solve = None if solve_time is UNSET else solve_time
            if estimate is UNSET:
                estimate = None
            elif len(estimate) != ESTIMATE_WIDTH:
                return cls._checked(payload, cables, expect)
            if lengths is UNSET:
                if tensions is not UNSET and expect != "lengths" and (cables is None or len(tensions) == cables):
                    return cls(step, t, tensions, feasible, status, None, solve, estimate)
            elif (tensions is UNSET and expect != "tensions" and (cables is None or len(lengths) == cables)
                  and (not lengths or min(lengths) > 0.0)):
                return cls(step, t, (), feasible, status, lengths, solve, estimate)
        return cls._checked(payload, cables, expect)

    @classmethod
    def _checked(cls, payload: bytes, cables: int | None = None, expect: CommandKind | None = None) -> Command:
        msg = unpack(payload)
        feasible = msg.get("feasible", True)
        status = msg.get("status", "ok")
        if not isinstance(feasible, bool):
            raise ProtocolError(f"feasible: expected true/false, got {type(feasible).__name__}")
        if not isinstance(status, str):
            raise ProtocolError(f"status: expected a string, got {type(status).__name__}")
        step, t = _int(msg, "step"), _float(msg, "t")
        solve_time = _float(msg, "solve_time") if "solve_time" in msg else None
        estimate = _vector(msg, "estimate", ESTIMATE_WIDTH) if "estimate" in msg else None
        if "lengths" not in msg:
            if expect == "lengths":
                raise ProtocolError("lengths: missing (this session's controller commands cable lengths)")
            return cls(step, t, _vector(msg, "tensions", cables), feasible, status, None, solve_time, estimate)
        if "tensions" in msg:
            raise ProtocolError("lengths: a command carries tensions or lengths, not both")
        if expect == "tensions":
            raise ProtocolError("lengths: this session's controller commands tensions, not lengths")
        lengths = _vector(msg, "lengths", cables)
        for i, x in enumerate(lengths):
            if x <= 0.0:
                raise ProtocolError(f"lengths[{i}]: must be > 0, got {x}")
        return cls(step, t, (), feasible, status, lengths, solve_time, estimate)


_COMMAND_FIELDS: list[_WireField] = [
    ("step", Count), ("t", Finite), ("tensions", Floats | UnsetType, UNSET), ("lengths", Floats | UnsetType, UNSET),
    ("feasible", bool, True), ("status", str, "ok"), ("solve_time", Finite | UnsetType, UNSET),
    ("estimate", Floats | UnsetType, UNSET)]
_COMMAND = _wire("CommandWire", _COMMAND_FIELDS)
_CommandOut = msgspec.defstruct("CommandOut", [("v", int), *_COMMAND_FIELDS], frozen=True, gc=False)


class _SensorsBase(msgspec.Struct, frozen=True, gc=False):
    """``sim/sensors``: what the simulated sensors read at step ``step`` (noisy, biased, quantised).

    Its fields after ``step`` and ``t`` are the channels of :data:`cdpr.sensors.SENSOR_COLUMNS` (each kind's, in
    the table's order: ``encoders`` (m, m), ``load_cells`` (m, N), the IMU's ``accel`` (m/s²) and ``gyro`` (rad/s),
    ``laser_tracker`` (3, m), …); a channel whose kind the scenario does not have, or whose reading is not
    delivered at this step (its rate, latency, dropout), is absent (``UNSET``; :meth:`get` gives None). Positional
    arguments after ``t`` are the channels in that order. The ground truth stays in ``sim/state``.
    """

    step: int
    t: float

    if TYPE_CHECKING:
        def __init__(self, step: int, t: float, *channels: tuple[float, ...], **named: tuple[float, ...]) -> None: ...

        def __getattr__(self, name: str) -> tuple[float, ...]: ...

    def get(self, name: str) -> tuple[float, ...] | None:
        """Channel ``name``'s values, or None when absent."""
        value = getattr(self, name)
        return None if value is UNSET else value

    @property
    def readings(self) -> dict[str, tuple[float, ...]]:
        """The channels present, name → values, in the table's order."""
        return {c.name: v for c in SENSOR_COLUMNS if (v := getattr(self, c.name)) is not UNSET}

    def encode(self) -> bytes:
        return _ENCODER.encode(self)

    @classmethod
    def decode(cls, payload: bytes, cables: int | None = None) -> Sensors:
        f = _fast(_SENSORS, payload)
        if f is not None and _sensor_widths(f[2:], cables):
            return Sensors(*f)
        return cls._checked(payload, cables)

    @classmethod
    def _checked(cls, payload: bytes, cables: int | None = None) -> Sensors:
        msg = unpack(payload)
        step, t = _int(msg, "step"), _float(msg, "t")
        values: list[Any] = []
        for c in SENSOR_COLUMNS:
            if c.name not in msg:
                values.append(UNSET)
                continue
            v = _vector(msg, c.name, cables if c.width is None else c.width)
            if c.width is None:
                cables = len(v)  # the first per-cable channel tells the others their length
            values.append(v)
        return Sensors(step, t, *values)


def _sensor_widths(values: Sequence[Any], cables: int | None) -> bool:
    """The channels' lengths agree with their widths (per-cable ones with ``cables``, or with each other)."""
    for c, v in zip(SENSOR_COLUMNS, values, strict=True):
        if v is UNSET:
            continue
        if c.width is None:
            if cables is None:
                cables = len(v)
            elif len(v) != cables:
                return False
    return True


def _channel_type(c: Any) -> Any:
    return Floats if c.width is None else fixed(c.width)


if TYPE_CHECKING:
    Sensors = _SensorsBase
else:
    Sensors = msgspec.defstruct("Sensors", [(c.name, _channel_type(c) | UnsetType, UNSET) for c in SENSOR_COLUMNS],
                                bases=(_SensorsBase,), module=__name__, **_STRUCT)
    Sensors.__doc__ = _SensorsBase.__doc__
_SENSORS = _wire("SensorsWire", [("step", Count), ("t", Finite),
                                 *((c.name, _channel_type(c) | UnsetType, UNSET) for c in SENSOR_COLUMNS)])


@dataclass(frozen=True, slots=True)
class Setpoints:
    """``trajectory/setpoints``: consecutive setpoints ``first`` … ``first + len − 1`` in one message.

    On the wire the columns are flat arrays: ``t`` (n), ``pose`` (7n), ``twist`` (6n), ``accel`` (6n).
    """

    items: tuple[Setpoint, ...]

    def encode(self) -> bytes:
        s = self.items
        return _ENCODER.encode({"v": PROTOCOL_VERSION, "first": s[0].step if s else 0, "t": [x.t for x in s],
                                "pose": _chain(x.pose for x in s), "twist": _chain(x.twist for x in s),
                                "accel": _chain(x.accel for x in s)})

    @classmethod
    def decode(cls, payload: bytes) -> Setpoints:
        f = _fast(_SETPOINTS, payload)
        if f is not None:
            first, t, pose, twist, accel = f
            n = len(t)
            if len(pose) == 7 * n and len(twist) == 6 * n and len(accel) == 6 * n:
                return cls(tuple(itertools.starmap(Setpoint, zip(range(first, first + n), t, _split(pose, n, 7),
                                                                 _split(twist, n, 6), _split(accel, n, 6),
                                                                 strict=True))))
        return cls._checked(payload)

    @classmethod
    def _checked(cls, payload: bytes) -> Setpoints:
        msg = unpack(payload)
        first = _int(msg, "first")
        t = _vector(msg, "t", None)
        n = len(t)
        pose, twist, accel = _rows(msg, "pose", n, 7), _rows(msg, "twist", n, 6), _rows(msg, "accel", n, 6)
        return cls(tuple(Setpoint(first + i, t[i], pose[i], twist[i], accel[i]) for i in range(n)))


_SETPOINTS = _wire("SetpointsWire", [("first", Count), ("t", Floats), ("pose", Floats), ("twist", Floats),
                                     ("accel", Floats)])


def _chain(rows: Any) -> list[Any]:
    """The rows one after the other, as one flat list (a block's column on the wire)."""
    return list(itertools.chain.from_iterable(rows))


def _split(flat: Sequence[Any], n: int, width: int) -> list[Any]:
    """``n`` rows of ``width`` from a flat column (``len(flat) == n * width``)."""
    return [flat[i:i + width] for i in range(0, n * width, width)] if width else [flat[:0]] * n


@dataclass(frozen=True, slots=True)
class Telemetry:
    """``sim/telemetry``: what the sim did over a block of steps, for the clock, recorders and monitors.

    ``states``: the states the sim published on ``sim/state`` since the last block (every one, in step
    order; a block sent on request may repeat the current one); ``commands``: the commands it applied
    over the same steps (the first valid one of each step), each with ``lags[i]``, the seconds from the
    step's state going out to the start of its integration (the controller's answer time plus any wait
    for the clock's grant), and the controller's ``solve_time`` when it sent one; ``sensors``: the
    sensor readings taken with the states (empty without sensors); ``lateness``: in free-running realtime,
    the seconds each step's integration started after its wall-clock deadline (one per command; empty in
    lock-step); ``resume``: the sim's snapshot at the block's last state (:class:`Resume`). On the wire every
    column is a flat array (see docs/protocol.md).
    """

    states: tuple[State, ...]
    commands: tuple[Command, ...] = ()
    lags: tuple[float, ...] = ()
    sensors: tuple[Sensors, ...] = ()
    lateness: tuple[float, ...] = ()
    resume: Resume | None = None  # what a restarted sim needs to go on from the block's last state

    def encode(self) -> bytes:
        s, c, r = self.states, self.commands, self.sensors
        kind = c[0].kind if c else "tensions"
        columns = list(zip(*(msgspec.structs.astuple(x) for x in s), strict=True)) or [()] * (2 + len(STATE_COLUMNS))
        msg: dict[str, Any] = {
            "v": PROTOCOL_VERSION, "step": columns[0], "t": columns[1],
            **{col.name: columns[i] if col.width == 1 else _chain(columns[i])
               for i, col in enumerate(STATE_COLUMNS, start=2)},
            "command": {
                "step": [x.step for x in c], "t": [x.t for x in c], "kind": kind,
                "values": _chain(x.values for x in c),
                "feasible": [bool(x.feasible) for x in c], "status": [x.status for x in c],
                "solve_time": [-1.0 if x.solve_time is None else float(x.solve_time) for x in c],
                "lag": _floats(self.lags),
            },
        }
        if self.lateness:
            msg["command"]["lateness"] = _floats(self.lateness)
        if any(x.estimate is not None for x in c):  # the rows that have one (estimate_rows: which, if not all)
            rows = [i for i, x in enumerate(c) if x.estimate is not None]
            msg["command"]["estimate"] = _chain(c[i].estimate for i in rows)
            if len(rows) != len(c):
                msg["command"]["estimate_rows"] = rows
        if self.resume is not None:
            msg["resume"] = self.resume.as_map()
        if r:
            msg["sensors"] = _sensors_block(r)
        return _ENCODER.encode(msg)

    @classmethod
    def decode(cls, payload: bytes, cables: int | None = None) -> Telemetry:
        f = _fast(_TELEMETRY, payload)
        block = None if f is None else _telemetry(f, cables)
        return cls._checked(payload, cables) if block is None else block

    @classmethod
    def _checked(cls, payload: bytes, cables: int | None = None) -> Telemetry:
        msg = unpack(payload)
        steps = _ints(msg, "step")
        n = len(steps)
        t = _vector(msg, "t", n)
        columns, cables = _state_block(msg, n, cables)
        m = cables or 0
        states = tuple(itertools.starmap(State, zip(steps, t, *columns, strict=True)))
        c = _field(msg, "command")
        if not isinstance(c, dict):
            raise ProtocolError("command: expected a map")
        c_steps = _ints(c, "step")
        k = len(c_steps)
        c_t = _vector(c, "t", k)
        kind = _field(c, "kind")
        if kind not in COMMAND_KINDS:
            raise ProtocolError(f"command.kind: expected {' or '.join(COMMAND_KINDS)}, got {kind!r}")
        values = _rows(c, "values", k, m) if k else []
        feasible, status = _field(c, "feasible"), _field(c, "status")
        if not isinstance(feasible, list) or len(feasible) != k or not all(isinstance(x, bool) for x in feasible):
            raise ProtocolError(f"command.feasible: expected {k} true/false values")
        if not isinstance(status, list) or len(status) != k or not all(isinstance(x, str) for x in status):
            raise ProtocolError(f"command.status: expected {k} strings")
        solve, lags = _vector(c, "solve_time", k), _vector(c, "lag", k)
        lateness = _vector(c, "lateness", k) if "lateness" in c else ()
        estimates: list[tuple[float, ...] | None] = [None] * k
        if "estimate" in c:
            rows = _ints(c, "estimate_rows") if "estimate_rows" in c else list(range(k))
            if any(x >= k for x in rows) or len(set(rows)) != len(rows):
                raise ProtocolError(f"command.estimate_rows: expected distinct rows below {k}")
            flat = _vector(c, "estimate", len(rows) * ESTIMATE_WIDTH)
            for n, row in enumerate(rows):
                estimates[row] = flat[n * ESTIMATE_WIDTH:(n + 1) * ESTIMATE_WIDTH]
        elif "estimate_rows" in c:
            raise ProtocolError("command.estimate_rows: rows of an estimate the block does not have")
        commands = tuple(
            Command(c_steps[i], c_t[i], values[i] if kind == "tensions" else (), feasible[i], status[i],
                    values[i] if kind == "lengths" else None, solve[i] if solve[i] >= 0.0 else None, estimates[i])
            for i in range(k)
        )
        sensors: tuple[Sensors, ...] = ()
        if "sensors" in msg:
            r = msg["sensors"]
            if not isinstance(r, dict):
                raise ProtocolError("sensors: expected a map")
            r_steps = _ints(r, "step")
            j = len(r_steps)
            r_t = _vector(r, "t", j)
            present = r.get("rows", {})
            if not isinstance(present, dict):
                raise ProtocolError("sensors.rows: expected a map")
            per_row: list[list[Any]] = [[UNSET] * len(SENSOR_COLUMNS) for _ in range(j)]
            for i, col in enumerate(SENSOR_COLUMNS):
                if col.name not in r:
                    if col.name in present:
                        raise ProtocolError(f"sensors.rows.{col.name}: rows of a channel the block does not have")
                    continue
                rows = _ints(present, col.name) if col.name in present else list(range(j))
                if any(x >= j for x in rows) or len(set(rows)) != len(rows):
                    raise ProtocolError(f"sensors.rows.{col.name}: expected distinct rows below {j}")
                width = m if col.width is None else col.width
                flat = _vector(r, col.name, len(rows) * width)
                for n, row in enumerate(rows):
                    per_row[row][i] = flat[n * width:(n + 1) * width]
            sensors = tuple(Sensors(r_steps[i], r_t[i], *per_row[i]) for i in range(j))
        resume = Resume.from_map(msg["resume"], "resume: ") if "resume" in msg else None
        return cls(states, commands, lags, sensors, lateness, resume)


_COMMAND_BLOCK = msgspec.defstruct("CommandBlockWire", [
    ("step", list[Count]), ("t", Floats), ("kind", Literal["tensions", "lengths"]), ("values", Floats),
    ("feasible", list[bool]), ("status", list[str]), ("solve_time", Floats), ("lag", Floats),
    ("lateness", Floats | UnsetType, UNSET), ("estimate", Floats | UnsetType, UNSET),
    ("estimate_rows", list[Count] | UnsetType, UNSET)], frozen=True, gc=False)
_SENSORS_BLOCK = msgspec.defstruct("SensorsBlockWire", [
    ("step", list[Count]), ("t", Floats), *((c.name, Floats | UnsetType, UNSET) for c in SENSOR_COLUMNS),
    ("rows", dict[str, list[Count]] | UnsetType, UNSET)], frozen=True, gc=False)


def _sensors_block(r: Sequence[Sensors]) -> dict[str, Any]:
    """A telemetry block's ``sensors`` map: each channel flat over the rows that have it (``rows.<name>``: which,
    when not every row does)."""
    block: dict[str, Any] = {"step": [x.step for x in r], "t": [x.t for x in r]}
    present: dict[str, list[int]] = {}
    for c in SENSOR_COLUMNS:
        values = [getattr(x, c.name) for x in r]
        rows = [i for i, v in enumerate(values) if v is not UNSET]
        if not rows:
            continue
        block[c.name] = _flat([values[i] for i in rows])
        if len(rows) != len(r):
            present[c.name] = rows
    if present:
        block["rows"] = present
    return block
_TELEMETRY = _wire("TelemetryWire", [
    ("step", list[Count]), ("t", Floats), *((c.name, list[Count] if c.integer else Floats) for c in STATE_COLUMNS),
    ("command", _COMMAND_BLOCK), ("sensors", _SENSORS_BLOCK | UnsetType, UNSET),
    ("resume", msgspec.Raw | UnsetType, UNSET)])


def _telemetry(f: tuple[Any, ...], cables: int | None) -> Telemetry | None:
    """A telemetry block from its decoded wire fields, or None where the columns' lengths do not agree (the
    reference checks then say which)."""
    steps, t, *state_columns, c, r, resume_raw = f
    n = len(steps)
    if len(t) != n:
        return None
    columns: list[Any] = []
    for col, values in zip(STATE_COLUMNS, state_columns, strict=True):
        if col.width is None and cables is None and n:
            if len(values) % n:
                return None
            cables = len(values) // n
        width = 1 if col.width == 1 else cables if col.width is None else col.width
        if width is None:  # an empty block without a cable count: an empty column
            if values:
                return None
            columns.append([])
            continue
        if len(values) != n * width:
            return None
        columns.append(values if col.width == 1 else _split(values, n, width))
    m = cables or 0
    k = len(c.step)
    if not (len(c.t) == len(c.feasible) == len(c.status) == len(c.solve_time) == len(c.lag) == k) \
            or (k and len(c.values) != k * m) or (c.lateness is not UNSET and len(c.lateness) != k):
        return None
    values = _split(c.values, k, m) if k else []
    tensions = c.kind == "tensions"
    estimates: list[Any] = [None] * k
    if c.estimate is not UNSET:
        rows = range(k) if c.estimate_rows is UNSET else c.estimate_rows
        if len(c.estimate) != len(rows) * ESTIMATE_WIDTH or (c.estimate_rows is not UNSET and (
                len(set(rows)) != len(rows) or any(x >= k for x in rows))):
            return None
        for n, row in enumerate(rows):
            estimates[row] = tuple(c.estimate[n * ESTIMATE_WIDTH:(n + 1) * ESTIMATE_WIDTH])
    elif c.estimate_rows is not UNSET:
        return None
    commands = tuple(Command(step, ct, v if tensions else (), ok, status, None if tensions else v,
                             solve if solve >= 0.0 else None, e)
                     for step, ct, v, ok, status, solve, e in zip(c.step, c.t, values, c.feasible, c.status,
                                                                  c.solve_time, estimates, strict=False))
    sensors: tuple[Sensors, ...] = ()
    if r is not UNSET:
        j = len(r.step)
        if len(r.t) != j:
            return None
        present = {} if r.rows is UNSET else r.rows
        per_row: list[list[Any]] = [[UNSET] * len(SENSOR_COLUMNS) for _ in range(j)]
        for i, col in enumerate(SENSOR_COLUMNS):
            flat = getattr(r, col.name)
            if flat is UNSET:
                if col.name in present:
                    return None
                continue
            rows = present.get(col.name, range(j))
            width = m if col.width is None else col.width
            if len(flat) != len(rows) * width or (col.name in present and (len(set(rows)) != len(rows)
                                                                           or any(x >= j for x in rows))):
                return None
            for n, row in enumerate(rows):
                per_row[row][i] = flat[n * width:(n + 1) * width]
        sensors = tuple(Sensors(r.step[i], r.t[i], *per_row[i]) for i in range(j))
    resume = None
    if resume_raw is not UNSET:
        try:
            resume = Resume.from_map(msgpack.unpackb(bytes(resume_raw), raw=False, strict_map_key=False), "resume: ")
        except ProtocolError:
            return None
    states = tuple(itertools.starmap(State, zip(steps, t, *columns, strict=True)))
    return Telemetry(states, commands, c.lag, sensors, () if c.lateness is UNSET else c.lateness, resume)


@dataclass(frozen=True, slots=True)
class Resume:
    """``session/resume``: what a sim needs to go on from step ``step`` of a session under way: the ``snapshot``
    its model took there (``model``: the cable model's name; its other fields are the model's own, see
    docs/faults.md). The sim sends one with every telemetry block (for the block's last state), the clock
    keeps the last and publishes it when a sim (re)joins a session under way, just before the grant."""

    step: int
    model: str
    snapshot: dict[str, Any]

    def encode(self) -> bytes:
        return pack(self.as_map())

    def as_map(self) -> dict[str, Any]:
        return {"step": self.step, "model": self.model, "snapshot": self.snapshot}

    @classmethod
    def from_map(cls, msg: Any, where: str = "") -> Resume:
        if not isinstance(msg, dict):
            raise ProtocolError(f"{where}expected a map")
        step, model, snapshot = _int(msg, "step"), _field(msg, "model"), _field(msg, "snapshot")
        if not isinstance(model, str) or not isinstance(snapshot, dict):
            raise ProtocolError(f"{where}model, snapshot: expected a string and a map")
        return cls(step, model, snapshot)

    @classmethod
    def decode(cls, payload: bytes) -> Resume:
        return cls.from_map(unpack(payload))


@dataclass(frozen=True, slots=True)
class End:
    """``session/end``: a participant asks the clock to end the session now, as ``finished`` (a learning
    environment whose episode ended before the trajectory did). ``by``: who asks (a service name);
    ``reason``: one line, in the clock's status and log."""

    by: str
    reason: str

    def encode(self) -> bytes:
        return pack({"by": self.by, "reason": self.reason})

    @classmethod
    def decode(cls, payload: bytes) -> End:
        msg = unpack(payload)
        by, reason = _field(msg, "by"), _field(msg, "reason")
        if not isinstance(by, str) or by not in SERVICES:
            raise ProtocolError(f"by: expected one of {', '.join(SERVICES)}, got {by!r}")
        if not isinstance(reason, str) or len(reason) > END_REASON_MAX or "\n" in reason:
            raise ProtocolError(f"reason: expected one line of at most {END_REASON_MAX} characters")
        return cls(by, reason)


@dataclass(frozen=True, slots=True)
class ServiceStats:
    """``stats/{service}``: a service's fault counters (dropped, clamped, … messages), about once a second
    while they change and once when the service stops. The clock gathers them into its status."""

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


@dataclass(frozen=True, slots=True)
class CameraFrame:
    """``sim/camera/{camera}``: the markers a camera of the scenario saw in one frame (docs/protocol.md).

    ``step``/``t``: the frame's exposure (it goes out ``latency_steps`` later); ``ids``: the markers seen, in
    the scenario's order (not in front of the camera, outside the image or dropped: absent); ``pixels``:
    their ``u, v`` image coordinates, flat (OpenCV's convention: origin at the top-left pixel's corner, ``u``
    right, ``v`` down); ``depth``: their distance along the optical axis (m, the truth). The camera's
    intrinsics and distortion are in ``session/info`` (``sim.cameras``).
    """

    camera: str
    step: int
    t: float
    ids: tuple[str, ...]
    pixels: tuple[float, ...]
    depth: tuple[float, ...]

    def encode(self) -> bytes:
        return pack({"camera": self.camera, "step": self.step, "t": self.t, "ids": list(self.ids),
                     "pixels": list(self.pixels), "depth": list(self.depth)})

    @classmethod
    def decode(cls, payload: bytes) -> CameraFrame:
        msg = unpack(payload)
        camera = _field(msg, "camera")
        if not isinstance(camera, str) or not camera:
            raise ProtocolError(f"camera: expected the camera's name, got {camera!r}")
        ids = _field(msg, "ids")
        if not isinstance(ids, list) or not all(isinstance(i, str) for i in ids):
            raise ProtocolError("ids: expected a list of marker names")
        return cls(camera, _int(msg, "step"), _float(msg, "t"), tuple(ids), _vector(msg, "pixels", 2 * len(ids)),
                   _vector(msg, "depth", len(ids)))


@dataclass(frozen=True, slots=True)
class CameraImage:
    """``sim/camera/{camera}/image``: an image of a camera whose scenario entry says ``image: true``, taken with
    the frame of the same ``step`` (docs/protocol.md): ``format`` ``jpeg``, ``data`` the encoded bytes."""

    camera: str
    step: int
    t: float
    width: int
    height: int
    format: str
    data: bytes

    def encode(self) -> bytes:
        return pack({"camera": self.camera, "step": self.step, "t": self.t, "width": self.width,
                     "height": self.height, "format": self.format, "data": self.data})

    @classmethod
    def decode(cls, payload: bytes) -> CameraImage:
        msg = unpack(payload)
        camera, fmt, data = _field(msg, "camera"), _field(msg, "format"), _field(msg, "data")
        if not isinstance(camera, str) or not camera:
            raise ProtocolError(f"camera: expected the camera's name, got {camera!r}")
        if fmt != "jpeg":
            raise ProtocolError(f"format: expected 'jpeg', got {fmt!r}")
        if not isinstance(data, bytes) or not data:
            raise ProtocolError("data: expected the encoded image's bytes")
        return cls(camera, _int(msg, "step"), _float(msg, "t"), _int(msg, "width", 1), _int(msg, "height", 1), fmt,
                   data)


ClockState = Literal["waiting", "running", "paused", "finished", "aborted"]
CLOCK_STATES: tuple[ClockState, ...] = get_args(ClockState)


@dataclass(frozen=True, slots=True)
class Status:
    """``clock/status``: the session's state, published on every change and about once a second.

    ``state`` is one of waiting | running | paused | finished | aborted; ``missing`` lists the expected
    participants without a liveliness token; ``stats`` holds the clock's counters (documented).
    """

    state: ClockState
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
