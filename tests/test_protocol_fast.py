"""The per-step messages' fast decoding (msgspec) takes exactly what the reference checks take, with the same
result, and every payload it refuses gets the reference's one-line error: on well-formed payloads and on
thousands of mutated ones (a field dropped, retyped, made non-finite, resized; another version)."""

from __future__ import annotations

from typing import Any

import msgpack
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cdpr.protocol import Command, ProtocolError, Sensors, Setpoint, Setpoints, State, Telemetry, Tick

GOOD: dict[str, tuple[type, dict[str, Any], list[tuple[Any, ...]]]] = {
    # message class, a well-formed payload's map, the decode() argument tuples to try
    "tick": (Tick, {"v": 2, "step": 5, "t": 0.005, "until": 300, "resend": False, "flush": True, "free": False,
                    "paced": True}, [()]),
    "state": (State, {"v": 2, "step": 7, "t": 0.007, "pose": [0.1, 0.2, 1.5, 0.0, 0.0, 0.0, 1.0],
                      "twist": [0.5] * 6, "cable_lengths": [1.25, 2.5, 3.0], "tensions": [100.0, 200.0, 0.0],
                      "clamped": 3, "command_age": 0, "watchdog": 0}, [(), (3,), (4,)]),
    "setpoint": (Setpoint, {"v": 2, "step": 1, "t": 0.001, "pose": [0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
                            "twist": [0.0] * 6, "accel": [0.0] * 6}, [()]),
    "command": (Command, {"v": 2, "step": 3, "t": 0.003, "tensions": [10.0, 20.0, 30.0], "feasible": True,
                          "status": "ok", "solve_time": 1e-4},
                [(), (3,), (2,), (3, "tensions"), (3, "lengths")]),
    "lengths": (Command, {"v": 2, "step": 3, "t": 0.003, "lengths": [1.0, 2.0, 3.0], "feasible": False,
                          "status": "infeasible"},
                [(), (3,), (3, "lengths"), (3, "tensions")]),
    "sensors": (Sensors, {"v": 2, "step": 2, "t": 0.002, "encoders": [1.0, 2.0], "load_cells": [5.0, 6.0],
                          "accel": [0.0, 0.0, 9.81], "gyro": [0.0] * 3}, [(), (2,), (3,)]),
    "setpoints": (Setpoints, {"v": 2, "first": 4, "t": [0.004, 0.005], "pose": [0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0] * 2,
                              "twist": [0.1] * 12, "accel": [0.2] * 12}, [()]),
    "telemetry": (Telemetry, {
        "v": 2, "step": [1, 2], "t": [0.001, 0.002], "pose": [0.1, 0.2, 1.5, 0.0, 0.0, 0.0, 1.0] * 2,
        "twist": [0.5] * 12, "cable_lengths": [1.0, 2.0] * 2, "tensions": [10.0, 20.0] * 2, "clamped": [0, 1],
        "command_age": [0, 0], "watchdog": [0, 0],
        "command": {"step": [0, 1], "t": [0.0, 0.001], "kind": "tensions", "values": [10.0, 20.0] * 2,
                    "feasible": [True, False], "status": ["ok", "infeasible"], "solve_time": [1e-4, -1.0],
                    "lag": [2e-4, 3e-4], "lateness": [1e-5, 2e-5]},
        "resume": {"step": 2, "model": "ideal", "snapshot": {"step": 2, "tensions": [10.0, 20.0]}},
        "sensors": {"step": [1, 2], "t": [0.001, 0.002], "encoders": [1.0, 2.0] * 2, "load_cells": [9.0, 8.0] * 2,
                    "accel": [0.0, 0.0, 9.81] * 2, "gyro": [0.0] * 6}},
        [(), (2,), (3,)]),
    "empty_telemetry": (Telemetry, {
        "v": 2, "step": [], "t": [], "pose": [], "twist": [], "cable_lengths": [], "tensions": [], "clamped": [],
        "command_age": [], "watchdog": [],
        "command": {"step": [], "t": [], "kind": "tensions", "values": [], "feasible": [], "status": [],
                    "solve_time": [], "lag": []}}, [(), (2,)]),
}

numbers = st.one_of(st.integers(-3, 2**64 - 1), st.floats(allow_nan=True, allow_infinity=True),
                    st.sampled_from([0, -1, 2, 0.0, -0.0, 1e308, -1e308, 5e-324]))
scalars = st.one_of(st.none(), st.booleans(), numbers, st.text(max_size=4), st.binary(max_size=4))
values = st.one_of(scalars, st.lists(st.one_of(numbers, st.booleans(), st.none()), max_size=9),
                   st.dictionaries(st.text(max_size=3), scalars, max_size=2))


def outcome(decode: Any, payload: bytes, args: tuple[Any, ...]) -> Any:
    try:
        return ("ok", decode(payload, *args))
    except ProtocolError as exc:
        return ("error", str(exc))


def same(cls: type, payload: bytes, args: tuple[Any, ...]) -> None:
    fast, checked = outcome(cls.decode, payload, args), outcome(cls._checked, payload, args)
    assert fast == checked, (msgpack.unpackb(payload, strict_map_key=False), args)
    if fast[0] == "ok":  # the same numbers, of the same types (a float stays a float)
        assert [type(x) for x in msgpack_fields(fast[1])] == [type(x) for x in msgpack_fields(checked[1])]


def msgpack_fields(msg: Any) -> list[Any]:
    import msgspec

    if isinstance(msg, Setpoints | Telemetry):  # the messages of a block
        groups = (msg.items,) if isinstance(msg, Setpoints) else (msg.states, msg.commands, msg.sensors)
        return [x for group in groups for item in group for x in msgpack_fields(item)]
    return [x for f in msgspec.structs.astuple(msg) for x in (f if isinstance(f, tuple) else (f,))]


@pytest.mark.parametrize("name", list(GOOD))
def test_well_formed_payloads_take_the_fast_path_with_the_reference_result(name: str) -> None:
    cls, msg, arg_sets = GOOD[name]
    payload = msgpack.packb(msg, use_bin_type=True)
    for args in arg_sets:
        same(cls, payload, args)
    assert cls.decode(payload, *arg_sets[0]).encode() == payload  # and it encodes back to the same bytes


mutation = st.tuples(st.sampled_from(list(GOOD)), st.integers(0, 4), st.lists(
    st.tuples(st.sampled_from(["drop", "set", "resize", "element"]), st.integers(0, 20), values, st.integers(0, 9)),
    min_size=1, max_size=3))


@settings(max_examples=4000, deadline=None, database=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(mutation)
def test_mutated_payloads_get_the_reference_result_or_its_error_line(case: Any) -> None:
    name, which_args, edits = case
    cls, good, arg_sets = GOOD[name]
    msg = dict(good)
    for op, index, value, size in edits:
        key = sorted(msg)[index % len(msg)] if msg else "v"
        if op == "drop":
            msg.pop(key, None)
        elif op == "set":
            msg[key] = value
        elif op == "resize" and isinstance(msg.get(key), list):
            msg[key] = (msg[key] * 10)[:size]
        elif op == "element" and isinstance(msg.get(key), list) and msg[key]:
            msg[key] = [*msg[key]]
            msg[key][index % len(msg[key])] = value
        elif op == "element" and isinstance(msg.get(key), dict) and msg[key]:  # a block's nested map
            inner = msg[key] = dict(msg[key])
            name = sorted(inner)[size % len(inner)]
            if isinstance(inner[name], list) and inner[name] and index % 2:
                inner[name] = [*inner[name]][:index % (len(inner[name]) + 1)] if index % 3 else [value, *inner[name]]
            else:
                inner[name] = value
    same(cls, msgpack.packb(msg, use_bin_type=True), arg_sets[which_args % len(arg_sets)])


def test_not_msgpack_and_not_a_map_get_the_reference_lines() -> None:
    for payload in (b"\xc1", b"", msgpack.packb([1, 2]), msgpack.packb({"v": 2, "step": 1, "t": 0.0}) + b"\x00"):
        for cls, _, arg_sets in GOOD.values():
            same(cls, payload, arg_sets[0])
    with pytest.raises(ProtocolError, match="v: missing"):
        State.decode(msgpack.packb({k: v for k, v in GOOD["state"][1].items() if k != "v"}))
    with pytest.raises(ProtocolError, match="v: unsupported protocol version 3"):
        Command.decode(msgpack.packb({**GOOD["command"][1], "v": 3}))
