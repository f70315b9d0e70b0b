"""Feedback linearisation (seed paper eq. 6–7). Pure numpy.

The commanded acceleration (eq. 6) is

    ẍ = ẍ_d + K_p (x_d − x) + K_d (ẋ_d − ẋ)

with, in ``6dof`` mode, the orientation error taken on SO(3) as the world-frame rotation vector
e_R = log(R_d Rᵀ) and the angular velocity error ω_d − ω. The cable wrench that produces it (eq. 7,
in this project's sign convention, see :mod:`cdpr.kinematics`) is

    W f = M ẍ + C ẋ − w_g

``3dof`` is the paper's own experiment: only the position is controlled (force rows of W), the
platform's orientation is left free. Point-mass robots always use it; planar robots control x, z and
the rotation about y.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from cdpr.dynamics import required_wrench
from cdpr.robot import Robot
from cdpr.rotation import Array, orientation_error

Variant = Literal["6dof", "3dof"]


@dataclass(frozen=True)
class Gains:
    """Diagonal gains on [x, y, z, rx, ry, rz]."""

    kp: Array
    kd: Array

    @classmethod
    def of(cls, kp: float | ArrayLike, kd: float | ArrayLike) -> Gains:
        def six(g: float | ArrayLike) -> Array:
            a = np.asarray(g, dtype=float)
            return np.full(6, float(a)) if a.ndim == 0 else np.array(a, dtype=float).reshape(6)

        return cls(six(kp), six(kd))


def controlled_rows(robot: Robot, variant: Variant) -> tuple[int, ...]:
    """Rows of the 6×m wrench matrix (and of the 6-vectors) that ``variant`` controls on ``robot``."""
    if variant == "3dof" or robot.mode == "point_mass":
        return (0, 1, 2)
    return robot.controlled_rows


def commanded_acceleration(
    position: ArrayLike,
    R: ArrayLike,
    twist: ArrayLike,
    position_d: ArrayLike,
    R_d: ArrayLike,
    twist_d: ArrayLike,
    accel_d: ArrayLike,
    gains: Gains,
) -> Array:
    """Eq. 6 for all 6 DOF: [a; α] (world frame)."""
    e = np.empty(6)
    e[:3] = np.asarray(position_d, dtype=float) - np.asarray(position, dtype=float)
    e[3:] = orientation_error(R_d, R)
    de = np.asarray(twist_d, dtype=float) - np.asarray(twist, dtype=float)
    return np.asarray(accel_d, dtype=float) + gains.kp * e + gains.kd * de


def feedback_linearisation(
    robot: Robot,
    position: ArrayLike,
    R: ArrayLike,
    twist: ArrayLike,
    position_d: ArrayLike,
    R_d: ArrayLike,
    twist_d: ArrayLike,
    accel_d: ArrayLike,
    gains: Gains,
    variant: Variant = "6dof",
) -> Array:
    """Eq. 7: the wrench the cables must exert, restricted to the controlled rows (length 3 or 6)."""
    acc = commanded_acceleration(position, R, twist, position_d, R_d, twist_d, accel_d, gains)
    rows = controlled_rows(robot, variant)
    if robot.mode == "point_mass":
        return required_wrench(robot, R, twist, acc[:3])
    w = required_wrench(robot, R, twist, acc)
    return w[list(rows)]
