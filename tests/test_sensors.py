"""Simulated sensors: noise statistics against the configured σ and bias, quantisation, the IMU's physics
(free fall reads zero, hanging still reads +g up, in the platform frame), determinism with a seed, each kind's
own noise stream, rates, latencies and dropouts, and the sim/sensors message. The statistics use 20 000 draws: a
mean within 5 σ/√n, a σ within 5 %."""

from __future__ import annotations

import math
import zlib
from typing import Any

import numpy as np
import pytest
from msgspec import UNSET

from cdpr.config.robot import load_robot
from cdpr.config.scenario import SensorsSpec, load_scenario
from cdpr.mechanics.rotation import rpy_to_matrix
from cdpr.protocol import ProtocolError, Sensors, Telemetry
from cdpr.sensors import KINDS, truth
from cdpr_sim.core import PlatformSim
from cdpr_sim.elastic import ElasticSim
from cdpr_sim.sensors import Draws, SensorSuite, draws

N = 20_000
M = 8
G = 9.81
ROBOT = load_robot("caroca")


def fixed_truth(step: int, R: np.ndarray | None = None) -> Any:
    return truth(step, step * 1e-3, np.eye(3) if R is None else R, [0.1, -0.2, 0.3, 0.4, -0.5, 0.6],
                 [1.0, -2.0, 0.5], np.linspace(3.0, 6.0, M), np.linspace(10.0, 80.0, M))


def moving_truth(step: int) -> Any:
    """A platform moving at 1 m/s along x."""
    return truth(step, step * 1e-3, np.eye(3), [1.0, 0.0, 0.0, 0.0, 0.0, 0.0], [0.0, 0.0, 0.0],
                 np.linspace(3.0, 6.0, M), np.linspace(10.0, 80.0, M), [step * 1e-3, 0.0, 1.0])


def suite(**entries: Any) -> SensorSuite:
    return SensorSuite(SensorsSpec.model_validate(entries), ROBOT, 1e-3)


def readings(s: SensorSuite, R: np.ndarray | None = None, n: int = N) -> dict[str, np.ndarray]:
    msgs = [s.take(fixed_truth(k, R)) for k in range(n)]
    names = ("encoders", "load_cells", "accel", "gyro")
    return {name: np.array([getattr(m, name) for m in msgs]) for name in names}


def test_noise_statistics_match_the_configuration() -> None:
    R = rpy_to_matrix(0.3, -0.2, 1.1)
    s = suite(seed=11, encoders={"sigma": 2e-4}, load_cells={"sigma": 0.7, "bias": np.linspace(-1, 1, M).tolist()},
              imu={"accel_sigma": 0.05, "accel_bias": [0.1, -0.2, 0.3], "gyro_sigma": 0.01, "gyro_bias": 0.02})
    r = readings(s, R)
    t = fixed_truth(0, R)
    expected = {
        "encoders": (t.encoder_lengths, 2e-4),
        "load_cells": (t.load_cell_tensions + np.linspace(-1, 1, M), 0.7),
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
    exact = readings(suite(encoders={"resolution": q}))["encoders"]
    t = fixed_truth(0).encoder_lengths
    assert np.abs(exact[0] - t).max() <= q / 2 + 1e-15
    assert np.allclose(exact / q, np.round(exact / q), atol=1e-9)
    noisy = readings(suite(seed=2, encoders={"resolution": q, "sigma": q}))["encoders"]
    assert np.allclose(noisy / q, np.round(noisy / q), atol=1e-9)  # noise, then quantisation: on the grid
    # σ² + q²/12 (quantisation noise of a value spread over several steps), mean unbiased
    assert noisy.std(axis=0) == pytest.approx(np.full(M, math.sqrt(q * q + q * q / 12.0)), rel=0.05)
    assert np.abs(noisy.mean(axis=0) - t).max() < 5.0 * q / math.sqrt(N)


def test_determinism_with_a_seed_and_a_stream_per_kind() -> None:
    noisy = {"encoders": {"sigma": 1e-3}, "load_cells": {"sigma": 1.0}, "imu": {"accel_sigma": 0.1, "gyro_sigma": 0.1}}
    a = suite(seed=5, **noisy).take(fixed_truth(42))
    assert a == suite(seed=5, **noisy).take(fixed_truth(42))
    assert a != suite(seed=5, **noisy).take(fixed_truth(43))
    assert a.encoders != suite(seed=6, **noisy).take(fixed_truth(42)).encoders
    # one kind's configuration, or another kind added, does not change another's noise
    quiet_imu = suite(seed=5, encoders={"sigma": 1e-3}, load_cells={"sigma": 1.0}).take(fixed_truth(42))
    assert quiet_imu.encoders == a.encoders
    assert quiet_imu.load_cells == a.load_cells
    tracked = suite(seed=5, laser_tracker={}, **noisy).take(fixed_truth(42))
    assert (tracked.encoders, tracked.load_cells, tracked.accel, tracked.gyro) == (a.encoders, a.load_cells, a.accel,
                                                                                     a.gyro)
    # the reading of step k of kind K: PCG64(SeedSequence([seed, k])) advanced by K.stream · 2⁶⁴ (Draws: the same)
    fast = Draws()
    for seed, step, kind in ((0, 0, "encoders"), (5, 42, "imu"), (5, 42, "encoders"), (2**40, 10**9, "laser_tracker"),
                             (3, 7, "load_cells"), (3, 8, "load_cells")):
        normals, lost = draws(seed, KINDS[kind], step, 7, 0.5)
        bits = np.random.PCG64(np.random.SeedSequence([seed, step]))
        bits.advance(zlib.crc32(kind.encode()) * 2**64)
        rng = np.random.Generator(bits)
        assert np.array_equal(normals, rng.standard_normal(7))
        assert lost == (rng.random() < 0.5)
        f_normals, f_lost = fast(seed, KINDS[kind], step, 7, 0.5)
        assert np.array_equal(normals, f_normals)
        assert lost == f_lost


def test_rates_latencies_and_dropouts() -> None:
    # a 100 Hz tracker (every 10 steps of 1 ms) with 3 ms of latency, an IMU that loses 30 % of its readings
    s = suite(seed=3, laser_tracker={"rate": 100.0, "latency": 0.003}, imu={"dropout": 0.3, "gyro_sigma": 0.01})
    msgs = [s.take(moving_truth(k)) for k in range(2000)]
    tracked = [m.step for m in msgs if m.get("laser_tracker") is not None]
    assert tracked == list(range(3, 2000, 10))  # measured at 0, 10, …; delivered 3 steps later
    for m in msgs:  # the platform's place 3 steps before (3 mm away from its place at delivery; σ ≈ 40 µm)
        if m.get("laser_tracker") is not None:
            assert np.allclose(m.laser_tracker, moving_truth(m.step - 3).point([0, 0, 0]), atol=3e-4), m.step
    lost = sum(m.get("gyro") is None for m in msgs) / len(msgs)
    assert abs(lost - 0.3) < 5 * math.sqrt(0.3 * 0.7 / len(msgs))
    assert all((m.get("accel") is None) == (m.get("gyro") is None) for m in msgs)  # a kind's channels together
    assert all(m.get("encoders") is not None for m in msgs)
    # a restarted sim goes on with the readings still on their way
    s2 = suite(seed=3, laser_tracker={"rate": 100.0, "latency": 0.003}, imu={"dropout": 0.3, "gyro_sigma": 0.01})
    for k in range(1001):
        s2.take(moving_truth(k))
    restarted = suite(seed=3, laser_tracker={"rate": 100.0, "latency": 0.003}, imu={"dropout": 0.3, "gyro_sigma": 0.01})
    restarted.restore(s2.snapshot())
    assert restarted.snapshot() == s2.snapshot()  # the readings in flight and the snapshot step's message
    assert [restarted.take(moving_truth(k)) for k in range(1001, 1010)] == msgs[1001:1010]
    # they travel in telemetry blocks, rows marked where a channel is missing
    block = Telemetry((), sensors=tuple(msgs[:30]))
    assert Telemetry.decode(block.encode(), M).sensors == block.sensors
    assert Telemetry._checked(block.encode(), M).sensors == block.sensors


def test_imu_reads_zero_in_free_fall_and_g_up_when_hanging_still() -> None:
    robot = load_robot("caroca").with_mass(15.0).replace(tmin=1.0, tmax=6500.0)
    R = rpy_to_matrix(0.2, 0.1, -0.4)
    # free fall (no cable pulls): the accelerometer feels nothing, the gyroscope the spin in its own frame
    spin = [0.0, 0.0, 0.0, 0.0, 0.0, 0.3]
    falling = PlatformSim(robot.replace(cable_damping=0.0), 1e-3, [0.0, 0.0, 1.5], R, spin)
    sensors = SensorSuite(SensorsSpec(), robot, 1e-3)
    first = sensors.read(falling)
    assert first.accel == pytest.approx(R.T @ [0.0, 0.0, G], abs=1e-12)  # step 0: no step yet, a = 0
    for _ in range(3):
        falling.step(np.zeros(robot.m))
        reading = sensors.read(falling)  # every step, as the sim node does
    s = falling.state()
    assert reading.accel == pytest.approx([0.0, 0.0, 0.0], abs=1e-9)
    assert reading.gyro == pytest.approx(s.rotation.T @ s.twist[3:], abs=1e-12)  # (z is no principal axis)
    assert reading.encoders == pytest.approx(s.cable_lengths)
    assert reading.load_cells == pytest.approx(np.zeros(robot.m))
    assert sensors.read(falling) is reading  # a resend reads the same message
    falling.step(np.zeros(robot.m))
    falling.step(np.zeros(robot.m))
    after_gap = sensors.read(falling)
    assert after_gap.accel == pytest.approx(falling.state().rotation.T @ [0.0, 0.0, G], abs=1e-12)
    # winches holding the platform still: +g up in the platform frame; encoders read the paid-out l0
    held = ElasticSim(robot, 1e-3, [0.0, 0.0, 1.0], R, command="lengths")
    sensors = SensorSuite(SensorsSpec(), robot, 1e-3)
    l0 = held.encoder_lengths().copy()
    for _ in range(5):
        held.step(l0)
        reading = sensors.read(held)
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
    assert msg.get("laser_tracker") is None
    assert msg.laser_tracker is UNSET
    spec = load_scenario("caroca_15kg_winch").spec.sim.sensors
    assert spec is not None
    entries = dict((kind.name, entry) for kind, entry in spec.kinds())
    assert spec.seed == 7  # no tracker unless given
    assert sorted(entries) == ["encoders", "imu", "load_cells"]
    assert entries["encoders"].resolution == 1e-5
    assert entries["load_cells"].sigma == 0.5
    assert entries["load_cells"].bias == 0.2
    assert entries["imu"].accel_bias == [0.01, -0.01, 0.02]


def test_the_protocol_document_lists_every_channel_of_the_table() -> None:
    import re
    from pathlib import Path

    from cdpr.sensors import COLUMN_KIND, SENSOR_COLUMNS

    text = (Path(__file__).resolve().parents[1] / "docs" / "protocol.md").read_text(encoding="utf-8")
    rows = re.findall(r"^\| `(\w+)` \| `(\w+)` \| (\w+) \| ([^|]+) \|", text, re.MULTILINE)
    listed = {name: (kind, numbers, unit.strip()) for name, kind, numbers, unit in rows}
    assert listed == {c.name: (COLUMN_KIND[c.name].name, "m" if c.width is None else str(c.width), c.unit)
                      for c in SENSOR_COLUMNS}


def test_encoders_read_the_robots_zero_errors_and_the_feedback_takes_them_off() -> None:
    from cdpr.protocol.session import robot_from_summary
    from cdpr.runtime.feedback import SensorFeedback

    offsets = np.linspace(-0.01, 0.01, 8)
    robot = load_robot("caroca").with_mass(15.0).replace(tmin=1.0, tmax=6500.0, encoder_offsets=offsets)
    assert robot_from_summary(robot.summary()).encoder_offsets == pytest.approx(offsets, abs=0.0)
    assert "encoder_offsets" not in load_robot("caroca").summary()  # zeros: not said
    sim = PlatformSim(robot, 1e-3, [0.2, -0.1, 1.2], rpy_to_matrix(0.1, 0.0, 0.2))
    reading = SensorSuite(SensorsSpec(), robot, 1e-3).read(sim)
    lengths = sim.state().cable_lengths
    assert np.array(reading.encoders) - lengths == pytest.approx(offsets, abs=1e-12)
    feedback = SensorFeedback(robot, 1e-3, {"encoders": {}}, [0.2, -0.1, 1.2], rpy_to_matrix(0.1, 0.0, 0.2))
    state = feedback.state(reading)
    assert state is not None
    assert state.cable_lengths == pytest.approx(lengths, abs=1e-12)
    assert state.pose[:3] == pytest.approx(sim.state().position, abs=1e-9)
