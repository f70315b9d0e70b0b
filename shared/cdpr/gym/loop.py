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
import threading
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
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
            self.setpoint_at = _cached(node_class("trajectory").make_block_core(scenario))
        self.sensors = sim.make_sensors(scenario)
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


def _cached(block: Callable[[int, int], tuple[Setpoint, ...]], size: int = 100) -> Callable[[int], Setpoint]:
    """Step k → setpoint k from the trajectory's block core (the same messages as the node's), ``size`` steps at
    a time (a trajectory is defined at every time: a block may reach past the episode's end), each remembered."""
    memo: list[Setpoint] = []

    def cached(step: int) -> Setpoint:
        while len(memo) <= step:
            memo.extend(block(len(memo), max(step, len(memo) + size - 1)))
        return memo[step]

    return cached


# --------------------------------------------------------------------------------------------------
# Session mode


class _EnvNode(Node):
    """The environment's side of the protocol in a session: a controller whose answers come from the env's
    commander of the current env step. Its handlers run on Zenoh's receive thread (as the controller service's
    do: no thread hand-off between a state and its command); the env's thread only sets a window of steps to
    answer and waits, under :attr:`lock`, until the loop has reached its end."""

    name = "controller"

    def __init__(self, keys: Keys, m: int, sensors: bool, total_steps: int) -> None:
        super().__init__(keys)
        self.leave_out("camera")  # no camera in its observation
        self.m = m
        self.with_sensors = sensors
        self.total_steps = total_steps
        self.lock = threading.Condition()
        self.states: dict[int, State] = {}
        self.setpoints: dict[int, Setpoint] = {}
        self.sensors: dict[int, Sensors] = {}
        self.last_setpoint: Setpoint | None = None
        self.status: Status | None = None
        self.answers: dict[int, Command] = {}  # the last answer, for a state the clock asks for again
        self.error: BaseException | None = None
        # the window the env's thread opened: answer states step … stop − 1 with commander
        self.commander: Commander | None = None
        self.step = 0
        self.stop = 0
        self.errors: list[float] = []
        self.applied: list[Sequence[float]] = []

    def declare(self, session: zenoh.Session, inbox: Inbox) -> list[Any]:
        # the sensors are not the controller's input in the wiring table: the environment reads them itself
        return [inbox.subscribe(session, self.keys.sensors, "sensors")] if self.with_sensors else []

    def handle(self, event: Event) -> None:
        with self.lock:
            try:
                self._take(event)
                self._answer()
            except Exception as exc:  # a commander's error goes to the env's thread, which raises it
                self.error = exc
            self.lock.notify_all()

    def _take(self, event: Event) -> None:
        if event.topic == "state":
            state = self.decode(event, self.m)
            if state is None:
                return
            if (again := self.answers.get(state.step)) is not None:
                self._publish(again)  # the clock asked for it again (a resend): the same answer
            self.states[state.step] = state
        elif event.topic == "setpoints":
            if (block := self.decode(event)) is not None:
                self.setpoints.update((sp.step, sp) for sp in block.items if sp.step >= self.step)
                if block.items:
                    self.last_setpoint = block.items[-1]
        elif event.topic == "sensors":
            with contextlib.suppress(Exception):
                sensors = Sensors.decode(event.payload, self.m)
                self.sensors[sensors.step] = sensors

    def _answer(self) -> None:
        """Answer the window's next state if it and its setpoint are in (and record the one it led to)."""
        while self.commander is not None:
            k = self.step
            if k >= self.stop or k not in self.states or k not in self.setpoints:
                return
            if self.answers and k in self.answers:  # answered: wait for state k + 1
                if k + 1 not in self.states:
                    return
                self.applied.append(self.states[k + 1].tensions)
                for cache in (self.states, self.setpoints, self.sensors):
                    cache.pop(k, None)
                self.step = k + 1
                continue
            state, setpoint = self.states[k], self.setpoints[k]
            command = self.commander(state, setpoint)
            self.answers = {k: command}
            self._publish(command)
            self.errors.append(math.dist(state.pose[:3], setpoint.pose[:3]))

    def _publish(self, command: Command) -> None:
        with contextlib.suppress(zenoh.ZError):
            self.publishers["command"].put(command.encode())

    def on_status(self, status: Status) -> None:  # the env's thread decides when the node leaves
        with self.lock:
            self.status = status
            self.lock.notify_all()

    def ended(self) -> str | None:
        s = self.status
        if s is None or s.state not in ("finished", "aborted"):
            return None
        return s.state + (f": {s.reason}" if s.reason else "")

    def ready(self, step: int) -> bool:
        """State ``step`` is in, with its setpoint (none for the final state) and its sensor readings."""
        return (step in self.states and (step >= self.total_steps or step in self.setpoints)
                and (not self.with_sensors or step in self.sensors))


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
        self.thread: threading.Thread | None = None
        self.stop: StopFlag | None = None
        self.node: _EnvNode | None = None
        self.info: SessionInfo | None = None
        self._clocks_gone = threading.Semaphore(0)
        self._watch: Any = None

    # -- the session's life --------------------------------------------------------------------------
    def _open(self) -> zenoh.Session:
        if self.zenoh is None:
            self.zenoh = open_session(self.conf, "gym")

            def on_token(sample: zenoh.Sample) -> None:
                # every clock that leaves (its token deleted, or the link to it lost): the next session is a new clock
                if sample.kind == zenoh.SampleKind.DELETE:
                    self._clocks_gone.release()

            # on Zenoh's thread (indirect=False): no Python thread of the binding's left to end at exit (see
            # cdpr.runtime.service.declare_topics)
            self._watch = self.zenoh.liveliness().declare_subscriber(
                self.keys.alive("clock"), zenoh.handlers.Callback(on_token, indirect=False))
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
        self.node = _EnvNode(self.keys, scenario.robot.m, scenario.spec.sim.sensors is not None, info.total_steps)
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
        node = self.node
        if self.thread is None or node is None:
            return
        with node.lock:
            node.commander = None
            # after the final state the session ends by itself (the clock may not have heard of that state yet)
            final = max(node.states, default=-1) >= node.total_steps
            if node.ended() is None and not final and (pub := node.publishers.get("end")) is not None:
                with contextlib.suppress(zenoh.ZError):
                    pub.put(End("controller", reason[:200]).encode())
            node.lock.wait_for(lambda: node.ended() is not None, timeout=10.0)
        assert self.stop is not None
        self.stop.set()
        self.thread.join(timeout=10.0)
        self.thread = None
        # the next session has a new clock: wait until this one has gone (it lingers a moment after the end, and
        # until then it still answers session/info)
        self._clocks_gone.acquire(timeout=15.0)

    def _reached(self, step: int, deadline: float) -> Reached:
        """Wait for state ``step`` (with its setpoint, the last one for the final state, and its sensor readings),
        or the session's end (then the last state heard)."""
        node = self.node
        assert node is not None
        with node.lock:
            done = node.lock.wait_for(lambda: node.error is not None or node.ready(step) or node.ended() is not None,
                                      timeout=max(0.0, deadline - time.monotonic()))
            if node.error is not None:
                error, node.error = node.error, None
                raise error
            if not done:
                raise TimeoutError(f"session {self.keys.session!r}: no state {step} within {self.timeout:g} s")
            ended = None if node.ready(step) else node.ended()
            if ended is not None:
                if not node.states or node.last_setpoint is None:
                    raise RuntimeError(f"session {self.keys.session!r} {ended}")
                step = max(node.states)
            setpoint = node.setpoints.get(step) or node.last_setpoint
            assert setpoint is not None
            return Reached(node.states[step], setpoint, node.sensors.get(step), ended=ended)

    def run(self, n: int, commander: Commander) -> Reached:
        node = self.node
        assert node is not None
        with node.lock:
            node.commander, node.stop, node.errors, node.applied = commander, node.step + n, [], []
            stop = node.stop
            try:
                node._answer()  # the window's first state is in: answer it now
            except Exception:
                node.commander = None
                raise
        try:
            reached = self._reached(stop, time.monotonic() + self.timeout)
        finally:
            with node.lock:
                node.commander = None
        reached.errors, reached.applied = node.errors, node.applied
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
