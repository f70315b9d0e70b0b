"""Simulated sensors: noise statistics against the configured σ and bias, quantisation, the IMU's physics
(free fall reads zero, hanging still reads +g up, in the platform frame), determinism with a seed, and
the sim/sensors message. The statistics use 20 000 draws: a mean within 5 σ/√n, a σ within 5 %."""

from __future__ import annotations

import math

import numpy as np
import pytest

from cdpr.config.robot import load_robot
from cdpr.config.scenario import load_scenario
from cdpr.mechanics.rotation import rpy_to_matrix
from cdpr.protocol import ProtocolError, Sensors
from cdpr_sim.core import PlatformSim
from cdpr_sim.elastic import ElasticSim
from cdpr_sim.sensors import SensorConfig, SensorSuite, measure, truth

N = 20_000
M = 8
G = 9.81


def fixed_truth(step: int, R: np.ndarray | None = None) -> object:
    return truth(step, step * 1e-3, np.eye(3) if R is None else R, [0.1, -0.2, 0.3, 0.4, -0.5, 0.6],
                 [1.0, -2.0, 0.5], np.linspace(3.0, 6.0, M), np.linspace(10.0, 80.0, M))


def readings(config: SensorConfig, R: np.ndarray | None = None) -> dict[str, np.ndarray]:
    msgs = [measure(fixed_truth(k, R), config) for k in range(N)]  # type: ignore[arg-type]
    names = ("encoders", "load_cells", "accel", "gyro")
    return {name: np.array([getattr(m, name) for m in msgs]) for name in names}


def test_noise_statistics_match_the_configuration() -> None:
    R = rpy_to_matrix(0.3, -0.2, 1.1)
    config = SensorConfig(M, seed=11, encoder_sigma=2e-4, load_cell_sigma=0.7,
                          load_cell_bias=np.linspace(-1, 1, M), accel_sigma=0.05, accel_bias=[0.1, -0.2, 0.3],
                          gyro_sigma=0.01, gyro_bias=0.02)
    r = readings(config, R)
    t = fixed_truth(0, R)
    expected = {
        "encoders": (t.encoder_lengths, 2e-4),  # type: ignore[attr-defined]
        "load_cells": (t.load_cell_tensions + np.linspace(-1, 1, M), 0.7),  # type: ignore[attr-defined]
        # specific force in the platform frame: Rᵀ (a − g) + bias
        "accel": (R.T @ np.array([1.0, -2.0, 0.5 + G]) + [0.1, -0.2, 0.3], 0.05),
        "gyro": (R.T @ np.array([0.4, -0.5, 0.6]) + 0.02, 0.01),
    }
    for name, (mean, sigma) in expected.items():
        values = r[name]
        assert np.abs(values.mean(axis=0) - mean).max() < 5.0 * sigma / math.sqrt(N), name
        assert values.std(axis=0) == pytest.approx(np.full(values.shape[1], sigma), rel=0.05), name
    # the sensors' noises are independent of each other
    first_axes = np.column_stack([r[name][:, 0] for name in ("encoders", "load_cells", "accel", "gyro")])
    corr = np.corrcoef(first_axes.T)
    assert np.abs(corr - np.eye(4)).max() < 5.0 / math.sqrt(N)


def test_encoders_are_quantised() -> None:
    q = 1e-4
    exact = readings(SensorConfig(M, encoder_resolution=q))["encoders"]
    t = fixed_truth(0).encoder_lengths  # type: ignore[attr-defined]
    assert np.abs(exact[0] - t).max() <= q / 2 + 1e-15
    assert np.allclose(exact / q, np.round(exact / q), atol=1e-9)
    noisy = readings(SensorConfig(M, seed=2, encoder_resolution=q, encoder_sigma=q))["encoders"]
    assert np.allclose(noisy / q, np.round(noisy / q), atol=1e-9)  # noise, then quantisation: on the grid
    # σ² + q²/12 (quantisation noise of a value spread over several steps), mean unbiased
    assert noisy.std(axis=0) == pytest.approx(np.full(M, math.sqrt(q * q + q * q / 12.0)), rel=0.05)
    assert np.abs(noisy.mean(axis=0) - t).max() < 5.0 * q / math.sqrt(N)


def test_determinism_with_a_seed() -> None:
    config = SensorConfig(M, seed=5, encoder_sigma=1e-3, load_cell_sigma=1.0, accel_sigma=0.1, gyro_sigma=0.1)
    a = measure(fixed_truth(42), config)  # type: ignore[arg-type]
    assert a == measure(fixed_truth(42), config)  # type: ignore[arg-type]
    assert a != measure(fixed_truth(43), config)  # type: ignore[arg-type]
    other_seed = SensorConfig(M, seed=6, encoder_sigma=1e-3, load_cell_sigma=1.0, accel_sigma=0.1,
                              gyro_sigma=0.1)
    assert a.encoders != measure(fixed_truth(42), other_seed).encoders  # type: ignore[arg-type]
    # one sensor's configuration does not change another's noise
    quiet_imu = SensorConfig(M, seed=5, encoder_sigma=1e-3, load_cell_sigma=1.0)
    assert measure(fixed_truth(42), quiet_imu).encoders == a.encoders  # type: ignore[arg-type]


def test_imu_reads_zero_in_free_fall_and_g_up_when_hanging_still() -> None:
    robot = load_robot("caroca").with_mass(15.0).replace(tmin=1.0, tmax=6500.0)
    R = rpy_to_matrix(0.2, 0.1, -0.4)
    config = SensorConfig(robot.m)
    # free fall (no cable pulls): the accelerometer feels nothing, the gyroscope the spin in its own frame
    spin = [0.0, 0.0, 0.0, 0.0, 0.0, 0.3]
    falling = PlatformSim(robot.replace(cable_damping=0.0), 1e-3, [0.0, 0.0, 1.5], R, spin)
    suite = SensorSuite(config, 1e-3)
    first = suite.read(falling)
    assert first.accel == pytest.approx(R.T @ [0.0, 0.0, G], abs=1e-12)  # step 0: no step yet, a = 0
    for _ in range(3):
        falling.step(np.zeros(robot.m))
        reading = suite.read(falling)  # every step, as the sim node does
    s = falling.state()
    assert reading.accel == pytest.approx([0.0, 0.0, 0.0], abs=1e-9)
    assert reading.gyro == pytest.approx(s.rotation.T @ s.twist[3:], abs=1e-12)  # (z is no principal axis)
    assert reading.encoders == pytest.approx(s.cable_lengths)
    assert reading.load_cells == pytest.approx(np.zeros(robot.m))
    assert suite.read(falling) is reading  # a resend reads the same message
    falling.step(np.zeros(robot.m))
    falling.step(np.zeros(robot.m))
    after_gap = suite.read(falling)
    assert after_gap.accel == pytest.approx(falling.state().rotation.T @ [0.0, 0.0, G], abs=1e-12)
    # winches holding the platform still: +g up in the platform frame; encoders read the paid-out l0
    held = ElasticSim(robot, 1e-3, [0.0, 0.0, 1.0], R, command="lengths")
    suite = SensorSuite(config, 1e-3)
    l0 = held.encoder_lengths().copy()
    for _ in range(5):
        held.step(l0)
        reading = suite.read(held)
    assert reading.accel == pytest.approx(R.T @ [0.0, 0.0, G], abs=1e-6)
    assert reading.encoders == pytest.approx(l0, abs=1e-12)
    assert np.all(np.array(reading.encoders) < held.state().cable_lengths)  # the cables are stretched
    assert reading.load_cells == pytest.approx(held.state().tensions, rel=1e-9)


def test_sensors_message_and_configuration() -> None:
    msg = Sensors(3, 0.003, (4.0,) * M, (20.0,) * M, (0.0, 0.0, 9.81), (0.0, 0.0, 0.1))
    assert Sensors.decode(msg.encode(), cables=M) == msg
    with pytest.raises(ProtocolError, match=r"^load_cells: expected 8 numbers"):
        Sensors.decode(Sensors(3, 0.003, (4.0,) * M, (20.0,) * 7, (0.0,) * 3, (0.0,) * 3).encode())
    with pytest.raises(ProtocolError, match=r"^accel: expected 3 numbers"):
        Sensors.decode(Sensors(3, 0.003, (4.0,) * M, (20.0,) * M, (0.0,) * 2, (0.0,) * 3).encode())
    with pytest.raises(ValueError, match="load_cell_bias"):
        SensorConfig(M, load_cell_bias=[1.0, 2.0])
    with pytest.raises(ValueError, match="gyro_sigma"):
        SensorConfig(M, gyro_sigma=-1.0)
    spec = load_scenario("caroca_15kg_winch").spec.sim.sensors
    assert spec is not None
    config = SensorConfig.from_spec(spec, M)
    assert config.seed == 7
    assert config.encoder_resolution == 1e-5
    assert config.load_cell_sigma == 0.5
    assert np.array_equal(config.load_cell_bias, np.full(M, 0.2))
    assert np.array_equal(config.accel_bias, [0.01, -0.01, 0.02])
