"""Trajectory generators: boundary conditions, continuity, derivatives, S-curve phases, spec parsing.

Independent references: finite differences of the sampled poses, scipy's Rotation/Slerp for the SO(3)
geodesic and the quaternion, and closed-form values of the quintic blend s(τ) = 10τ³ − 15τ⁴ + 6τ⁵.
"""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import BaseModel, ValidationError
from scipy.spatial.transform import Rotation, Slerp

from cdpr.config.trajectory import TrajectorySpec, trajectory_from_spec
from cdpr.mechanics.rotation import rpy_to_matrix
from cdpr.mechanics.trajectory import (
    PlatformPoint,
    QuinticWaypoints,
    SCurve,
    Setpoint,
    Trajectory,
)

# CASPR's CAROCA demo: (0, 0, 0.2) → (0, 0, 1.2) → (0.9, 0.9, 1.2), 10 s a segment, plus rotations.
TIMES = [0.0, 10.0, 20.0, 26.0]
POSITIONS = [[0.0, 0.0, 0.2], [0.0, 0.0, 1.2], [0.9, 0.9, 1.2], [-0.4, 0.3, 0.8]]
RPYS = [[0.0, 0.0, 0.0], [0.3, -0.2, 0.5], [0.3, -0.2, 0.5], [-0.6, 0.4, 2.5]]

A = [0.9, 0.9, 0.2]  # the paper's S-curve end points (robots.md)
B = [-0.9, -0.9, 1.0]


def world_rotvec(R_to: np.ndarray, R_from: np.ndarray) -> np.ndarray:
    """World-frame rotation vector taking R_from to R_to (scipy, independent of cdpr.mechanics.rotation)."""
    return Rotation.from_matrix(R_to @ R_from.T).as_rotvec()


def random_quintic(seed: int) -> QuinticWaypoints:
    rng = np.random.default_rng(seed)
    n = int(rng.integers(2, 7))
    times = np.cumsum(rng.uniform(0.5, 4.0, n)) - rng.uniform(0.0, 3.0)
    positions = rng.uniform(-2.0, 2.0, (n, 3))
    rpys = rng.uniform(-1.2, 1.2, (n, 3))
    return QuinticWaypoints(times.tolist(), positions.tolist(), rpys.tolist())


@pytest.fixture
def traj() -> QuinticWaypoints:
    return QuinticWaypoints(TIMES, POSITIONS, RPYS)


def assert_at_rest(sp: Setpoint) -> None:
    np.testing.assert_array_equal(sp.twist, np.zeros(6))
    np.testing.assert_array_equal(sp.accel, np.zeros(6))


# ---------------------------------------------------------------- QuinticWaypoints


def test_boundary_conditions_at_every_waypoint(traj: QuinticWaypoints) -> None:
    for t, p, rpy in zip(TIMES, POSITIONS, RPYS, strict=True):
        sp = traj.sample(t)
        np.testing.assert_allclose(sp.position, p, atol=1e-12)
        np.testing.assert_allclose(sp.rotation, rpy_to_matrix(*rpy), atol=1e-12)
        np.testing.assert_allclose(sp.twist, 0.0, atol=1e-12)
        np.testing.assert_allclose(sp.accel, 0.0, atol=1e-12)
        # approaching the waypoint from the previous segment ends at the same pose
        if t > TIMES[0]:
            before = traj.sample(t - 1e-9)
            np.testing.assert_allclose(before.position, p, atol=1e-9)
            np.testing.assert_allclose(before.rotation, rpy_to_matrix(*rpy), atol=1e-9)


@pytest.mark.parametrize("seed", range(6))
def test_continuity_across_waypoints(seed: int) -> None:
    traj = random_quintic(seed)
    for t, _ in traj.waypoints():
        lo, hi = traj.sample(t - 1e-7), traj.sample(t + 1e-7)
        np.testing.assert_allclose(lo.position, hi.position, atol=1e-9)
        np.testing.assert_allclose(lo.rotation, hi.rotation, atol=1e-9)
        np.testing.assert_allclose(lo.twist, hi.twist, atol=1e-9)
        # the jerk at a segment end is 60·Δx/h³ (up to ~2e3 m/s³ here), so |a(t ± 1e-7)| stays below 1e-3
        np.testing.assert_allclose(lo.accel, hi.accel, atol=1e-3)
        assert np.abs(lo.accel).max() < 1e-3


def test_midpoint_values_match_the_quintic_blend(traj: QuinticWaypoints) -> None:
    # τ = 1/2: s = 1/2, ṡ = 30/16 / h, s̈ = 0; τ = 1/4: s = 0.103515625, s̈ = 60·(1/4)(3/4)(1/2) / h²
    p0, p1 = np.array(POSITIONS[0]), np.array(POSITIONS[1])
    h = TIMES[1] - TIMES[0]
    mid = traj.sample(TIMES[0] + 0.5 * h)
    np.testing.assert_allclose(mid.position, 0.5 * (p0 + p1), atol=1e-12)
    np.testing.assert_allclose(mid.twist[:3], 1.875 / h * (p1 - p0), atol=1e-12)
    np.testing.assert_allclose(mid.accel[:3], 0.0, atol=1e-12)
    quarter = traj.sample(TIMES[0] + 0.25 * h)
    np.testing.assert_allclose(quarter.position, p0 + 0.103515625 * (p1 - p0), atol=1e-12)
    np.testing.assert_allclose(quarter.accel[:3], 5.625 / h**2 * (p1 - p0), atol=1e-12)


@pytest.mark.parametrize("seed", range(8))
def test_twist_and_accel_match_finite_differences(seed: int) -> None:
    traj = random_quintic(seed)
    rng = np.random.default_rng(100 + seed)
    (t_first, _), (t_last, _) = traj.waypoints()[0], traj.waypoints()[-1]
    h = 1e-5
    for t in rng.uniform(t_first + 2 * h, t_last - 2 * h, 20):
        lo, mid, hi = traj.sample(t - h), traj.sample(t), traj.sample(t + h)
        v_fd = (hi.position - lo.position) / (2 * h)
        a_fd = (hi.position - 2 * mid.position + lo.position) / h**2
        w_fd = world_rotvec(hi.rotation, lo.rotation) / (2 * h)
        alpha_fd = (hi.twist[3:] - lo.twist[3:]) / (2 * h)
        accel_lin_fd = (hi.twist[:3] - lo.twist[:3]) / (2 * h)
        np.testing.assert_allclose(mid.twist[:3], v_fd, atol=1e-7)
        np.testing.assert_allclose(mid.accel[:3], a_fd, atol=2e-4)
        np.testing.assert_allclose(mid.accel[:3], accel_lin_fd, atol=1e-7)
        np.testing.assert_allclose(mid.twist[3:], w_fd, atol=1e-7)
        np.testing.assert_allclose(mid.accel[3:], alpha_fd, atol=1e-7)


@pytest.mark.parametrize("seed", range(4))
def test_orientation_is_the_so3_geodesic(seed: int) -> None:
    """R(t) equals scipy's Slerp between the waypoint rotations evaluated at s(τ)."""
    traj = random_quintic(seed)
    wps = traj.waypoints()
    rotations = [traj.sample(t).rotation for t, _ in wps]
    rng = np.random.default_rng(seed)
    for i in range(len(wps) - 1):
        ta, tb = wps[i][0], wps[i + 1][0]
        slerp = Slerp([0.0, 1.0], Rotation.from_matrix(np.stack([rotations[i], rotations[i + 1]])))
        for tau in rng.uniform(0.0, 1.0, 5):
            s = 10 * tau**3 - 15 * tau**4 + 6 * tau**5
            sp = traj.sample(ta + tau * (tb - ta))
            np.testing.assert_allclose(sp.rotation, slerp([s]).as_matrix()[0], atol=1e-10)
            np.testing.assert_allclose(sp.rotation @ sp.rotation.T, np.eye(3), atol=1e-12)


def test_orientation_reaches_the_goal_rotation(traj: QuinticWaypoints) -> None:
    goal = Rotation.from_euler("xyz", RPYS[-1]).as_matrix()  # extrinsic xyz = Rz·Ry·Rx
    np.testing.assert_allclose(traj.sample(TIMES[-1]).rotation, goal, atol=1e-12)
    np.testing.assert_allclose(traj.sample(TIMES[-1] - 1e-6).rotation, goal, atol=1e-9)


def test_rotation_without_rpys_is_identity() -> None:
    traj = QuinticWaypoints([0.0, 1.0], [[0, 0, 0], [1, 2, 3]])
    sp = traj.sample(0.3)
    np.testing.assert_array_equal(sp.rotation, np.eye(3))
    np.testing.assert_array_equal(sp.twist[3:], np.zeros(3))
    np.testing.assert_array_equal(sp.quaternion, [0.0, 0.0, 0.0, 1.0])


def test_quaternion_matches_scipy(traj: QuinticWaypoints) -> None:
    sp = traj.sample(23.7)
    q = Rotation.from_matrix(sp.rotation).as_quat()  # [x, y, z, w]
    q = q if q[3] >= 0 else -q
    np.testing.assert_allclose(sp.quaternion, q, atol=1e-12)


def test_holds_before_the_start_and_after_the_end() -> None:
    traj = QuinticWaypoints([2.0, 5.0], [[1.0, 2.0, 3.0], [0.0, -1.0, 2.0]], [[0, 0, 0.2], [0.1, 0, 1.0]])
    assert traj.duration == 5.0
    for t in (-100.0, 0.0, 1.999, 2.0):
        sp = traj.sample(t)
        np.testing.assert_array_equal(sp.position, [1.0, 2.0, 3.0])
        np.testing.assert_allclose(sp.rotation, rpy_to_matrix(0, 0, 0.2), atol=1e-15)
        assert_at_rest(sp)
    for t in (5.0, 5.001, 1e6):
        sp = traj.sample(t)
        np.testing.assert_array_equal(sp.position, [0.0, -1.0, 2.0])
        np.testing.assert_allclose(sp.rotation, rpy_to_matrix(0.1, 0, 1.0), atol=1e-15)
        assert_at_rest(sp)
    # moving in between
    assert np.linalg.norm(traj.sample(3.5).twist) > 0.1


def _assert_block_is_samples(trajectory: Trajectory, times: np.ndarray) -> None:
    block = trajectory.sample_block(times)
    quats = block.quaternion
    for j, t in enumerate(times.tolist()):
        sp = trajectory.sample(t)
        for field in ("position", "rotation", "twist", "accel"):
            np.testing.assert_array_equal(getattr(block, field)[j], getattr(sp, field), err_msg=f"{field} at t={t}")
        np.testing.assert_array_equal(quats[j], sp.quaternion, err_msg=f"quaternion at t={t}")


@pytest.mark.parametrize("seed", range(6))
def test_sample_block_is_sample_bit_for_bit(seed: int) -> None:
    """A block of samples (the trajectory node's setpoints) = one sample() per time, to the last bit: before the
    first waypoint, on the waypoints, between them, after the last; quintic, S-curve, a point off the frame."""
    rng = np.random.default_rng(seed)
    quintic = random_quintic(seed)
    times = np.concatenate([np.array(quintic.times), rng.uniform(quintic.times[0] - 1.0, quintic.duration + 1.0, 300)])
    rng.shuffle(times)
    _assert_block_is_samples(quintic, times)
    _assert_block_is_samples(PlatformPoint(quintic, rng.uniform(-0.2, 0.2, 3)), times)
    scurve = SCurve(A, B, None, 1.0, 2.0, 1.0, [0.1, -0.1, 0.2], [0.0, 0.2, -0.4], t_start=0.5, pass_height=[1.3, 1.1])
    _assert_block_is_samples(scurve, np.arange(-10, 500) * 0.01)
    _assert_block_is_samples(scurve, np.array([]))


def test_sample_block_of_a_trajectory_without_one_samples_each_time() -> None:
    """A Trajectory subclass that only knows sample() gets the generic block, the same numbers."""

    class Circle(Trajectory):
        duration = 1.0

        def sample(self, t: float) -> Setpoint:
            return Setpoint(np.array([np.cos(t), np.sin(t), 1.0]), np.eye(3), np.full(6, t), np.zeros(6))

        def waypoints(self) -> list[tuple[float, np.ndarray]]:
            return []

    _assert_block_is_samples(Circle(), np.linspace(0.0, 2.0, 7))


def test_sample_block_rejects_non_finite_times(traj: QuinticWaypoints) -> None:
    with pytest.raises(ValueError, match="finite"):
        traj.sample_block([0.0, float("nan")])


def test_setpoints_are_read_only(traj: QuinticWaypoints) -> None:
    for t in (-1.0, 4.0, 100.0):
        sp = traj.sample(t)
        with pytest.raises(ValueError, match="read-only"):
            sp.position[0] = 1.0
    # the held setpoint was not modified by the attempt
    np.testing.assert_array_equal(traj.sample(-1.0).position, POSITIONS[0])


def test_waypoints_lists_times_and_positions(traj: QuinticWaypoints) -> None:
    wps = traj.waypoints()
    assert [t for t, _ in wps] == TIMES
    np.testing.assert_array_equal(np.array([p for _, p in wps]), POSITIONS)
    wps[0][1][0] = 99.0  # a copy: the trajectory is unchanged
    np.testing.assert_array_equal(traj.sample(0.0).position, POSITIONS[0])
    assert isinstance(traj, Trajectory)


def test_rotation_by_pi_about_an_axis_is_followed() -> None:
    traj = QuinticWaypoints([0.0, 1.0], [[0, 0, 0], [0, 0, 0]], [[0, 0, 0], [0, 0, np.pi]])
    mid = traj.sample(0.5)
    angle = Rotation.from_matrix(mid.rotation).magnitude()
    assert angle == pytest.approx(np.pi / 2, abs=1e-12)
    np.testing.assert_allclose(traj.sample(1.0).rotation, rpy_to_matrix(0, 0, np.pi), atol=1e-12)


@pytest.mark.parametrize(
    ("times", "positions", "rpys", "message"),
    [
        ([0.0], [[0, 0, 0]], None, "at least 2 waypoints"),
        ([0.0, 1.0, 1.0], [[0, 0, 0]] * 3, None, r"strictly increasing \(times\[2\]"),
        ([0.0, 2.0, 1.0], [[0, 0, 0]] * 3, None, "strictly increasing"),
        ([0.0, float("nan")], [[0, 0, 0]] * 2, None, "times must be finite"),
        ([0.0, 1.0], [[0, 0, 0]], None, "positions must have one entry per waypoint"),
        ([0.0, 1.0], [[0, 0], [0, 0]], None, "positions must be a list of"),
        ([0.0, 1.0], [[0, 0, 0], [0, 0, np.inf]], None, "positions must be finite"),
        ([0.0, 1.0], [[0, 0, 0]] * 2, [[0, 0, 0]], "rpys must have one entry per waypoint"),
        ([0.0, 1.0], [[0, 0, 0]] * 2, [[0, 0, 0], [0, 0, float("nan")]], "rpys must be finite"),
        ([[0.0, 1.0]], [[0, 0, 0]] * 2, None, "flat list"),
    ],
)
def test_quintic_rejects_bad_input(times: list, positions: list, rpys: list | None, message: str) -> None:
    with pytest.raises(ValueError, match=message):
        QuinticWaypoints(times, positions, rpys)


def test_sample_rejects_non_finite_time(traj: QuinticWaypoints) -> None:
    with pytest.raises(ValueError, match="finite"):
        traj.sample(float("nan"))


# ---------------------------------------------------------------- SCurve


def scurve_phases(curve: SCurve, n: int = 60) -> list[np.ndarray]:
    t0, t1, t2, t3 = curve.phase_times
    return [np.linspace(a, b, n) for a, b in ((t0, t1), (t1, t2), (t2, t3))]


def test_scurve_lift_travel_lower_at_one_pass_height() -> None:
    curve = SCurve(A, B, None, 4.0, 20.0, 6.0, t_start=1.0, pass_height=1.3)
    assert curve.phase_times == (1.0, 5.0, 25.0, 31.0)
    assert curve.duration == 31.0
    lift, travel, lower = scurve_phases(curve)
    z_prev = -np.inf
    for t in lift:  # vertical: x, y fixed, z rising monotonically
        sp = curve.sample(t)
        np.testing.assert_allclose(sp.position[:2], A[:2], atol=1e-12)
        np.testing.assert_allclose(sp.twist[:2], 0.0, atol=1e-12)
        assert sp.position[2] >= z_prev - 1e-12
        z_prev = sp.position[2]
    for t in travel:  # horizontal, along the straight line between the two xy points
        sp = curve.sample(t)
        assert sp.position[2] == pytest.approx(1.3, abs=1e-12)
        assert sp.twist[2] == pytest.approx(0.0, abs=1e-12)
        np.testing.assert_allclose(sp.position[0], sp.position[1], atol=1e-12)  # A, B on the line x = y
    for t in lower:  # vertical above the goal
        sp = curve.sample(t)
        np.testing.assert_allclose(sp.position[:2], B[:2], atol=1e-12)
        assert 1.0 - 1e-12 <= sp.position[2] <= 1.3 + 1e-12
    corners = [A, [0.9, 0.9, 1.3], [-0.9, -0.9, 1.3], B]
    for t, corner in zip(curve.phase_times, corners, strict=True):
        sp = curve.sample(t)
        np.testing.assert_allclose(sp.position, corner, atol=1e-12)
        np.testing.assert_allclose(sp.twist, 0.0, atol=1e-12)
        np.testing.assert_allclose(sp.accel, 0.0, atol=1e-12)
    np.testing.assert_allclose(np.array([p for _, p in curve.waypoints()]), corners)
    assert_at_rest(curve.sample(0.0))
    np.testing.assert_array_equal(curve.sample(0.0).position, A)
    np.testing.assert_array_equal(curve.sample(40.0).position, B)


def test_scurve_with_two_pass_heights_climbs_during_travel() -> None:
    """The reference file's pass heights 0.6 (above A) and 1.3 (above B)."""
    curve = SCurve(A, B, None, 5.0, 20.0, 5.0, pass_height=(0.6, 1.3))
    np.testing.assert_allclose(curve.sample(5.0).position, [0.9, 0.9, 0.6], atol=1e-12)
    np.testing.assert_allclose(curve.sample(25.0).position, [-0.9, -0.9, 1.3], atol=1e-12)
    mid = curve.sample(15.0)
    np.testing.assert_allclose(mid.position, [0.0, 0.0, 0.95], atol=1e-12)
    lift, _, lower = scurve_phases(curve)
    for t in lift:
        np.testing.assert_allclose(curve.sample(t).position[:2], A[:2], atol=1e-12)
    for t in lower:
        np.testing.assert_allclose(curve.sample(t).position[:2], B[:2], atol=1e-12)
    np.testing.assert_allclose(curve.sample(30.0).position, B, atol=1e-12)


def test_scurve_lift_height_is_relative_to_the_start() -> None:
    curve = SCurve([0.0, 0.0, 0.5], [1.0, 0.0, 0.3], 0.4, 1.0, 2.0, 1.0)
    np.testing.assert_allclose(curve.sample(1.0).position, [0.0, 0.0, 0.9], atol=1e-12)
    np.testing.assert_allclose(curve.sample(3.0).position, [1.0, 0.0, 0.9], atol=1e-12)
    np.testing.assert_allclose(curve.sample(4.0).position, [1.0, 0.0, 0.3], atol=1e-12)


def test_scurve_rotates_during_travel_only() -> None:
    start_rpy, goal_rpy = [0.0, 0.0, 0.0], [0.1, -0.2, 1.5]
    curve = SCurve(A, B, None, 4.0, 10.0, 4.0, start_rpy=start_rpy, goal_rpy=goal_rpy, pass_height=1.3)
    lift, travel, lower = scurve_phases(curve)
    R_a, R_b = rpy_to_matrix(*start_rpy), rpy_to_matrix(*goal_rpy)
    for t in lift:
        np.testing.assert_allclose(curve.sample(t).rotation, R_a, atol=1e-12)
    for t in lower:
        np.testing.assert_allclose(curve.sample(t).rotation, R_b, atol=1e-12)
    assert np.linalg.norm(curve.sample(travel[30]).twist[3:]) > 0.05
    np.testing.assert_allclose(curve.sample(100.0).rotation, R_b, atol=1e-12)
    # the default goal orientation is the start's
    same = SCurve(A, B, None, 1.0, 1.0, 1.0, start_rpy=goal_rpy, pass_height=1.3)
    np.testing.assert_allclose(same.sample(3.0).rotation, R_b, atol=1e-12)
    np.testing.assert_allclose(same.sample(1.5).twist[3:], 0.0, atol=1e-12)


@pytest.mark.parametrize(
    ("kwargs", "message"),
    [
        ({"lift_height": 0.5, "pass_height": 1.3}, "exactly one of lift_height"),
        ({"lift_height": None}, "exactly one of lift_height"),
        ({"lift_height": None, "pass_height": 0.1}, "below the start height"),
        ({"lift_height": None, "pass_height": 0.8}, "below the goal height"),
        ({"lift_height": None, "pass_height": (1.3, 0.9)}, "below the goal height"),
        ({"lift_height": None, "pass_height": (1.0, 1.1, 1.2)}, "pass_height must be one"),
        ({"lift_height": -0.1}, "lift_height must be finite and >= 0"),
        ({"lift_height": 1.5, "t_travel": 0.0}, "t_travel must be a finite duration > 0"),
        ({"lift_height": 1.5, "t_lift": -1.0}, "t_lift must be"),
        ({"lift_height": 0.5, "goal": [0, 0]}, "goal must be 3 numbers"),
        ({"lift_height": 1.5, "start_rpy": [0, 0, np.nan]}, "start_rpy must be finite"),
    ],
)
def test_scurve_rejects_bad_input(kwargs: dict, message: str) -> None:
    args = {"start": A, "goal": B, "t_lift": 1.0, "t_travel": 1.0, "t_lower": 1.0} | kwargs
    with pytest.raises(ValueError, match=message):
        SCurve(**args)


# ---------------------------------------------------------------- specs


QUINTIC_SPEC = {
    "type": "quintic",
    "waypoints": [{"t": TIMES[i], "position": POSITIONS[i], "rpy": RPYS[i]} for i in range(len(TIMES))],
}


def test_quintic_spec_builds_the_same_trajectory(traj: QuinticWaypoints) -> None:
    built = trajectory_from_spec(QUINTIC_SPEC)
    assert isinstance(built, QuinticWaypoints)
    for t in np.linspace(-1.0, 30.0, 47):
        a, b = built.sample(t), traj.sample(t)
        np.testing.assert_array_equal(a.position, b.position)
        np.testing.assert_array_equal(a.rotation, b.rotation)
        np.testing.assert_array_equal(a.twist, b.twist)
        np.testing.assert_array_equal(a.accel, b.accel)


def test_quintic_spec_omitted_rpy_keeps_the_previous_orientation() -> None:
    spec = {
        "type": "quintic",
        "waypoints": [
            {"t": 0, "position": [0, 0, 1]},
            {"t": 1, "position": [1, 0, 1], "rpy": [0, 0, 0.5]},
            {"t": 2, "position": [1, 1, 1]},
        ],
    }
    traj = trajectory_from_spec(spec)
    np.testing.assert_allclose(traj.sample(0.0).rotation, np.eye(3), atol=1e-15)
    np.testing.assert_allclose(traj.sample(1.5).rotation, rpy_to_matrix(0, 0, 0.5), atol=1e-12)
    np.testing.assert_allclose(traj.sample(1.5).twist[3:], 0.0, atol=1e-12)


def test_scurve_spec_builds_the_paper_s_curve() -> None:
    spec = {
        "type": "scurve",
        "start": A,
        "goal": B,
        "pass_height": [0.6, 1.3],
        "t_start": 2.0,
        "times": [7.0, 27.0, 32.0],
    }
    curve = trajectory_from_spec(spec)
    assert isinstance(curve, SCurve)
    assert curve.phase_times == (2.0, 7.0, 27.0, 32.0)
    np.testing.assert_allclose(
        np.array([p for _, p in curve.waypoints()]), [A, [0.9, 0.9, 0.6], [-0.9, -0.9, 1.3], B], atol=1e-15
    )
    relative = trajectory_from_spec(
        {"type": "scurve", "start": A, "goal": B, "lift_height": 1.1, "times": [1, 2, 3]}
    )
    np.testing.assert_allclose(relative.sample(2.0).position, [-0.9, -0.9, 1.3], atol=1e-12)
    assert relative.duration == 3.0


@pytest.mark.parametrize(
    ("spec", "message"),
    [
        ([1, 2], "trajectory: expected a mapping"),
        ({"waypoints": []}, "trajectory: type: missing"),
        ({"type": "spline"}, "trajectory: type: unknown type 'spline'"),
        ({"type": "quintic"}, r"quintic\.waypoints: missing required key"),
        (
            {"type": "quintic", "waypoints": [{"t": 0, "position": [0, 0, 0]}]},
            r"quintic\.waypoints: List should have at least 2",
        ),
        (
            {
                "type": "quintic",
                "waypoints": [{"t": 0, "position": [0, 0, 0]}, {"t": 0, "position": [1, 0, 0]}],
            },
            r"waypoints\.1\.t: times must be strictly increasing",
        ),
        (
            {"type": "quintic", "waypoints": [{"t": 0, "position": [0, 0]}, {"t": 1, "position": [1, 0, 0]}]},
            r"quintic\.waypoints\.0\.position:",
        ),
        (
            {
                "type": "quintic",
                "waypoints": [{"t": 0, "position": [0, 0, 0]}, {"t": 1, "position": [1, 0, ".nan"]}],
            },
            r"waypoints\.1\.position\.2:",
        ),
        (
            {
                "type": "quintic",
                "waypoints": [{"t": 0, "position": [0, 0, 0], "yaw": 1}, {"t": 1, "position": [1, 0, 0]}],
            },
            r"waypoints\.0\.yaw: unknown key",
        ),
        (
            {
                "type": "quintic",
                "waypoints": [{"t": float("inf"), "position": [0, 0, 0]}, {"t": 1, "position": [1, 0, 0]}],
            },
            r"waypoints\.0\.t: must be a finite number",
        ),
        ({"type": "scurve", "start": A, "goal": B, "times": [1, 2, 3]}, "exactly one of pass_height"),
        (
            {"type": "scurve", "start": A, "goal": B, "pass_height": 1.3},
            r"scurve\.times: missing required key",
        ),
        ({"type": "scurve", "start": A, "goal": B, "pass_height": 1.3, "times": [1, 2]}, r"scurve\.times:"),
        (
            {"type": "scurve", "start": A, "goal": B, "pass_height": 1.3, "times": [1, 3, 2]},
            r"times\.2: must be after times\.1",
        ),
        (
            {"type": "scurve", "start": A, "goal": B, "pass_height": 1.3, "t_start": 1, "times": [1, 2, 3]},
            r"times\.0: must be after t_start",
        ),
        (
            {"type": "scurve", "start": A, "goal": B, "pass_height": 0.5, "times": [1, 2, 3]},
            "below the goal height",
        ),
        (
            {"type": "scurve", "start": A, "goal": B, "lift_height": -1, "times": [1, 2, 3]},
            r"scurve\.lift_height:",
        ),
        (
            {"type": "scurve", "start": A, "goal": B, "lift_height": 1, "times": [1, 2, 3], "speed": 2},
            r"scurve\.speed: unknown key",
        ),
    ],
)
def test_spec_errors_name_the_field(spec: object, message: str) -> None:
    with pytest.raises(ValueError, match=message) as info:
        trajectory_from_spec(spec)  # type: ignore[arg-type]
    assert str(info.value).startswith("trajectory:")
    assert "\n" not in str(info.value)


class _Scenario(BaseModel):
    """A stand-in for the scenario loader's model: TrajectorySpec embedded as a field."""

    trajectory: TrajectorySpec


def test_trajectory_spec_embeds_as_a_field() -> None:
    scenario = _Scenario.model_validate({"trajectory": QUINTIC_SPEC})
    built = scenario.trajectory.build()
    assert isinstance(built, QuinticWaypoints)
    assert built.duration == TIMES[-1]
    scurve = TrajectorySpec.model_validate(
        {"type": "scurve", "start": A, "goal": B, "pass_height": 1.3, "times": [1, 2, 3]}
    )
    assert isinstance(scurve.build(), SCurve)
    with pytest.raises(ValidationError) as info:
        _Scenario.model_validate(
            {"trajectory": {"type": "scurve", "start": A, "goal": B, "pass_height": 1.3}}
        )
    assert info.value.errors()[0]["loc"] == ("trajectory", "scurve", "times")
    with pytest.raises(ValidationError):
        _Scenario.model_validate({"trajectory": {"type": "circle"}})


def test_the_nodes_setpoint_blocks_are_its_setpoints_step_by_step() -> None:
    """What the trajectory node publishes (blocks) = setpoint_at of each step, message for message, over every
    step of every shipped scenario (and a few past its end, where the final pose is held)."""
    from cdpr.config.scenario import load_scenario, shipped_scenarios
    from cdpr_trajectory.core import setpoint_at, setpoints_between

    for name in shipped_scenarios():
        sc = load_scenario(name)
        n = sc.total_steps + 5
        blocks = [setpoints_between(sc.trajectory, k, min(k + 99, n - 1), sc.dt) for k in range(0, n, 100)]
        got = [sp for block in blocks for sp in block]
        assert got == [setpoint_at(sc.trajectory, k, sc.dt) for k in range(n)], name
    assert setpoints_between(load_scenario("caroca_15kg").trajectory, 5, 4, 1e-3) == ()
