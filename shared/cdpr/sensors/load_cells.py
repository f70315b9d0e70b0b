"""Load cells, one per cable at its winch: ``f + b + σ n`` — the tension where the cable leaves the winch (the
frame end: for sagging cables it includes the cable's weight), over the step that led to this state, plus a bias
and white Gaussian noise. Published with the encoders on ROS 2 (``sensors/joint_states``' effort)."""

from __future__ import annotations

from typing import Any

from cdpr.columns import ChannelField, Column, Series
from cdpr.sensors import encoders
from cdpr.sensors.base import Array, Param, SensorKind, Truth, per_cable_bias, vector

SERIES = "sensors/load_cells"  # m values: cable tensions the load cells measure, N


def measure(truth: Truth, spec: Any, normals: Array) -> tuple[Array, ...]:
    m = len(truth.load_cell_tensions)
    return (truth.load_cell_tensions + vector(spec.bias, m) + spec.sigma * normals,)


KIND = SensorKind(
    name="load_cells", doc="the cables' tensions",
    params=(Param("sigma", 0.0, "white noise, N", ge=0.0),
            Param("bias", 0.0, "N: one number for every cell or one per cable", kind="bias")),
    channels=(Column("load_cells", None, "N", "the tensions the load cells measure at the winches (for sagging "
                     "cables, the frame-end tension), those of the step that led to this state, cable 0 first",
                     series=(Series(SERIES),), fields=(ChannelField(encoders.CHANNEL, "load_cells"),)),),
    draws=lambda spec, m: m, measure=measure,
    check=lambda spec, m: per_cable_bias(spec.bias, m, "bias"),
)
