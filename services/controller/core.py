"""The controller's step: (state k, setpoint k) → tensions k. No I/O.

Feedback linearisation (eq. 6–7) gives the wrench; the scenario's tension distribution method turns it
into tensions within [tmin, tmax]. The distributor keeps its warm start / previous tensions between
calls, so the same sequence of inputs gives the same sequence of outputs.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cdpr.control import Gains, Variant, controlled_rows, feedback_linearisation
from cdpr.kinematics import inverse_kinematics
from cdpr.protocol import Setpoint, State
from cdpr.robot import Robot
from cdpr.rotation import quat_to_matrix
from cdpr.scenario import Scenario
from cdpr.tda import TdaResult, TensionDistributor, make_tda


@dataclass
class ControllerCore:
    robot: Robot
    gains: Gains
    variant: Variant
    tda: TensionDistributor

    @classmethod
    def from_scenario(cls, scenario: Scenario) -> ControllerCore:
        return cls(scenario.robot, scenario.gains, scenario.variant, make_tda(scenario.tda_method, **scenario.tda_options))

    @property
    def rows(self) -> list[int]:
        return list(controlled_rows(self.robot, self.variant))

    def step(self, state: State, setpoint: Setpoint) -> TdaResult:
        position = np.asarray(state.pose[:3])
        R = quat_to_matrix(state.pose[3:])
        wrench = feedback_linearisation(
            self.robot,
            position,
            R,
            state.twist,
            setpoint.pose[:3],
            quat_to_matrix(setpoint.pose[3:]),
            setpoint.twist,
            setpoint.accel,
            self.gains,
            self.variant,
        )
        W6 = inverse_kinematics(self.robot, position, R).wrench_matrix
        W = W6[self.rows]
        if self.robot.cable_damping > 0.0:
            # The cables' viscous damping (the robot file's, applied by the sim along each cable as
            # c·l̇ on top of the tension) is a known external wrench of eq. 5: compensate it like gravity.
            rates = -(W6.T @ np.asarray(state.twist))  # l̇ = J v, J = −Wᵀ
            wrench = wrench - W @ (self.robot.cable_damping * rates)
        return self.tda.solve(W, wrench, self.robot.tmin, self.robot.tmax)
