"""Feedback linearisation (seed paper eq. 6–7). Pure numpy.

The commanded acceleration (eq. 6) is

    ẍ = ẍ_d + K_p (x_d − x) + K_d (ẋ_d − ẋ)

with, in ``6dof`` mode, the orientation error taken on SO(3) as the world-frame rotation vector
e_R = log(R_d Rᵀ) and the angular velocity error ω_d − ω. The cable wrench that produces it (eq. 7,
in this project's sign convention, see :mod:`cdpr.mechanics.kinematics`) is

    W f = M ẍ + C ẋ − w_g

``3dof`` is the paper's own experiment: only the position is controlled (force rows of W), the
platform's orientation is left free. Point-mass robots always use it; planar robots control their plane's
two coordinates and the rotation about its normal (x, z and about y; or x, y and about z).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Literal

import numpy as np
from numpy.typing import ArrayLike

from cdpr.mechanics.dynamics import required_wrench
from cdpr.mechanics.robot import GRAVITY, Robot
from cdpr.mechanics.rotation import Array, orientation_error, quat_matrix

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
    """Rows of the 6×m wrench matrix (and of the 6-vectors) that ``variant`` controls on ``robot`` (``3dof``: the
    forces; in the horizontal x–y plane the two in it, the weight being out of the plane)."""
    if robot.mode == "planar" and robot.plane == "xy" and variant == "3dof":
        return (0, 1)
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


class FeedbackLaw:
    """Eq. 6–7 for one robot, gains and variant, set up once; the per-step work is a few dozen float
    operations on the wire's flat sequences (no per-call setup, no small numpy temporaries).

    ``law(pose, twist, pose_d, twist_d, accel_d)`` with poses ``[x, y, z, qx, qy, qz, qw]`` and 6-vectors
    returns ``(position, R, wrench)``: the measured position (3,), its rotation matrix and the wrench of
    :func:`feedback_linearisation` on the controlled rows, equal to it to rounding (the orientation error
    is taken on the quaternions, ``log(q_d q⁻¹)``, instead of on the matrix ``R_d Rᵀ``).
    """

    def __init__(self, robot: Robot, gains: Gains, variant: Variant = "6dof") -> None:
        self.point_mass = robot.mode == "point_mass"
        rows = controlled_rows(robot, variant)
        self.rows: list[int] | None = None if rows == (0, 1, 2, 3, 4, 5) or self.point_mass else list(rows)
        self.mass = float(robot.mass)
        self.inertia = np.array(robot.inertia, dtype=float)
        self.weight = (self.mass * GRAVITY).tolist()  # m g: the gravity wrench's force
        self.kp = gains.kp.tolist()
        self.kd = gains.kd.tolist()

    def __call__(
        self,
        pose: Sequence[float],
        twist: Sequence[float],
        pose_d: Sequence[float],
        twist_d: Sequence[float],
        accel_d: Sequence[float],
    ) -> tuple[Array, Array, Array]:
        x, y, z, qx, qy, qz, qw = pose
        xd, yd, zd, dx, dy, dz, dw = pose_d
        # A zero quaternion has no rotation: NaN, as quat_to_matrix gives (the distributor then
        # reports invalid_input), never a ZeroDivisionError in the controller.
        n = math.sqrt(qx * qx + qy * qy + qz * qz + qw * qw) or math.nan
        qx, qy, qz, qw = qx / n, qy / n, qz / n, qw / n
        n = math.sqrt(dx * dx + dy * dy + dz * dz + dw * dw) or math.nan
        dx, dy, dz, dw = dx / n, dy / n, dz / n, dw / n
        # e_R = log(q_d ⊗ q⁻¹) as a rotation vector, angle in [0, π]
        ew = dw * qw + dx * qx + dy * qy + dz * qz
        ex = qw * dx - dw * qx - (dy * qz - dz * qy)
        ey = qw * dy - dw * qy - (dz * qx - dx * qz)
        ez = qw * dz - dw * qz - (dx * qy - dy * qx)
        if ew < 0.0:
            ew, ex, ey, ez = -ew, -ex, -ey, -ez
        s = math.sqrt(ex * ex + ey * ey + ez * ez)
        k = 2.0 if s < 1e-12 else 2.0 * math.atan2(s, ew) / s
        error = (xd - x, yd - y, zd - z, ex * k, ey * k, ez * k)
        kp, kd = self.kp, self.kd
        acc = [
            a + p * e + d * (vd - v)
            for a, p, e, d, vd, v in zip(accel_d, kp, error, kd, twist_d, twist, strict=True)
        ]
        R = quat_matrix(qx, qy, qz, qw)
        m, (gx, gy, gz) = self.mass, self.weight
        force = [m * acc[0] - gx, m * acc[1] - gy, m * acc[2] - gz]
        if self.point_mass:
            return np.array((x, y, z)), R, np.array(force)
        (i00, i01, i02), (i10, i11, i12), (i20, i21, i22) = (R @ self.inertia @ R.T).tolist()  # R I Rᵀ
        _, _, _, ax, ay, az = acc
        _, _, _, wx, wy, wz = twist
        hx = i00 * wx + i01 * wy + i02 * wz  # h = I_w ω
        hy = i10 * wx + i11 * wy + i12 * wz
        hz = i20 * wx + i21 * wy + i22 * wz
        wrench = np.array(
            (
                *force,
                i00 * ax + i01 * ay + i02 * az + (wy * hz - wz * hy),
                i10 * ax + i11 * ay + i12 * az + (wz * hx - wx * hz),
                i20 * ax + i21 * ay + i22 * az + (wx * hy - wy * hx),
            )
        )
        return np.array((x, y, z)), R, wrench if self.rows is None else wrench[self.rows]
