"""Simulated sensors: winch encoders, load cells and a platform IMU, read from the sim's ground truth. No I/O.

Models (σ, biases, resolution and seed from the scenario's ``sim.sensors``; every noise is white and
Gaussian, independent between sensors and steps)
-------------------------------------------------------------------------------------------------------
* **Encoders** (one per winch): ``q · round((l + σ n) / q)`` — the length the winch has paid out (the
  unstretched length ``l0`` for winch-driven cable models, the cable length for the ideal and U-P-S
  ones) plus noise, quantised to the resolution ``q`` (no quantisation when q = 0).
* **Load cells** (one per cable, at the winch): ``f + b + σ n`` — the tension where the cable leaves
  the winch (the frame end: for sagging cables it includes the cable's weight), over the step that led
  to this state, plus bias and noise.
* **IMU** (at the centre of mass, axes of the platform frame): accelerometer ``Rᵀ (a − g) + b + σ n``,
  the specific force, with ``a`` the centre of mass's mean acceleration over the step that led here
  ``(v_k − v_{k−1}) / dt`` (zero at step 0, and after a gap in the steps), ``g = (0, 0, −9.81)``; gyroscope
  ``Rᵀ ω + b + σ n``.

Determinism: the noise of step k is drawn from ``numpy.random.default_rng([seed, k])``, always in the
same order (m encoders, m load cells, 3 accelerometer axes, 3 gyroscope axes), so a reading is a pure
function of the seed, the step and the truth: the same on a resend, in another run, whatever the
configuration of the other sensors.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from cdpr.config.scenario import SensorsSpec
from cdpr.mechanics.robot import GRAVITY
from cdpr.mechanics.rotation import Array
from cdpr.protocol import Sensors
from cdpr_sim.core import SimModel


@dataclass(frozen=True)
class SensorConfig:
    """Noise, bias and resolution of every sensor (SI units), and the seed."""

    cables: int
    seed: int = 0
    encoder_resolution: float = 0.0  # m
    encoder_sigma: float = 0.0  # m
    load_cell_sigma: float = 0.0  # N
    load_cell_bias: ArrayLike = 0.0  # N, one number or (m,); an (m,) read-only array after construction
    accel_sigma: float = 0.0  # m/s²
    accel_bias: ArrayLike = 0.0  # m/s², one number or (3,) platform frame; (3,) after construction
    gyro_sigma: float = 0.0  # rad/s
    gyro_bias: ArrayLike = 0.0  # rad/s, one number or (3,) platform frame; (3,) after construction

    def __post_init__(self) -> None:
        for name, n in (("load_cell_bias", self.cables), ("accel_bias", 3), ("gyro_bias", 3)):
            raw = np.asarray(getattr(self, name), dtype=float)
            value = np.full(n, float(raw)) if raw.ndim == 0 else np.array(raw)
            if value.shape != (n,) or not np.all(np.isfinite(value)):
                raise ValueError(f"{name} must be one number or {n} finite numbers")
            value.flags.writeable = False
            object.__setattr__(self, name, value)
        for name in ("encoder_resolution", "encoder_sigma", "load_cell_sigma", "accel_sigma", "gyro_sigma"):
            v = float(getattr(self, name))
            if not (np.isfinite(v) and v >= 0.0):
                raise ValueError(f"{name} must be a finite number >= 0 (got {v})")
        if not (isinstance(self.seed, int) and self.seed >= 0):
            raise ValueError(f"seed must be an integer >= 0 (got {self.seed!r})")

    @classmethod
    def from_spec(cls, spec: SensorsSpec, cables: int) -> SensorConfig:
        """From a :class:`cdpr.config.scenario.SensorsSpec`."""
        return cls(
            cables=cables,
            seed=spec.seed,
            encoder_resolution=spec.encoders.resolution,
            encoder_sigma=spec.encoders.sigma,
            load_cell_sigma=spec.load_cells.sigma,
            load_cell_bias=np.asarray(spec.load_cells.bias, dtype=float),
            accel_sigma=spec.imu.accel_sigma,
            accel_bias=np.asarray(spec.imu.accel_bias, dtype=float),
            gyro_sigma=spec.imu.gyro_sigma,
            gyro_bias=np.asarray(spec.imu.gyro_bias, dtype=float),
        )


@dataclass(frozen=True)
class SensorTruth:
    """What the sensors measure, exactly, at one step (world frame unless said otherwise)."""

    step: int
    t: float
    rotation: Array  # (3, 3) platform → world
    twist: Array  # (6,) [v; ω]
    acceleration: Array  # (3,) the centre of mass's mean acceleration over the last step
    encoder_lengths: Array  # (m,) m
    load_cell_tensions: Array  # (m,) N


def measure(truth: SensorTruth, config: SensorConfig) -> Sensors:
    """The readings of one step: a pure function of the truth, the configuration, the seed and the step."""
    m = config.cables
    noise = np.random.default_rng([config.seed, truth.step]).standard_normal(2 * m + 6)
    encoders = np.asarray(truth.encoder_lengths, dtype=float) + config.encoder_sigma * noise[:m]
    if config.encoder_resolution > 0.0:
        encoders = config.encoder_resolution * np.round(encoders / config.encoder_resolution)
    cells = np.asarray(truth.load_cell_tensions, dtype=float) + np.asarray(config.load_cell_bias)
    cells = cells + config.load_cell_sigma * noise[m : 2 * m]
    Rt = np.asarray(truth.rotation, dtype=float).T
    accel = Rt @ (np.asarray(truth.acceleration, dtype=float) - GRAVITY) + np.asarray(config.accel_bias)
    accel = accel + config.accel_sigma * noise[2 * m : 2 * m + 3]
    gyro = Rt @ np.asarray(truth.twist, dtype=float)[3:] + np.asarray(config.gyro_bias)
    gyro = gyro + config.gyro_sigma * noise[2 * m + 3 :]
    return Sensors(truth.step, truth.t, tuple(encoders.tolist()), tuple(cells.tolist()),
                   tuple(accel.tolist()), tuple(gyro.tolist()))


class SensorSuite:
    """The sensors of one sim (owned by the sim node): the truth from the sim, one reading per step.

    :meth:`read` takes the sim's current state (and, when the sim has them, its winches'
    ``encoder_lengths()`` and ``load_cell_tensions()``), keeps the previous step's twist for the mean
    acceleration, and returns the same message again for a step already read (a resend).
    """

    def __init__(self, config: SensorConfig, dt: float) -> None:
        self.config = config
        self.dt = float(dt)
        self.previous: tuple[int, Array] | None = None  # (step, twist) of the last new step read (a sim's snapshot)
        self._last: Sensors | None = None

    def read(self, sim: SimModel) -> Sensors:
        state = sim.state()
        if self._last is not None and self._last.step == state.step:
            return self._last
        twist = np.asarray(state.twist, dtype=float)
        prev = self.previous
        if prev is not None and prev[0] == state.step - 1:
            acceleration = (twist[:3] - prev[1][:3]) / self.dt
        else:
            acceleration = np.zeros(3)
        encoders, cells = sim.encoder_lengths(), sim.load_cell_tensions()
        truth = SensorTruth(state.step, state.t, state.rotation, twist, acceleration, encoders, cells)
        self.previous = (state.step, twist)
        self._last = measure(truth, self.config)
        return self._last


def truth(step: int, t: float, rotation: ArrayLike, twist: ArrayLike, acceleration: ArrayLike,
          encoder_lengths: ArrayLike, load_cell_tensions: ArrayLike) -> SensorTruth:
    """A :class:`SensorTruth` from array-likes (for tests and offline use)."""
    return SensorTruth(step, t, *(np.asarray(x, dtype=float) for x in (rotation, twist, acceleration,
                                                                        encoder_lengths, load_cell_tensions)))
