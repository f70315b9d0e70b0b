"""Forward kinematics (#46, shared/cdpr/mechanics/forward.py): the pose from cable lengths computed by IK, on random
feasible poses of every shipped robot (spatial, planar, point mass, exit pulleys) and of the ten CASPR-imported
ones (every default cable set, CAROCA's rotating pulleys, platform.com offsets); the analytic Jacobian against
finite differences; noisy and inconsistent lengths; warm starts along a path; elastic stretch; `cdpr fk` as a user
runs it; the `cdpr bench` part.

POSES random feasible poses a robot (2,000: the whole module's FK solves take ~20 s on a busy 2-core machine; the
issue's 10,000 a robot passes as well, in about five times as long): FK from a guess off by up to 2 % of the frame
box's diagonal and 2–10° (1 % and 2–5° for a robot with as many cables as DOF, whose lengths have other poses
not far off: there, a solve that finds another pose with exactly the same lengths is no miss, if rare) must give
the true pose within 1e-9 m and 1e-9 rad. From the home pose, the shipped robots' too.
"""

from __future__ import annotations

import json
import math
import subprocess
from pathlib import Path

import numpy as np
import pytest

from cdpr.config.robot import load_robot, shipped_robots
from cdpr.mechanics.catenary import unstretched_lengths
from cdpr.mechanics.forward import MAX_ITERATIONS, TOL, ForwardKinematics, forward_kinematics, rotvec_matrix
from cdpr.mechanics.kinematics import forward_kinematics as kinematics_fk
from cdpr.mechanics.kinematics import inverse_kinematics
from cdpr.mechanics.robot import Robot
from cdpr.mechanics.rotation import matrix_to_rotvec, rotvec_to_matrix, rpy_to_matrix
from cdpr.tools.bench.fk import bench_robot, feasible_poses, fk_lines, fk_targets, pose_error, turns, unit_vectors
from conftest import CDPR, cdpr, cdpr_here, cdpr_in_one_process
from test_caspr import FIXTURES, HOME, MODELS

POSES = 2_000  # random feasible poses a robot (the issue asks 10,000: the same tests pass, ~5× longer)
HOME_POSES = 300  # of them solved from the home pose too (the shipped robots)
ACCURACY = 1e-9  # m and rad
SPREAD = {"fast": 0.2}  # FAST's 30 t platform is held only near its home: sample nearer it (as fraction of the box)


@pytest.fixture(scope="module")
def caspr_files(tmp_path_factory: pytest.TempPathFactory) -> dict[str, Path]:
    """The ten CASPR models imported once by `cdpr import caspr` (all in one process)."""
    folder = tmp_path_factory.mktemp("caspr")
    files = {name: folder / f"{name}.yaml" for name in MODELS}
    procs = cdpr_in_one_process([["import", "caspr", str(FIXTURES / name), "-o", str(files[name]), *HOME.get(name, [])]
                                 for name in MODELS], folder / "results.json", timeout=300)
    for name, proc in zip(MODELS, procs, strict=True):
        assert proc.returncode == 0, (name, proc.stderr)
    return files


# every shipped robot, then the CASPR models (their default cable sets, and CAROCA's rotating pulleys)
CASES = [("shipped", name, None) for name in shipped_robots()] + [("caspr", name, None) for name in MODELS] + [
    ("caspr", "caroca", "with_rotating_pulleys")]


def _robot(case: tuple[str, str, str | None], caspr_files: dict[str, Path]) -> Robot:
    kind, name, cable_set = case
    return load_robot(name if kind == "shipped" else caspr_files[name], cable_set)


def _near_guesses(robot: Robot, p: np.ndarray, R: np.ndarray, rng: np.random.Generator
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Guesses off by up to 2 % of the frame box's diagonal and 2–10° (1 % and 2–5° with m = DOF), in the robot's
    coordinates (a planar robot's plane and its normal, a point mass's position only)."""
    n = len(p)
    square = robot.m == robot.dof
    reach = (0.01 if square else 0.02) * float(np.linalg.norm(robot.frame_max - robot.frame_min))
    shift = unit_vectors(rng, n) * rng.uniform(0.0, reach, n)[:, None]
    angles = rng.uniform(math.radians(2.0), math.radians(5.0 if square else 10.0), n)
    axes = unit_vectors(rng, n)
    if robot.mode == "planar":
        shift[:, robot.normal_axis] = 0.0
        axes = np.zeros((n, 3))
        axes[:, robot.normal_axis] = rng.choice([-1.0, 1.0], n)
    if robot.mode == "point_mass":
        angles = np.zeros(n)
    return p + shift, turns(axes, angles) @ R


def _poses(robot: Robot, n: int, seed: int = 46) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.random.Generator]:
    """n random statically feasible poses (the robot's own limits) and their lengths by IK."""
    rng = np.random.default_rng(seed)
    p, R = feasible_poses(robot, n, rng, spread=SPREAD.get(robot.name, 0.5), max_angle=0.3)
    lengths = np.array([inverse_kinematics(robot, p[k], R[k]).lengths for k in range(n)])
    return p, R, lengths, rng


def _misses(robot: Robot, fk: ForwardKinematics, lengths: np.ndarray, guess_p: np.ndarray, guess_R: np.ndarray,
            p: np.ndarray, R: np.ndarray, others: list[str] | None = None) -> list[str]:
    """The solves that missed the true pose. With ``others``, a solve that found another pose with exactly these
    lengths (as a robot with as many cables as DOF has) goes there instead."""
    misses = []
    for k in range(len(lengths)):
        res = fk.solve(lengths[k], guess_p[k], guess_R[k])
        err = float(np.abs(pose_error(robot, res.position, res.rotation, p[k], R[k])).max())
        if res.converged and err <= ACCURACY and res.residual <= 1e-9:
            continue
        what = (f"pose {k}: converged {res.converged} after {res.iterations}, error {err:.3g}, "
                f"residual {res.residual:.3g}")
        exact = np.abs(inverse_kinematics(robot, res.position, res.rotation).lengths - lengths[k]).max() <= 1e-9
        (others if others is not None and res.converged and exact else misses).append(what)
    return misses


@pytest.mark.parametrize("case", CASES, ids=["-".join(x for x in c if x) for c in CASES])
def test_fk_gives_the_true_pose_of_random_feasible_poses(case: tuple[str, str, str | None],
                                                         caspr_files: dict[str, Path]) -> None:
    robot = _robot(case, caspr_files)
    p, R, lengths, rng = _poses(robot, POSES)
    guess_p, guess_R = _near_guesses(robot, p, R, rng)
    others: list[str] = []
    misses = _misses(robot, ForwardKinematics(robot), lengths, guess_p, guess_R, p, R,
                     others if robot.m == robot.dof else None)
    assert not misses, f"{robot.name}: {len(misses)} of {POSES} missed: {misses[:5]}"
    assert len(others) <= POSES // 500, others  # FAST (6 cables): now and then another pose of the same lengths


@pytest.mark.parametrize("name", shipped_robots())
def test_fk_from_the_home_pose(name: str) -> None:
    """What a robot does when it knows nothing: start at home (the shipped robots, their random feasible poses)."""
    robot = load_robot(name)
    p, R, lengths, _ = _poses(robot, HOME_POSES, seed=7)
    home_p = np.broadcast_to(robot.home_position, p.shape)
    home_R = np.broadcast_to(robot.home_rotation, R.shape)
    misses = _misses(robot, ForwardKinematics(robot), lengths, home_p, home_R, p, R)
    assert not misses, misses[:5]


def test_the_cases_cover_what_the_issue_lists(caspr_files: dict[str, Path]) -> None:
    robots = [_robot(c, caspr_files) for c in CASES]
    assert {r.mode for r in robots} == {"spatial", "planar", "point_mass"}
    assert {r.plane for r in robots if r.mode == "planar"} == {"xy", "xz"}
    assert sum(r.pulleys is not None for r in robots) == 2  # caroca_pulleys, CASPR CAROCA's rotating pulleys
    assert sum(bool(np.any(r.com_offset != 0.0)) for r in robots) >= 2  # CASPR's CoGiRo and IPAnema 2
    assert {r.cable_set for r in robots} >= {"default", "original", "with_rotating_pulleys"}
    assert len([c for c in CASES if c[0] == "caspr"]) == 11


# ------------------------------------------------------------------------------------------------
# The Jacobian, the update, the solver's rules


JACOBIAN_CASES = ["caroca", "caroca_pulleys", "cogiro", "kntu_planar", "planar_xy_4", "point_mass_4"]


@pytest.mark.parametrize("name", JACOBIAN_CASES)
def test_the_analytic_jacobian_is_the_finite_differences_one(name: str) -> None:
    """∂l/∂δ in the solver's coordinates (over pulleys too: the derivative of the wrapped length) against central
    differences of the lengths through the same update; for a spatial robot it is eq. 4's J = −Wᵀ."""
    robot = load_robot(name)
    fk = ForwardKinematics(robot)
    p, R, _, _ = _poses(robot, 5, seed=3)
    h = 1e-6
    for k in range(len(p)):
        J = fk.jacobian(p[k], R[k])
        assert J.shape == (robot.m, robot.dof)
        fd = np.empty_like(J)
        for j in range(robot.dof):
            step = np.zeros(robot.dof)
            step[j] = h
            plus, minus = fk.moved(p[k], R[k], step), fk.moved(p[k], R[k], -step)
            fd[:, j] = (fk.lengths(*plus) - fk.lengths(*minus)) / (2 * h)
        np.testing.assert_allclose(J, fd, rtol=0, atol=1e-8)
        if robot.mode == "spatial":
            np.testing.assert_allclose(J, inverse_kinematics(robot, p[k], R[k]).jacobian, rtol=0, atol=1e-13)
        np.testing.assert_allclose(fk.lengths(p[k], R[k]), inverse_kinematics(robot, p[k], R[k]).lengths, rtol=0,
                                   atol=1e-13)


def test_the_update_is_the_exponential_map() -> None:
    rng = np.random.default_rng(1)
    for w in [*rng.normal(size=(20, 3)), *(1e-5 * rng.normal(size=(5, 3))), np.zeros(3)]:
        R = rotvec_matrix(*w.tolist())
        np.testing.assert_allclose(R, rotvec_to_matrix(w), rtol=0, atol=1e-15)
        np.testing.assert_allclose(R @ R.T, np.eye(3), rtol=0, atol=1e-15)
    robot = load_robot("cogiro")
    p, R = robot.home_position, robot.home_rotation
    q, S = ForwardKinematics(robot).moved(p, R, [0.1, 0.0, 0.0, 0.0, 0.0, 0.3])
    np.testing.assert_allclose(q, p + np.array([0.1, 0.0, 0.0]))
    np.testing.assert_allclose(S, rotvec_to_matrix([0.0, 0.0, 0.3]) @ R, atol=1e-15)  # world frame, on the left


def test_defaults_and_bad_settings() -> None:
    assert (TOL, MAX_ITERATIONS) == (1e-9, 30)
    robot = load_robot("caroca")
    with pytest.raises(Exception, match="lengths: expected 8"):
        ForwardKinematics(robot).solve(np.ones(7))
    with pytest.raises(Exception, match="tol: must be > 0"):
        ForwardKinematics(robot, tol=0.0)
    with pytest.raises(Exception, match="tensions and EA"):
        ForwardKinematics(robot).solve(np.ones(8), tensions=np.ones(8))


def test_warm_started_along_a_path_each_solve_takes_two_or_three_iterations() -> None:
    """The control loop's use: one solver, ``solve(lengths)`` every 1 ms, each from the last solution."""
    robot = load_robot("cogiro")
    fk = ForwardKinematics(robot)
    t = np.arange(0.0, 2.0, 1e-3)
    for k, s in enumerate(t):
        p = robot.home_position + np.array([0.8 * math.sin(s), 0.5 * math.sin(2 * s), 0.3 * (1 - math.cos(s))])
        R = rpy_to_matrix(0.1 * math.sin(3 * s), 0.05 * s, 0.2 * math.sin(s)) @ robot.home_rotation
        res = fk.solve(inverse_kinematics(robot, p, R).lengths)
        assert res.converged, (k, res)
        assert res.iterations <= (5 if k == 0 else 3), (k, res)
        assert float(np.abs(pose_error(robot, res.position, res.rotation, p, R)).max()) <= ACCURACY
        assert fk.position is res.position  # the next start


def test_noisy_lengths_give_the_least_squares_pose_and_report_the_residual() -> None:
    robot = load_robot("cogiro")
    rng = np.random.default_rng(5)
    p, R, lengths, _ = _poses(robot, 20, seed=5)
    fk = ForwardKinematics(robot)
    for k in range(len(p)):
        noisy = lengths[k] + rng.normal(0.0, 5e-3, robot.m)
        res = fk.solve(noisy, p[k], R[k])
        assert res.converged
        r = inverse_kinematics(robot, res.position, res.rotation).lengths - noisy
        assert res.residual == pytest.approx(float(np.abs(r).max()), abs=1e-10)  # at the pose returned
        assert res.residual_norm == pytest.approx(float(np.linalg.norm(r)), abs=1e-10)
        assert 1e-4 < res.residual < 0.05
        J = fk.jacobian(res.position, res.rotation)
        assert float(np.abs(J.T @ r).max()) < 1e-9  # least squares: the gradient vanishes
        # no pose fits the lengths better nearby
        for step in 1e-4 * np.eye(6):
            q, S = fk.moved(res.position, res.rotation, step)
            assert np.linalg.norm(fk.lengths(q, S) - noisy) >= res.residual_norm - 1e-15


def test_inconsistent_lengths_leave_a_residual() -> None:
    robot = load_robot("caroca")
    lengths = inverse_kinematics(robot, robot.home_position, robot.home_rotation).lengths.copy()
    lengths[0] += 0.2
    res = forward_kinematics(robot, lengths)
    assert res.residual > 0.05
    old = kinematics_fk(robot, lengths)  # the kinematics module's API: converged only for consistent lengths
    assert not old.converged
    assert old.residual > 1e-3


def test_far_off_guesses_are_restarted_from_home() -> None:
    """The protocol's cold guesses (1 m, 2–40° off) land some solves in a wrong local minimum: the solver tries
    again from home, and from the guess's position at the home orientation, within its 30 iterations."""
    robot = load_robot("cogiro")
    rng = np.random.default_rng(11)
    n = 400
    p, R = feasible_poses(robot, n, rng, payload=100.0, tmin=10.0, tmax=6000.0)  # the bench's poses
    lengths = np.array([inverse_kinematics(robot, p[k], R[k]).lengths for k in range(n)])
    guess_p = p + unit_vectors(rng, n) * rng.uniform(0.0, 1.0, n)[:, None]
    guess_R = turns(unit_vectors(rng, n), rng.uniform(math.radians(2.0), math.radians(40.0), n)) @ R
    with_restarts = _misses(robot, ForwardKinematics(robot), lengths, guess_p, guess_R, p, R)
    without = _misses(robot, ForwardKinematics(robot, restart_residual=math.inf), lengths, guess_p, guess_R, p, R)
    assert len(with_restarts) <= 1 < len(without), (with_restarts, without)


def test_elastic_stretch_is_corrected_given_the_tensions() -> None:
    """Encoders read unstretched lengths l0; under tensions f the cables are l0 (1 + f/EA) long (cdpr_sim.elastic's
    static law, inverted by catenary.unstretched_lengths)."""
    robot = load_robot("caroca")
    p = robot.home_position + np.array([0.2, -0.1, 0.3])
    R = rpy_to_matrix(0.05, 0.02, -0.1)
    lengths = inverse_kinematics(robot, p, R).lengths
    f = np.linspace(200.0, 900.0, robot.m)
    EA = np.full(robot.m, 2.0e5)
    l0 = unstretched_lengths(lengths, f, 2.0e5)
    fk = ForwardKinematics(robot)
    res = fk.solve(l0, tensions=f, EA=EA)
    assert res.converged
    assert float(np.abs(pose_error(robot, res.position, res.rotation, p, R)).max()) <= ACCURACY
    rigid = ForwardKinematics(robot).solve(l0)  # the stretch ignored: another pose, a residual
    assert float(np.abs(rigid.position - p).max()) > 1e-3


# ------------------------------------------------------------------------------------------------
# cdpr fk


def _ik(*args: str) -> list[str]:
    proc = cdpr_here("ik", *args)
    assert proc.returncode == 0, proc.stderr
    return [repr(x) for x in json.loads(proc.stdout)["lengths"]]


def test_cdpr_fk_gives_back_the_pose_of_cdpr_ik() -> None:
    pose = ["0.3", "-0.2", "1.4", "0.05", "-0.03", "0.12"]
    proc = cdpr("fk", "caroca", "--lengths", *_ik("caroca", "--pose", *pose), timeout=60)  # the real command
    assert proc.returncode == 0, proc.stderr
    out = json.loads(proc.stdout)
    np.testing.assert_allclose(out["position"], [0.3, -0.2, 1.4], rtol=0, atol=1e-9)
    np.testing.assert_allclose(out["rpy"], [0.05, -0.03, 0.12], rtol=0, atol=1e-9)
    np.testing.assert_allclose(out["rotation"], rpy_to_matrix(0.05, -0.03, 0.12), rtol=0, atol=1e-9)
    assert out["converged"] is True
    assert out["consistent"] is True
    assert out["problems"] == []
    assert out["residual"] < 1e-9
    assert 1 <= out["iterations"] <= 30
    # a planar robot: its plane's coordinates and the turn about its normal
    planar = json.loads(cdpr_here("fk", "planar_xy_4", "--lengths",
                                  *_ik("planar_xy_4", "--pose", "0.6", "0.4", "0", "0", "0", "0.1")).stdout)
    np.testing.assert_allclose(planar["position"] + planar["rpy"], [0.6, 0.4, 0, 0, 0, 0.1], rtol=0, atol=1e-9)


def test_cdpr_fk_with_a_com_offset_and_euler_xyz(caspr_files: dict[str, Path]) -> None:
    """CASPR's CoGiRo: its platform frame is not its COM (platform.com); FK gives the platform frame's pose, as
    `cdpr ik --pose` takes it, and the COM's."""
    path = str(caspr_files["cogiro"])
    robot = load_robot(path)
    assert np.abs(robot.com_offset).max() > 0.1
    pose = ["0.4", "-0.3", "2.5", "0.1", "-0.05", "0.2"]
    out = json.loads(cdpr_here("fk", path, "--angles", "xyz", "--guess", "0", "0", "2.2",
                               "--lengths", *_ik(path, "--pose", *pose, "--angles", "xyz")).stdout)
    np.testing.assert_allclose(out["position"] + out["xyz"], [float(x) for x in pose], rtol=0, atol=1e-9)
    R = np.array(out["rotation"])
    np.testing.assert_allclose(out["com"], np.array(out["position"]) + R @ robot.com_offset, rtol=0, atol=1e-12)


def test_cdpr_fk_elastic_correction() -> None:
    lengths = np.array([float(x) for x in _ik("caroca", "--pose", "0.1", "0.2", "1.5")])
    tensions = np.full(8, 500.0)
    l0 = unstretched_lengths(lengths, tensions, 1.0e5)
    proc = cdpr_here("fk", "caroca", "--lengths", *map(repr, l0.tolist()), "--tensions", *map(repr, tensions.tolist()),
                     "--ea", "1e5")
    assert proc.returncode == 0, proc.stderr
    np.testing.assert_allclose(json.loads(proc.stdout)["position"], [0.1, 0.2, 1.5], rtol=0, atol=1e-9)


@pytest.mark.parametrize(("args", "needle"), [
    (("fk", "caroca", "--lengths", "1", "2", "3"), "--lengths: expected 8 lengths (one per cable of caroca), got 3"),
    (("fk", "caroca", "--lengths", "3", "3", "3", "3", "3", "3", "3", "x"), "--lengths"),
    (("fk", "caroca", "--lengths", "3", "3", "3", "3", "3", "3", "3", "-1"), "--lengths"),
    (("fk", "caroca"), "--lengths"),
    (("fk", "caroca", "--lengths", *["3"] * 8, "--guess", "0", "0"), "--guess"),
    (("fk", "caroca", "--lengths", *["3"] * 8, "--ea", "1e5"), "--ea/--tensions"),
    (("fk", "caroca", "--lengths", *["3"] * 8, "--max-residual", "0"), "--max-residual"),
    (("fk", "caroca", "--csv", "/no/such/file.csv"), "/no/such/file.csv"),
])
def test_cdpr_fk_bad_input_gives_one_line_and_exit_2(args: tuple[str, ...], needle: str) -> None:
    proc = cdpr_here(*args)
    assert proc.returncode == 2, proc.stderr
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1, proc.stderr
    assert needle in lines[0], proc.stderr


def test_cdpr_fk_inconsistent_or_unsolved_lengths_exit_3() -> None:
    lengths = [float(x) for x in _ik("caroca", "--pose", "0.1", "0.2", "1.5")]
    lengths[0] += 0.2
    proc = cdpr_here("fk", "caroca", "--lengths", *map(repr, lengths))
    assert proc.returncode == 3, proc.stderr
    out = json.loads(proc.stdout)
    assert out["consistent"] is False
    assert out["residual"] > 0.05
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1
    assert lines[0].startswith("cdpr fk: no pose has these lengths: the lengths are inconsistent: residual ")
    assert "> --max-residual 0.001 m" in lines[0]
    # the same lengths pass with a looser threshold
    assert cdpr_here("fk", "caroca", "--lengths", *map(repr, lengths), "--max-residual", "0.5").returncode == 0
    # one iteration is not enough from home
    far = _ik("caroca", "--pose", "1", "1", "1", "0.2", "0", "0")
    proc = cdpr_here("fk", "caroca", "--lengths", *far, "--max-iterations", "1")
    assert proc.returncode == 3
    assert json.loads(proc.stdout)["converged"] is False
    assert "the solver did not converge in 1 iterations" in proc.stderr


def test_cdpr_fk_csv_a_pose_per_line_warm_started(tmp_path: Path) -> None:
    poses = [(0.1, 0.2, 1.5 + 0.001 * k, 0.05, 0.0, 0.01 * k) for k in range(5)]
    rows = [", ".join(_ik("caroca", "--pose", *map(str, pose))) for pose in poses]
    csv = tmp_path / "lengths.csv"
    csv.write_text("# lengths, m\n" + rows[0] + "\n\n" + "\n".join(" ".join(r.split(", ")) for r in rows[1:]) + "\n")
    proc = cdpr_here("fk", "caroca", "--csv", str(csv))
    assert proc.returncode == 0, proc.stderr
    lines = proc.stdout.strip().splitlines()
    assert lines[0] == "line,x,y,z,roll,pitch,yaw,iterations,converged,residual"
    assert len(lines) == 1 + len(poses)
    for pose, line in zip(poses, lines[1:], strict=True):
        fields = line.split(",")
        np.testing.assert_allclose([float(x) for x in fields[1:7]], pose, rtol=0, atol=1e-9)
        assert fields[8] == "true"
    assert max(int(line.split(",")[7]) for line in lines[2:]) <= 3  # warm: each from the line before
    assert [line.split(",")[0] for line in lines[1:]] == ["2", "4", "5", "6", "7"]  # the file's line numbers
    # a bad line: exit 2 naming it; an inconsistent one: every line printed, exit 3 and one line
    csv.write_text(rows[0] + "\n1, 2\n")
    proc = cdpr_here("fk", "caroca", "--csv", str(csv))
    assert proc.returncode == 2
    assert "line 2: expected 8 lengths" in proc.stderr
    csv.write_text(rows[0] + "\n" + ", ".join(["3"] * 8) + "\n")
    proc = cdpr_here("fk", "caroca", "--csv", str(csv))
    assert proc.returncode == 3
    assert len(proc.stdout.strip().splitlines()) == 3
    assert len(proc.stderr.strip().splitlines()) == 1
    assert "1 of 2 line(s)" in proc.stderr


def test_cdpr_help_lists_fk() -> None:
    proc = subprocess.run([*CDPR, "--help"], capture_output=True, text=True, check=True)
    assert "  fk " in proc.stdout
    options = cdpr_here("fk", "--help").stdout.split("Options:")[1]
    for flag in ("--lengths", "--guess", "--csv", "--tensions", "--ea", "--angles", "--max-residual"):
        assert f"  {flag} " in options, flag


# ------------------------------------------------------------------------------------------------
# The bench part


def test_the_bench_part_runs_the_protocol() -> None:
    r = bench_robot("caroca", 60)
    assert r["poses"] == 60
    for run in ("cold", "warm"):
        assert r[run]["success"] >= 0.95
        assert r[run]["median_us"] > 0
        assert r[run]["iterations_max"] <= 30
    assert r["warm"]["success"] == 1.0
    assert r["warm"]["iterations_p99"] <= 3
    noisy = r["noisy"]
    assert 0.5 < noisy["nees_ratio"] < 2.0
    assert noisy["residual_median_m"] > 1e-3
    result = {"protocol": {"poses": 60, "payload_kg": 100.0, "tensions_N": [10.0, 6000.0], "tol": 1e-9,
                           "max_iterations": 30, "noise_m": 5e-3}, "robots": {"cogiro": r}}
    assert set(fk_targets(result)) == {"fk_cold_success>=0.99", "fk_warm_success>=0.9999", "fk_warm_median_us<=60",
                                       "fk_noisy_covariance_ratio_within_0.1"}
    assert "forward kinematics" in "\n".join(fk_lines(result))


def test_matrix_to_rotvec_is_the_pose_error() -> None:
    robot = load_robot("cogiro")
    R = rotvec_to_matrix([0.1, 0.2, -0.1])
    e = pose_error(robot, robot.home_position, R @ robot.home_rotation, robot.home_position, robot.home_rotation)
    np.testing.assert_allclose(e, [0, 0, 0, 0.1, 0.2, -0.1], atol=1e-15)
    np.testing.assert_allclose(matrix_to_rotvec(R), [0.1, 0.2, -0.1], atol=1e-15)
