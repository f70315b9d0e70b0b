"""Winch encoders, one per winch: ``q · round((l + σ n) / q)`` — the length the winch has paid out (the
unstretched length ``l0`` for winch-driven cable models, the cable length for the ideal and U-P-S ones) plus
white Gaussian noise, quantised to the resolution ``q`` (none when q = 0)."""

from __future__ import annotations

from typing import Any

import numpy as np

from cdpr.columns import ChannelField, Column, Series
from cdpr.sensors.base import Array, Param, Ros2Topic, SensorKind, Truth

SERIES = "sensors/encoders"  # m values: cable lengths the winch encoders measure, m
CHANNEL = "/sensors"  # Foxglove JSON channel of the encoders, load cells and IMU


def measure(truth: Truth, spec: Any, normals: Array) -> tuple[Array, ...]:
    lengths = truth.encoder_lengths + spec.sigma * normals
    if spec.resolution > 0.0:
        lengths = spec.resolution * np.round(lengths / spec.resolution)
    return (lengths,)


KIND = SensorKind(
    name="encoders", doc="the winches' cable lengths",
    params=(Param("resolution", 0.0, "quantisation step, m (0: none)", ge=0.0),
            Param("sigma", 0.0, "white noise, m", ge=0.0)),
    channels=(Column("encoders", None, "m", "the cable lengths the winch encoders measure, cable 0 first: the "
                     "paid-out (unstretched) length for winch-driven cable models, the cable length otherwise",
                     series=(Series(SERIES),), fields=(ChannelField(CHANNEL, "encoders"),)),),
    draws=lambda spec, m: m, measure=measure,
    ros2=(Ros2Topic("sensors/joint_states", "sensor_msgs/msg/JointState",
                    lambda r: {"position": r["encoders"], "effort": r.get("load_cells", ())}, frame=""),),
)
