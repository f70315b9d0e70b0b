"""Feedback linearisation (eq. 6-7) on cases worked out by hand."""

from __future__ import annotations

import numpy as np
import pytest

from cdpr.config.robot import load_robot
from cdpr.mechanics.control import Gains, commanded_acceleration, controlled_rows, feedback_linearisation
from cdpr.mechanics.dynamics import forward_dynamics
from cdpr.mechanics.kinematics import inverse_kinematics
from cdpr.mechanics.rotation import rotvec_to_matrix
from cdpr.mechanics.tda import make_tda

G = 9.81


def test_at_rest_on_target_the_wrench_is_the_weight() -> None:
    robot = load_robot("caroca").with_mass(15.0)
    p, R = np.array([0.0, 0.0, 1.2]), np.eye(3)
    w = feedback_linearisation(robot, p, R, np.zeros(6), p, R, np.zeros(6), np.zeros(6), Gains.of(1500, 1500))
    assert np.allclose(w, [0, 0, 15.0 * G, 0, 0, 0], atol=1e-12)


def test_position_and_velocity_errors_by_hand() -> None:
    robot = load_robot("caroca").with_mass(2.0)
    gains = Gains.of(100.0, 20.0)
    p = np.array([0.1, 0.0, 1.0])
    pd = np.array([0.1, 0.01, 1.0])  # 1 cm behind in y
    v = np.array([0.0, 0.0, 0.05, 0, 0, 0])  # moving up at 5 cm/s, should be still
    ad = np.array([0.2, 0.0, 0.0, 0, 0, 0])
    w = feedback_linearisation(robot, p, np.eye(3), v, pd, np.eye(3), np.zeros(6), ad, gains)
    # a = a_d + Kp e + Kd (v_d - v) = (0.2, 100*0.01, -20*0.05) = (0.2, 1.0, -1.0); W f = m a - m g
    assert np.allclose(w[:3], 2.0 * np.array([0.2, 1.0, -1.0 + G]), atol=1e-12)
    assert np.allclose(w[3:], 0.0, atol=1e-12)


def test_orientation_error_is_a_rotation_vector_on_so3() -> None:
    gains = Gains.of(10.0, 0.0)
    Rd = rotvec_to_matrix([0.0, 0.0, 0.3])
    acc = commanded_acceleration(np.zeros(3), np.eye(3), np.zeros(6), np.zeros(3), Rd, np.zeros(6), np.zeros(6), gains)
    assert np.allclose(acc[3:], [0.0, 0.0, 3.0], atol=1e-12)  # Kp * 0.3 rad about z
    # a large error goes the short way round: 350° about x is -10°
    Rd = rotvec_to_matrix([np.deg2rad(350.0), 0.0, 0.0])
    acc = commanded_acceleration(np.zeros(3), np.eye(3), np.zeros(6), np.zeros(3), Rd, np.zeros(6), np.zeros(6), gains)
    assert np.allclose(acc[3:], [10.0 * np.deg2rad(-10.0), 0.0, 0.0], atol=1e-9)


def test_gyroscopic_term_is_compensated() -> None:
    robot = load_robot("caroca")  # 150 kg, inertia (6.5, 20, 22.5)
    twist = np.array([0, 0, 0, 1.0, 0.0, 0.5])
    w = feedback_linearisation(robot, np.zeros(3), np.eye(3), twist, np.zeros(3), np.eye(3), twist, np.zeros(6),
                               Gains.of(0.0, 0.0))
    J = np.diag([6.5, 20.0, 22.5])
    assert np.allclose(w[3:], np.cross(twist[3:], J @ twist[3:]), atol=1e-12)


@pytest.mark.parametrize("variant", ["6dof", "3dof"])
def test_the_law_produces_the_commanded_acceleration(variant: str) -> None:
    """Closing the loop by hand: tensions from the law give, through Newton–Euler, the commanded acceleration."""
    robot = load_robot("caroca").with_mass(15.0)
    rng = np.random.default_rng(1)
    p = np.array([0.2, -0.1, 1.3])
    R = rotvec_to_matrix([0.02, -0.01, 0.03])
    twist = rng.normal(scale=0.05, size=6)
    pd, Rd = p + np.array([0.002, -0.001, 0.003]), np.eye(3)
    twist_d, accel_d = twist + rng.normal(scale=0.005, size=6), rng.normal(scale=0.2, size=6)
    gains = Gains.of(100.0, 20.0)
    rows = list(controlled_rows(robot, variant))  # type: ignore[arg-type]
    w = feedback_linearisation(robot, p, R, twist, pd, Rd, twist_d, accel_d, gains, variant)  # type: ignore[arg-type]
    W = inverse_kinematics(robot, p, R).wrench_matrix
    f = make_tda("qp").solve(W[rows], w, 1.0, 6500.0)
    assert f.feasible
    acc = forward_dynamics(robot, R, twist, W @ f.tensions)
    want = commanded_acceleration(p, R, twist, pd, Rd, twist_d, accel_d, gains)
    assert np.allclose(acc[rows], want[rows], atol=1e-8)


def test_point_mass_robot_uses_three_rows() -> None:
    robot = load_robot("point_mass_4")
    assert controlled_rows(robot, "6dof") == (0, 1, 2)
    p = robot.home_position
    w = feedback_linearisation(robot, p, np.eye(3), np.zeros(6), p, np.eye(3), np.zeros(6), np.zeros(6), Gains.of(1, 1))
    assert np.allclose(w, [0.0, 0.0, robot.mass * G])
