"""A platform frame whose origin is not the centre of mass (#32, `platform.com`): points and poses in that frame,
the dynamics about the COM. The same robot described about its COM moves the same (≤ 1e-9 m)."""

from __future__ import annotations

import json
import subprocess
from pathlib import Path

import numpy as np
import pytest
import yaml

from cdpr import recording
from cdpr.config.robot import load_robot
from cdpr.mechanics.kinematics import inverse_kinematics
from cdpr.mechanics.rotation import quat_to_matrix, rpy_to_matrix
from cdpr.mechanics.trajectory import PlatformPoint, QuinticWaypoints
from cdpr.tools.report import read_recording
from conftest import cdpr, cdpr_in_one_process

CUBE = Path(__file__).parent / "robots" / "valid" / "cube_8.yaml"
C = [0.05, -0.03, 0.04]  # the COM in the offset robot's platform frame


def offset_robot(tmp_path: Path) -> Path:
    """cube_8 described in a platform frame whose origin is −C from its COM: points and home moved by +C/−C."""
    spec = yaml.safe_load(CUBE.read_text())
    spec["name"] = "cube_8_offset"
    spec["platform"]["com"] = C
    for cable in spec["cables"]:
        cable["platform"] = (np.array(cable["platform"]) + C).tolist()
    spec["home"]["position"] = (np.array(spec["home"]["position"]) - C).tolist()
    path = tmp_path / "cube_8_offset.yaml"
    path.write_text(yaml.safe_dump(spec))
    return path


def test_points_and_home_are_taken_from_the_com(tmp_path: Path) -> None:
    about_com, offset = load_robot(CUBE), load_robot(offset_robot(tmp_path))
    np.testing.assert_allclose(offset.platform_points, about_com.platform_points, rtol=0, atol=1e-15)
    np.testing.assert_allclose(offset.home_position, about_com.home_position, rtol=0, atol=1e-15)
    assert offset.com_offset.tolist() == C
    assert offset.summary()["com_offset"] == C
    # a pose of the platform frame on the command line is that frame's: the COM is at p + R c
    p, rpy = [0.2, -0.1, 1.4], [0.1, -0.05, 0.2]
    R = rpy_to_matrix(*rpy)
    proc = cdpr("ik", str(offset_robot(tmp_path)), "--pose", *map(str, p + rpy), timeout=60)
    assert proc.returncode == 0, proc.stderr
    expected = inverse_kinematics(about_com, np.array(p) + R @ C, R).lengths
    np.testing.assert_allclose(json.loads(proc.stdout)["lengths"], expected, rtol=0, atol=1e-12)


def test_the_com_follows_the_frame_s_motion() -> None:
    """PlatformPoint: position, twist and acceleration of the point C of a platform on a turning quintic are
    each other's derivatives (central differences)."""
    frame = QuinticWaypoints([0.0, 2.0], [[0.0, 0.0, 1.0], [0.5, -0.2, 1.3]], [[0.0, 0.0, 0.0], [0.3, -0.2, 0.6]])
    com = PlatformPoint(frame, C)
    h = 1e-5
    for t in (0.3, 0.9, 1.6):
        s, before, after = com.sample(t), com.sample(t - h), com.sample(t + h)
        f = frame.sample(t)
        np.testing.assert_allclose(s.position, f.position + f.rotation @ C, atol=1e-15)
        np.testing.assert_array_equal(s.rotation, f.rotation)
        np.testing.assert_allclose(s.twist[:3], (after.position - before.position) / (2 * h), atol=1e-8)
        np.testing.assert_allclose(s.accel[:3], (after.twist[:3] - before.twist[:3]) / (2 * h), atol=1e-6)
        np.testing.assert_array_equal(s.twist[3:], f.twist[3:])
    assert com.waypoints()[-1][1].tolist() == pytest.approx((frame.sample(2.0).position
                                                            + frame.sample(2.0).rotation @ C).tolist())


def _positions(rrd: Path) -> np.ndarray:
    return read_recording(rrd).get(recording.ACTUAL_POSITION).values


HOME = np.array(yaml.safe_load(CUBE.read_text())["home"]["position"])
GOAL = HOME + np.array([0.3, -0.2, 0.1])
TURN = [{"t": 0.0, "position": (HOME - np.array(C)).tolist()},
        {"t": 2.0, "position": (HOME - np.array(C) + np.array([0.2, -0.1, 0.1])).tolist(), "rpy": [0.1, -0.05, 0.3]}]


def scenarios(folder: Path) -> dict[str, Path]:
    """The three sessions' scenarios: cube_8 about its COM ("com"), the same motion of the offset robot given by its
    frame's waypoints ("offset"), and the offset robot's frame turning through :data:`TURN` ("turn")."""
    files = {}
    for name, robot, shift in (("com", str(CUBE), 0.0), ("offset", str(offset_robot(folder)), 1.0)):
        scenario = {
            "name": f"cube_{name}", "robot": robot, "dt": 0.001, "duration": 2.5,
            "trajectory": {"type": "quintic", "waypoints": [
                {"t": 0.0, "position": (HOME - shift * np.array(C)).tolist()},
                {"t": 2.0, "position": (GOAL - shift * np.array(C)).tolist()}]},
            "controller": {"kp": 400.0, "kd": 40.0},
        }
        files[name] = folder / f"{name}.yaml"
        files[name].write_text(yaml.safe_dump(scenario))
    scenario = {"name": "cube_offset_turn", "robot": str(offset_robot(folder)), "dt": 0.001, "duration": 2.5,
                "trajectory": {"type": "quintic", "waypoints": TURN}, "controller": {"kp": 400.0, "kd": 40.0}}
    files["turn"] = folder / "turn.yaml"
    files["turn"].write_text(yaml.safe_dump(scenario))
    return files


@pytest.fixture(scope="module")
def sessions(tmp_path_factory: pytest.TempPathFactory) -> dict[str, tuple[subprocess.CompletedProcess[str], Path]]:
    """The three real sessions of :func:`scenarios`, each `cdpr run --in-process --rrd` (one after the other in one
    process): each one's outcome and recording."""
    folder = tmp_path_factory.mktemp("sessions")
    files = scenarios(folder)
    rrds = {name: folder / f"{name}.rrd" for name in files}
    procs = cdpr_in_one_process([["run", str(files[name]), "--in-process", "--rrd", str(rrds[name])] for name in files],
                                folder / "results.json", timeout=600)
    return {name: (proc, rrds[name]) for name, proc in zip(files, procs, strict=True)}


def test_the_offset_robot_moves_as_the_robot_described_about_its_com(sessions: dict) -> None:
    """Two real sessions: cube_8 (about its COM) and the same robot in an offset frame whose waypoints are the
    frame's (the COM's minus C, a translation): the recorded COM motions agree to 1e-9 m."""
    runs = {}
    for name in ("com", "offset"):
        proc, rrd = sessions[name]
        assert proc.returncode == 0, proc.stderr[-3000:]
        runs[name] = _positions(rrd)
    a, b = runs["com"], runs["offset"]
    assert a.shape == b.shape
    assert a.shape[0] > 2000
    assert np.abs(a - b).max() <= 1e-9
    assert np.abs(a[-1] - GOAL).max() < 1e-3  # and it went where it was sent


def test_a_turning_offset_platform_s_frame_follows_the_waypoints(sessions: dict) -> None:
    """Waypoints of the platform frame with a turn: the session's COM follows p(t) + R(t) c, so the frame's origin,
    recovered from the recorded COM pose as p_com − R c, follows the quintic through the waypoints (to the
    tracking error; the wrong sign or no conversion would be 2|c| or |c| = 7 cm off at the end)."""
    proc, rrd = sessions["turn"]
    assert proc.returncode == 0, proc.stderr[-3000:]
    data = read_recording(rrd)
    positions, quaternions = data.get(recording.ACTUAL_POSITION), data.get(recording.ACTUAL_QUATERNION)
    frame = QuinticWaypoints([0.0, 2.0], [w["position"] for w in TURN], [[0.0, 0.0, 0.0], [0.1, -0.05, 0.3]])
    errors = []
    for t, p, q in zip(positions.t, positions.values, quaternions.values, strict=True):
        origin = p - quat_to_matrix(q) @ C
        errors.append(float(np.linalg.norm(origin - frame.sample(t).position)))
    assert max(errors) < 1e-3, max(errors)
    assert errors[-1] < 1e-4
