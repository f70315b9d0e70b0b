"""The sim's physics core on real DART: clamping, free fall, Newton–Euler, equilibrium, determinism.

Independent references: the closed form of semi-implicit Euler under constant gravity,
``cdpr.mechanics.dynamics.forward_dynamics`` (Newton–Euler written in numpy, no DART), ``cdpr.mechanics.kinematics``
for cable lengths, rates and the wrench matrix, scipy's ``lsq_linear`` for equilibrium tensions, and
the scalar planar equations m·a = F + m·g, I_yy·θ̈ = τ_y. Point-mass and planar test robots are
built here, so these tests do not move when the shipped robot files change.
"""

from __future__ import annotations

from collections.abc import Callable
from functools import partial

import numpy as np
import pytest
from scipy.linalg import block_diag
from scipy.optimize import lsq_linear

from cdpr.config.robot import RobotSpec, load_robot, robot_from_spec, shipped_robots
from cdpr.mechanics.dynamics import forward_dynamics, gravity_wrench
from cdpr.mechanics.kinematics import cable_length_rates, inverse_kinematics
from cdpr.mechanics.robot import Robot
from cdpr.mechanics.rotation import (
    matrix_to_quat,
    matrix_to_rotvec,
    quat_to_matrix,
    rotvec_quat,
    rotvec_to_matrix,
    rpy_to_matrix,
)
from cdpr_sim.core import PlatformBody, PlatformSim, PlatformState, clamp_tensions, state_message

G = 9.81
DT = 1e-3
# A full, non-diagonal, positive-definite inertia (kg·m²) for CAROCA: exercises every term of ω × Iω.
FULL_INERTIA = np.array([[6.5, 0.8, -0.4], [0.8, 20.0, 0.6], [-0.4, 0.6, 22.5]])


def _spec(**overrides: object) -> dict[str, object]:
    base: dict[str, object] = {
        "source": "tests/test_sim_core.py",
        "limits": {"tmin": 5.0, "tmax": 100.0, "max_length": 7.0, "max_speed": 10.0},
        "damping": {"cable": 1.0, "passive": 0.0},
    }
    base.update(overrides)
    return base


def point_mass_robot() -> Robot:
    """Four cables from the top corners of a 4 m cube to the centre of a 1 kg sphere."""
    corners = [[-2.0, -2.0, 4.0], [-2.0, 2.0, 4.0], [2.0, 2.0, 4.0], [2.0, -2.0, 4.0]]
    spec = _spec(
        name="test_point_mass",
        mode="point_mass",
        platform={"mass": 1.0, "inertia": [0.016, 0.02, 0.025], "shape": {"type": "sphere", "size": [0.2]}},
        cables=[{"frame": a, "platform": [0.0, 0.0, 0.0]} for a in corners],
        home={"position": [0.2, -0.1, 3.0]},
        frame_box={"min": [-2.0, -2.0, 0.0], "max": [2.0, 2.0, 4.0]},
    )
    return robot_from_spec(RobotSpec.model_validate(spec), "test")


def planar_robot() -> Robot:
    """A 4-cable plate in the x–z plane: two cables from above, two from below, crossed lever arms."""
    spec = _spec(
        name="test_planar",
        mode="planar",
        # Ixy and Iyz are not zero: a planar joint must still give I_yy θ̈ = τ_y.
        platform={
            "mass": 4.0,
            "inertia": [[0.06, 0.01, 0.0], [0.01, 0.1, 0.02], [0.0, 0.02, 0.05]],
            "shape": {"type": "box", "size": [0.4, 0.05, 0.2]},
        },
        cables=[
            {"frame": [-2.0, 0.0, 3.0], "platform": [-0.2, 0.0, 0.1]},
            {"frame": [2.0, 0.0, 3.0], "platform": [0.2, 0.0, 0.1]},
            {"frame": [-2.0, 0.0, 0.0], "platform": [-0.2, 0.0, -0.1]},
            {"frame": [2.0, 0.0, 0.0], "platform": [0.2, 0.0, -0.1]},
        ],
        home={"position": [0.1, 0.0, 1.6]},
        frame_box={"min": [-2.0, -0.1, 0.0], "max": [2.0, 0.1, 3.0]},
    )
    return robot_from_spec(RobotSpec.model_validate(spec), "test")


def planar_xy_robot() -> Robot:
    """A 4-cable plate in the horizontal x–y plane (gravity out of it, held by the joint), crossed cables."""
    spec = _spec(
        name="test_planar_xy",
        mode="planar",
        plane="xy",
        # Ixz and Iyz are not zero: a planar joint must still give I_zz θ̈ = τ_z.
        platform={
            "mass": 3.0,
            "inertia": [[0.05, 0.0, 0.01], [0.0, 0.06, 0.02], [0.01, 0.02, 0.09]],
            "shape": {"type": "box", "size": [0.4, 0.2, 0.05]},
        },
        cables=[
            {"frame": [-2.0, -1.5, 0.0], "platform": [-0.2, 0.1, 0.0]},
            {"frame": [2.0, -1.5, 0.0], "platform": [0.2, 0.1, 0.0]},
            {"frame": [2.0, 1.5, 0.0], "platform": [0.2, -0.1, 0.0]},
            {"frame": [-2.0, 1.5, 0.0], "platform": [-0.2, -0.1, 0.0]},
        ],
        home={"position": [0.1, -0.2, 0.0]},
        frame_box={"min": [-2.0, -1.5, -0.1], "max": [2.0, 1.5, 0.1]},
    )
    return robot_from_spec(RobotSpec.model_validate(spec), "test")


def in_plane(robot: Robot, x: float, normal: float, turn: float) -> list[float]:
    """A 3-vector of a planar robot's plane: ``x`` along x, ``normal`` along the plane's other axis (z for x–z, y
    for x–y), ``turn`` along the normal (y for x–z, z for x–y)."""
    return [x, 0.0, normal] if robot.plane == "xz" else [x, normal, 0.0]


def about_normal(robot: Robot, angle: float) -> list[float]:
    """The rotation vector of ``angle`` about a planar robot's normal."""
    axis = np.eye(3)[robot.normal_axis]
    return (axis * angle).tolist()


def caroca_full_inertia() -> Robot:
    return load_robot("caroca").replace(inertia=FULL_INERTIA)


TEST_ROBOTS: dict[str, Callable[[], Robot]] = {
    "caroca_full_inertia": caroca_full_inertia,
    "point_mass": point_mass_robot,
    "planar": planar_robot,
    "planar_xy": planar_xy_robot,
}
ROBOTS: dict[str, Callable[[], Robot]] = {
    **TEST_ROBOTS,
    **{name: partial(load_robot, name) for name in shipped_robots()},
}


def moving_state(robot: Robot, spinning: bool) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """A pose near home and a twist (zero, or translating and spinning), valid for the robot's mode."""
    p = np.array(robot.home_position, dtype=float)
    if robot.mode == "planar":
        p += in_plane(robot, 0.05, -0.03, 0.0)
        R = rotvec_to_matrix(about_normal(robot, 0.2)) @ robot.home_rotation
        twist = np.r_[in_plane(robot, 0.4, -0.3, 0.0), about_normal(robot, 1.5)]
    else:
        p += [0.05, -0.04, 0.03]
        R = rpy_to_matrix(0.1, -0.15, 0.2) @ robot.home_rotation
        twist = np.array([0.4, -0.3, 0.2, 0.8, -1.5, 2.0])
    return p, R, twist if spinning else np.zeros(6)


def reference_acceleration(robot: Robot, R: np.ndarray, twist: np.ndarray, wrench: np.ndarray) -> np.ndarray:
    """[a; α] of the platform, world frame, from Newton–Euler without DART, for each mode's joint."""
    if robot.mode == "planar":
        # The plane's own equations: the joint removes the normal axis and the two other rotations, and ω along the
        # normal has no in-plane gyroscopic term. In the x–y plane gravity is out of the plane: the joint holds it.
        n = robot.normal_axis
        out = np.zeros(6)
        for j in range(3):
            if j != n:
                out[j] = wrench[j] / robot.mass - (G if j == 2 else 0.0)
        out[3 + n] = wrench[3 + n] / (R @ robot.inertia @ R.T)[n, n]
        return out
    if robot.mode == "point_mass":
        # The cables exert no moment: the sphere spins freely (Euler's equations) while its centre moves.
        linear = forward_dynamics(robot, R, twist, wrench[:3])
        Iw = R @ robot.inertia @ R.T
        w = twist[3:]
        return np.concatenate((linear, np.linalg.solve(Iw, -np.cross(w, Iw @ w))))
    return np.asarray(forward_dynamics(robot, R, twist, wrench))


def equilibrium_tensions(robot: Robot, position: np.ndarray, R: np.ndarray) -> np.ndarray:
    """Tensions in [tmin, tmax] with W f = −w_g on the controlled rows (scipy, not the project's TDA)."""
    rows = list(robot.controlled_rows)
    W = inverse_kinematics(robot, position, R).wrench_matrix
    wg = np.r_[gravity_wrench(robot), np.zeros(3)] if robot.mode == "point_mass" else gravity_wrench(robot)
    sol = lsq_linear(W[rows], -wg[rows], bounds=(robot.tmin, robot.tmax), tol=1e-15, method="bvls")
    f = np.asarray(sol.x)
    # every row, including the uncontrolled ones (they vanish), but the weight out of an x–y plane (the joint's)
    held = np.arange(6) != 2 if robot.mode == "planar" and robot.plane == "xy" else np.ones(6, dtype=bool)
    assert np.abs(W @ f + wg)[held].max() < 1e-9
    return f


def angle_between(R1: np.ndarray, R2: np.ndarray) -> float:
    return float(np.linalg.norm(matrix_to_rotvec(R1 @ R2.T)))


# -- clamp_tensions ---------------------------------------------------------------------------------


@pytest.mark.parametrize(
    ("commanded", "applied", "low", "high"),
    [
        ([1.0, 50.0, 99.9], [1.0, 50.0, 99.9], 0, 0),
        ([-3.0, 0.0, 100.0, 100.5, 1e9], [0.0, 0.0, 100.0, 100.0, 100.0], 1, 2),
        ([-1e-12, -np.inf, np.inf], [0.0, 0.0, 100.0], 2, 1),
        ([], [], 0, 0),
    ],
)
def test_clamp_tensions(commanded: list[float], applied: list[float], low: int, high: int) -> None:
    given = np.array(commanded, dtype=float)
    before = given.copy()
    out, n_low, n_high = clamp_tensions(given, 100.0)
    assert out.tolist() == applied
    assert (n_low, n_high) == (low, high)
    assert type(n_low) is int
    assert type(n_high) is int
    np.testing.assert_array_equal(given, before)  # pure: the input is untouched


def test_clamp_tensions_does_not_lift_to_tmin_and_rejects_nan() -> None:
    out, low, high = clamp_tensions(np.array([0.5, 2.0]), 10.0)  # below a robot's tmin, still allowed
    assert out.tolist() == [0.5, 2.0]
    assert low == high == 0
    with pytest.raises(ValueError, match="NaN"):
        clamp_tensions(np.array([1.0, np.nan]), 10.0)


# -- construction, reset, state -------------------------------------------------------------------


@pytest.mark.parametrize("name", list(ROBOTS))
def test_initial_state_round_trips_pose_and_twist(name: str) -> None:
    robot = ROBOTS[name]()
    p, R, twist = moving_state(robot, spinning=True)
    sim = PlatformSim(robot, DT, p, R, twist)
    s = sim.state()
    assert (s.step, s.t, sim.step_count) == (0, 0.0, 0)
    np.testing.assert_allclose(s.position, p, atol=1e-14)
    np.testing.assert_allclose(s.rotation, R, atol=1e-14)
    np.testing.assert_allclose(quat_to_matrix(s.quaternion), R, atol=1e-14)
    assert s.quaternion[3] >= 0.0
    assert abs(np.linalg.norm(s.quaternion) - 1.0) < 1e-15
    np.testing.assert_allclose(s.twist, twist, atol=1e-14)  # world frame [v; ω], whatever the joint
    np.testing.assert_array_equal(s.tensions, np.zeros(robot.m))
    with pytest.raises(ValueError, match="read-only"):
        s.position[0] = 1.0

    sim.step(np.full(robot.m, robot.tmin))
    sim.reset()  # back to home, at rest
    s = sim.state()
    assert (s.step, s.t) == (0, 0.0)
    np.testing.assert_allclose(s.position, robot.home_position, atol=1e-14)
    np.testing.assert_allclose(s.rotation, robot.home_rotation, atol=1e-14)
    np.testing.assert_array_equal(s.twist, np.zeros(6))
    np.testing.assert_array_equal(s.tensions, np.zeros(robot.m))


def test_time_is_step_count_times_dt() -> None:
    sim = PlatformSim(caroca_full_inertia(), dt=0.1)
    for k in range(1, 8):
        sim.step(np.full(8, 500.0))
        assert sim.step_count == k
        assert sim.t == k * 0.1
        assert (sim.state().step, sim.state().t) == (k, k * 0.1)


def test_bad_inputs_raise() -> None:
    robot = caroca_full_inertia()
    sim = PlatformSim(robot)
    with pytest.raises(ValueError, match="expected 8 tensions"):
        sim.step(np.ones(7))
    with pytest.raises(ValueError, match="NaN"):
        sim.step(np.r_[np.ones(7), np.nan])
    with pytest.raises(ValueError, match="rotation"):
        sim.reset(rotation=np.diag([1.0, 1.0, -1.0]))
    with pytest.raises(ValueError, match="twist"):
        sim.reset(twist=[0.0, 0.0, 0.0])
    with pytest.raises(ValueError, match="dt"):
        PlatformSim(robot, dt=0.0)
    assert sim.step_count == 0  # nothing was integrated
    planar = PlatformSim(planar_robot())
    with pytest.raises(ValueError, match="planar"):
        planar.reset(position=[0.0, 0.1, 1.5])
    with pytest.raises(ValueError, match="planar"):
        planar.reset(rotation=rpy_to_matrix(0.1, 0.0, 0.0))
    with pytest.raises(ValueError, match="planar"):
        planar.reset(twist=[0.0, 0.0, 0.0, 0.0, 0.0, 0.3])
    horizontal = PlatformSim(planar_xy_robot())
    for bad, message in [({"position": [0.0, 0.1, 0.2]}, "x–y plane: position z must be 0"),
                         ({"rotation": rpy_to_matrix(0.0, 0.1, 0.0)}, "rotation \\(not about z\\)"),
                         ({"twist": [0.0, 0.0, 0.3, 0.0, 0.0, 0.0]}, "twist v_z"),
                         ({"twist": [0.0, 0.0, 0.0, 0.2, 0.0, 0.0]}, "twist ω_x, ω_y")]:
        with pytest.raises(ValueError, match=message):
            horizontal.reset(**bad)


# -- free fall ------------------------------------------------------------------------------------


def test_free_fall_is_semi_implicit_euler() -> None:
    """Zero tensions, no damping: v_n = −g n dt and z_n = z_0 − g dt² n(n+1)/2.

    So z_n − (z_0 − g t²/2) = −g t dt / 2 exactly: the semi-implicit Euler bound is g·t·dt/2 (4.9 mm
    after 1 s at dt = 1 ms), and the closed form of the scheme holds to rounding.
    """
    robot = caroca_full_inertia().replace(cable_damping=0.0)
    z0 = float(robot.home_position[2])
    sim = PlatformSim(robot, DT)
    n = 1000
    for _ in range(n):
        report = sim.step(np.zeros(robot.m))
    s = sim.state()
    t = n * DT
    assert s.t == t
    assert abs(s.twist[2] - (-G * t)) < 1e-11
    assert abs(s.position[2] - (z0 - G * DT * DT * n * (n + 1) / 2)) < 1e-11
    error = abs(s.position[2] - (z0 - G * t * t / 2))
    assert error <= G * t * DT / 2 + 1e-11
    assert error > 0.99 * G * t * DT / 2  # and it really is the integrator's error, not a smaller one
    np.testing.assert_array_equal(s.position[:2], robot.home_position[:2])
    np.testing.assert_array_equal(s.twist[[0, 1, 3, 4, 5]], np.zeros(5))
    np.testing.assert_allclose(s.rotation, robot.home_rotation, atol=1e-15)
    np.testing.assert_array_equal(report.applied, np.zeros(robot.m))
    np.testing.assert_array_equal(report.damping, np.zeros(robot.m))


# -- one step against Newton–Euler ----------------------------------------------------------------


@pytest.mark.parametrize("spinning", [False, True], ids=["from_rest", "spinning"])
@pytest.mark.parametrize("name", list(ROBOTS))
def test_one_step_matches_newton_euler(name: str, spinning: bool) -> None:
    robot = ROBOTS[name]()
    p0, R0, v0 = moving_state(robot, spinning)
    rng = np.random.default_rng(sum(map(ord, name)) + spinning)
    f = rng.uniform(robot.tmin, robot.tmax, robot.m)
    sim = PlatformSim(robot, DT, p0, R0, v0)
    report = sim.step(f)
    s1 = sim.state()

    kin = inverse_kinematics(robot, p0, R0)
    rates = cable_length_rates(kin, v0)
    np.testing.assert_array_equal(report.applied, f)
    assert (report.clamped_low, report.clamped_high) == (0, 0)
    np.testing.assert_allclose(report.damping, robot.cable_damping * rates, rtol=1e-12, atol=1e-12)
    assert np.all(report.damping * rates >= 0.0)  # the damping opposes each cable's length rate
    np.testing.assert_array_equal(s1.tensions, f)

    expected = reference_acceleration(robot, R0, v0, kin.wrench_matrix @ (f + report.damping))
    measured = (s1.twist - v0) / DT
    assert np.linalg.norm(measured - expected) <= 1e-6 * np.linalg.norm(expected)
    # Semi-implicit Euler: the pose moves with the new twist.
    np.testing.assert_allclose(s1.position, p0 + DT * s1.twist[:3], rtol=0, atol=1e-14)
    # R₁ = exp(dt [ω₁]×) R₀; for small angles DART evaluates exp by its Taylor series to second order,
    # whose error is below θ³/6 (θ = dt‖ω₁‖).
    theta = DT * float(np.linalg.norm(s1.twist[3:]))
    R_expected = rotvec_to_matrix(DT * s1.twist[3:]) @ R0
    assert np.abs(s1.rotation - R_expected).max() <= theta**3 / 6 + 1e-14

    if spinning and robot.mode == "spatial":
        # The comparison is sharp enough to see the gyroscopic term and the damping.
        no_gyro = np.linalg.solve(
            block_diag(robot.mass * np.eye(3), R0 @ robot.inertia @ R0.T),
            kin.wrench_matrix @ (f + report.damping) + gravity_wrench(robot),
        )
        assert np.linalg.norm(no_gyro - expected) > 1e-3 * np.linalg.norm(expected)
        no_damping = reference_acceleration(robot, R0, v0, kin.wrench_matrix @ f)
        assert np.linalg.norm(no_damping - expected) > 1e-5 * np.linalg.norm(expected)


def test_clamped_tensions_are_the_ones_applied() -> None:
    robot = caroca_full_inertia().replace(cable_damping=0.0)
    commanded = np.array([-20.0, 300.0, 2e4, 400.0, 0.0, -1.0, 15000.0, 600.0])
    sim = PlatformSim(robot)
    report = sim.step(commanded)
    tmax = robot.tmax[0]
    applied = np.array([0.0, 300.0, tmax, 400.0, 0.0, 0.0, tmax, 600.0])
    np.testing.assert_array_equal(report.applied, applied)
    assert (report.clamped_low, report.clamped_high) == (2, 2)
    np.testing.assert_array_equal(sim.state().tensions, applied)
    kin = inverse_kinematics(robot, robot.home_position, robot.home_rotation)
    expected = forward_dynamics(robot, robot.home_rotation, np.zeros(6), kin.wrench_matrix @ applied)
    assert np.linalg.norm(sim.state().twist / DT - expected) <= 1e-6 * np.linalg.norm(expected)


# -- equilibrium ----------------------------------------------------------------------------------


@pytest.mark.parametrize("name", list(TEST_ROBOTS))
def test_static_equilibrium_holds_still(name: str) -> None:
    """Tensions with W f + w_g = 0 (residual < 1e-9 N) keep the platform at rest for 1 s.

    The bound: a residual force r moves the platform by r t²/(2m) in time t; fixed tensions make the
    pose's equilibrium mildly unstable (geometric stiffness; growth rate λ ≲ 2 /s here, so at most a
    factor cosh(λ t) ≈ 4 after 1 s). From r < 1e-9 N and m ≥ 1 kg that is below 1e-8 m. A force or
    lever-arm error of δ in the applied wrench would instead drift δ/(2m) m, i.e. 1e-6 m as soon as
    δ ≈ 2e-6·m N (3e-4 N on CAROCA's ~1500 N of tension). So 1e-6 m and 1e-6 rad.
    """
    robot = TEST_ROBOTS[name]()
    p0 = robot.home_position + (in_plane(robot, 0.1, -0.05, 0.0) if robot.mode == "planar" else [0.1, -0.08, -0.05])
    tilt = about_normal(robot, 0.04) if robot.mode == "planar" else [0.05, -0.08, 0.1]
    R0 = rotvec_to_matrix(tilt) @ robot.home_rotation
    f = equilibrium_tensions(robot, p0, R0)
    sim = PlatformSim(robot, DT, p0, R0)
    for _ in range(1000):
        sim.step(f)
    s = sim.state()
    assert np.linalg.norm(s.position - p0) < 1e-6
    assert angle_between(s.rotation, R0) < 1e-6
    assert np.abs(s.twist).max() < 1e-6
    # After a second at rest the body still responds at once (DART never put it to sleep).
    f2 = f * 1.01  # (a horizontal planar robot's tensions are a preload: scaling them moves nothing)
    f2[0] += 1.0
    sim.step(f2)
    kin = inverse_kinematics(robot, s.position, s.rotation)
    expected = reference_acceleration(robot, s.rotation, s.twist, kin.wrench_matrix @ f2)
    measured = (sim.state().twist - s.twist) / DT
    assert np.linalg.norm(measured - expected) <= 1e-6 * np.linalg.norm(expected)


# -- kinematics of the state ----------------------------------------------------------------------


@pytest.mark.parametrize("name", list(ROBOTS))
def test_state_cable_lengths_and_rates_match_kinematics(name: str) -> None:
    robot = ROBOTS[name]()
    p0, R0, v0 = moving_state(robot, spinning=True)
    sim = PlatformSim(robot, DT, p0, R0, v0)
    rng = np.random.default_rng(7)
    for k in range(60):
        s = sim.state() if k % 20 == 0 else None
        if s is not None:
            kin = inverse_kinematics(robot, s.position, s.rotation)
            np.testing.assert_allclose(s.cable_lengths, kin.lengths, rtol=1e-13)
            np.testing.assert_allclose(s.cable_rates, kin.jacobian @ s.twist, rtol=1e-12, atol=1e-12)
        sim.step(rng.uniform(robot.tmin, robot.tmax, robot.m))


# -- modes ----------------------------------------------------------------------------------------


def test_point_mass_never_turns_and_planar_stays_in_plane() -> None:
    rng = np.random.default_rng(3)
    pm = point_mass_robot()
    sim = PlatformSim(pm, DT)
    for _ in range(300):
        sim.step(rng.uniform(0.0, pm.tmax, pm.m))
    s = sim.state()
    np.testing.assert_array_equal(s.rotation, pm.home_rotation)  # no cable moment, no spin: exactly
    np.testing.assert_array_equal(s.twist[3:], np.zeros(3))

    for pl in (planar_robot(), planar_xy_robot()):
        p0, R0, v0 = moving_state(pl, spinning=True)
        sim = PlatformSim(pl, DT, p0, R0, v0)
        for _ in range(300):
            sim.step(rng.uniform(0.0, pl.tmax, pl.m))
        s = sim.state()
        n = pl.normal_axis
        assert s.position[n] == 0.0
        assert np.linalg.norm(s.position - p0) > 1e-3  # it moved, in the plane
        out = [n] + [3 + j for j in range(3) if j != n]  # no velocity along the normal, no turn about another axis
        np.testing.assert_array_equal(s.twist[out], np.zeros(3))
        np.testing.assert_array_equal(s.rotation[n], np.eye(3)[n])  # a rotation about the normal only
        np.testing.assert_array_equal(s.rotation[:, n], np.eye(3)[n])
        np.testing.assert_array_equal(s.quaternion[[j for j in range(3) if j != n]], [0.0, 0.0])


# -- determinism ----------------------------------------------------------------------------------


def _assert_same(a: PlatformState, b: PlatformState) -> None:
    for field in ("position", "quaternion", "rotation", "twist", "cable_lengths", "cable_rates", "tensions"):
        assert np.array_equal(getattr(a, field), getattr(b, field)), field
    assert (a.step, a.t) == (b.step, b.t)


def test_same_tensions_give_bit_identical_states() -> None:
    robot = caroca_full_inertia()
    p0, R0, v0 = moving_state(robot, spinning=True)
    commands = np.random.default_rng(11).uniform(-100.0, 1.2 * robot.tmax, (400, robot.m))  # some clamp
    sims = [PlatformSim(robot, DT, p0, R0, v0), PlatformSim(robot, DT, p0, R0, v0)]
    replay = PlatformSim(robot, DT)
    for k, f in enumerate(commands):
        reports = [sim.step(f.copy()) for sim in sims]
        for field in ("applied", "damping"):
            assert np.array_equal(getattr(reports[0], field), getattr(reports[1], field))
        if k % 7 == 0:  # reading the state between steps must not change the trajectory
            sims[0].state()
    _assert_same(sims[0].state(), sims[1].state())
    assert sims[0].state().step == len(commands)
    replay.reset(p0, R0, v0)  # a reset sim replays the same run
    for f in commands:
        replay.step(f)
    _assert_same(replay.state(), sims[1].state())


@pytest.mark.parametrize("name", list(ROBOTS))
def test_message_is_the_state_as_a_message(name: str) -> None:
    """``message`` (what the sim service sends first) equals ``state_message(state())`` exactly, read
    before the state or after it, and reading it does not change the run."""
    robot = ROBOTS[name]()
    p0, R0, v0 = moving_state(robot, spinning=True)
    sims = [PlatformSim(robot, DT, p0, R0, v0), PlatformSim(robot, DT, p0, R0, v0)]
    commands = np.random.default_rng(5).uniform(-10.0, 1.1 * robot.tmax, (50, robot.m))  # some clamp
    for k, f in enumerate(commands):
        first = sims[0].message(k)  # the message first, then the state (the service's order)
        assert first == state_message(sims[0].state(), k)
        sims[1].state()
        assert sims[1].message(k) == first  # or after it
        for sim in sims:
            sim.step(f)
    _assert_same(sims[0].state(), sims[1].state())


# -- reading and writing DART through the joint's coordinates (module docstring) -------------------


def _random_rotation(rng: np.random.Generator, robot: Robot) -> np.ndarray:
    """Any rotation (angle up to π) for a spatial or point-mass robot, one about its normal for a planar one."""
    if robot.mode == "planar":
        return rotvec_to_matrix(about_normal(robot, rng.uniform(-np.pi, np.pi)))
    axis = rng.standard_normal(3)
    return rotvec_to_matrix(axis / np.linalg.norm(axis) * rng.uniform(0.0, np.pi))


@pytest.mark.parametrize("angle", [0.0, 1e-9, 9.9e-5, 1.01e-4, 0.3, 2.0, np.pi - 1e-9, 3.5, 7.0, 13.0])
def test_rotvec_quat_is_the_quaternion_of_the_rotation(angle: float) -> None:
    """Any angle (a planar joint's is not wrapped), either side of the series' threshold: the unit quaternion
    with qw ≥ 0 of ``rotvec_to_matrix``, as ``matrix_to_quat`` gives it."""
    rng = np.random.default_rng(int(angle * 1e3))
    for _ in range(20):
        axis = rng.standard_normal(3)
        r = axis / np.linalg.norm(axis) * angle
        q = np.array(rotvec_quat(*r))
        assert q[3] >= 0.0
        assert abs(np.linalg.norm(q) - 1.0) < 1e-15
        np.testing.assert_allclose(quat_to_matrix(q), rotvec_to_matrix(r), rtol=0, atol=2e-15)
        np.testing.assert_allclose(q, matrix_to_quat(rotvec_to_matrix(r)), rtol=0, atol=2e-15)


@pytest.mark.parametrize("name", list(TEST_ROBOTS))
def test_the_state_read_from_the_joint_equals_dart_world_frame_getters(name: str) -> None:
    """The pose and twist read from the joint's positions and velocities are what ``getTransform``,
    ``getLinearVelocity`` and ``getAngularVelocity`` of the body return, to the last bit or so, at any
    rotation."""
    robot = TEST_ROBOTS[name]()
    rng = np.random.default_rng(17)
    p0, _, v0 = moving_state(robot, spinning=True)
    sim = PlatformSim(robot, DT, p0, _random_rotation(rng, robot), v0)
    body = sim._platform.body
    for _ in range(100):
        sim.step(rng.uniform(robot.tmin, robot.tmax, robot.m))
        s, tf = sim.state(), body.getTransform()
        np.testing.assert_allclose(s.position, tf.translation(), rtol=0, atol=1e-15)
        np.testing.assert_allclose(s.rotation, tf.rotation(), rtol=0, atol=1e-15)
        twist = np.concatenate((body.getLinearVelocity(), body.getAngularVelocity()))
        np.testing.assert_allclose(s.twist, twist, rtol=0, atol=1e-15 * np.abs(twist).max())


@pytest.mark.parametrize("name", ["caroca_full_inertia", "planar", "planar_xy"])
def test_the_joint_forces_are_the_wrench_about_the_com(name: str) -> None:
    """A ``FreeJoint``'s generalized forces [M; F] (a planar joint's [F_z, F_x, M_y] in the x–z plane, [F_x, F_y, M_z]
    in the x–y plane) step the body as the
    external force at the COM and torque, world frame, do (to rounding); ``World.step`` zeroes them afterwards."""
    robot = TEST_ROBOTS[name]()
    p0, R0, v0 = moving_state(robot, spinning=True)
    external, joint = PlatformBody(robot, DT), PlatformBody(robot, DT)
    rng = np.random.default_rng(23)
    for body in (external, joint):
        body.place(p0, R0, v0)
    for _ in range(20):
        force, moment = rng.normal(0.0, 100.0, 3), rng.normal(0.0, 10.0, 3)
        if robot.mode == "planar":
            n = robot.normal_axis
            force[n] = 0.0
            moment[[j for j in range(3) if j != n]] = 0.0
        external.body.setExtForce(force, np.zeros(3), False, True)
        external.body.setExtTorque(moment, False)
        generalized = ([force[2], force[0], moment[1]] if robot.plane == "xz" else [force[0], force[1], moment[2]]
                       ) if robot.mode == "planar" else [*moment, *force]
        joint.joint.setForces(generalized)
        external.world.step()
        joint.world.step()
        np.testing.assert_array_equal(joint.joint.getForces(), np.zeros(joint.joint.getNumDofs()))
        for get in ("getPositions", "getVelocities"):  # the same step, to the last bit or so
            expected = getattr(external.joint, get)()
            atol = 1e-15 * np.abs(expected).max()
            np.testing.assert_allclose(getattr(joint.joint, get)(), expected, rtol=0, atol=atol)


@pytest.mark.parametrize("name", list(ROBOTS))
def test_a_step_applies_the_cables_wrench_as_kinematics_has_it(name: str) -> None:
    """Stepped side by side with a body pulled by ``W (f + c J v)`` of :mod:`cdpr.mechanics.kinematics`
    (applied as DART's external force at the COM and torque, read back with DART's world-frame getters), at
    any rotation, the sim stays with it to rounding: the cables' Plücker coordinates, the moment shifted
    to the COM, the twist referred to the origin and the joint forces are the same physics."""
    robot = ROBOTS[name]()
    rng = np.random.default_rng(sum(map(ord, name)))
    p0, _, v0 = moving_state(robot, spinning=True)
    R0 = _random_rotation(rng, robot)
    sim = PlatformSim(robot, DT, p0, R0, v0)
    ref = PlatformBody(robot, DT)
    ref.place(p0, R0, v0)
    for _ in range(50):
        tf = ref.body.getTransform()
        twist = np.concatenate((ref.body.getLinearVelocity(), ref.body.getAngularVelocity()))
        kin = inverse_kinematics(robot, tf.translation(), tf.rotation())
        f = rng.uniform(robot.tmin, robot.tmax, robot.m)
        damping = robot.cable_damping * (kin.jacobian @ twist)
        wrench = kin.wrench_matrix @ (f + damping)
        ref.body.setExtForce(wrench[:3], np.zeros(3), False, True)
        ref.body.setExtTorque(wrench[3:], False)
        ref.world.step()
        report = sim.step(f)
        np.testing.assert_allclose(report.damping, damping, rtol=0, atol=1e-12 * (1.0 + np.abs(damping).max()))
        s, tf = sim.state(), ref.body.getTransform()
        np.testing.assert_allclose(s.position, tf.translation(), rtol=0, atol=1e-13)
        np.testing.assert_allclose(s.rotation, tf.rotation(), rtol=0, atol=1e-13)
        twist = np.concatenate((ref.body.getLinearVelocity(), ref.body.getAngularVelocity()))
        np.testing.assert_allclose(s.twist, twist, rtol=0, atol=1e-12 * np.abs(twist).max())
        kin = inverse_kinematics(robot, s.position, s.rotation)
        np.testing.assert_allclose(s.cable_lengths, kin.lengths, rtol=1e-14)
        np.testing.assert_allclose(s.cable_rates, kin.jacobian @ s.twist, rtol=0, atol=1e-12)
