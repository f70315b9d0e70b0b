"""The laser tracker (cdpr.sensors.laser_tracker), and what a new sensor kind costs.

The statistics: 10,000 readings of a reflector on a platform moving over CAROCA's workspace, each residual
(reading − the reflector's true position) standardised by the model's σ = 15 µm + 6 µm/m of range. Six checks,
each with a false-failure probability of 1e-6 / 6 (so ≤ 1e-6 in all): each axis's sample mean against a normal
bound, each axis's sample variance against the χ²(n − 1) quantiles.

The cost of a kind is shown on a copy of the tree (as tests/test_streams.py does for a state column): a second
tracker, ``tracker_b``, is its module and a row of the table; a session then carries its readings to
``sim/sensors``, the telemetry block, the .rrd, the .mcap, ``cdpr convert`` and a ROS 2 bag read with rosbags."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path
from typing import Any

import numpy as np
import pytest
from scipy import stats

from cdpr.config.robot import load_robot
from cdpr.config.scenario import SensorsSpec
from cdpr.mechanics.rotation import rotvec_to_matrix
from cdpr.sensors import KINDS, SENSOR_KINDS, truth
from cdpr.sensors.laser_tracker import sigma
from cdpr_sim.core import PlatformSim
from cdpr_sim.sensors import SensorSuite
from conftest import changed_sources, source_copy

ROOT = Path(__file__).resolve().parents[1]
N = 10_000
ALPHA = 1e-6 / 6  # each of the six checks' false-failure probability
STATION = [3.5, -2.5, 0.0]  # a corner of CAROCA's frame, on the floor
REFLECTOR = [0.05, -0.04, 0.03]  # platform frame
COM = [0.01, 0.02, -0.015]  # a centre of mass off the platform frame's origin


def poses(n: int, seed: int = 1) -> tuple[np.ndarray, np.ndarray]:
    rng = np.random.default_rng(seed)
    positions = rng.uniform([-1.5, -1.0, 0.2], [1.5, 1.0, 2.5], (n, 3))
    rotations = np.array([rotvec_to_matrix(v) for v in rng.uniform(-0.4, 0.4, (n, 3))])
    return positions, rotations


def tracker_readings(seed: int, entries: dict[str, Any] | None = None) -> tuple[np.ndarray, np.ndarray, list[Any]]:
    """Readings of N steps (the platform at a random pose each), the reflector's true positions, the messages."""
    spec = SensorsSpec.model_validate({"seed": seed, "laser_tracker": {"station": STATION, "reflector": REFLECTOR},
                                       **(entries or {})})
    suite = SensorSuite(spec, load_robot("caroca").replace(com_offset=np.array(COM)), 1e-3)
    positions, rotations = poses(N)
    readings, true, msgs = [], [], []
    for k in range(N):
        t = truth(k, k * 1e-3, rotations[k], np.zeros(6), np.zeros(3), np.full(8, 3.0), np.full(8, 50.0),
                  positions[k], COM)
        msg = suite.take(t)
        msgs.append(msg)
        readings.append(msg.laser_tracker)
        # the reflector, by hand: the platform frame's origin is the COM less R c
        true.append(positions[k] - rotations[k] @ np.array(COM) + rotations[k] @ np.array(REFLECTOR))
    return np.array(readings), np.array(true), msgs


def test_the_readings_are_the_reflector_plus_noise_of_the_instruments_sigma() -> None:
    readings, true, _ = tracker_readings(seed=4)
    spec = SensorsSpec.model_validate({"laser_tracker": {"station": STATION, "reflector": REFLECTOR}}).laser_tracker
    assert (spec.sigma, spec.sigma_per_m) == (15e-6, 6e-6)  # the default: an AT960-class instrument's MPE
    ranges = np.linalg.norm(true - np.array(STATION), axis=1)
    assert ranges.min() < 3.0 < 5.0 < ranges.max()  # σ varies by half over the workspace
    z = (readings - true) / np.array([sigma(spec, r) for r in ranges])[:, None]
    mean_bound = stats.norm.isf(ALPHA / 2) / np.sqrt(N)
    low, high = stats.chi2.ppf(ALPHA / 2, N - 1) / (N - 1), stats.chi2.isf(ALPHA / 2, N - 1) / (N - 1)
    for axis in range(3):
        assert abs(z[:, axis].mean()) < mean_bound, axis
        assert low < z[:, axis].var(ddof=1) < high, axis
    # the checks can fail: a σ 10 % off, or a reflector 10 µm off, is caught
    assert not low < (z[:, 0] / 1.10).var(ddof=1) < high
    offset = (readings[:, 0] + 10e-6 - true[:, 0]) / np.array([sigma(spec, r) for r in ranges])
    assert abs(offset.mean()) > mean_bound


def test_same_seed_same_readings_and_the_other_sensors_unchanged() -> None:
    noisy = {"encoders": {"sigma": 1e-4}, "load_cells": {"sigma": 0.5}, "imu": {"accel_sigma": 0.02}}
    a, _, _ = tracker_readings(seed=9, entries=noisy)
    b, _, _ = tracker_readings(seed=9, entries=noisy)
    c, _, _ = tracker_readings(seed=10, entries=noisy)
    assert np.array_equal(a, b)
    assert not np.array_equal(a, c)
    # a sim without the tracker reads the same encoders, load cells and IMU, step by step
    robot = load_robot("caroca").with_mass(15.0).replace(tmin=1.0, tmax=6500.0)
    plain = SensorSuite(SensorsSpec.model_validate({"seed": 9, **noisy}), robot, 1e-3)
    tracked = SensorSuite(SensorsSpec.model_validate({"seed": 9, "laser_tracker": {}, **noisy}), robot, 1e-3)
    sim = PlatformSim(robot, 1e-3, [0.0, 0.0, 1.0], np.eye(3))
    for _ in range(200):
        sim.step(np.full(robot.m, 40.0))
        p, t = plain.read(sim), tracked.read(sim)
        assert t.get("laser_tracker") is not None
        assert p.get("laser_tracker") is None
        assert {k: v for k, v in t.readings.items() if k != "laser_tracker"} == p.readings
    assert KINDS["laser_tracker"] in SENSOR_KINDS
    assert not KINDS["laser_tracker"].default


# A second tracker for the copy of the tree: the shipped one's module under another name
def _tracker_b(text: str) -> str:
    out = text.replace('"laser_tracker"', '"tracker_b"').replace("sensors/laser_tracker", "sensors/tracker_b")
    assert out.count("tracker_b") >= 4
    return out


SCENARIO = """\
name: tracked
robot: caroca
platform: {mass: 15.0}
limits: {tmin: 1.0, tmax: 6500.0}
dt: 0.001
duration: 0.05
trajectory:
  type: quintic
  waypoints:
    - {t: 0.0, position: [0.9, 0.9, 0.2]}
    - {t: 10.0, position: [-0.9, -0.9, 1.0]}
controller: {variant: 6dof, kp: 1500.0, kd: 1500.0, tda: {method: qp}}
sim:
  sensors:
    seed: 3
    tracker_b: {station: [3.5, -2.5, 0.0], rate: 200.0, latency: 0.002}
"""

# Run in the copy: the sim's readings as the sim publishes them (sim/sensors) and in a telemetry block
MESSAGES = """\
import json, sys
from cdpr.config.scenario import load_scenario
from cdpr.protocol import Sensors, Telemetry
from cdpr_sim.models import make_sim
from cdpr_sim.node import SimNode
scenario = load_scenario(sys.argv[1])
sim, sensors = make_sim(scenario), SimNode.make_sensors(scenario)
out = []
for k in range(51):
    payload = sensors.read(sim).encode()  # what goes out on sim/sensors
    out.append(Sensors.decode(payload, 8))
    sim.step([60.0] * 8)
block = Telemetry.decode(Telemetry((), sensors=tuple(out)).encode(), 8)
print(json.dumps({"wire": {m.step: m.tracker_b for m in out if m.get("tracker_b") is not None},
                  "telemetry": {m.step: m.tracker_b for m in block.sensors if m.get("tracker_b") is not None}}))
"""


@pytest.mark.slow
def test_a_new_sensor_kind_is_its_module_and_a_row(tmp_path: Path) -> None:
    tree, env = source_copy(tmp_path)
    kinds = tree / "shared/cdpr/sensors"
    (kinds / "tracker_b.py").write_text(_tracker_b((kinds / "laser_tracker.py").read_text(encoding="utf-8")),
                                        encoding="utf-8")
    table = (kinds / "__init__.py").read_text(encoding="utf-8")
    assert table.count("    laser_tracker.KIND,\n") == 1
    table = table.replace("    laser_tracker.KIND,\n", "    laser_tracker.KIND,\n    tracker_b.KIND,\n")
    table = table.replace("import encoders, imu, laser_tracker, load_cells", "import encoders, imu, laser_tracker, "
                          "load_cells, tracker_b")
    (kinds / "__init__.py").write_text(table, encoding="utf-8")
    # the table and the new module: nothing else
    assert changed_sources(tree) == ["shared/cdpr/sensors/__init__.py", "shared/cdpr/sensors/tracker_b.py"]

    scenario = tmp_path / "tracked.yaml"
    scenario.write_text(SCENARIO, encoding="utf-8")

    def run(*args: str) -> str:
        done = subprocess.run([sys.executable, *args], cwd=tmp_path, env=env, capture_output=True, text=True,
                              timeout=300, check=False)
        assert done.returncode == 0, done.stderr[-3000:]
        return done.stdout

    # sim/sensors and the telemetry block: measured at 0, 5, 10, … (200 Hz), delivered 2 steps later
    script = tmp_path / "messages.py"
    script.write_text(MESSAGES, encoding="utf-8")
    wire = json.loads(run(str(script), str(scenario)))
    steps = list(range(2, 51, 5))
    assert sorted(map(int, wire["wire"])) == steps
    assert wire["telemetry"] == wire["wire"]
    rrd, mcap, converted, bag = (tmp_path / name for name in ("t.rrd", "t.mcap", "c.mcap", "bag"))
    run("-m", "cdpr", "run", str(scenario), "--in-process", "--quiet", "--rrd", str(rrd), "--mcap", str(mcap))
    run("-m", "cdpr", "convert", str(rrd), "--to", "mcap", "-o", str(converted))
    run("-m", "cdpr", "convert", str(rrd), "--to", "rosbag2", "-o", str(bag))

    from cdpr.tools.report import read_recording  # the project's reader of a .rrd's series (rerun.chunk.RrdReader)

    data = read_recording(rrd)
    tracker, position = data.get("sensors/tracker_b"), data.get("actual/position")
    recorded = dict(zip(tracker.step.tolist(), tracker.values.tolist(), strict=True))
    actual = dict(zip(position.step.tolist(), position.values.tolist(), strict=True))
    assert sorted(recorded) == steps
    for k in steps:  # the platform frame's origin (the reflector's default place) when measured, within ~6 σ
        assert recorded[k] == pytest.approx(actual[k - 2], abs=3e-4)

    from mcap.reader import make_reader

    for file in (mcap, converted):
        with file.open("rb") as f:
            rows = [json.loads(message.data) for _, _, message in
                    make_reader(f).iter_messages(topics=["/sensors/tracker_b"])]
        assert [r["step"] for r in rows] == steps, file
        assert [r["position"] for r in rows] == [recorded[k] for k in steps], file

    from rosbags.highlevel import AnyReader

    with AnyReader([bag]) as reader:
        connections = [c for c in reader.connections if c.topic == "/cdpr/sensors/tracker_b"]
        assert [c.msgtype for c in connections] == ["geometry_msgs/msg/PointStamped"]
        points = [reader.deserialize(raw, c.msgtype) for c, _, raw in reader.messages(connections=connections)]
    assert [[p.point.x, p.point.y, p.point.z] for p in points] == [recorded[k] for k in steps]
    # stamped when measured: 2 steps before delivery
    assert [p.header.stamp.sec * 10**9 + p.header.stamp.nanosec for p in points] == \
        [round((k - 2) * 1e-3 * 1e9) for k in steps]
    assert {p.header.frame_id for p in points} == {"world"}
