"""The sim node: a Zenoh shell around :class:`cdpr_sim.core.PlatformSim`.

Step k is integrated only when both the clock's tick k and a valid command k have arrived; the state
at step k+1 is published right after. On tick k while at step k the state k is published (again, if
the tick is repeated: that is how the clock asks for a resend). Bad commands are dropped with a
one-line log; out-of-range tensions are clamped to [0, tmax] and counted.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import zenoh

from cdpr.config.scenario import Scenario
from cdpr.protocol import Command, Keys, ProtocolError, Tick
from cdpr.runtime.service import Node
from cdpr.runtime.transport import Event, Inbox, RateLimitedLog, log
from cdpr_sim.core import make_sim, state_message
from cdpr_sim.sensors import SensorConfig, SensorSuite


class SimNode(Node):
    name = "sim"
    direct = True  # handled on Zenoh's receive thread: no hand-off between a message and its answer

    make_core = staticmethod(make_sim)  # the model: .state(), .step(values); state_message(state, clamped)
    state_message = staticmethod(state_message)

    def __init__(self, scenario: Scenario, keys: Keys) -> None:
        super().__init__(keys)
        self.scenario = scenario
        self.total_steps = scenario.total_steps
        self.sim = make_sim(scenario)
        self.m = scenario.robot.m
        self.allowed = -1  # highest tick received
        self.seen_ticks: set[int] = set()  # ticks received for steps not yet taken (a repeat asks for a resend)
        self.published_step = -1
        self.pending: Command | None = None  # a valid command for the current step, waiting for its tick
        self.clamped = 0
        self.last_command: Command | None = None  # the command of the last step taken
        self.warn = RateLimitedLog(self.name)
        self._pub: zenoh.Publisher | None = None
        self.command_kind = scenario.output  # "tensions" or "lengths": the commands this sim takes
        sensors = scenario.spec.sim.sensors
        self.sensors = None if sensors is None else SensorSuite(SensorConfig.from_spec(sensors, self.m),
                                                                  scenario.dt)
        self._sensors_pub: zenoh.Publisher | None = None

    # -- wiring -----------------------------------------------------------------------------------
    subscribes = ("tick", "command")
    publishes = ("state", "sensors")

    def declare(self, session: zenoh.Session, inbox: Inbox) -> list[Any]:
        self._pub, self._sensors_pub = self.publishers["state"], self.publishers["sensors"]
        return []

    def handle(self, event: Event) -> None:
        if event.kind == "tick":
            try:
                tick = Tick.decode(event.payload)
            except ProtocolError as exc:
                self.count("bad_ticks")
                self.warn("bad_tick", f"dropped a bad clock/tick: {exc}")
                return
            self.on_tick(tick.step)
        elif event.kind == "command":
            try:
                cmd = Command.decode(event.payload, self.m, self.command_kind)
            except ProtocolError as exc:
                self.count("bad_commands")
                self.warn("bad_command", f"dropped a bad controller/command: {exc}")
                return
            self.on_command(cmd)

    # -- the step logic ---------------------------------------------------------------------------
    @property
    def step(self) -> int:
        return self.sim.step_count

    def publish_state(self) -> None:
        assert self._pub is not None
        self._pub.put(state_message(self.sim.state(), self.clamped).encode())
        if self.sensors is not None and self._sensors_pub is not None:  # sim/sensors, right after the state
            self._sensors_pub.put(self.sensors.read(self.sim).encode())
        self.published_step = self.step

    def on_tick(self, k: int) -> None:
        if k > self.allowed:
            self.allowed = k
        repeat = k in self.seen_ticks
        if k >= self.step:
            self.seen_ticks.add(k)
        if self.published_step < 0 and k != self.step:
            # A sim that joins a session already under way announces where it is (step 0): the clock
            # sees the step go back and ends the session, since this sim's state is not the session's.
            self.publish_state()
            return
        if k != self.step:
            return
        if self.published_step != self.step or repeat:
            self.publish_state()
        if self.pending is not None:
            cmd, self.pending = self.pending, None
            self.on_command(cmd)

    def on_command(self, cmd: Command) -> None:
        if cmd.step < self.step:
            last = self.last_command
            if last is not None and cmd.step == last.step and cmd.values != last.values:
                # The first valid command of a step wins; a different one for the same step means
                # a second controller is publishing in this session.
                self.count("conflicting_commands")
                self.warn("conflict", f"step {cmd.step}: a different command arrived after the one applied "
                          "(is a second controller publishing in this session?); ignored")
            else:
                self.count("stale_commands")  # a repeated answer (after a resend) or a late one
            return
        if cmd.step > self.step or cmd.step >= self.total_steps:
            self.count("future_commands")
            self.warn("future_command",
                      f"dropped controller/command for step {cmd.step}: the sim is at step {self.step}")
            return
        if self.step > self.allowed:
            self.pending = cmd  # the controller was quicker than the tick: wait for the clock
            return
        report = self.sim.step(np.asarray(cmd.values))
        self.last_command = cmd
        if report.clamped_low or report.clamped_high:
            self.clamped += 1
            self.count("clamped_commands")
            self.warn(
                "clamped",
                f"step {cmd.step}: clamped {report.clamped_low} tension(s) below 0 and "
                f"{report.clamped_high} above tmax = {self.scenario.robot.tmax:g} N"
                if cmd.lengths is None else
                f"step {cmd.step}: clamped {report.clamped_high} length(s) above max_length = "
                f"{self.scenario.robot.max_length:g} m",
            )
        self.seen_ticks.discard(cmd.step)
        self.publish_state()

    def close(self) -> None:
        log(self.name, f"stopped at step {self.step}/{self.total_steps}; clamped commands: {self.clamped}"
            + (f"; {self.counters}" if self.counters else ""))
