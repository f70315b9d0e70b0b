"""``controller.feedback: sensors``: the state a law is fed, estimated from ``sim/sensors`` instead of read from
``sim/state``. No I/O.

Each step's readings go through :class:`cdpr.mechanics.estimation.PoseEstimator` (the encoders' lengths through
forward kinematics, the IMU's specific force and rate), in step order; the law then gets a :class:`State` whose
pose and twist are the estimate's, whose cable lengths are the encoders' and whose tensions are the load cells'
(zeros without). A reading asked for again (the clock's resend) gets the state it got the first time.

Stretching cables (``sim.cable_model`` elastic or sag, whose ``EA`` the session says) with load cells: the encoders
pay out unstretched lengths, so forward kinematics solves for the lengths the measured tensions stretch them to,
``l0 (1 + f / EA)`` (:meth:`cdpr.mechanics.forward.ForwardKinematics.solve`). A sagging cable's arc is still taken
for its chord.
"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from cdpr.errors import InputError
from cdpr.mechanics.estimation import EstimatorNoise, PoseEstimator
from cdpr.mechanics.robot import Robot
from cdpr.mechanics.rotation import matrix_to_quat
from cdpr.protocol import Sensors, State
from cdpr.protocol.session import SessionInfo

HISTORY = 1024  # states kept for readings asked for again (a sim going on from a snapshot: 50 steps back)
ENCODER_SIGMA_FLOOR = 1e-7  # m: an ideal encoder still has the float's rounding; keeps the FK covariance finite


def noise_of(sensors: Mapping[str, Any]) -> tuple[EstimatorNoise, bool]:
    """What the estimator assumes of a session's sensors (its ``sim.sensors`` entries, as a map: the scenario's,
    or ``session/info``'s), and whether they include an IMU."""
    encoders, imu = sensors.get("encoders") or {}, sensors.get("imu")
    noise = EstimatorNoise(encoder_sigma=max(float(encoders.get("sigma", 0.0)), ENCODER_SIGMA_FLOOR),
                           encoder_resolution=float(encoders.get("resolution", 0.0)),
                           accel_sigma=0.0 if imu is None else float(imu.get("accel_sigma", 0.0)),
                           gyro_sigma=0.0 if imu is None else max(float(imu.get("gyro_sigma", 0.0)), 1e-6))
    return noise, imu is not None


class SensorFeedback:
    """The controller's view of the platform from its sensors (module docstring): the controller node's, and the
    SDK's for a remote controller (``cdpr.runtime.client``, ``--feedback sensors``)."""

    def __init__(self, robot: Robot, dt: float, sensors: Mapping[str, Any], position: ArrayLike | None = None,
                 rotation: ArrayLike | None = None, EA: float | list[float] | None = None) -> None:
        self.noise, self.imu = noise_of(sensors)
        # the stretch correction: the cables' EA, when they stretch and the load cells measure their tensions
        self.EA = EA if sensors.get("load_cells") else None
        self.m = robot.m
        # the encoders' zero errors (the robot file's encoder_offset, cdpr calibrate), taken off their readings
        self.offsets = np.array(robot.encoder_offsets, dtype=float) if robot.encoder_offsets.any() else None
        self.estimator = PoseEstimator(robot, dt, self.noise, position, rotation)
        self.states: OrderedDict[int, State] = OrderedDict()

    @classmethod
    def from_scenario(cls, scenario: Any) -> SensorFeedback:
        """For a :class:`cdpr.config.scenario.Scenario` (its start pose known)."""
        params = scenario.spec.sim.cable_params
        return cls(scenario.robot, scenario.dt, scenario.spec.sim.sensors.model_dump(), scenario.initial_position,
                   scenario.initial_rotation, getattr(params, "EA", None))

    @classmethod
    def from_info(cls, info: SessionInfo) -> SensorFeedback:
        """For a session known by its ``session/info`` (the start: the first reading's forward kinematics)."""
        sensors = (info.raw.get("sim") or {}).get("sensors")
        if not isinstance(sensors, dict) or not sensors.get("encoders"):
            raise InputError(f"session {info.scenario}: feedback from sensors needs its winch encoders (sim.sensors."
                             "encoders in session/info)")
        sim = info.raw.get("sim") or {}
        params = sim.get(sim.get("cable_model")) if isinstance(sim.get("cable_model"), str) else None
        EA = params.get("EA") if isinstance(params, dict) else None
        for name in ("encoders", "imu", *(["load_cells"] if EA is not None else [])):
            entry = sensors.get(name) or {}
            if any(entry.get(key) for key in ("rate", "latency", "dropout")):
                raise InputError(f"session {info.scenario}: feedback from sensors reads sim.sensors.{name} every "
                                 "step as measured then: its rate, latency and dropout must be 0")
        return cls(info.robot, info.dt, sensors, EA=EA)

    def state(self, reading: Sensors) -> State | None:
        """The state of ``reading``'s step for the law, or None when the reading has no encoder lengths."""
        known = self.states.get(reading.step)
        if known is not None:
            return known
        counted = reading.get("encoders")
        if counted is None:
            return None
        lengths = counted if self.offsets is None else tuple((np.asarray(counted) - self.offsets).tolist())
        accel, gyro = (reading.get("accel"), reading.get("gyro")) if self.imu else (None, None)
        measured = reading.get("load_cells")
        stretch = None if self.EA is None or measured is None else (measured, self.EA)
        e = self.estimator.update(reading.step, lengths, accel, gyro, stretch)
        tensions = measured or (0.0,) * self.m
        state = State(reading.step, reading.t, (*e.position.tolist(), *matrix_to_quat(e.rotation).tolist()),
                      tuple(e.twist.tolist()), tuple(lengths), tuple(tensions))
        self.states[reading.step] = state
        while len(self.states) > HISTORY:
            self.states.popitem(last=False)
        return state
