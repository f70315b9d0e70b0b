"""Feedback linearisation, the seed paper's law (``controller.law: feedback_linearisation``): (state k, setpoint k)
→ tensions k, or unstretched cable lengths k. No I/O.

Feedback linearisation (eq. 6–7) gives the wrench; the scenario's tension distribution method turns it
into tensions within [tmin, tmax]. The distributor keeps its warm start / previous tensions between
calls, so the same sequence of inputs gives the same sequence of outputs.

Length output (scenario ``controller: {output: lengths}``, for winch-driven elastic or sagging cables):
the command is the unstretched length each winch must pay out so that, at the **desired** pose, each
cable holds the tension the distribution chose — inverse kinematics minus the static stretch
(:func:`stretch_compensated_lengths`: ``l0 = l·EA/(EA + f)``, i.e. ``l − f l0/EA``). The feedback acts
through f: a platform below its setpoint gets larger tensions, hence shorter cables. The cables' EA is
the scenario's ``sim`` section (the controller knows it). Sagging cables are treated as straight: the
sag is a model error this controller does not compensate. (Compensating it with the catenary's length
for the commanded tension makes the loop limit-cycle whenever the distribution puts a cable at tmin:
there the sag's compliance, ∝ w²l³/T³, multiplies every change of tension into centimetres of cable.)
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from cdpr.laws.base import Law, SetpointLike, StateLike, warm_up
from cdpr.mechanics.catenary import unstretched_lengths
from cdpr.mechanics.control import FeedbackLaw, Gains, Variant, controlled_rows
from cdpr.mechanics.kinematics import WrenchMatrix, inverse_kinematics
from cdpr.mechanics.robot import Robot
from cdpr.mechanics.rotation import Array, quat_to_matrix
from cdpr.mechanics.tda import TdaResult, TensionDistributor, make_tda


def stretch_compensated_lengths(robot: Robot, position: ArrayLike, R: ArrayLike, tensions: ArrayLike,
                                EA: float) -> Array:
    """Unstretched lengths (m,) of straight elastic cables holding ``tensions`` at the pose: l·EA/(EA + f).

    ``l`` is the inverse-kinematics length; the static law ``f = EA (l − l0)/l0`` solved for l0.
    """
    return unstretched_lengths(inverse_kinematics(robot, position, R).lengths, tensions, EA)


@dataclass
class ControllerCore:
    robot: Robot
    gains: Gains
    variant: Variant
    tda: TensionDistributor
    output: str = "tensions"  # or "lengths"
    axial_stiffness: float | None = None  # EA, N, of the cables: needed for length output
    _law: FeedbackLaw = field(init=False, repr=False)
    _wrench_matrix: WrenchMatrix = field(init=False, repr=False)
    _rows: list[int] | None = field(init=False, repr=False)
    _tmin: float | np.ndarray = field(init=False, repr=False)
    _tmax: float | np.ndarray = field(init=False, repr=False)

    def __post_init__(self) -> None:
        if self.output not in ("tensions", "lengths"):
            raise ValueError(f"output must be 'tensions' or 'lengths' (got {self.output!r})")
        EA = self.axial_stiffness
        if self.output == "lengths" and not (EA is not None and 0.0 < EA < np.inf):
            raise ValueError(f"length output needs the cables' axial_stiffness EA > 0 (got {EA})")
        # Everything that does not change from step to step is set up here, once.
        self._law = FeedbackLaw(self.robot, self.gains, self.variant)
        self._wrench_matrix = WrenchMatrix(self.robot)
        rows = self.rows
        self._rows = None if rows == [0, 1, 2, 3, 4, 5] else rows
        # (one number each when every cable has the same limits: the distribution's cheapest input)
        uniform = self.robot.uniform_limits
        self._tmin = float(self.robot.tmin[0]) if uniform else self.robot.tmin
        self._tmax = float(self.robot.tmax[0]) if uniform else self.robot.tmax

    @classmethod
    def from_scenario(cls, scenario: Any) -> ControllerCore:
        """For a :class:`cdpr.config.scenario.Scenario`."""
        params = scenario.spec.sim.cable_params  # a stretching cable's EA, for length commands
        EA = None if params is None else params.EA
        tda = make_tda(scenario.tda_method, **scenario.tda_options)
        return cls(scenario.robot, scenario.gains, scenario.variant, tda, scenario.output, EA)

    def lengths(self, setpoint: SetpointLike, tensions: ArrayLike) -> Array:
        """The unstretched lengths that hold ``tensions`` at the setpoint's pose (length output)."""
        if self.axial_stiffness is None:
            raise ValueError("length output needs the cables' axial_stiffness EA")
        R = quat_to_matrix(setpoint.pose[3:])
        return stretch_compensated_lengths(self.robot, setpoint.pose[:3], R, tensions, self.axial_stiffness)

    def command(self, state: StateLike, setpoint: SetpointLike | None,
                residual: Array | None = None) -> tuple[TdaResult, Array | None]:
        """The distribution of step k and, for length output, the lengths to command (else None)."""
        if setpoint is None:
            raise ValueError("feedback linearisation needs the setpoint of the state's step")
        result = self.step(state, setpoint, residual)
        return result, (self.lengths(setpoint, result.tensions) if self.output == "lengths" else None)

    def reset(self) -> None:
        self.tda.reset()

    def warm_up(self, state: StateLike, setpoint: SetpointLike, rounds: int = 3) -> None:
        """:func:`cdpr.laws.base.warm_up`."""
        warm_up(self, state, setpoint, rounds)

    @property
    def rows(self) -> list[int]:
        return list(controlled_rows(self.robot, self.variant))

    def step(self, state: StateLike, setpoint: SetpointLike, residual: Array | None = None) -> TdaResult:
        """The tensions of step k. ``residual``: a wrench on the controlled rows added to the law's before the
        distribution (a learned residual policy's, :mod:`cdpr.gym`); None adds nothing."""
        # Eq. 6–7 by cdpr.mechanics.control.FeedbackLaw and W by cdpr.mechanics.kinematics.WrenchMatrix, both set
        # up once:
        # the same numbers as feedback_linearisation and inverse_kinematics, without their per-call work.
        position, R, wrench = self._law(state.pose, state.twist, setpoint.pose, setpoint.twist, setpoint.accel)
        W6 = self._wrench_matrix(position, R)
        W = W6 if self._rows is None else W6[self._rows]
        if self.robot.cable_damping > 0.0:
            # The cables' viscous damping (the robot file's, applied by the sim along each cable as
            # c·l̇ on top of the tension) is a known external wrench of eq. 5: compensate it like gravity.
            rates = -(W6.T @ np.asarray(state.twist))  # l̇ = J v, J = −Wᵀ
            wrench = wrench - W @ (self.robot.cable_damping * rates)
        if residual is not None:
            wrench = wrench + residual
        return self.tda.solve(W, wrench, self._tmin, self._tmax)


LAW = Law(name="feedback_linearisation", build=ControllerCore.from_scenario,
          doc="feedback linearisation (eq. 6–7) on the setpoints, then the tension distribution")
