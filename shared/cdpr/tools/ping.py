"""``cdpr ping``: the round trip from here to a session's participant, and whether it fits the session's dt.

Every service answers ``ping/{service}`` (a Zenoh queryable, docs/protocol.md) with the payload it was sent,
on Zenoh's own thread: the measure is the link (through the router, as a controller's messages go), not the
service's load. A lock-step realtime session needs, every step, a state to reach the controller and its
command to come back: the round trip plus the controller's answer must fit in dt. Free-running realtime
keeps the wall clock whatever the link, and the command then acts about ``round trip / dt`` steps late.
"""

from __future__ import annotations

import math
import threading
import time
from dataclasses import dataclass
from typing import Any

import numpy as np
import zenoh

from cdpr.protocol import Keys
from cdpr.runtime.client import fetch_info

PAYLOAD = 400  # bytes sent each time: about a state message of an 8-cable robot


@dataclass(frozen=True)
class PingResult:
    node: str
    sent: int
    answered: int
    round_trips: tuple[float, ...]  # s, in order
    dt: float | None  # the session's step, if its clock answered session/info

    def summary(self) -> dict[str, Any]:
        rt = np.asarray(self.round_trips) * 1e3
        out: dict[str, Any] = {"node": self.node, "sent": self.sent, "answered": self.answered}
        if rt.size:
            p50, p90, p99 = (float(x) for x in np.percentile(rt, [50, 90, 99]))
            out.update(round_trip_p50_ms=p50, round_trip_p90_ms=p90, round_trip_p99_ms=p99,
                       round_trip_max_ms=float(rt.max()))
        if self.dt is not None:
            out["dt_ms"] = self.dt * 1e3
            if rt.size:
                out["lock_step_realtime_fits"] = bool(out["round_trip_p99_ms"] < self.dt * 1e3)
                out["free_running_command_age_steps"] = math.ceil(out["round_trip_p50_ms"] / (self.dt * 1e3))
        return out

    def verdict(self) -> str:
        s = self.summary()
        if not self.answered:
            return f"no answer from {self.node}: is the session running (cdpr up), and --session right?"
        line = (f"round trip to {self.node}: median {s['round_trip_p50_ms']:.3f} ms, p99 "
                f"{s['round_trip_p99_ms']:.3f} ms, max {s['round_trip_max_ms']:.3f} ms "
                f"({self.answered} of {self.sent})")
        if self.dt is None:
            return line + "; no clock answered session/info, so no dt to compare with"
        dt_ms = self.dt * 1e3
        if s["lock_step_realtime_fits"]:
            return line + (f"; fits dt = {dt_ms:g} ms: lock-step realtime can keep up if the controller answers "
                           f"within the {dt_ms - s['round_trip_p99_ms']:.3f} ms left")
        return line + (f"; does not fit dt = {dt_ms:g} ms: lock-step realtime would fall behind; use --sync free "
                       f"(commands about {s['free_running_command_age_steps']} steps old) or --mode fast")


def ping(session: zenoh.Session, keys: Keys, node: str = "sim", count: int = 200, interval: float = 0.005,
         timeout: float = 2.0, info_timeout: float = 3.0, wait: float = 10.0) -> PingResult:
    """``count`` gets of ``ping/{node}``, one at a time, ``interval`` s apart; the session's dt from its clock.
    First it waits (at most ``wait`` s) for the node's liveliness token, which the node declares after its
    ping queryable: pinged right after ``cdpr up``, a starting node is waited for, not counted as silent."""
    key = keys.topic("ping", node)
    payload = bytes(PAYLOAD)
    trips: list[float] = []
    there = threading.Event()

    def on_token(sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            there.set()

    watch = session.liveliness().declare_subscriber(keys.alive(node), zenoh.handlers.Callback(on_token, indirect=False),
                                                    history=True)
    there.wait(wait)
    watch.undeclare()
    for _ in range(3):  # warm the route (the first query also resolves it)
        for _reply in session.get(key, payload=payload, timeout=timeout):
            pass
    for _ in range(count):
        start = time.perf_counter()
        got = False
        for reply in session.get(key, payload=payload, timeout=timeout):
            if reply.ok is not None and not got:
                got = True
                trips.append(time.perf_counter() - start)
        time.sleep(interval)
    info = fetch_info(session, keys, timeout=info_timeout, who="ping")
    return PingResult(node, count, len(trips), tuple(trips), None if info is None else info.dt)
