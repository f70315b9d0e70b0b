"""The two ways an environment runs the loop: in this process (local) or as a session's controller (session).

Both take, per env step, a *commander* ``(state k, setpoint k) -> Command`` and run ``n`` sim steps with
it; both return the state reached (step ``k + n``) with its setpoint and sensor readings, and the
position error of every state they commanded (for the episode's RMS). The local loop steps the sim's
and the trajectory's own cores (the services' step functions, no Zenoh, no messages); the session loop
is a controller of a running session (docs/protocol.md, "The rule for a controller"): it answers each
``sim/state`` with one ``controller/command`` and keeps the session waiting while the environment is
not stepping (lock-step).
"""

from __future__ import annotations

import contextlib
import math
import queue
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from functools import partial
from typing import Any

import numpy as np
import zenoh

from cdpr.config.scenario import Scenario
from cdpr.errors import InputError
from cdpr.protocol import Command, End, Keys, Sensors, Setpoint, State, Status
from cdpr.protocol.session import SessionInfo
from cdpr.runtime.registry import node_class
from cdpr.runtime.service import Node, serve_composed
from cdpr.runtime.transport import Event, Inbox, StopFlag, open_session, zenoh_config

Commander = Callable[[State, Setpoint], Command]


@dataclass
class Reached:
    """Where a run of sim steps ended, and what was measured on the way."""

    state: State  # the state reached (step k + n), or the last one heard if the session ended
    setpoint: Setpoint  # its setpoint (the last one of the session for the final state, which has none)
    sensors: Sensors | None
    errors: list[float] = field(default_factory=list)  # ‖position error‖ of each commanded state
    applied: list[Sequence[float]] = field(default_factory=list)  # the tensions acting over each step
    ended: str | None = None  # the session ended (finished/aborted + reason) before the run did


class LocalLoop:
    """The plant in this process: the sim's model (DART) and sensors, the trajectory's setpoints."""

    def __init__(self) -> None:
        self.sim: Any = None
        self.setpoint_at: Callable[[int], Setpoint] | None = None
        self.sensors: Any = None
        self.total_steps = 0
        self.clamped = 0
        self._trajectory: tuple[str, float] | None = None  # the trajectory (spec, dt) the cache below holds

    def start(self, scenario: Scenario) -> Reached:
        """A new episode of ``scenario`` (the plant's: randomised parameters included); its state 0."""
        sim = node_class("sim")
        self.sim = sim.make_core(scenario)
        key = (scenario.spec.trajectory.model_dump_json(), scenario.dt)
        if key != self._trajectory:  # the setpoints depend on the trajectory only: kept from episode to episode
            self._trajectory = key
            self.setpoint_at = _cached(node_class("trajectory").make_core(scenario))
        self.sensors = sim.make_sensors(scenario)  # type: ignore[attr-defined]  # the sim node's
        self.total_steps = scenario.total_steps
        self.clamped = 0
        return self._reached(self.sim.message(0), [], [])

    def _reached(self, state: State, errors: list[float], applied: list[Sequence[float]]) -> Reached:
        assert self.setpoint_at is not None
        setpoint = self.setpoint_at(min(state.step, self.total_steps - 1))
        sensors = None if self.sensors is None else self.sensors.read(self.sim)
        return Reached(state, setpoint, sensors, errors, applied)

    def run(self, n: int, commander: Commander) -> Reached:
        sim, setpoint_at = self.sim, self.setpoint_at
        assert sim is not None
        assert setpoint_at is not None
        errors: list[float] = []
        applied: list[Sequence[float]] = []
        state = sim.message(self.clamped)
        for _ in range(n):
            setpoint = setpoint_at(state.step)
            if self.sensors is not None:
                self.sensors.read(sim)  # every step, as the sim node does: the IMU's mean acceleration
            command = commander(state, setpoint)
            errors.append(math.dist(state.pose[:3], setpoint.pose[:3]))
            values = command.tensions if command.lengths is None else command.lengths
            report = sim.step(np.asarray(values, dtype=float))
            self.clamped += report.clamped_low + report.clamped_high
            applied.append(report.applied)
            state = sim.message(self.clamped)
        return self._reached(state, errors, applied)

    def end(self, reason: str) -> None:
        """An episode ends early: nothing to tell anyone."""

    def close(self) -> None:
        self.sim = None


def _cached(setpoint_at: Callable[[int], Setpoint]) -> Callable[[int], Setpoint]:
    """``setpoint_at`` remembering every setpoint it computed (the trajectory's core, the same messages)."""
    memo: list[Setpoint] = []

    def cached(step: int) -> Setpoint:
        while len(memo) <= step:
            memo.append(setpoint_at(len(memo)))
        return memo[step]

    return cached


# --------------------------------------------------------------------------------------------------
# Session mode


class _EnvNode(Node):
    """The environment's side of the protocol in a session: a controller whose answers come from another
    thread. Its handlers only queue what arrives (on Zenoh's thread: they never wait)."""

    name = "controller"

    def __init__(self, keys: Keys, m: int, sensors: bool, inbox: queue.SimpleQueue[tuple[str, Any]]) -> None:
        super().__init__(keys)
        self.m = m
        self.with_sensors = sensors
        self.out = inbox

    def declare(self, session: zenoh.Session, inbox: Inbox) -> list[Any]:
        # the sensors are not the controller's input in the wiring table: the environment reads them itself
        return [inbox.subscribe(session, self.keys.sensors, "sensors")] if self.with_sensors else []

    def handle(self, event: Event) -> None:
        if event.topic == "state":
            if (state := self.decode(event, self.m)) is not None:
                self.out.put(("state", state))
        elif event.topic == "setpoints":
            if (block := self.decode(event)) is not None:
                self.out.put(("setpoints", block))
        elif event.topic == "sensors":
            with contextlib.suppress(Exception):
                self.out.put(("sensors", Sensors.decode(event.payload, self.m)))

    def on_status(self, status: Status) -> None:
        super().on_status(status)
        self.out.put(("status", status))


class SessionLoop:
    """The environment as the controller of a session (``cdpr up SCENARIO --without controller``).

    Each episode is one session: :meth:`start` waits for the next session under the id to answer
    ``session/info`` (``cdpr up --episodes N`` runs them back to back), joins it as its controller and
    returns its state 0. An episode that ends before the session does ends the session
    (``session/end``); the next :meth:`start` then waits for that session's clock to be gone.
    """

    def __init__(self, connect: str | Sequence[str], session: str = "default", zenoh_config_file: str | None = None,
                 mode: str = "client", timeout: float = 120.0) -> None:
        endpoints = [connect] if isinstance(connect, str) else list(connect)
        try:
            self.keys = Keys(session)
        except ValueError as exc:
            raise InputError(f"session: {exc}") from None
        self.conf = zenoh_config(mode, endpoints, (), zenoh_config_file)
        self.endpoints = endpoints
        self.timeout = float(timeout)
        self.zenoh: zenoh.Session | None = None
        self.events: queue.SimpleQueue[tuple[str, Any]] = queue.SimpleQueue()
        self.thread: threading.Thread | None = None
        self.stop: StopFlag | None = None
        self.node: _EnvNode | None = None
        self.states: dict[int, State] = {}
        self.setpoints: dict[int, Setpoint] = {}
        self.sensors: dict[int, Sensors] = {}
        self.last_setpoint: Setpoint | None = None
        self.status: Status | None = None
        self.info: SessionInfo | None = None
        self.answers: dict[int, Command] = {}
        self.step = 0
        self._clocks_gone = threading.Semaphore(0)
        self._watch: Any = None

    # -- the session's life --------------------------------------------------------------------------
    def _open(self) -> zenoh.Session:
        if self.zenoh is None:
            self.zenoh = open_session(self.conf, "gym")
            # every clock that leaves (its token deleted, or the link to it lost): the next session is a new clock
            self._clocks_gone = threading.Semaphore(0)

            def on_token(sample: zenoh.Sample) -> None:
                if sample.kind == zenoh.SampleKind.DELETE:
                    self._clocks_gone.release()

            self._watch = self.zenoh.liveliness().declare_subscriber(self.keys.alive("clock"), on_token)
        return self.zenoh

    def _fetch_info(self, deadline: float) -> SessionInfo:
        z = self._open()
        while time.monotonic() < deadline:
            for reply in z.get(self.keys.info, timeout=2.0):
                if reply.ok is not None:
                    return SessionInfo.from_payload(reply.ok.payload.to_bytes())
            time.sleep(0.2)
        raise TimeoutError(f"no session {self.keys.session!r} answered {self.keys.info} at "
                           f"{', '.join(self.endpoints)} within {self.timeout:g} s: start one with "
                           f"`cdpr up SCENARIO --without controller --episodes 0`")

    def start(self, scenario: Scenario) -> Reached:
        self._leave("the environment was reset")
        deadline = time.monotonic() + self.timeout
        info = self._fetch_info(deadline)
        if info.dt != scenario.dt or info.total_steps != scenario.total_steps or info.robot.m != scenario.robot.m:
            raise InputError(f"session {self.keys.session!r} runs {info.scenario} (dt {info.dt:g} s, "
                             f"{info.total_steps} steps, {info.robot.m} cables), this environment {scenario.name} "
                             f"(dt {scenario.dt:g} s, {scenario.total_steps} steps, {scenario.robot.m} cables)")
        self.info = info
        while self._clocks_gone.acquire(blocking=False):  # clocks gone before this session: not this one
            pass
        self.events = queue.SimpleQueue()
        self.states, self.setpoints, self.sensors, self.answers = {}, {}, {}, {}
        self.status, self.last_setpoint, self.step = None, None, 0
        self.node = _EnvNode(self.keys, scenario.robot.m, scenario.spec.sim.sensors is not None, self.events)
        self.stop = StopFlag()
        node, stop, z = self.node, self.stop, self._open()
        self.thread = threading.Thread(target=serve_composed, args=([node], z, stop), kwargs={"freeze": False},
                                       name="cdpr-gym-session", daemon=True)
        self.thread.start()
        reached = self._reached(0, deadline)
        if reached.ended is not None:
            raise RuntimeError(f"session {self.keys.session!r} ended before its first step: {reached.ended}")
        return reached

    def _leave(self, reason: str) -> None:
        """End the current episode's session (unless it has ended) and wait for its clock to be gone."""
        if self.thread is None:
            return
        # after the final state the session ends by itself (the clock may not have heard of that state yet)
        final = self.info is not None and max(self.states, default=-1) >= self.info.total_steps
        if self._ended() is None and not final and self.node is not None and \
                (pub := self.node.publishers.get("end")) is not None:
            with contextlib.suppress(zenoh.ZError):
                pub.put(End("controller", reason[:200]).encode())
        deadline = time.monotonic() + 10.0
        while self._ended() is None and time.monotonic() < deadline:
            self._next(deadline)
        assert self.stop is not None
        self.stop.set()
        self.thread.join(timeout=10.0)
        self.thread = None
        # the next session has a new clock: wait until this one has gone (it lingers a moment after the end, and
        # until then it still answers session/info)
        self._clocks_gone.acquire(timeout=15.0)

    # -- the events ----------------------------------------------------------------------------------
    def _next(self, deadline: float) -> None:
        """Take one event (or time out at ``deadline``) into the caches; answer a state asked for again."""
        try:
            kind, item = self.events.get(timeout=max(0.0, deadline - time.monotonic()))
        except queue.Empty:
            return
        if kind == "status":
            self.status = item
        elif kind == "sensors":
            self.sensors[item.step] = item
        elif kind == "setpoints":
            self.setpoints.update((sp.step, sp) for sp in item.items if sp.step >= self.step)
            if item.items:
                self.last_setpoint = item.items[-1]
        elif kind == "state":
            if (again := self.answers.get(item.step)) is not None:
                self._publish(again)  # the clock asked for it again (a resend): the same answer
            self.states[item.step] = item

    def _ended(self) -> str | None:
        s = self.status
        if s is None or s.state not in ("finished", "aborted"):
            return None
        return s.state + (f": {s.reason}" if s.reason else "")

    def _wait(self, ready: Callable[[], bool], deadline: float, what: str) -> str | None:
        """Take events until ``ready()``; the session's end (finished/aborted, with its reason) if it came first."""
        while not ready():
            if (ended := self._ended()) is not None:
                return ended
            if time.monotonic() > deadline:
                raise TimeoutError(f"session {self.keys.session!r}: no {what} within {self.timeout:g} s")
            self._next(deadline)
        return None

    def _reached(self, step: int, deadline: float) -> Reached:
        """State ``step`` with its setpoint (the last one for the final state) and its sensor readings."""
        want_sensors = self.node is not None and self.node.with_sensors
        final = self.info is not None and step >= self.info.total_steps  # the last state has no setpoint

        def ready() -> bool:
            return (step in self.states and (final or step in self.setpoints)
                    and (not want_sensors or step in self.sensors))

        ended = self._wait(ready, deadline, f"state {step}")
        if ended is not None:
            if not self.states or self.last_setpoint is None:
                raise RuntimeError(f"session {self.keys.session!r} {ended}")
            step = max(self.states)
        setpoint = self.setpoints.get(step) or self.last_setpoint
        assert setpoint is not None
        return Reached(self.states[step], setpoint, self.sensors.get(step), ended=ended)

    def _publish(self, command: Command) -> None:
        assert self.node is not None
        with contextlib.suppress(zenoh.ZError):
            self.node.publishers["command"].put(command.encode())

    def run(self, n: int, commander: Commander) -> Reached:
        errors: list[float] = []
        applied: list[Sequence[float]] = []
        ended: str | None = None
        for _ in range(n):
            k = self.step
            ended = self._wait(partial(self.setpoints.__contains__, k), time.monotonic() + self.timeout,
                               f"setpoint {k}")
            if ended is not None:
                break
            state, setpoint = self.states[k], self.setpoints[k]
            command = commander(state, setpoint)
            self.answers = {k: command}
            self._publish(command)
            errors.append(math.dist(state.pose[:3], setpoint.pose[:3]))
            ended = self._wait(partial(self.states.__contains__, k + 1), time.monotonic() + self.timeout,
                               f"state {k + 1}")
            if ended is not None:
                break
            applied.append(self.states[k + 1].tensions)
            for cache in (self.states, self.setpoints, self.sensors):
                cache.pop(k, None)
            self.step = k + 1
        reached = self._reached(self.step, time.monotonic() + self.timeout)
        reached.errors, reached.applied = errors, applied
        reached.ended = reached.ended or ended
        return reached

    def end(self, reason: str) -> None:
        """The episode ended before the session: end the session."""
        self._leave(reason)

    def close(self) -> None:
        try:
            self._leave("the environment was closed")
        finally:
            if self.zenoh is not None:
                self._watch.undeclare()
                self.zenoh.close()
                self.zenoh = None
