"""The wire protocol: every key expression and every message of a session, in one place.

The keys and messages are in :mod:`cdpr.protocol.messages`, the wiring table in :mod:`cdpr.protocol.wiring`,
``session/info`` in :mod:`cdpr.protocol.session`; this package gathers the names a participant uses.
"""

from cdpr.protocol.messages import (
    CLOCK_STATES,
    PROTOCOL_VERSION,
    SERVICES,
    SESSION_RE,
    ClockState,
    Command,
    Keys,
    ProtocolError,
    Resume,
    Sensors,
    ServiceStats,
    Setpoint,
    Setpoints,
    State,
    Status,
    Telemetry,
    Tick,
    check_session,
    pack,
    unpack,
)

__all__ = [
    "CLOCK_STATES",
    "PROTOCOL_VERSION",
    "SERVICES",
    "SESSION_RE",
    "ClockState",
    "Command",
    "Keys",
    "ProtocolError",
    "Resume",
    "Sensors",
    "ServiceStats",
    "Setpoint",
    "Setpoints",
    "State",
    "Status",
    "Telemetry",
    "Tick",
    "check_session",
    "pack",
    "unpack",
]
