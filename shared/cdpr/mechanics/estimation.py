"""State estimation from what a cable robot measures: the pose and twist from winch encoders and an IMU. Pure numpy.

A loosely coupled Kalman filter, one step per sensor reading:

* **Pose measurement**: forward kinematics of the encoders' lengths (:class:`cdpr.mechanics.forward.
  ForwardKinematics`, warm-started from the prediction), whose covariance is ``σ² (JᵀJ)⁻¹`` (``J`` the length
  Jacobian at the pose, σ the encoders' noise with their quantisation, ``q²/12``).
* **Translation**, per world axis, the state ``[p, v]``: predicted with the IMU's acceleration ``R f + g`` (``f``
  its specific force, body frame; the mean acceleration over the step, as the sim's semi-implicit step moves
  ``v ← v + a dt``, ``p ← p + v dt``), process noise from the accelerometer's σ; a step without its reading (no
  IMU) a constant velocity with a random acceleration of ``motion_walk`` (m/s²). Updated with the FK position.
* **Rotation**, per world axis, an error state ``[δθ, ω]`` about the predicted ``R`` (``R ← exp([ω dt]×) R``):
  updated with the FK orientation (``δθ = log(R_fk Rᵀ)``) and, with an IMU, with the gyroscope's rate
  ``R g`` (world frame); the correction is folded back into ``R``.

The filter is deterministic: the same readings in the same order give the same estimates. A step that skips
readings (a gap) is predicted over the gap.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from cdpr.mechanics.forward import ForwardKinematics, rotvec_matrix
from cdpr.mechanics.robot import GRAVITY, Robot
from cdpr.mechanics.rotation import Array, matrix_to_rotvec


@dataclass(frozen=True)
class EstimatorNoise:
    """What the filter assumes of the sensors (SI units): white noise σ of each reading, an encoder resolution
    (its quantisation adds ``q²/12`` to the variance), and the random acceleration (m/s²) and angular acceleration
    (rad/s²) the model allows between steps."""

    encoder_sigma: float = 2e-5
    encoder_resolution: float = 0.0
    accel_sigma: float = 0.02
    gyro_sigma: float = 0.002
    accel_walk: float = 0.05  # m/s²: the accelerometer's error between readings (a step with its reading)
    motion_walk: float = 20.0  # m/s²: the motion's acceleration the model allows (a step without one)
    angular_walk: float = 5.0  # rad/s², the angular rate's change the model allows (unmeasured angular accel)

    @property
    def length_variance(self) -> float:
        return self.encoder_sigma ** 2 + self.encoder_resolution ** 2 / 12.0


@dataclass(frozen=True)
class Estimate:
    """The filter's pose and twist at ``step`` (centre of mass, world frame)."""

    step: int
    position: Array  # (3,)
    rotation: Array  # (3, 3)
    twist: Array  # (6,) [v; ω]
    fk_residual: float  # the FK's max length residual, m (the encoders' consistency)


class PoseEstimator:
    """The filter of one robot (module docstring). :meth:`update` with each step's readings, in step order."""

    def __init__(self, robot: Robot, dt: float, noise: EstimatorNoise, position: ArrayLike | None = None,
                 rotation: ArrayLike | None = None) -> None:
        """``position``/``rotation``: where the platform starts, at rest, if known; otherwise the first reading's
        forward kinematics from the robot's home pose."""
        if robot.mode != "spatial":
            raise ValueError(f"the estimator needs a spatial robot (this one is {robot.mode})")
        self.robot, self.dt, self.noise = robot, float(dt), noise
        # noisy lengths converge linearly: a step a thousandth of the noise is converged enough here
        self.fk = ForwardKinematics(robot, tol=max(1e-12, 1e-3 * noise.encoder_sigma))
        self.p = np.array(robot.home_position if position is None else position, dtype=float)
        self.R = np.array(robot.home_rotation if rotation is None else rotation, dtype=float)
        self.known = position is not None and rotation is not None
        self.v, self.w = np.zeros(3), np.zeros(3)
        start = 1e-6  # variance of the start: a millimetre, a milliradian; at rest, to a mm/s
        # each axis's 2×2 covariance [[a, b], [b, c]], three axes at once: translation [p, v], rotation [δθ, ω]
        self.t_a, self.t_b, self.t_c = np.full(3, start), np.zeros(3), np.full(3, start)
        self.r_a, self.r_b, self.r_c = np.full(3, start), np.zeros(3), np.full(3, start)
        self.step = -1

    def update(self, step: int, lengths: ArrayLike, accel: ArrayLike | None = None,
               gyro: ArrayLike | None = None, stretch: tuple[ArrayLike, ArrayLike] | None = None) -> Estimate:
        """The estimate at ``step`` from its readings: the encoders' ``lengths`` (m), the IMU's specific force
        ``accel`` (m/s², body frame) and rate ``gyro`` (rad/s, body frame), each None when not read; ``stretch``
        ``(tensions, EA)``: the lengths are unstretched ones, stretched by those tensions (N) to solve for."""
        dt = self.dt * (step - self.step if self.step >= 0 else 0)
        self._predict(dt, None if accel is None else np.asarray(accel, dtype=float))
        fk = (self.fk.solve(lengths, self.p, self.R) if stretch is None
              else self.fk.solve(lengths, self.p, self.R, tensions=stretch[0], EA=stretch[1]))
        if self.step < 0 and not self.known:  # the first reading: the pose is its forward kinematics
            self.p, self.R = fk.position.copy(), fk.rotation.copy()
        cov = self._pose_covariance(fk.position, fk.rotation)
        self._correct_translation(fk.position, np.diag(cov)[:3])
        self._correct_rotation(fk.rotation, np.diag(cov)[3:], None if gyro is None else np.asarray(gyro, dtype=float))
        self.step = step
        return Estimate(step, self.p.copy(), self.R.copy(), np.concatenate([self.v, self.w]), float(fk.residual))

    # -- the filter's steps -------------------------------------------------------------------------------------
    def _predict(self, dt: float, accel: Array | None) -> None:
        if dt <= 0.0:
            return
        n = self.noise
        self.R = rotvec_matrix(*(self.w * dt).tolist()) @ self.R  # the orientation at the reading's step
        if accel is not None:  # the specific force of the step that led here, in the body frame of its end
            a = self.R @ accel + GRAVITY
            q_a = n.accel_sigma ** 2 + n.accel_walk ** 2
        else:
            a = np.zeros(3)
            q_a = n.motion_walk ** 2
        self.v = self.v + a * dt
        self.p = self.p + self.v * dt
        # P ← F P Fᵀ + q G Gᵀ, F = [[1, dt], [0, 1]], G = [dt², dt] (the input enters v by dt, p by dt²)
        g0, g1 = dt * dt, dt
        for q, (a0, b0, c0) in ((q_a, (self.t_a, self.t_b, self.t_c)),
                                (n.angular_walk ** 2, (self.r_a, self.r_b, self.r_c))):
            a0 += 2.0 * dt * b0 + dt * dt * c0 + q * g0 * g0
            b0 += dt * c0 + q * g0 * g1
            c0 += q * g1 * g1

    def _pose_covariance(self, p: Array, R: Array) -> Array:
        """σ² (JᵀJ)⁻¹ of the FK pose: 6×6, position then orientation (world frame)."""
        J = self.fk.jacobian(p, R)
        cov: Array = self.noise.length_variance * np.linalg.inv(J.T @ J).astype(float)
        return cov

    def _correct_translation(self, p_fk: Array, var: Array) -> None:
        a, b, c = self.t_a, self.t_b, self.t_c
        s = a + var  # H = [1, 0]: the FK's position
        k0, k1 = a / s, b / s
        innovation = p_fk - self.p
        self.p = self.p + k0 * innovation
        self.v = self.v + k1 * innovation
        c -= k1 * b
        b -= k0 * b
        a -= k0 * a

    def _correct_rotation(self, R_fk: Array, var: Array, gyro: Array | None) -> None:
        a, b, c = self.r_a, self.r_b, self.r_c
        err = matrix_to_rotvec(R_fk @ self.R.T)  # the FK's orientation less the prediction's, world frame
        s = a + var  # H = [1, 0]: the FK's angle (the error state's angle is 0 before it)
        k0, k1 = a / s, b / s
        angle = k0 * err
        w = self.w + k1 * err
        c -= k1 * b
        b -= k0 * b
        a -= k0 * a
        if gyro is not None:  # H = [0, 1]: the gyroscope's rate, in the world frame
            s = c + self.noise.gyro_sigma ** 2
            k0, k1 = b / s, c / s
            innovation = self.R @ gyro - w
            angle = angle + k0 * innovation
            w = w + k1 * innovation
            a -= k0 * b
            b -= k0 * c
            c -= k1 * c
        self.w = w
        self.R = rotvec_matrix(*angle.tolist()) @ self.R


def estimate_errors(estimated: ArrayLike, actual: ArrayLike) -> tuple[Array, Array]:
    """Per row of two (n, 7) pose arrays (x, y, z, qx, qy, qz, qw): the distance between the positions (m) and the
    angle of the rotation from one orientation to the other (rad, in [0, π]; a quaternion's sign does not count),
    as 4·atan2(‖q₁ − q₂‖, ‖q₁ + q₂‖) with q₂ on q₁'s side: accurate near 0, where an arccos of a dot is not."""
    e = np.asarray(estimated, dtype=float).reshape(-1, 7)
    a = np.asarray(actual, dtype=float).reshape(-1, 7)
    position = np.linalg.norm(e[:, :3] - a[:, :3], axis=1)
    q1 = e[:, 3:] / np.linalg.norm(e[:, 3:], axis=1, keepdims=True)
    q2 = a[:, 3:] / np.linalg.norm(a[:, 3:], axis=1, keepdims=True)
    q2 = np.where(np.sum(q1 * q2, axis=1, keepdims=True) < 0.0, -q2, q2)
    angle = 4.0 * np.arctan2(np.linalg.norm(q1 - q2, axis=1), np.linalg.norm(q1 + q2, axis=1))
    return position, angle
