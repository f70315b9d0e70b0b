"""A platform IMU at the centre of mass, axes of the platform frame: accelerometer ``Rᵀ (a − g) + b + σ n``, the
specific force, with ``a`` the centre of mass's mean acceleration over the step that led here ``(v_k − v_{k−1}) /
dt`` (zero at step 0, and after a gap in the steps), ``g = (0, 0, −9.81)``; gyroscope ``Rᵀ ω + b + σ n``."""

from __future__ import annotations

from typing import Any

from cdpr.columns import ChannelField, Column, Series
from cdpr.mechanics.robot import GRAVITY
from cdpr.sensors import encoders
from cdpr.sensors.base import Array, Param, Ros2Topic, SensorKind, Truth, vector

ACCEL = "sensors/imu/accel"  # [ax, ay, az] specific force in the platform frame, m/s²
GYRO = "sensors/imu/gyro"  # [wx, wy, wz] angular velocity in the platform frame, rad/s


def measure(truth: Truth, spec: Any, normals: Array) -> tuple[Array, ...]:
    Rt = truth.rotation.T
    accel = Rt @ (truth.acceleration - GRAVITY) + vector(spec.accel_bias, 3) + spec.accel_sigma * normals[:3]
    gyro = Rt @ truth.twist[3:] + vector(spec.gyro_bias, 3) + spec.gyro_sigma * normals[3:]
    return accel, gyro


KIND = SensorKind(
    name="imu", doc="the platform's specific force and angular rate, body frame",
    params=(Param("accel_sigma", 0.0, "m/s²", ge=0.0),
            Param("accel_bias", 0.0, "m/s², body frame: one number or [x, y, z]", kind="bias3"),
            Param("gyro_sigma", 0.0, "rad/s", ge=0.0),
            Param("gyro_bias", 0.0, "rad/s, body frame: one number or [x, y, z]", kind="bias3")),
    channels=(
        Column("accel", 3, "m/s²", "the IMU's specific force (acceleration minus gravity: +9.81 up at rest), "
               "platform frame", series=(Series(ACCEL),), fields=(ChannelField(encoders.CHANNEL, "accel"),)),
        Column("gyro", 3, "rad/s", "the IMU's angular velocity, platform frame",
               series=(Series(GYRO),), fields=(ChannelField(encoders.CHANNEL, "gyro"),)),
    ),
    draws=lambda spec, m: 6, measure=measure,
    ros2=(Ros2Topic("imu", "sensor_msgs/msg/Imu",
                    lambda r: {"angular_velocity": r["gyro"], "linear_acceleration": r["accel"]}, frame="platform"),),
)
