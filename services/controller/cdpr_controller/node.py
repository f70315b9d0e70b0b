"""The controller node: answers every ``sim/state`` k with one ``controller/command`` k.

It waits until it holds both the state and the setpoint of the same step, computes the tensions with
:class:`cdpr_controller.core.ControllerCore` and publishes them. A repeated state (the clock asked for a
resend) is answered again.
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import zenoh

from cdpr.config.scenario import Scenario
from cdpr.mechanics.rotation import matrix_to_quat
from cdpr.mechanics.tda import TdaResult
from cdpr.protocol import Command, Keys, Setpoint, State
from cdpr.protocol.pairing import Pairing
from cdpr.runtime.service import Node, pair
from cdpr.runtime.transport import Event, Inbox, log, may_be_denied
from cdpr_controller.core import ControllerCore
from cdpr_controller.ibvs import frame_needed, ibvs_from_scenario


class ControllerNode(Node):
    name = "controller"
    direct = True  # handled on Zenoh's receive thread: no hand-off between a message and its answer

    @classmethod
    def make_core(cls, scenario: Scenario) -> ControllerCore:
        """(state k, setpoint k) → tensions k: ``.step(state, setpoint)``."""
        return ControllerCore.from_scenario(scenario)

    def __init__(self, scenario: Scenario, keys: Keys) -> None:
        super().__init__(keys)
        # image-based visual servoing (controller.law: ibvs): the camera's frames instead of the state's pose
        self.ibvs = ibvs_from_scenario(scenario) if scenario.spec.controller.law == "ibvs" else None
        if self.ibvs is None:
            self.leave_out("camera")
        self.waiting: State | None = None  # IBVS: a state whose frame has not come yet
        self.frames_given_up = -1  # IBVS: the exposure of the last frame given up for lost
        self.total_steps = scenario.total_steps
        self.core = self.make_core(scenario)
        # held at the start pose, at rest: about what step 0 brings
        pose = (*scenario.initial_position.tolist(), *matrix_to_quat(scenario.initial_rotation).tolist())
        m = scenario.robot.m
        self.core.warm_up(State(0, 0.0, pose, (0.0,) * 6, (1.0,) * m, (0.0,) * m),
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
        if self.ibvs is not None:
            self.handle_ibvs(event)
        elif (due := pair(self, self.pairing, event, self.m)) is not None:
            self.answer(*due)

    def handle_ibvs(self, event: Event) -> None:
        """IBVS: state k is answered once the newest frame out by step k is in (whatever the order the frames and
        the states arrive in: the answers are the same in every run); the setpoints are not used."""
        assert self.ibvs is not None
        if event.topic == "camera":
            frame = self.decode(event)
            if frame is None or frame.camera != self.ibvs.camera.name:
                return
            self.ibvs.on_frame(frame)
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
                          f"{may_be_denied(self.keys.topic('camera', self.ibvs.camera.name))})")
                self.frames_given_up = frame_needed(self.ibvs.camera, state.step) or 0  # not waited for again
                self.answer_ibvs(state)
                return
        else:
            return
        state = self.waiting
        if state is None or state.step >= self.total_steps:
            return  # (the session's last state awaits no command)
        needed = frame_needed(self.ibvs.camera, state.step)
        if needed is not None and self.ibvs.frame_step < needed and needed > self.frames_given_up:
            return  # its frame is on its way
        self.answer_ibvs(state)

    def answer_ibvs(self, state: State) -> None:
        assert self.ibvs is not None
        self.waiting = None
        start = time.perf_counter()
        result = self.ibvs.step(state.step)
        self.send(state, result, None, time.perf_counter() - start)

    def answer(self, state: State, setpoint: Setpoint) -> None:
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
        self._pub.put(
            Command(state.step, state.t, tuple(result.tensions.tolist()), result.feasible, result.status,
                    None, solve_time).encode()
            if lengths is None else
            Command(state.step, state.t, (), result.feasible, result.status, tuple(lengths.tolist()),
                    solve_time).encode()
        )
        self.pairing.done(state.step)

    def close(self) -> None:
        servo = "" if self.ibvs is None else (f"; IBVS: the last frame (step {self.ibvs.frame_step}) "
                                              f"{self.ibvs.feature_error:.3f} px RMS from the desired image")
        log(self.name, f"answered up to step {self.pairing.answered}; infeasible distributions: {self.infeasible}"
            + servo)
