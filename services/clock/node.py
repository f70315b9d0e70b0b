"""The clock node: waits for every expected participant, then issues ticks (see :mod:`cdpr_clock.core`).

It publishes ``clock/status`` on every change and once a second, pauses while an expected participant
has no liveliness token, repeats the ticks of an unfinished step after a stall (``resend_after``) or a
resume, answers ``session/info`` queries with the scenario, and ends the session with a ``finished``
status once the sim has published its last state.
"""

from __future__ import annotations

import time
from collections.abc import Sequence
from typing import Any

import msgpack
import zenoh

from cdpr.protocol import PROTOCOL_VERSION, Keys, ProtocolError, ServiceStats, State, Status, Tick
from cdpr.scenario import Scenario
from cdpr.service import Node
from cdpr.transport import PUBLISH_OPTS, Event, Inbox, RateLimitedLog, log
from cdpr_clock.core import ClockCore

LINGER = 2.0  # seconds the clock keeps announcing "finished" while participants leave


class ClockNode(Node):
    name = "clock"
    direct = True  # handled on Zenoh's receive thread: no hand-off between a message and its answer

    def __init__(
        self,
        scenario: Scenario,
        keys: Keys,
        expected: Sequence[str] = ("sim", "trajectory", "controller"),
        realtime: bool = False,
        lookahead: int = 1,
        resend_after: float = 1.0,
        status_period: float = 1.0,
    ) -> None:
        super().__init__(keys)
        self.scenario = scenario
        self.core = ClockCore(scenario.total_steps, scenario.dt, realtime=realtime, lookahead=lookahead)
        self.expected = tuple(expected)
        self.present: set[str] = set()
        self.resend_after = resend_after
        self.status_period = status_period
        self.last_status = 0.0
        self.state = "waiting"
        self.reason = ""
        self.finished_at: float | None = None
        self.faults: dict[str, dict[str, int]] = {}  # every service's fault counters (stats/{service})
        self.warn = RateLimitedLog(self.name)
        self._tick: zenoh.Publisher | None = None
        self._status: zenoh.Publisher | None = None
        self._info = msgpack.packb({"v": PROTOCOL_VERSION, **scenario.info()}, use_bin_type=True)

    @property
    def missing(self) -> tuple[str, ...]:
        return tuple(s for s in self.expected if s not in self.present)

    def declare(self, session: zenoh.Session, inbox: Inbox) -> list[Any]:
        self._tick = session.declare_publisher(self.keys.tick, **PUBLISH_OPTS)
        self._status = session.declare_publisher(self.keys.status, **PUBLISH_OPTS)
        info = self._info

        def on_query(query: zenoh.Query) -> None:
            query.reply(query.key_expr, info)

        return [
            inbox.subscribe(session, self.keys.state, "state"),
            inbox.subscribe(session, self.keys.stats_all, "stats"),
            inbox.watch_liveliness(session, self.keys.alive_all),
            session.declare_queryable(self.keys.info, on_query),
            self._tick,
            self._status,
        ]

    def on_status(self, status: Status) -> None:
        """The clock publishes the status; it does not obey it."""

    # -- events -----------------------------------------------------------------------------------
    def handle(self, event: Event) -> None:
        now = time.monotonic()
        if event.kind == "state":
            try:
                state = State.decode(event.payload)
            except ProtocolError as exc:
                self.count("bad_states")
                self.warn("bad_state", f"dropped a bad sim/state: {exc}")
                return
            if state.step < self.core.reached:
                # Only a sim that started afresh goes back in time (a reconnecting sim, e.g. after a
                # router restart, carries on from its step): the platform's state is lost.
                self.abort(f"the sim restarted: its state went back from step {self.core.reached} to "
                           f"step {state.step}; the platform's state is lost", now)
                return
            self.core.on_state(state.step, now)
            if self.core.finished and self.finished_at is None:
                self.finish(now)
            return
        if event.kind == "stats":
            try:
                stats = ServiceStats.decode(event.payload)
            except ProtocolError as exc:
                self.count("bad_stats")
                self.warn("bad_stats", f"dropped a bad stats message: {exc}")
                return
            self.faults[stats.service] = stats.counters
            return
        service = event.key.rsplit("/", 1)[-1]
        if event.kind == "alive":
            self.present.add(service)
        else:
            self.present.discard(service)
            if service in self.expected and self.finished_at is None:
                log(self.name, f"{service} left the session at step {self.core.reached}")
        if self.finished_at is not None:
            return
        if self.missing:
            if not self.core.paused:
                self.core.pause(now)
                self.set_state("paused", f"waiting for {', '.join(self.missing)}", now)
        elif self.core.paused:
            resend = self.core.resume(now)
            if self.core.started_at is not None and resend:
                log(self.name, f"all participants back; resuming at step {self.core.reached}")
                self.send_ticks(resend, now, again=True)
            self.set_state("running", "", now)

    # -- ticking ----------------------------------------------------------------------------------
    def timeout(self, now: float) -> float:
        wait = self.core.wait_time(now)
        return self.idle_period if wait is None else min(wait, self.idle_period)

    def idle(self, now: float) -> None:
        if self.finished_at is not None:
            if now - self.last_status >= 0.25:
                self.publish_status(now)
            if not (set(self.expected) & self.present) or now - self.finished_at > LINGER:
                self.done = True
            return
        while (k := self.core.next_tick(time.monotonic())) is not None:
            self.send_ticks([k], time.monotonic())
        if (
            not self.core.paused
            and self.core.started_at is not None
            and now - self.core.last_progress > self.resend_after
        ):
            pending = self.core.pending_ticks()
            self.warn("stall", f"no progress for {self.resend_after:g} s at step {self.core.reached}; "
                      f"repeating tick(s) {pending}")
            self.send_ticks(pending, now, again=True)
            self.core.last_progress = now
        if now - self.last_status >= self.status_period:
            self.publish_status(now)

    def send_ticks(self, steps: list[int], now: float, again: bool = False) -> None:
        assert self._tick is not None
        for k in steps:
            if again:
                self.core.resends += 1
            else:
                self.core.issue(k, now)
            self._tick.put(Tick(k, k * self.core.dt).encode())

    # -- status -----------------------------------------------------------------------------------
    def set_state(self, state: str, reason: str, now: float) -> None:
        self.state, self.reason = state, reason
        if reason:
            log(self.name, f"{state}: {reason}")
        self.publish_status(now)

    def publish_status(self, now: float) -> None:
        assert self._status is not None
        final = self.finished_at is not None
        stats = self.core.stats(self.finished_at if final else now, exact=final)
        faults = {**self.faults, "clock": dict(self.counters)} if self.counters else dict(self.faults)
        stats["faults"] = {k: v for k, v in faults.items() if v}
        status = Status(
            state=self.state,
            step=max(self.core.reached, 0),
            t=max(self.core.reached, 0) * self.core.dt,
            total_steps=self.core.total_steps,
            missing=self.missing,
            reason=self.reason,
            stats=stats,
        )
        self._status.put(status.encode())
        self.final_status = status
        self.last_status = now

    def abort(self, reason: str, now: float) -> None:
        self.finished_at = now
        self.exit_code = 1
        self.set_state("aborted", reason, now)

    def finish(self, now: float) -> None:
        self.finished_at = now
        self.set_state("finished", "", now)
        st = self.core.stats(now)
        log(self.name, f"finished {st['steps']} steps in {st['wall_time']:.2f} s "
            f"({st['rate']:.0f} steps/s, RTF {st['rtf']:.2f}, late ticks {st['late_ticks']}, resends {st['resends']})")
