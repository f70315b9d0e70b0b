"""The simulated sensors, declared once: each kind is its module (its scenario entry, its pure seeded model, its
columns, its ROS 2 topics) and a row of :data:`SENSOR_KINDS`. From this table follow the scenario's
``sim.sensors`` section, the ``sim/sensors`` message and the telemetry block (:mod:`cdpr.protocol.messages`), the
sim's readings (``cdpr_sim.sensors``), the recording's series and Foxglove channels (the columns' ``series`` and
``fields``), the ROS 2 topics, ``cdpr convert`` and docs/protocol.md's field list.

A new kind: a module like :mod:`cdpr.sensors.laser_tracker` and its row below (docs/protocol.md, "Adding a
sensor"). Each kind draws its noise from its own stream (seed, kind, step), so adding one never changes
another's readings.
"""

from __future__ import annotations

from cdpr.columns import Column
from cdpr.sensors import encoders, imu, laser_tracker, load_cells
from cdpr.sensors.base import COMMON, Param, Ros2Topic, SensorKind, Truth, latency_steps, period, truth

SENSOR_KINDS: tuple[SensorKind, ...] = (
    encoders.KIND,
    load_cells.KIND,
    imu.KIND,
    laser_tracker.KIND,
)
KINDS = {k.name: k for k in SENSOR_KINDS}
SENSOR_COLUMNS: tuple[Column, ...] = tuple(c for k in SENSOR_KINDS for c in k.channels)
COLUMN_KIND = {c.name: k for k in SENSOR_KINDS for c in k.channels}

__all__ = ["COLUMN_KIND", "COMMON", "KINDS", "SENSOR_COLUMNS", "SENSOR_KINDS", "Param", "Ros2Topic", "SensorKind",
           "Truth", "latency_steps", "period", "truth"]
