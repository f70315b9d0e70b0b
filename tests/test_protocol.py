"""The wire protocol module and its document stay in step; messages round-trip; bad ones name the field."""

from __future__ import annotations

import math
import re
from pathlib import Path

import msgpack
import pytest
import yaml

from cdpr.protocol import (
    PROTOCOL_VERSION,
    Command,
    Keys,
    ProtocolError,
    Sensors,
    Setpoint,
    Setpoints,
    State,
    Status,
    Telemetry,
    Tick,
    wiring,
)
from cdpr.protocol.wiring import TOPICS, WIRING
from cdpr.runtime.client import _ControllerNode
from cdpr.runtime.registry import node_class, node_names

ROOT = Path(__file__).resolve().parents[1]
DOC = (ROOT / "docs" / "protocol.md").read_text(encoding="utf-8")


def test_every_key_is_documented() -> None:
    for name, key in Keys("s").table().items():
        doc_key = key.replace("cdpr/s/", "cdpr/{session}/")
        assert f"`{doc_key}`" in DOC, f"{name} key {doc_key} missing from docs/protocol.md"


def _names(cell: str) -> set[str]:
    return {w for w in re.findall(r"[a-z][a-z0-9]*", cell) if w in WIRING}


def test_wiring_table_matches_the_document() -> None:
    rows = {m.group(1): m for m in re.finditer(r"^\| (\w+)\s*\| `[^`]+`\s*\| ([^|]+)\| ([^|]+)\|$", DOC, re.M)}
    assert set(rows) == set(TOPICS)
    for topic in TOPICS:
        assert _names(rows[topic].group(2)) == set(wiring.publishers(topic)), topic
        if topic != "alive":  # the clock watches the tokens with a liveliness subscriber, not a topic
            assert _names(rows[topic].group(3)) == set(wiring.subscribers(topic)), topic


def test_every_registered_node_is_wired_as_the_table_says() -> None:
    """Each registered node lists exactly the topics of its row; the SDK's controller those of the controller."""
    assert set(node_names()) == set(WIRING)
    for name in node_names():
        cls = node_class(name)
        assert cls.name == name
        wiring.check_node(name, cls.subscribes, cls.publishes)
    wiring.check_node("controller", _ControllerNode.subscribes, _ControllerNode.publishes)


def test_a_node_off_the_table_is_refused() -> None:
    with pytest.raises(ValueError,
                       match=r"publishes \['command', 'state'\], the wiring table lists \['command', 'end'\]"):
        wiring.check_node("controller", ("state", "setpoints", "camera"), ("command", "state"))
    with pytest.raises(ValueError, match="subscribes"):
        wiring.check_node("sim", ("tick",), ("state", "sensors"))
    # an optional topic may be left out (a controller that is no visual servo takes no camera frames; one fed from
    # the sensors, no state), no other
    wiring.check_node("controller", ("state", "setpoints"), ("command", "end"))
    wiring.check_node("controller", ("sensors", "setpoints"), ("command", "end"))
    with pytest.raises(ValueError, match=r"subscribes \['camera', 'state'\], .* \(state, camera, sensors optional\)"):
        wiring.check_node("controller", ("state", "camera"), ("command", "end"))
    with pytest.raises(ValueError, match="not in the wiring table"):
        wiring.check_node("estimator", (), ())


def test_compose_runs_the_nodes_of_the_table() -> None:
    """Every service of docker/compose.yaml is the router, a node of the table started by its name, or (profile
    study) a Ray node or a study's driver, which are no session's participants."""
    compose = yaml.safe_load((ROOT / "docker" / "compose.yaml").read_text(encoding="utf-8"))
    nodes = {name: svc for name, svc in compose["services"].items()
             if name != "router" and svc.get("profiles") != ["study"]}
    assert set(nodes) <= set(WIRING)
    assert {"clock", "sim", "trajectory", "controller"} <= set(nodes)
    for name, svc in nodes.items():
        command = svc["command"] if isinstance(svc["command"], str) else " ".join(svc["command"])
        assert command.split()[0] == name, (name, command)


@pytest.mark.parametrize(
    "msg",
    [
        Tick(3, 0.003),
        Tick(3, 0.003, 99, False, True),
        Tick(7, 0.007, 12, True, True),
        State(5, 0.005, (1, 2, 3, 0, 0, 0, 1), (0.1,) * 6, (4.0,) * 8, (10.0,) * 8, 2),
        Setpoint(5, 0.005, (1, 2, 3, 0, 0, 0, 1), (0.0,) * 6, (0.5,) * 6),
        Command(5, 0.005, (1.0,) * 8, False, "infeasible"),
        Command(5, 0.005, (), True, "optimal", (2.0,) * 8, 3.5e-5),
        Status("running", 7, 0.007, 100, ("controller",), "why", {"rate": 1.5}),
    ],
)
def test_round_trip(msg: object) -> None:
    cls = type(msg)
    back = cls.decode(msg.encode())  # type: ignore[attr-defined]
    assert back == cls.decode(back.encode())
    for field in ("step", "t"):
        assert getattr(back, field) == getattr(msg, field)
    assert back == msg
    raw = msgpack.unpackb(msg.encode())  # type: ignore[attr-defined]
    assert raw["v"] == PROTOCOL_VERSION == 2


def _states(n: int, first: int = 0) -> tuple[State, ...]:
    # numbers as the sim makes them (floats: a State is encoded as built, an int stays an int on the wire)
    pose = (1.0, 2.0, 3.0, 0.0, 0.0, 0.0, 1.0)
    return tuple(State(k, k / 1000, pose, (0.1 * k,) * 6, (4.0,) * 8, (10.0 + k,) * 8, k // 3)
                 for k in range(first, first + n))


def test_blocks_round_trip() -> None:
    sps = Setpoints(tuple(Setpoint(10 + i, 0.01 + i / 1000, (1, 2, 3 + i, 0, 0, 0, 1), (0.1,) * 6, (0.2,) * 6)
                          for i in range(50)))
    assert Setpoints.decode(sps.encode()) == sps
    commands = tuple(Command(k, k / 1000, (float(k),) * 8, k != 2, "optimal" if k != 2 else "infeasible",
                             None, None if k == 1 else 1e-4 * k) for k in range(4))
    sensors = tuple(Sensors(k, k / 1000, (4.0,) * 8, (9.0,) * 8, (0.0, 0.0, 9.81), (0.0,) * 3) for k in range(5))
    block = Telemetry(_states(5), commands, (1e-4, 2e-4, 3e-4, 4e-4), sensors)
    assert Telemetry.decode(block.encode(), cables=8) == block
    assert Telemetry.decode(Telemetry(_states(1, 7)).encode()).states == _states(1, 7)  # a heartbeat
    # a state stream re-encoded from telemetry is the stream the sim published (the run's digest)
    assert [s.encode() for s in Telemetry.decode(block.encode()).states] == [s.encode() for s in _states(5)]


@pytest.mark.parametrize(
    ("change", "field"),
    [
        (lambda m: m.update(pose=m["pose"][:-1]), "pose"),
        (lambda m: m.update(clamped=[0] * 2), "clamped"),
        (lambda m: m["command"].update(kind="volts"), "command.kind"),
        (lambda m: m["command"].update(status=["ok"]), "command.status"),
        (lambda m: m["command"].update(lag=[math.nan] * 3), "lag[0]"),
        (lambda m: m.update(step=[0, 1, -2]), "step"),
    ],
)
def test_bad_telemetry_names_the_field(change: object, field: str) -> None:
    commands = tuple(Command(k, k / 1000, (1.0,) * 8) for k in range(3))
    raw = msgpack.unpackb(Telemetry(_states(3), commands, (0.0,) * 3).encode())
    change(raw)  # type: ignore[operator]
    with pytest.raises(ProtocolError) as err:
        Telemetry.decode(msgpack.packb(raw), cables=8)
    assert str(err.value).startswith(f"{field}:"), str(err.value)


def test_a_tick_never_grants_backwards() -> None:
    raw = msgpack.unpackb(Tick(5, 0.005, 9).encode())
    raw["until"] = 4
    with pytest.raises(ProtocolError, match=r"^until: must be >= step"):
        Tick.decode(msgpack.packb(raw))


def _cmd(**fields: object) -> bytes:
    base: dict[str, object] = {"v": PROTOCOL_VERSION, "step": 1, "t": 0.001, "tensions": [1.0] * 8}
    base.update(fields)
    return msgpack.packb({k: v for k, v in base.items() if v is not None})


@pytest.mark.parametrize(
    ("payload", "field"),
    [
        (b"\xc1", "payload"),
        (msgpack.packb([1, 2]), "payload"),
        (_cmd(v=1), "v"),  # a protocol version 1 peer: refused, naming the version
        (_cmd(v=None), "v"),
        (_cmd(step=None), "step"),
        (_cmd(step=-1), "step"),
        (_cmd(step=1.5), "step"),
        (_cmd(step=True), "step"),
        (_cmd(t=math.inf), "t"),
        (_cmd(t="now"), "t"),
        (_cmd(tensions=[1.0] * 7), "tensions"),
        (_cmd(tensions="many"), "tensions"),
        (_cmd(tensions=[1.0] * 7 + [math.nan]), "tensions[7]"),
        (_cmd(tensions=[1.0] * 7 + [None]), "tensions[7]"),
        (_cmd(feasible="yes"), "feasible"),
    ],
)
def test_bad_command_names_the_field(payload: bytes, field: str) -> None:
    with pytest.raises(ProtocolError) as err:
        Command.decode(payload, cables=8)
    message = str(err.value)
    assert message.startswith(f"{field}:"), message
    assert "\n" not in message


def test_state_lengths_must_agree() -> None:
    raw = msgpack.unpackb(State(1, 0.001, (0,) * 7, (0,) * 6, (1.0,) * 8, (1.0,) * 8).encode())
    raw["tensions"] = [1.0] * 4
    with pytest.raises(ProtocolError, match=r"^tensions: expected 8 numbers"):
        State.decode(msgpack.packb(raw))
    with pytest.raises(ProtocolError, match=r"^cable_lengths: expected 4 numbers"):
        State.decode(State(1, 0.001, (0,) * 7, (0,) * 6, (1.0,) * 8, (1.0,) * 8).encode(), cables=4)


def test_session_ids_are_checked() -> None:
    assert Keys("lab-1_a").state == "cdpr/lab-1_a/sim/state"
    for bad in ("", "a/b", "x*", "a" * 65, "white space"):
        with pytest.raises(ValueError, match="session id"):
            Keys(bad)


def test_every_fault_counter_of_a_subscribed_topic_is_documented() -> None:
    for name, topic in TOPICS.items():
        if wiring.subscribers(name) and topic.bad:
            assert f"`{topic.bad}`" in DOC, f"{topic.bad} (dropping a bad {name}) missing from docs/protocol.md"


def test_a_commands_estimate_round_trips_alone_and_in_telemetry_and_a_bad_one_is_refused_by_name() -> None:
    """``Command.estimate`` (a controller fed from the sensors): 13 numbers, on the command and in the sim's telemetry
    (flat over the commands that have one, ``estimate_rows`` when not all do); both decoders agree."""
    from cdpr.protocol.streams import ESTIMATE_WIDTH

    assert ESTIMATE_WIDTH == 13
    estimate = tuple(0.5 + i for i in range(13))
    cmd = Command(7, 0.007, (1.0, 2.0, 3.0, 4.0), estimate=estimate)
    assert Command.decode(cmd.encode()) == cmd == Command._checked(cmd.encode())
    assert "estimate" not in msgpack.unpackb(Command(7, 0.007, (1.0,) * 4).encode())  # absent: the wire as before
    raw = msgpack.unpackb(cmd.encode())
    for bad, says in ((list(estimate[:12]), "estimate: expected 13 numbers, got 12"),
                      ([*estimate[:12], float("nan")], "estimate[12]: must be finite")):
        with pytest.raises(ProtocolError, match=re.escape(says)):
            Command.decode(msgpack.packb({**raw, "estimate": bad}))
    states = _states(3)
    commands = (Command(0, 0.0, (1.0,) * 8, estimate=estimate), Command(1, 0.001, (1.0,) * 8),
                Command(2, 0.002, (1.0,) * 8, estimate=estimate[::-1]))
    block = Telemetry(states, commands, (1e-4,) * 3)
    wire = msgpack.unpackb(block.encode())["command"]
    assert wire["estimate_rows"] == [0, 2]
    assert len(wire["estimate"]) == 26
    assert Telemetry.decode(block.encode(), 8).commands == commands == Telemetry._checked(block.encode(), 8).commands
    every = Telemetry(states, tuple(c if c.estimate else Command(1, 0.001, (1.0,) * 8, estimate=estimate)
                                    for c in commands), (1e-4,) * 3)
    assert "estimate_rows" not in msgpack.unpackb(every.encode())["command"]
    assert Telemetry.decode(every.encode(), 8) == every
    for change, says in (({"estimate_rows": [0, 3]}, "command.estimate_rows: expected distinct rows below 3"),
                         ({"estimate": wire["estimate"][:-1]}, "estimate: expected 26 numbers, got 25")):
        bad = msgpack.unpackb(block.encode())
        bad["command"].update(change)
        with pytest.raises(ProtocolError, match=re.escape(says)):
            Telemetry.decode(msgpack.packb(bad), 8)
