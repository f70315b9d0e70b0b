"""Cable kinematics (seed paper eq. 2–4): hand-computed cases, J by finite differences, W = −Jᵀ, FK ∘ IK.

Conventions under test (shared/cdpr/mechanics/kinematics.py): l_i = a_i − t − R b_i, d_i = l_i / ‖l_i‖, l̇ = J v with the
world-frame twist v = [ṫ; ω], and W f = [Σ f_i d_i; Σ (R b_i) × f_i d_i] with W = −Jᵀ.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from cdpr.config.robot import load_robot, shipped_robots
from cdpr.mechanics.kinematics import cable_length_rates, forward_kinematics, inverse_kinematics
from cdpr.mechanics.pulley import pulley_geometry
from cdpr.mechanics.robot import Robot, Shape
from cdpr.mechanics.rotation import Array, rotvec_to_matrix, rpy_to_matrix

TEST_ROBOTS = Path(__file__).parent / "robots" / "valid"


def make_robot(frame: Array, platform: Array, mode: str = "spatial") -> Robot:
    """A Robot built directly (no loader checks): only the geometry matters to kinematics."""
    return Robot(
        name="hand",
        description="",
        source="test",
        mode=mode,  # type: ignore[arg-type]
        frame_points=np.asarray(frame, dtype=float),
        platform_points=np.asarray(platform, dtype=float),
        mass=1.0,
        inertia=np.eye(3),
        shape=Shape("box", (1.0, 1.0, 1.0)),
        tmin=0.0,
        tmax=100.0,
        max_length=20.0,
        max_speed=1.0,
        cable_damping=0.0,
        passive_damping=0.0,
        home_position=np.array([0.0, 0.0, 1.0]),
        home_rotation=np.eye(3),
        frame_min=np.array([-3.0, -4.0, 0.0]),
        frame_max=np.array([3.0, 4.0, 7.0]),
    )


# The hand case: four cables, quadrant signs (sx, sy); a_i = (3 sx, 4 sy, 7), b_i = (sx, sy, 0),
# platform at t = (0, 0, 1).
SIGNS = np.array([[1.0, 1.0], [-1.0, 1.0], [-1.0, -1.0], [1.0, -1.0]])
HAND_FRAME = np.c_[3 * SIGNS[:, 0], 4 * SIGNS[:, 1], np.full(4, 7.0)]
HAND_PLATFORM = np.c_[SIGNS, np.zeros(4)]
HAND_T = np.array([0.0, 0.0, 1.0])
RZ90 = np.array([[0.0, -1.0, 0.0], [1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])


def test_hand_case_without_rotation() -> None:
    """l_i = (2 sx, 3 sy, 6), ‖l_i‖ = 7.

    Moment column: (sx, sy, 0) × (2 sx, 3 sy, 6) / 7 = (6 sy, −6 sx, sx sy) / 7.
    """
    kin = inverse_kinematics(make_robot(HAND_FRAME, HAND_PLATFORM), HAND_T, np.eye(3))
    assert np.allclose(kin.vectors, [[2, 3, 6], [-2, 3, 6], [-2, -3, 6], [2, -3, 6]])
    assert np.allclose(kin.lengths, [7.0, 7.0, 7.0, 7.0])
    assert np.allclose(kin.directions, np.array([[2, 3, 6], [-2, 3, 6], [-2, -3, 6], [2, -3, 6]]) / 7)
    assert np.allclose(kin.platform_points_world, [[1, 1, 1], [-1, 1, 1], [-1, -1, 1], [1, -1, 1]])
    expected_W = (
        np.array(
            [
                [2, 3, 6, 6, -6, 1],
                [-2, 3, 6, 6, 6, -1],
                [-2, -3, 6, -6, 6, 1],
                [2, -3, 6, -6, -6, -1],
            ]
        ).T
        / 7
    )
    assert np.allclose(kin.wrench_matrix, expected_W)
    assert np.allclose(kin.jacobian, -expected_W.T)


def test_hand_case_rotated_a_quarter_turn_about_z() -> None:
    """R b_i = (−sy, sx, 0), so l_i = (3 sx + sy, 4 sy − sx, 6)."""
    kin = inverse_kinematics(make_robot(HAND_FRAME, HAND_PLATFORM), HAND_T, RZ90)
    vectors = np.array([[4, 3, 6], [-2, 5, 6], [-4, -3, 6], [2, -5, 6]], dtype=float)
    lengths = np.sqrt([61.0, 65.0, 61.0, 65.0])
    assert np.allclose(kin.vectors, vectors)
    assert np.allclose(kin.lengths, lengths)
    assert np.allclose(kin.platform_points_world, [[-1, 1, 1], [-1, -1, 1], [1, -1, 1], [1, 1, 1]])
    # (R b_i) × l_i worked out by hand, then divided by the length.
    moments = np.array([[6, 6, -7], [-6, 6, -7], [-6, -6, -7], [6, -6, -7]]) / lengths[:, None]
    assert np.allclose(kin.wrench_matrix[:3].T, vectors / lengths[:, None])
    assert np.allclose(kin.wrench_matrix[3:].T, moments)


def test_hand_case_length_rates() -> None:
    """Rising at 1 m/s shortens every cable by 6/7 m/s; spinning about z at 1 rad/s moves b_i at
    (−sy, sx, 0), which changes l_i at −d_i · (−sy, sx, 0) = −sx sy / 7."""
    kin = inverse_kinematics(make_robot(HAND_FRAME, HAND_PLATFORM), HAND_T, np.eye(3))
    assert np.allclose(cable_length_rates(kin, [0, 0, 1, 0, 0, 0]), np.full(4, -6 / 7))
    assert np.allclose(cable_length_rates(kin, [0, 0, 0, 0, 0, 1]), -SIGNS[:, 0] * SIGNS[:, 1] / 7)


# --- every robot: J by finite differences, W = −Jᵀ, the wrench of W f -------------------------------------


def all_robots() -> list[object]:
    params = [pytest.param(load_robot(name), id=name) for name in shipped_robots()]
    params += [pytest.param(load_robot(p), id=p.stem) for p in sorted(TEST_ROBOTS.glob("*.yaml"))]
    params.append(pytest.param(make_robot(HAND_FRAME, HAND_PLATFORM), id="hand"))
    return params


def poses(robot: Robot) -> list[tuple[Array, Array]]:
    """The home pose and a displaced, tilted one."""
    moved = robot.home_position + np.array([0.05, -0.04, 0.06])
    tilted = rpy_to_matrix(0.04, -0.03, 0.08) @ robot.home_rotation
    return [(robot.home_position, robot.home_rotation), (moved, tilted)]


def lengths_at(robot: Robot, t: Array, R: Array) -> Array:
    return inverse_kinematics(robot, t, R).lengths


def finite_difference_jacobian(robot: Robot, t: Array, R: Array, h: float = 1e-6) -> Array:
    """Column k: central difference of the lengths along twist k.

    Translations move t to t ± h e; rotations turn R into exp(±h e) R (a world-frame angular velocity).
    """
    J = np.empty((robot.m, 6))
    for k in range(3):
        e = np.eye(3)[k] * h
        J[:, k] = (lengths_at(robot, t + e, R) - lengths_at(robot, t - e, R)) / (2 * h)
        turned_plus = lengths_at(robot, t, rotvec_to_matrix(e) @ R)
        turned_minus = lengths_at(robot, t, rotvec_to_matrix(-e) @ R)
        J[:, 3 + k] = (turned_plus - turned_minus) / (2 * h)
    return J


@pytest.mark.parametrize("robot", all_robots())
def test_jacobian_matches_finite_differences_and_w_is_minus_j_transpose(robot: Robot) -> None:
    for t, R in poses(robot):
        kin = inverse_kinematics(robot, t, R)
        J_fd = finite_difference_jacobian(robot, t, R)
        assert np.allclose(kin.jacobian, J_fd, atol=1e-7)
        assert np.allclose(kin.wrench_matrix, -J_fd.T, atol=1e-7)


@pytest.mark.parametrize("robot", all_robots())
def test_wrench_of_tensions_is_the_sum_of_cable_forces_and_moments(robot: Robot) -> None:
    rng = np.random.default_rng(7)
    for t, R in poses(robot):
        f = rng.uniform(1.0, 100.0, robot.m)
        force = np.zeros(3)
        moment = np.zeros(3)
        ends = robot.frame_points if robot.pulleys is None else pulley_geometry(  # where it leaves its pulley
            robot.frame_points, robot.pulleys, t + robot.platform_points @ R.T).tangent_points
        for a, b, fi in zip(ends, robot.platform_points, f, strict=True):
            p = t + R @ b  # the attach point in the world
            pull = fi * (a - p) / np.linalg.norm(a - p)  # a cable pulls the platform towards the frame
            force += pull
            moment += np.cross(p - t, pull)  # about the centre of mass
        W = inverse_kinematics(robot, t, R).wrench_matrix
        assert np.allclose(W @ f, np.r_[force, moment], rtol=1e-12, atol=1e-9)


@pytest.mark.parametrize("robot", all_robots())
def test_cable_power_is_minus_tension_times_length_rate(robot: Robot) -> None:
    """Virtual work: the power of the cable wrench along a twist is −Σ f_i l̇_i (cables pull inwards)."""
    rng = np.random.default_rng(11)
    t, R = poses(robot)[1]
    f = rng.uniform(1.0, 100.0, robot.m)
    twist = rng.normal(size=6)
    h = 1e-6
    plus = lengths_at(robot, t + h * twist[:3], rotvec_to_matrix(h * twist[3:]) @ R)
    minus = lengths_at(robot, t - h * twist[:3], rotvec_to_matrix(-h * twist[3:]) @ R)
    l_dot = (plus - minus) / (2 * h)
    kin = inverse_kinematics(robot, t, R)
    assert np.allclose(cable_length_rates(kin, twist), l_dot, atol=1e-7)
    assert (kin.wrench_matrix @ f) @ twist == pytest.approx(-f @ l_dot, rel=1e-6, abs=1e-6)


# --- forward kinematics -------------------------------------------------------------------------------


def displaced_pose(robot: Robot) -> tuple[Array, Array]:
    """A pose near home that the robot's mode can reach."""
    t, R = robot.home_position, robot.home_rotation
    if robot.mode == "point_mass":
        return t + np.array([0.2, -0.1, 0.15]), R
    if robot.mode == "planar":  # along x and the plane's other axis, turned about its normal
        xz = robot.plane == "xz"
        shift, turn = ([0.1, 0.0, -0.08], (0.0, 0.06, 0.0)) if xz else ([0.1, -0.08, 0.0], (0.0, 0.0, 0.06))
        return t + np.array(shift), rpy_to_matrix(*turn) @ R
    return t + np.array([0.12, -0.08, 0.1]), rpy_to_matrix(0.05, -0.03, 0.08) @ R


@pytest.mark.parametrize("name", shipped_robots())
def test_forward_kinematics_recovers_the_pose_from_its_lengths(name: str) -> None:
    robot = load_robot(name)
    t, R = displaced_pose(robot)
    lengths = inverse_kinematics(robot, t, R).lengths
    fk = forward_kinematics(robot, lengths)  # starts from the home pose
    assert fk.converged
    assert fk.residual < 1e-8
    assert np.allclose(fk.position, t, atol=1e-7)
    if robot.mode != "point_mass":  # a point mass's orientation is not defined by its cables
        assert np.allclose(fk.rotation, R, atol=1e-7)
    assert np.allclose(inverse_kinematics(robot, fk.position, fk.rotation).lengths, lengths, atol=1e-8)


@pytest.mark.parametrize("name", shipped_robots())
def test_forward_kinematics_from_an_explicit_guess(name: str) -> None:
    robot = load_robot(name)
    lengths = inverse_kinematics(robot, robot.home_position, robot.home_rotation).lengths
    t, R = displaced_pose(robot)
    guess_rotation = R if robot.mode == "spatial" else None
    fk = forward_kinematics(robot, lengths, guess_position=t, guess_rotation=guess_rotation)
    assert fk.converged
    assert np.allclose(fk.position, robot.home_position, atol=1e-7)
    if robot.mode != "point_mass":
        assert np.allclose(fk.rotation, robot.home_rotation, atol=1e-7)


def test_forward_kinematics_reports_inconsistent_lengths() -> None:
    """Eight lengths over-determine a 6-DOF pose: stretching one cable leaves a residual, not a pose."""
    robot = load_robot("caroca")
    lengths = inverse_kinematics(robot, robot.home_position, robot.home_rotation).lengths.copy()
    lengths[0] += 0.2
    fk = forward_kinematics(robot, lengths)
    assert not fk.converged
    assert fk.residual > 1e-3
