"""Platform dynamics (seed paper eq. 5) in the world frame at the centre of mass. Pure numpy.

    M(x) ẍ + C(x, ẋ) ẋ = W f + w_g + w_e

with ẍ = [a; α] (linear and angular acceleration, world frame), M = diag(m·I₃, R I Rᵀ),
C ẋ = [0; ω × (R I Rᵀ) ω] and w_g = [m g; 0]. In point-mass mode only the translational block exists.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, cast

import numpy as np
from numpy.typing import ArrayLike

from cdpr.mechanics.robot import GRAVITY
from cdpr.mechanics.rotation import Array, cross3

if TYPE_CHECKING:
    from cdpr.mechanics.robot import Robot


def world_inertia(robot: Robot, R: ArrayLike) -> Array:
    R = np.asarray(R, dtype=float)
    return R @ robot.inertia @ R.T


def mass_matrix(robot: Robot, R: ArrayLike) -> Array:
    """Spatial inertia matrix M (6×6; 3×3 in point-mass mode)."""
    if robot.mode == "point_mass":
        return robot.mass * np.eye(3)
    M = np.zeros((6, 6))
    M[:3, :3] = robot.mass * np.eye(3)
    M[3:, 3:] = world_inertia(robot, R)
    return M


def coriolis_wrench(robot: Robot, R: ArrayLike, twist: ArrayLike) -> Array:
    """C(x, ẋ) ẋ: the gyroscopic moment ω × (I_w ω) (zero force at the centre of mass)."""
    if robot.mode == "point_mass":
        return np.zeros(3)
    w = np.asarray(twist, dtype=float)[3:6]
    out = np.zeros(6)
    out[3:] = cross3(w, world_inertia(robot, R) @ w)
    return out


def gravity_wrench(robot: Robot) -> Array:
    """w_g = [m g; 0] (the centre of mass is the reference point, so gravity has no moment)."""
    g = robot.mass * GRAVITY
    return g if robot.mode == "point_mass" else np.r_[g, 0.0, 0.0, 0.0]


def required_wrench(robot: Robot, R: ArrayLike, twist: ArrayLike, accel: ArrayLike) -> Array:
    """The cable wrench W f that produces the acceleration ``accel`` (inverse dynamics, w_e = 0)."""
    accel = np.asarray(accel, dtype=float)
    return mass_matrix(robot, R) @ accel + coriolis_wrench(robot, R, twist) - gravity_wrench(robot)


def forward_dynamics(robot: Robot, R: ArrayLike, twist: ArrayLike, cable_wrench: ArrayLike,
                     external: ArrayLike | None = None) -> Array:
    """ẍ = M⁻¹ (W f + w_g + w_e − C ẋ), the Newton–Euler prediction of the platform's acceleration."""
    w = np.asarray(cable_wrench, dtype=float) + gravity_wrench(robot) - coriolis_wrench(robot, R, twist)
    if external is not None:
        w = w + np.asarray(external, dtype=float)
    return cast(Array, np.linalg.solve(mass_matrix(robot, R), w))
