"""Property-based fuzzing: thousands of random payloads fired at a running sim never stop the session."""

from __future__ import annotations

import subprocess
import time

import msgpack
import pytest
import zenoh
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cdpr.protocol import Keys, Status
from cdpr.runtime.transport import zenoh_config
from conftest import CDPR, free_port, last_json_line

pytestmark = pytest.mark.slow

EXAMPLES = 12_000

numbers = st.one_of(
    st.integers(min_value=-(2**63), max_value=2**64 - 1),
    st.floats(allow_nan=True, allow_infinity=True),
)
values = st.recursive(
    st.one_of(st.none(), st.booleans(), numbers, st.text(max_size=8), st.binary(max_size=8)),
    lambda inner: st.one_of(st.lists(inner, max_size=10), st.dictionaries(st.text(max_size=6), inner, max_size=4)),
    max_leaves=6,
)
keys = st.sampled_from(["v", "step", "t", "tensions", "pose", "feasible", "status", "x"])
protocolish = st.fixed_dictionaries(
    {"v": st.one_of(st.just(1), values), "step": st.one_of(st.integers(-5, 5000), values)},
    optional={
        "t": st.one_of(st.floats(), values),
        "tensions": st.one_of(st.lists(numbers, min_size=0, max_size=10), values),
        "feasible": values,
        "status": values,
    },
)
payloads = st.one_of(
    st.binary(max_size=64),
    values.map(lambda v: msgpack.packb(v, use_bin_type=True)),
    st.dictionaries(keys, values, max_size=6).map(lambda d: msgpack.packb(d, use_bin_type=True)),
    protocolish.map(lambda d: msgpack.packb(d, use_bin_type=True)),
)


def generate(n: int) -> list[tuple[bytes, bytes]]:
    """n hypothesis-drawn (command payload, tick noise) pairs, drawn before the session starts."""
    drawn: list[tuple[bytes, bytes]] = []

    @settings(max_examples=n, deadline=None, database=None, derandomize=True, suppress_health_check=list(HealthCheck))
    @given(payloads, st.binary(max_size=32))
    def draw(payload: bytes, noise: bytes) -> None:
        drawn.append((payload, noise + b"\xc1"))  # 0xc1 is never valid msgpack: the tick noise never decodes

    draw()
    return drawn


def test_random_payloads_do_not_stop_the_sim(session_id: str) -> None:
    drawn = generate(EXAMPLES)
    assert len(drawn) >= 10_000
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    k = Keys(session_id)
    up = subprocess.Popen(
        [*CDPR, "up", "caroca_15kg", "--duration", "6", "--session", session_id, "--listen", endpoint, "--quiet"],
        stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
    )
    fired = 0
    try:
        with zenoh.open(zenoh_config("client", connect=[endpoint])) as z:
            status = z.declare_subscriber(k.status)
            deadline = time.monotonic() + 60
            while (sample := status.try_recv()) is None or Status.decode(sample.payload.to_bytes()).state != "running":
                assert time.monotonic() < deadline
                assert up.poll() is None
                time.sleep(0.005)
            command, tick = z.declare_publisher(k.command), z.declare_publisher(k.tick)
            # Any payload on the command key; undecodable noise on the tick key (a *valid* tick from
            # anyone is obeyed: restricting clock/tick to the clock is the ACL's job, docs/security.md).
            for payload, noise in drawn:
                command.put(payload)
                tick.put(noise)
                fired += 1
            assert up.poll() is None, "the session ended before all payloads were fired"
        out, err = up.communicate(timeout=120)
    finally:
        if up.poll() is None:
            up.kill()
    assert fired == len(drawn)
    s = last_json_line(out)
    assert s["exit_ok"] is True, err[-3000:]
    assert s["steps"] == s["total_steps"]
    assert s["faults"]["sim"]["bad_commands"] > 1000
    assert s["faults"]["sim"]["bad_ticks"] > 1000
