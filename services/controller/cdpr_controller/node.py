"""The controller node: answers every ``sim/state`` k with one ``controller/command`` k.

It waits until it holds both the state and the setpoint of the same step, computes the tensions with
:class:`cdpr_controller.core.ControllerCore` and publishes them. A repeated state (the clock asked for a
resend) is answered again.
"""

from __future__ import annotations

import time
from typing import Any

import zenoh

from cdpr.config.scenario import Scenario
from cdpr.mechanics.rotation import matrix_to_quat
from cdpr.protocol import Command, Keys, Setpoint, State
from cdpr.protocol.pairing import Pairing
from cdpr.runtime.service import Node, pair
from cdpr.runtime.transport import Event, Inbox, log
from cdpr_controller.core import ControllerCore


class ControllerNode(Node):
    name = "controller"
    direct = True  # handled on Zenoh's receive thread: no hand-off between a message and its answer

    @classmethod
    def make_core(cls, scenario: Scenario) -> ControllerCore:
        """(state k, setpoint k) → tensions k: ``.step(state, setpoint)``."""
        return ControllerCore.from_scenario(scenario)

    def __init__(self, scenario: Scenario, keys: Keys) -> None:
        super().__init__(keys)
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
        if (due := pair(self, self.pairing, event, self.m)) is not None:
            self.answer(*due)

    def answer(self, state: State, setpoint: Setpoint) -> None:
        start = time.perf_counter()
        result, lengths = self.core.command(state, setpoint)
        solve_time = time.perf_counter() - start
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
        log(self.name, f"answered up to step {self.pairing.answered}; infeasible distributions: {self.infeasible}")
