"""The controller node: answers every ``sim/state`` k with one ``controller/command`` k.

Its law is the scenario's ``controller.law``, a row of :data:`cdpr.laws.LAWS`: it waits until it holds what the
law needs for state k — the setpoint of the same step, or the camera frame the state's step calls for — computes
the tensions (or lengths) with the law's core and publishes them. A repeated state (the clock asked for a resend)
is answered again.
"""

from __future__ import annotations

import time
from collections import Counter
from typing import Any, cast

import numpy as np
import zenoh

from cdpr.config.scenario import Scenario
from cdpr.laws import LAWS, FrameLaw, LawCore
from cdpr.laws.base import warm_up
from cdpr.mechanics.rotation import matrix_to_quat
from cdpr.mechanics.tda import TdaResult
from cdpr.protocol import Command, Keys, Setpoint, State
from cdpr.protocol.pairing import Pairing
from cdpr.runtime.feedback import SensorFeedback
from cdpr.runtime.service import Node, pair, pair_sensors
from cdpr.runtime.transport import Event, Inbox, log, may_be_denied


class ControllerNode(Node):
    name = "controller"
    direct = True  # handled on Zenoh's receive thread: no hand-off between a message and its answer

    @classmethod
    def make_core(cls, scenario: Scenario) -> LawCore:
        """The scenario's law's core: ``.command(state k, setpoint k)`` → (distribution k, lengths k or None)."""
        return LAWS[scenario.spec.controller.law].build(scenario)

    def __init__(self, scenario: Scenario, keys: Keys) -> None:
        super().__init__(keys)
        self.law = LAWS[scenario.spec.controller.law]
        if "camera" not in self.law.inputs:
            self.leave_out("camera")  # (the setpoints come whatever the law: a law without them ignores them)
        # controller.feedback: sensors: the law is fed an estimate from sim/sensors; sim/state never comes
        self.feedback = SensorFeedback.from_scenario(scenario) if scenario.spec.controller.feedback == "sensors" \
            else None
        self.leave_out("state" if self.feedback is not None else "sensors")
        self.received: Counter[str] = Counter()  # messages taken in, by topic (the log's last line)
        self.total_steps = scenario.total_steps
        self.core = self.make_core(scenario)
        # a law of camera frames (IBVS): the frames in, states answered once the frame they call for has come
        self.frames = cast(FrameLaw, self.core) if "camera" in self.law.inputs else None
        self.waiting: State | None = None  # a state whose frame has not come yet
        self.frames_given_up = -1  # the exposure of the last frame given up for lost
        # held at the start pose, at rest: about what step 0 brings
        pose = (*scenario.initial_position.tolist(), *matrix_to_quat(scenario.initial_rotation).tolist())
        m = scenario.robot.m
        warm_up(self.core, State(0, 0.0, pose, (0.0,) * 6, (1.0,) * m, (0.0,) * m),
                Setpoint(0, 0.0, pose, (0.0,) * 6, (0.0,) * 6))
        self.m = scenario.robot.m
        self.pairing = Pairing()
        self.answered = -1
        self.infeasible = 0
        self._pub: zenoh.Publisher | None = None

    scenario_checks = ("tda",)

    def declare(self, session: zenoh.Session, inbox: Inbox) -> list[Any]:
        self._pub = self.publishers["command"]
        return []

    def handle(self, event: Event) -> None:
        self.received[event.topic] += 1
        if self.frames is not None:
            self.handle_frames(self.frames, event)
        elif event.topic == "sensors":  # controller.feedback: sensors: the estimate stands for the state
            assert self.feedback is not None
            if (due := pair_sensors(self, self.pairing, self.feedback, event, self.m)) is not None:
                self.answer(*due)
        elif (due := pair(self, self.pairing, event, self.m)) is not None:
            self.answer(*due)

    def handle_frames(self, law: FrameLaw, event: Event) -> None:
        """A law of camera frames: state k is answered once the newest frame out by step k is in (whatever the
        order the frames and the states arrive in: the answers are the same in every run)."""
        if event.topic == "camera":
            frame = self.decode(event)
            if frame is None or frame.camera != law.camera_name:
                return
            law.on_frame(frame)
        elif event.topic == "state":
            if (state := self.decode(event, self.m)) is None:
                return
            # the clock asking for a state again (a stall) while its frame is still missing: a frame is lost, or
            # this controller expects frames the sim does not take (another rate): answer with the frames in
            # hand rather than stall the session
            lost = self.waiting is not None and state.step == self.waiting.step
            self.waiting = state
            if lost and state.step < self.total_steps:
                self.count("camera_frames_missing")
                self.warn("frames", f"step {state.step}: the frame it needs has not come; answered without it ("
                          f"{may_be_denied(self.keys.topic('camera', law.camera_name))})")
                self.frames_given_up = law.frame_needed(state.step) or 0  # not waited for again
                self.answer(state, None)
                return
        else:
            return
        state = self.waiting
        if state is None or state.step >= self.total_steps:
            return  # (the session's last state awaits no command)
        needed = law.frame_needed(state.step)
        if needed is not None and law.frame_step < needed and needed > self.frames_given_up:
            return  # its frame is on its way
        self.answer(state, None)

    def answer(self, state: State, setpoint: Setpoint | None) -> None:
        self.waiting = None
        start = time.perf_counter()
        result, lengths = self.core.command(state, setpoint)
        self.send(state, result, lengths, time.perf_counter() - start)

    def send(self, state: State, result: TdaResult, lengths: np.ndarray | None, solve_time: float) -> None:
        """Command k: the tensions (or lengths) of ``result``, said and counted when infeasible."""
        if not result.feasible:
            self.infeasible += 1
            self.count("infeasible_distributions")
            self.warn("infeasible", f"step {state.step}: tension distribution {result.status} "
                      f"(residual {result.residual:.3g}); sending the nearest admissible tensions")
        assert self._pub is not None
        estimate = None if self.feedback is None else (*state.pose, *state.twist)  # what it answered: recorded
        self._pub.put(
            Command(state.step, state.t, tuple(result.tensions.tolist()), result.feasible, result.status,
                    None, solve_time, estimate).encode()
            if lengths is None else
            Command(state.step, state.t, (), result.feasible, result.status, tuple(lengths.tolist()),
                    solve_time, estimate).encode()
        )
        self.pairing.done(state.step)

    def close(self) -> None:
        summary = self.law.summary(self.core)
        received = ", ".join(f"{n} {topic}" for topic, n in sorted(self.received.items()))
        log(self.name, f"answered up to step {self.pairing.answered}; infeasible distributions: {self.infeasible}"
            + (f"; {summary}" if summary else "") + f"; received: {received or 'nothing'}")
