"""The Zenoh round trip between two processes: ``python -P .../zenoh_rtt.py echo|ping ...``.

The two processes run this file by its path, not as ``-m cdpr.tools.bench.zenoh_rtt``: that would import the
package ``cdpr.tools.bench`` first (the whole bench, ~0.7 s of CPU each), and they need only the transport.
"""

from __future__ import annotations

import json
import math
import statistics
import struct
import subprocess
import sys
import threading
import time
from typing import Any

# --------------------------------------------------------------------------------------------------
# 3. The Zenoh round trip: `python -P zenoh_rtt.py echo|ping ENDPOINT ...`

_PING, _PONG = "cdpr/bench-rtt/ping", "cdpr/bench-rtt/pong"
_RTT_PAYLOAD = 240  # bytes, about a state message of 8 cables


def _rtt_config(endpoint: str, mode: str, listen: str) -> Any:
    """Clients of the router at ``endpoint``, or peers that meet through it and link directly, each listening
    at ``listen`` (as the services of ``cdpr run`` do: :data:`cdpr.tools.launch.PEER_LISTEN`)."""
    from cdpr.runtime.transport import zenoh_config

    if mode == "peer":
        return zenoh_config("peer", connect=[endpoint], listen=[listen])
    return zenoh_config("client", connect=[endpoint])


def _rtt_echo(endpoint: str, mode: str, listen: str) -> None:
    """Answer every ping with the same payload, from the Inbox callback (as the services do)."""
    from cdpr.runtime.transport import PUBLISH_OPTS, Inbox, open_session

    done = threading.Event()
    with open_session(_rtt_config(endpoint, mode, listen), "bench echo") as session:
        pub = session.declare_publisher(_PONG, **PUBLISH_OPTS)

        def on_ping(event: Any) -> None:
            if event.payload == b"stop":
                done.set()
            else:
                pub.put(event.payload)

        sub = Inbox(on_ping).subscribe(session, _PING, "ping")
        c0 = time.process_time()
        done.wait(600.0)
        print(json.dumps({"cpu_s": time.process_time() - c0}), flush=True)
        sub.undeclare()
        pub.undeclare()


def _rtt_ping(endpoint: str, count: int, mode: str, listen: str, warmup: int = 300) -> None:
    """Ping-pong ``count`` times (after ``warmup``), the next ping sent from the pong's callback."""
    from cdpr.runtime.transport import PUBLISH_OPTS, Inbox, open_session

    rtts: list[float] = []
    seq = [-1]  # the sequence number in flight; negative while probing for the echo
    sent_at = [0.0]
    started, done = threading.Event(), threading.Event()
    cpu = [0.0]
    with open_session(_rtt_config(endpoint, mode, listen), "bench ping") as session:
        pub = session.declare_publisher(_PING, **PUBLISH_OPTS)
        pad = bytes(_RTT_PAYLOAD - 8)

        def send(i: int) -> None:
            seq[0] = i
            sent_at[0] = time.perf_counter()
            pub.put(struct.pack("<q", i) + pad)

        def on_pong(event: Any) -> None:
            now = time.perf_counter()
            (i,) = struct.unpack_from("<q", event.payload)
            if i != seq[0]:
                return  # a late answer to an earlier probe
            if i < 0:  # a probe came back: the echo listens, the sequence starts
                started.set()
                nxt = 0
            else:
                if i >= warmup:
                    rtts.append(now - sent_at[0])
                nxt = i + 1
            if nxt == warmup:
                cpu[0] = time.process_time()
            if nxt >= warmup + count:
                cpu[0] = time.process_time() - cpu[0]
                done.set()
                return
            send(nxt)

        sub = Inbox(on_pong).subscribe(session, _PONG, "pong")
        probe = -1
        while not started.is_set():  # the echo may not be listening yet
            send(probe)
            started.wait(0.2)
            probe -= 1
        done.wait(600.0)
        pub.put(b"stop")
        time.sleep(0.2)
        sub.undeclare()
        pub.undeclare()
    rtts.sort()
    print(json.dumps({
        "count": len(rtts),
        "median_us": 1e6 * statistics.median(rtts),
        "p99_us": 1e6 * rtts[min(len(rtts) - 1, int(0.99 * len(rtts)))],
        "min_us": 1e6 * rtts[0],
        "ping_cpu_us": 1e6 * cpu[0] / max(len(rtts), 1),
    }), flush=True)


def bench_zenoh_rtt(count: int) -> dict[str, Any]:
    """A router in this process, the echo and the pinger as two processes on loopback: first as clients
    of the router (two hops each way: how remote participants talk), then as peers linked directly
    (one hop each way: how the services of ``cdpr run`` talk, under ``peers``)."""
    result = _zenoh_rtt(count, "client")
    result["peers"] = _zenoh_rtt(count, "peer")
    return result


def _zenoh_rtt(count: int, mode: str) -> dict[str, Any]:
    from cdpr.runtime.transport import open_session, zenoh_config
    from cdpr.tools.launch import PEER_LISTEN, free_port

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    script = [sys.executable, "-P", __file__]  # -P: not this file's folder first on sys.path (gym.py, …)
    with open_session(zenoh_config("router", listen=[endpoint]), "bench router"):
        echo = subprocess.Popen([*script, "echo", endpoint, mode, PEER_LISTEN], stdout=subprocess.PIPE, text=True)
        try:
            ping = subprocess.run([*script, "ping", endpoint, str(count), mode, PEER_LISTEN], capture_output=True,
                                  text=True, timeout=600, check=False)
            echo_out, _ = echo.communicate(timeout=30)
        finally:
            if echo.poll() is None:
                echo.kill()
    if ping.returncode != 0 or not ping.stdout.strip():
        raise RuntimeError(f"the Zenoh ping ({mode}) failed: {ping.stderr.strip()[-500:]}")
    result: dict[str, Any] = json.loads(ping.stdout.strip().splitlines()[-1])
    echo_cpu = json.loads(echo_out.strip().splitlines()[-1])["cpu_s"] if echo_out.strip() else math.nan
    result["echo_cpu_us"] = 1e6 * echo_cpu / max(result["count"], 1)
    result["one_way_us"] = result["median_us"] / 2.0
    result["payload_bytes"] = _RTT_PAYLOAD
    return result


if __name__ == "__main__":  # helper processes of the round-trip benchmark
    role, *rest = sys.argv[1:]
    if role == "echo":
        _rtt_echo(rest[0], rest[1], rest[2])
    elif role == "ping":
        _rtt_ping(rest[0], int(rest[1]), rest[2], rest[3])
    else:
        raise SystemExit(f"unknown role {role!r}")
