"""The `cdpr` command line (JSON on stdout, one-line errors with exit code 2): each command, and the bad arguments
of each command family, run as a real subprocess; the other checks of what a command prints and its exit code run
it in this process (the same `cdpr.tools.cli.main`, without a new interpreter's start-up)."""

from __future__ import annotations

import json
import re
import subprocess

import numpy as np
import pytest

from cdpr.config.robot import load_robot, shipped_robots
from cdpr.mechanics.kinematics import inverse_kinematics
from cdpr.mechanics.rotation import rotvec_to_matrix
from conftest import cdpr, cdpr_here


def _json(*args: str, code: int = 0, here: bool = False) -> object:
    """The JSON `cdpr ARGS` prints (``here``: run in this process), after checking its exit code."""
    proc = cdpr_here(*args) if here else cdpr(*args, timeout=60)
    assert proc.returncode == code, proc.stderr
    return json.loads(proc.stdout)


def test_robots_lists_every_shipped_robot() -> None:
    out = _json("robots")
    assert isinstance(out, list)
    assert [r["name"] for r in out] == shipped_robots()
    caroca = _json("robots", "caroca")
    assert caroca["cables"] == 8
    assert caroca["mass"] == 150.0


def test_ik_matches_the_library() -> None:
    out = _json("ik", "caroca", "--pose", "0.1", "-0.2", "1.5", "0", "0", "0.1")
    robot = load_robot("caroca")
    from cdpr.mechanics.rotation import rpy_to_matrix

    k = inverse_kinematics(robot, [0.1, -0.2, 1.5], rpy_to_matrix(0, 0, 0.1))
    assert np.allclose(out["lengths"], k.lengths)
    assert np.allclose(out["wrench_matrix"], k.wrench_matrix)
    assert np.array(out["directions"]).shape == (8, 3)
    assert (out["reachable"], out["problems"]) == (True, [])


@pytest.mark.parametrize(("robot", "pose", "problem"), [
    ("caroca", ("0", "0", "19"), r"^beyond max_length: cable 1 1\d\.\d+ m > 10 m, cable 2 "),
    ("caroca", ("0", "0", "3.2", "0", "0", "0"), None),  # reachable: inside the box, every cable short enough
    ("caroca", ("4.5", "0", "1.5"), r"^the platform at \[4\.5, 0, 1\.5\] m is outside the frame box \[-4, -2\.1, "
                                    r"0\.02\] … \[4, 2\.5, 3\.5\] m$"),
    ("caroca", ("0", "0", "-0.5"), r"^the platform at \[0, 0, -0\.5\] m is below the floor \(z = 0\.02 m"),
    ("kntu_planar", ("0", "0.3", "1"), r"^off the xz plane of this planar robot \(its y must be 0"),
    ("kntu_planar", ("0", "0", "1", "0.2", "0", "0"), r"^off the xz plane"),
    ("planar_xy_4", ("0", "0", "0.5"), r"^off the xy plane"),
])
def test_ik_flags_a_pose_the_robot_cannot_take(robot: str, pose: tuple[str, ...], problem: str | None) -> None:
    """`cdpr ik` answers an impossible pose as `cdpr tda` answers an infeasible wrench: the JSON (reachable
    false, the problems) and exit code 3, with the problems on one line of stderr."""
    proc = cdpr_here("ik", robot, "--pose", *pose)
    out = json.loads(proc.stdout)
    if problem is None:
        assert (proc.returncode, out["reachable"], proc.stderr) == (0, True, ""), proc.stderr
        return
    assert proc.returncode == 3, proc.stderr
    assert out["reachable"] is False
    assert any(re.search(problem, p) for p in out["problems"]), out["problems"]
    assert proc.stderr.startswith("cdpr ik: the robot cannot take this pose: ")
    assert len(proc.stderr.strip().splitlines()) == 1


@pytest.mark.parametrize("method", ["qp", "closed-form", "improved-closed-form", "continuity"])
def test_tda_static_holds_the_platform(method: str) -> None:
    out = _json("tda", "caroca", "--pose", "0", "0", "1.5", "--static", "--method", method, here=method != "qp")
    robot = load_robot("caroca")
    f = np.array(out["tensions"])
    W = inverse_kinematics(robot, [0, 0, 1.5]).wrench_matrix
    assert out["feasible"] is True
    assert out["method"] == method
    assert np.all(f >= robot.tmin - 1e-9)
    assert np.all(f <= robot.tmax + 1e-9)
    # W f balances gravity: force (0, 0, m g), no moment about the centre of mass
    assert np.allclose(W @ f, [0, 0, 150 * 9.81, 0, 0, 0], atol=1e-6)
    assert out["residual"] < 1e-6


def test_tda_payload_and_wrench_and_limits() -> None:
    a = _json("tda", "caroca", "--pose", "0", "0", "1.5", "--static", "--payload", "15",
              "--tmin", "1", "--tmax", "6500", here=True)
    b = _json("tda", "caroca", "--pose", "0", "0", "1.5", "--wrench", "0", "0", str(165 * 9.81), "0", "0", "0",
              "--tmin", "1", "--tmax", "6500", here=True)
    assert np.allclose(a["tensions"], b["tensions"], atol=1e-6)
    assert min(a["tensions"]) >= 1 - 1e-9
    infeasible = _json("tda", "caroca", "--pose", "0", "0", "1.5", "--static", "--tmax", "60", code=3)
    assert infeasible["feasible"] is False
    assert max(infeasible["tensions"]) <= 60 + 1e-9
    assert infeasible["residual"] > 1.0


def rotation(axis: int, angle: float) -> np.ndarray:
    """The elementary rotation about x (0), y (1) or z (2), from the rotation vector (independent of the CLI's code)."""
    return rotvec_to_matrix(np.eye(3)[axis] * angle)


def test_pose_angles_take_either_convention_and_say_which() -> None:
    """--angles xyz is CASPR's Euler XYZ, R = Rx(a)·Ry(b)·Rz(c); the default rpy is R = Rz(yaw)·Ry(pitch)·Rx(roll)."""
    robot = load_robot("caroca")
    a, b, c = 0.1, -0.2, 0.3
    cases = {"xyz": rotation(0, a) @ rotation(1, b) @ rotation(2, c),
             "rpy": rotation(2, c) @ rotation(1, b) @ rotation(0, a)}
    for angles, R in cases.items():
        out = _json("ik", "caroca", "--pose", "0.1", "0", "1.5", str(a), str(b), str(c), "--angles", angles, here=True)
        assert np.allclose(out["lengths"], inverse_kinematics(robot, [0.1, 0.0, 1.5], R).lengths, rtol=0, atol=1e-12)
    default = _json("ik", "caroca", "--pose", "0.1", "0", "1.5", str(a), str(b), str(c), here=True)
    assert default == _json("ik", "caroca", "--pose", "0.1", "0", "1.5", str(a), str(b), str(c), "--angles", "rpy",
                            here=True)
    tilted = _json("workspace", "caroca", "--step", "1", "--orientation", str(a), str(b), str(c), "--angles", "xyz")
    assert tilted["orientation_xyz"] == [a, b, c]


@pytest.mark.parametrize(("command", "flags"), [("ik", ("--pose", "--angles")),
                                                 ("tda", ("--pose", "--wrench", "--angles")),
                                                 ("workspace", ("--orientation", "--angles"))])
def test_help_lists_the_pose_and_wrench_and_the_angle_convention(command: str, flags: tuple[str, ...]) -> None:
    proc = cdpr(command, "--help", timeout=60)
    assert proc.returncode == 0, proc.stderr
    options = proc.stdout.split("Options:")[1]
    for flag in flags:
        assert f"  {flag} " in options, (flag, proc.stdout)
    assert "Rz(yaw)·Ry(pitch)·Rx(roll)" in options
    assert "Rx(a)·Ry(b)·Rz(c)" in options


# one of each command family as the real command's process: robots/ik/tda, run, and a service's (sim)
BAD_IN_A_PROCESS = {("tda", "caroca", "--pose", "0", "0", "--static"), ("run", "caroca_15kg", "--duration", "-1"),
                    ("sim", "caroca_15kg", "--rt-priority", "100")}


@pytest.mark.parametrize(
    ("args", "needle"),
    [
        (("tda", "caroca", "--pose", "0", "0", "--static"), "--pose"),
        (("ik", "caroca", "--pose", "0", "0", "1", "0", "0", "0", "--angles", "zyx"), "--angles"),
        (("tda", "caroca", "--pose", "0", "0", "1.5"), "--static"),
        (("tda", "caroca", "--pose", "0", "0", "1.5", "--static", "--method", "magic"), "--method"),
        (("tda", "caroca", "--pose", "0", "0", "1.5", "--static", "--tmin", "10", "--tmax", "5"), "--tmin"),
        (("tda", "caroca", "--pose", "0", "0", "x", "--static"), "--pose"),
        (("ik", "nosuchrobot", "--pose", "0", "0", "1"), "nosuchrobot"),
        (("ik", "caroca"), "--pose"),
        (("robots", "/no/such/file.yaml"), "/no/such/file.yaml"),
        (("run", "caroca_15kg", "--duration", "-1"), "--duration"),
        (("run", "caroca_15kg", "--session", "bad id!"), "--session"),
        (("run", "caroca_15kg", "--rt-priority", "0"), "--rt-priority"),
        (("sim", "caroca_15kg", "--rt-priority", "100"), "--rt-priority"),
    ],
)
def test_bad_arguments_give_one_line_and_exit_2(args: tuple[str, ...], needle: str) -> None:
    proc = cdpr(*args, timeout=60) if args in BAD_IN_A_PROCESS else cdpr_here(*args)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert needle in lines[0]
    assert "Traceback" not in proc.stderr


def test_python_dash_m_is_the_same_command() -> None:
    import sys

    proc = subprocess.run([sys.executable, "-m", "cdpr", "--help"], capture_output=True, text=True, check=True)
    assert "run" in proc.stdout
    assert "tda" in proc.stdout
