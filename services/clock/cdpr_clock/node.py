"""The clock node: waits for every expected participant, then issues ticks (see :mod:`cdpr_clock.core`).

It publishes ``clock/status`` on every change and once a second, pauses while an expected participant
has no liveliness token, repeats the ticks of an unfinished step after a stall (``resend_after``) or a
resume, answers ``session/info`` queries with the scenario, and ends the session with a ``finished``
status once the sim has published its last state.
"""

from __future__ import annotations

import argparse
import statistics
import time
from collections.abc import Sequence
from typing import Any

import zenoh

from cdpr.config.scenario import Scenario
from cdpr.errors import InputError
from cdpr.protocol import SERVICES, ClockState, Keys, Resume, Status, Telemetry, Tick
from cdpr.protocol.session import encode_session_info
from cdpr.runtime.service import Node
from cdpr.runtime.transport import Event, Inbox, log, may_be_denied
from cdpr_clock.core import ClockCore

LINGER = 2.0  # seconds the clock keeps announcing "finished" while participants leave
HANDSHAKE_FIRST_REPEAT = 0.05  # s: tick 0 is repeated after this, then twice as long each time (core docstring)
WAIT_LOG_FIRST, WAIT_LOG_EVERY = 2.0, 5.0  # "waiting for ..." lines before the start: the first, then every
PACE_CHECK_PERIOD = 0.25  # s between two looks at the share of late ticks of the last second (realtime)
# the topics every lock-step step needs, in the order they go: the grant, the state and the setpoint, the command,
# the sim's report (docs/protocol.md, "One step")
LOOP_TOPICS = ("tick", "state", "setpoints", "command", "telemetry")
REJOIN_TIMEOUT = 60.0  # s a participant that left a session under way may take to come back (--rejoin-timeout)


class ClockNode(Node):
    name = "clock"
    direct = True  # handled on Zenoh's receive thread: no hand-off between a message and its answer

    def __init__(
        self,
        scenario: Scenario,
        keys: Keys,
        expected: Sequence[str] = ("sim", "trajectory", "controller"),
        realtime: bool = False,
        lookahead: int = 100,
        free: bool = False,
        max_lateness: float = 0.0,
        resend_after: float = 1.0,
        status_period: float = 1.0,
        join_timeout: float = 0.0,
        rejoin_timeout: float = REJOIN_TIMEOUT,
    ) -> None:
        super().__init__(keys)
        self.scenario = scenario
        self.m = scenario.robot.m
        self.core = ClockCore(scenario.total_steps, scenario.dt, realtime=realtime, lookahead=lookahead, free=free)
        sim = scenario.spec.sim
        self.watchdog = sim.watchdog
        self.ages = free or sim.command_latency is not None  # the states carry command ages to count
        self.max_lateness = max_lateness  # s: abort when a tick (a step, free-running) is later (0: never)
        self.last_pace_check = 0.0
        self.stalls = 0  # grants repeated after a stall
        self.diagnosed = False  # the one-line diagnosis of a realtime session falling behind (given once)
        self.lags: list[float] = []  # the sim's wait for each command (telemetry), since the last check_pace()
        self.expected = tuple(expected)
        self.present: set[str] = set()
        self.resend_after = resend_after
        self.status_period = status_period
        self.last_status = 0.0
        self.state: ClockState = "waiting"
        self.reason = ""
        self.finished_at: float | None = None
        self.faults: dict[str, dict[str, int]] = {}  # every service's fault counters (stats/{service})
        self.join_timeout = join_timeout  # seconds for every participant to join (0: no limit)
        self.rejoin_timeout = rejoin_timeout  # seconds a participant that left may take to come back (0: no limit)
        self._gone: dict[str, tuple[float, int]] = {}  # participants that left after the start: (when, step)
        self._waiting_since: float | None = None  # the first idle() in state "waiting"
        self._next_wait_log = 0.0
        self._tick: zenoh.Publisher | None = None
        self._resume: zenoh.Publisher | None = None
        self.resume: Resume | None = None  # the sim's last snapshot
        self._status: zenoh.Publisher | None = None
        self._info = encode_session_info(scenario)

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        g = parser.add_argument_group("clock")
        g.add_argument("--mode", choices=("fast", "realtime"), default="fast", help="(default: %(default)s)")
        g.add_argument("--sync", choices=("lock", "free"), default="lock",
                       help="realtime: lock (every step waits for its command: lock-step) or free (the sim runs "
                            "on the wall clock with the newest command; docs/realtime.md) (default: %(default)s)")
        g.add_argument("--max-lateness", type=float, default=0.0, metavar="S",
                       help="realtime: abort (exit code 1) once a step is S seconds behind the wall clock "
                            "(0: never; default: %(default)s)")
        g.add_argument("--expect", default="sim,trajectory,controller",
                       help="comma-separated participants to wait for (default: %(default)s)")
        g.add_argument("--lookahead", type=int, default=100, metavar="STEPS",
                       help="steps granted ahead of the sim's last reported state (0: a strict one-step "
                            "handshake, with a report every step; default: %(default)s)")
        g.add_argument("--resend-after", type=float, default=1.0, metavar="S",
                       help="seconds without progress before the pending ticks are repeated (default: %(default)s)")
        g.add_argument("--join-timeout", type=float, default=0.0, metavar="S",
                       help="abort (exit code 1) if a participant has not joined S seconds after the start "
                            "(0: wait for ever; default: %(default)s)")
        g.add_argument("--rejoin-timeout", type=float, default=REJOIN_TIMEOUT, metavar="S",
                       help="abort (exit code 1) if a participant that left a session under way has not come "
                            "back within S seconds (0: wait for ever; default: %(default)s)")

    @classmethod
    def from_args(cls, scenario: Scenario, keys: Keys, args: argparse.Namespace) -> ClockNode:
        names = tuple(s.strip() for s in args.expect.split(",") if s.strip())
        unknown = [n for n in names if n not in SERVICES or n == "clock"]
        if unknown:
            raise InputError(f"--expect: unknown participant(s) {', '.join(unknown)}")
        if not 0 <= args.lookahead <= 100_000:
            raise InputError(f"--lookahead: must be between 0 and 100000 steps, got {args.lookahead}")
        if not args.resend_after >= 0.01:
            raise InputError(f"--resend-after: must be at least 0.01 s, got {args.resend_after}")
        if args.sync == "free" and args.mode != "realtime":
            raise InputError("--sync free: free-running needs --mode realtime (fast mode is lock-step)")
        if args.max_lateness and args.mode != "realtime":
            raise InputError("--max-lateness: only realtime sessions keep the wall clock (--mode realtime)")
        for flag, value in (("--join-timeout", args.join_timeout), ("--rejoin-timeout", args.rejoin_timeout),
                            ("--max-lateness", args.max_lateness)):
            if not value >= 0:
                raise InputError(f"{flag}: must be 0 (no limit) or a number of seconds, got {value}")
        return cls(scenario, keys, expected=names, realtime=args.mode == "realtime", lookahead=args.lookahead,
                   free=args.sync == "free", max_lateness=args.max_lateness, resend_after=args.resend_after,
                   join_timeout=args.join_timeout, rejoin_timeout=args.rejoin_timeout)

    @property
    def missing(self) -> tuple[str, ...]:
        return tuple(s for s in self.expected if s not in self.present)

    @property
    def blocking(self) -> tuple[str, ...]:
        """The missing participants the session pauses for: free-running, the sim runs on without a controller
        (its watchdog acts), once the session has started."""
        if self.core.free and self.core.started_at is not None:
            return tuple(s for s in self.missing if s != "controller")
        return self.missing

    scenario_checks = ("workspace",)  # the session's authority: a trajectory out of the workspace is refused

    def declare(self, session: zenoh.Session, inbox: Inbox) -> list[Any]:
        self._tick, self._status = self.publishers["tick"], self.publishers["status"]
        self._resume = self.publishers["resume"]
        return [inbox.watch_liveliness(session, self.keys.alive_all)]

    def reply(self, topic: str) -> bytes:
        return self._info  # session/info

    def on_status(self, status: Status) -> None:
        """The clock publishes the status; it does not obey it."""

    # -- events -----------------------------------------------------------------------------------
    def handle(self, event: Event) -> None:
        now = time.monotonic()
        if event.topic == "telemetry":
            block = self.decode(event, self.m)
            if block is None or not block.states:
                return
            step = block.states[-1].step
            if self.ages:
                self.on_ages(block, now)
            if block.lateness:
                self.core.on_lateness(block.lateness, now)
            if self.core.realtime and block.lags:
                self.lags.extend(block.lags)
            if step < self.core.reached:
                # Only a sim that started afresh goes back in time (a reconnecting sim, e.g. after a
                # router restart, carries on from its step): the platform's state is lost.
                self.abort(f"the sim restarted: its state went back from step {self.core.reached} to "
                           f"step {step}; the platform's state is lost", now)
                return
            self.core.on_state(step, now)
            if block.resume is not None and block.resume.step == step:
                self.resume = block.resume  # what a sim that replaces this one will need (docs/faults.md)
            if self.core.finished and self.finished_at is None:
                self.finish(now)
            return
        if event.topic == "stats":
            if (stats := self.decode(event)) is not None:
                self.faults[stats.service] = stats.counters
            return
        if event.topic == "end":  # a participant ends the session early (docs/protocol.md, session/end)
            if (end := self.decode(event)) is not None and self.finished_at is None:
                self.finish(now, f"ended by the {end.by} at step {max(self.core.reached, 0)}: {end.reason}")
            return
        service = event.key.rsplit("/", 1)[-1]
        if event.topic == "alive":
            self.present.add(service)
            self._gone.pop(service, None)
            if service == "sim" and self.core.started_at is not None and self.resume is not None \
                    and self.finished_at is None:
                # a sim (re)joins a session under way: the last snapshot first, then (below) the grant again;
                # a sim that kept its own state (a reconnection) ignores it
                assert self._resume is not None
                self._resume.put(self.resume.encode())
        else:
            self.present.discard(service)
            if service in self.expected and self.finished_at is None:
                log(self.name, f"{service} left the session at step {self.core.reached}")
                if self.state != "waiting":
                    self._gone.setdefault(service, (now, self.core.reached))
        if self.finished_at is not None:
            return
        if self.blocking:
            if not self.core.paused:
                self.core.pause(now)
                self.set_state("paused", f"waiting for {', '.join(self.blocking)}", now)
        elif event.topic == "alive" and self.core.free and service == "controller" and not self.core.paused:
            resend = self.core.pending()  # a controller back in a free-running session: the setpoints again
            if resend is not None:
                self.send_tick(resend[0], resend[1], now, resend=True)
        elif self.core.paused:
            resend = self.core.resume(now)
            if self.core.started_at is not None and resend is not None:
                log(self.name, f"all participants back; resuming at step {self.core.reached}")
                self.send_tick(resend[0], resend[1], now, resend=True)
            self.set_state("running", "", now)

    def on_ages(self, block: Telemetry, now: float) -> None:
        """Count the new states' command ages; the watchdog's abort policy ends the session."""
        news = [s for s in block.states if s.step > max(self.core.reached, 0)]
        tripped = [s.step for s in news if s.watchdog]
        self.core.on_ages([s.command_age for s in news], len(tripped))
        if tripped and self.watchdog.policy == "abort" and self.finished_at is None:
            self.abort(f"the controller sent no new command for {self.watchdog.timeout_ms:g} ms (watchdog at step "
                       f"{tripped[0] - 1}; policy abort)", now)

    # -- ticking ----------------------------------------------------------------------------------
    def timeout(self, now: float) -> float:
        repeat_at = self.core.handshake_repeat_due(HANDSHAKE_FIRST_REPEAT, self.resend_after)
        return self.idle_period if repeat_at is None else min(max(0.0, repeat_at - now), self.idle_period)

    def idle(self, now: float) -> None:
        if self.state == "waiting":
            self.check_joining(now)
        elif self._gone and self.finished_at is None:
            self.check_rejoining(now)
        if self.finished_at is not None:
            if now - self.last_status >= 0.25:
                self.publish_status(now)
            if not (set(self.expected) & self.present) or now - self.finished_at > LINGER:
                self.done = True
            return
        while (grant := self.core.next_grant(time.monotonic())) is not None:
            first, until, flush = grant
            self.send_tick(first, until, time.monotonic(), flush=flush)
        repeat_at = self.core.handshake_repeat_due(HANDSHAKE_FIRST_REPEAT, self.resend_after)
        if repeat_at is not None and now >= repeat_at and now - self.core.last_progress < self.resend_after:
            # state 1 not there yet: tick 0 again (quietly: a peer that has just joined may have missed it)
            self.core.last_progress = now
            self.send_tick(0, 0, now, resend=True, handshake=True)
        elif (
            not self.core.paused
            and self.core.started_at is not None
            and now - self.core.last_progress > self.resend_after
        ):
            pending = self.core.pending()
            if pending is not None:
                # the first time, the streams a step needs: one that never arrives is what a router's access
                # rules would make of a key its sender may not publish (docs/security.md)
                needed = "" if self.stalls else (
                    f" (a step needs {', '.join(self.keys.topic(t) for t in LOOP_TOPICS)}: "
                    f"{may_be_denied('one of them')})")
                self.stalls += 1
                self.warn("stall", f"no progress for {self.resend_after:g} s at step {self.core.reached}; "
                          f"repeating the grant of steps {pending[0]}-{pending[1]}{needed}")
                self.send_tick(pending[0], pending[1], now, resend=True)
            self.core.last_progress = now
        if self.core.realtime and now - self.last_pace_check >= PACE_CHECK_PERIOD:
            self.last_pace_check = now
            self.check_pace(now)
            if self.finished_at is not None:
                return
        if now - self.last_status >= self.status_period:
            self.publish_status(now)

    def send_tick(self, first: int, until: int, now: float, flush: bool = False, resend: bool = False,
                  handshake: bool = False) -> None:
        """Grant steps ``first`` … ``until`` (``resend``: again, asking for the current state; counted
        as a handshake repeat with ``handshake``, else as a resend)."""
        assert self._tick is not None
        if handshake:
            self.core.handshake_repeats += 1
        elif resend:
            self.core.resends += 1
        else:
            self.core.issue(first, now, until)
        paced = self.core.realtime and until >= 1  # after the handshake
        self._tick.put(Tick(first, first * self.core.dt, until, resend, flush or resend, paced and self.core.free,
                            paced).encode())

    # -- status -----------------------------------------------------------------------------------
    def set_state(self, state: ClockState, reason: str, now: float) -> None:
        self.state, self.reason = state, reason
        if reason:
            log(self.name, f"{state}: {reason}")
        self.publish_status(now)

    def check_pace(self, now: float) -> None:
        """Realtime: say once, in one line, when the session falls behind the wall clock, and what is slow;
        abort past ``--max-lateness``."""
        if not self.core.realtime or self.finished_at is not None or self.core.started_at is None:
            return
        share, n = self.core.late_share(now)
        lags, self.lags = self.lags, []
        behind = max(self.core.take_peak(), self.core.behind(now))
        if self.max_lateness > 0 and behind > self.max_lateness:
            self.abort(f"step {self.core.reached} is {behind:.3f} s behind the wall clock "
                       f"(--max-lateness {self.max_lateness:g} s)", now)
            return
        if self.diagnosed or n < 10 or share <= 0.1:
            return
        self.diagnosed = True
        dt_ms = self.core.dt * 1e3
        into = now - self.core.started_at - self.core.paused_time
        what = f"{share:.0%} of the steps of the last second were late ({into:.2f} s in, step {self.core.reached})"
        if self.core.free:
            log(self.name, f"free-running is falling behind the wall clock: {what}; the sim's steps take longer "
                f"than dt = {dt_ms:g} ms (a loaded machine?)")
            return
        if lags:
            lag = statistics.median(lags) * 1e3
            if lag > 0.5 * dt_ms:
                log(self.name, f"lock-step realtime is falling behind: {what}; after each state the sim waits "
                    f"{lag:.2f} ms (median) for the controller's command (its round trip and answer), against "
                    f"dt = {dt_ms:g} ms: use --sync free (commands then act a few steps late) or --mode fast")
                return
            log(self.name, f"lock-step realtime is falling behind: {what}; the controller answers in {lag:.2f} ms "
                f"(median) of dt = {dt_ms:g} ms, so the sim's steps are slow or start late (a loaded machine?): "
                "try --rt-priority and --cpu-latency 0, --mode fast or a longer dt")
            return
        log(self.name, f"lock-step realtime is falling behind: {what} (dt = {dt_ms:g} ms): use --sync free or "
            "--mode fast")

    def publish_status(self, now: float) -> None:
        assert self._status is not None
        final = self.finished_at is not None
        stats: dict[str, Any] = self.core.stats(now if self.finished_at is None else self.finished_at, exact=final)
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

    def check_joining(self, now: float) -> None:
        """Before the start: say who is missing every few seconds; abort once ``join_timeout`` has passed."""
        if self._waiting_since is None:
            self._waiting_since, self._next_wait_log = now, now + WAIT_LOG_FIRST
        waited = now - self._waiting_since
        if self.join_timeout > 0 and waited > self.join_timeout:
            joined = [s for s in self.expected if s in self.present]
            self.abort(f"{', '.join(self.missing)} did not join session {self.keys.session!r} within "
                       f"{self.join_timeout:g} s (joined: {', '.join(joined) or 'none'}; "
                       f"{may_be_denied(self.keys.alive(self.missing[0]))})", now)
        elif now >= self._next_wait_log:
            self._next_wait_log += WAIT_LOG_EVERY  # on a grid from the start (2, 7, 12 … s), however late this one
            log(self.name, f"waiting for {', '.join(self.missing)} to join session {self.keys.session!r} "
                f"({waited:.0f} s)")

    def check_rejoining(self, now: float) -> None:
        """Abort once a participant that left the session under way has stayed away ``rejoin_timeout`` s."""
        for service, (since, step) in self._gone.items():
            if self.rejoin_timeout > 0 and service in self.missing and now - since > self.rejoin_timeout:
                self.abort(f"{service} left the session at step {step} and did not come back within "
                           f"{self.rejoin_timeout:g} s", now)
                return

    def finish(self, now: float, reason: str = "") -> None:
        self.finished_at = now
        self.set_state("finished", reason, now)
        st = self.core.stats(now)
        log(self.name, f"finished {st['steps']} steps in {st['wall_time']:.2f} s "
            f"({st['rate']:.0f} steps/s, RTF {st['rtf']:.2f}, late ticks {st['late_ticks']}, resends {st['resends']}, "
            f"handshake repeats {st['handshake_repeats']})")
