"""Analyses of a scenario that need no simulation (pure).

:func:`tension_change_bound` derives, from the trajectory alone, how fast the cable tensions *must*
change: it is the bound the continuity-aware distribution is held to (docs/results.md).
"""

from __future__ import annotations

import numpy as np

from cdpr.config.scenario import Scenario
from cdpr.mechanics.control import controlled_rows
from cdpr.mechanics.dynamics import required_wrench
from cdpr.mechanics.kinematics import inverse_kinematics
from cdpr.mechanics.tda import make_tda

MARGIN = 2.0


def feedforward_tensions(scenario: Scenario) -> np.ndarray:
    """f*(t_k): the exact 2-norm distribution of the feed-forward wrench along the desired trajectory.

    That is what the tensions would be under perfect tracking (zero error, so no feedback term):
    the wrench of the desired acceleration, W at the desired pose, eq. 8 solved exactly.
    """
    robot = scenario.robot
    rows = list(controlled_rows(robot, scenario.variant))
    tda = make_tda("qp")
    out = np.empty((scenario.total_steps, robot.m))
    for k in range(scenario.total_steps):
        sp = scenario.trajectory.sample(k * scenario.dt)
        w = required_wrench(robot, sp.rotation, sp.twist, sp.accel[: 3 if robot.mode == "point_mass" else 6])
        w = w if robot.mode == "point_mass" else w[rows]
        W = inverse_kinematics(robot, sp.position, sp.rotation).wrench_matrix[rows]
        out[k] = tda.solve(W, w, robot.tmin, robot.tmax).tensions
    return out


def tension_change_bound(scenario: Scenario, margin: float = MARGIN) -> float:
    """B = margin · max_k ‖f*(t_{k+1}) − f*(t_k)‖∞ (N per step).

    The trajectory itself asks the tensions to move by at most max‖Δf*‖∞ per step; the closed loop
    adds feedback corrections of the size of the tracking error (sub-millimetre here), which the
    factor ``margin`` = 2 covers. A distribution whose tensions jump by more than B between two steps
    jumps for reasons of its own (solver noise, active-set switches), not because of the motion.
    """
    f = feedforward_tensions(scenario)
    return margin * float(np.abs(np.diff(f, axis=0)).max())
