"""A laser tracker: the 3D position of a reflector on the platform (a platform point), measured from a station
on the frame, world frame. Each axis reads the true position plus white Gaussian noise of σ = ``sigma`` +
``sigma_per_m`` · the range (the station–reflector distance): 15 µm + 6 µm/m by default, the maximum permissible
error of a Leica AT960-class instrument. Present only when the scenario gives ``sim.sensors.laser_tracker``."""

from __future__ import annotations

from typing import Any

import numpy as np

from cdpr.columns import ChannelField, Column, Series
from cdpr.sensors.base import Array, Param, Ros2Topic, SensorKind, Truth

SERIES = "sensors/laser_tracker"  # [x, y, z] the reflector's measured position, world frame, m


def sigma(spec: Any, distance: float) -> float:
    """Each axis's standard deviation at ``distance`` m from the station."""
    return spec.sigma + spec.sigma_per_m * distance


def measure(truth: Truth, spec: Any, normals: Array) -> tuple[Array, ...]:
    p = truth.point(spec.reflector)
    distance = float(np.linalg.norm(p - np.asarray(spec.station, dtype=float)))
    return (p + sigma(spec, distance) * normals,)


KIND = SensorKind(
    name="laser_tracker", default=False,
    params=(Param("station", [0.0, 0.0, 0.0], "the tracker's position on the frame, world frame, m", kind="vec3"),
            Param("reflector", [0.0, 0.0, 0.0], "the reflector on the platform, platform frame (the robot file's), m",
                  kind="vec3"),
            Param("sigma", 15e-6, "white noise of each axis at zero range, m", ge=0.0),
            Param("sigma_per_m", 6e-6, "white noise added per metre of range, m/m", ge=0.0)),
    doc="the position of a reflector on the platform, measured from a station on the frame",
    channels=(Column("laser_tracker", 3, "m", "the reflector's measured position [x, y, z], world frame",
                     series=(Series(SERIES),), fields=(ChannelField("/sensors/laser_tracker", "position"),)),),
    draws=lambda spec, m: 3, measure=measure,
    ros2=(Ros2Topic("sensors/laser_tracker", "geometry_msgs/msg/PointStamped",
                    lambda r: {"point": r["laser_tracker"]}),),
)
