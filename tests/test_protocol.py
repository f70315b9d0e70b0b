"""The wire protocol module and its document stay in step; messages round-trip; bad ones name the field."""

from __future__ import annotations

import math
import re
from pathlib import Path

import msgpack
import pytest

from cdpr.protocol import WIRING, Command, Keys, ProtocolError, Setpoint, State, Status, Tick

DOC = (Path(__file__).resolve().parents[1] / "docs" / "protocol.md").read_text(encoding="utf-8")


def test_every_key_is_documented() -> None:
    for name, key in Keys("s").table().items():
        doc_key = key.replace("cdpr/s/", "cdpr/{session}/")
        assert f"`{doc_key}`" in DOC, f"{name} key {doc_key} missing from docs/protocol.md"


def test_wiring_table_matches_the_document() -> None:
    rows = {m.group(1): m for m in re.finditer(r"^\| (\w+)\s*\| `[^`]+`\s*\| ([^|]+)\| ([^|]+)\|$", DOC, re.M)}
    for name, wiring in WIRING.items():
        assert name in rows, f"{name} missing from the key table"
        publishers = rows[name].group(2)
        for p in wiring["publishers"]:
            assert p in publishers, (name, p)
        subscribers = rows[name].group(3)
        for s in wiring["subscribers"]:
            assert s in subscribers or "every service" in subscribers


def test_services_wire_as_the_table_says() -> None:
    """Each service's node subscribes and publishes exactly the keys WIRING gives it."""
    root = Path(__file__).resolve().parents[1] / "services"
    for service in ("sim", "trajectory", "controller", "clock", "recorder"):
        code = (root / service / "node.py").read_text(encoding="utf-8")
        subscribed = {k.removesuffix("_all") for k in re.findall(r"inbox\.subscribe\(session, self\.keys\.(\w+)", code)}
        published = set(re.findall(r"declare_publisher\(self\.keys\.(\w+)", code))
        want_sub = {k for k, w in WIRING.items() if service in w["subscribers"]} - {"status"}
        want_pub = {k for k, w in WIRING.items() if service in w["publishers"]} - {"info", "stats"}
        assert subscribed == want_sub, service
        assert published == want_pub, service


@pytest.mark.parametrize(
    "msg",
    [
        Tick(3, 0.003),
        State(5, 0.005, (1, 2, 3, 0, 0, 0, 1), (0.1,) * 6, (4.0,) * 8, (10.0,) * 8, 2),
        Setpoint(5, 0.005, (1, 2, 3, 0, 0, 0, 1), (0.0,) * 6, (0.5,) * 6),
        Command(5, 0.005, (1.0,) * 8, False, "infeasible"),
        Status("running", 7, 0.007, 100, ("controller",), "why", {"rate": 1.5}),
    ],
)
def test_round_trip(msg: object) -> None:
    cls = type(msg)
    back = cls.decode(msg.encode())  # type: ignore[attr-defined]
    assert back == cls.decode(back.encode())
    for field in ("step", "t"):
        assert getattr(back, field) == getattr(msg, field)
    raw = msgpack.unpackb(msg.encode())  # type: ignore[attr-defined]
    assert raw["v"] == 1


def _cmd(**fields: object) -> bytes:
    base: dict[str, object] = {"v": 1, "step": 1, "t": 0.001, "tensions": [1.0] * 8}
    base.update(fields)
    return msgpack.packb({k: v for k, v in base.items() if v is not None})


@pytest.mark.parametrize(
    ("payload", "field"),
    [
        (b"\xc1", "payload"),
        (msgpack.packb([1, 2]), "payload"),
        (_cmd(v=2), "v"),
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
