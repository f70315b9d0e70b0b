"""Platform dynamics (seed paper eq. 5): M ẍ + C ẋ = W f + w_g + w_e, world frame at the centre of mass.

Each quantity is checked against an independent computation: kinetic energy in the body frame, the
derivative of the angular momentum by finite differences, inertia by quadrature over the solid shape.
"""

from __future__ import annotations

import math

import numpy as np
import pytest

from cdpr.config.robot import load_robot, shipped_robots
from cdpr.errors import InputError
from cdpr.mechanics.dynamics import (
    coriolis_wrench,
    forward_dynamics,
    gravity_wrench,
    mass_matrix,
    required_wrench,
    world_inertia,
)
from cdpr.mechanics.kinematics import inverse_kinematics
from cdpr.mechanics.robot import Robot, Shape
from cdpr.mechanics.rotation import Array, rotvec_to_matrix

G = 9.81
NAMES = shipped_robots()


def random_rotations(seed: int, n: int = 4) -> list[Array]:
    rng = np.random.default_rng(seed)
    return [np.eye(3)] + [rotvec_to_matrix(rng.normal(size=3)) for _ in range(n - 1)]


def dof(robot: Robot) -> int:
    """Size of the dynamics' state: 3 for a point mass, 6 otherwise (planar uses the spatial equations)."""
    return 3 if robot.mode == "point_mass" else 6


# --- mass matrix --------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
def test_mass_matrix_is_symmetric_positive_definite(name: str) -> None:
    robot = load_robot(name)
    for R in random_rotations(1):
        M = mass_matrix(robot, R)
        assert M.shape == (dof(robot), dof(robot))
        assert np.allclose(M, M.T)
        assert np.linalg.eigvalsh(M).min() > 0.0
        assert np.allclose(M[:3, :3], robot.mass * np.eye(3))
        if dof(robot) == 6:
            assert np.allclose(M[:3, 3:], 0.0)
            # Rotating the platform does not change its principal moments.
            assert np.allclose(np.linalg.eigvalsh(M[3:, 3:]), np.linalg.eigvalsh(robot.inertia))


@pytest.mark.parametrize("name", NAMES)
def test_mass_matrix_gives_the_kinetic_energy(name: str) -> None:
    """½ ẋᵀ M ẋ = ½ m ‖v‖² + ½ ω_bᵀ I ω_b with the body-frame angular velocity ω_b = Rᵀ ω."""
    robot = load_robot(name)
    rng = np.random.default_rng(2)
    for R in random_rotations(3):
        twist = rng.normal(size=6)
        v, w = twist[:3], twist[3:]
        w_body = R.T @ w
        energy = 0.5 * robot.mass * v @ v
        if dof(robot) == 6:
            energy += 0.5 * w_body @ robot.inertia @ w_body
        x_dot = twist[: dof(robot)]
        assert 0.5 * x_dot @ mass_matrix(robot, R) @ x_dot == pytest.approx(energy, rel=1e-12)


# --- gravity ------------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
def test_gravity_wrench_is_the_weight_at_the_centre_of_mass(name: str) -> None:
    robot = load_robot(name)
    expected = np.array([0.0, 0.0, -G * robot.mass, 0.0, 0.0, 0.0])[: dof(robot)]
    assert np.allclose(gravity_wrench(robot), expected)
    heavier = robot.with_payload(15.0)
    assert gravity_wrench(heavier)[2] == pytest.approx(-G * (robot.mass + 15.0))


@pytest.mark.parametrize("name", NAMES)
def test_static_tensions_give_zero_acceleration(name: str) -> None:
    """Tensions with W f = −w_g (least squares, any sign) hold the platform still: ẍ = 0."""
    robot = load_robot(name)
    R = robot.home_rotation
    W = inverse_kinematics(robot, robot.home_position, R).wrench_matrix[: dof(robot)]
    f = np.linalg.lstsq(W, -gravity_wrench(robot), rcond=None)[0]
    acc = forward_dynamics(robot, R, np.zeros(6), W @ f)
    # (a horizontal planar robot's weight is out of its plane: its joint holds it, the cables cannot)
    held = list(robot.controlled_rows) if robot.mode == "planar" else slice(None)
    assert np.allclose(acc[held], 0.0, atol=1e-9)
    # Without the cables the platform falls at g.
    fall = forward_dynamics(robot, R, np.zeros(6), np.zeros(dof(robot)))
    assert np.allclose(fall, np.r_[0.0, 0.0, -G, 0.0, 0.0, 0.0][: dof(robot)])


# --- Newton–Euler -------------------------------------------------------------------------------------


@pytest.mark.parametrize("name", NAMES)
def test_forward_dynamics_inverts_required_wrench(name: str) -> None:
    robot = load_robot(name)
    rng = np.random.default_rng(4)
    for R in random_rotations(5):
        twist = rng.normal(size=6)
        accel = rng.normal(size=dof(robot))
        w = required_wrench(robot, R, twist, accel)
        assert np.allclose(forward_dynamics(robot, R, twist, w), accel, atol=1e-10)
        # An external wrench adds to the cables': the cables then need that much less.
        external = rng.normal(size=dof(robot))
        assert np.allclose(forward_dynamics(robot, R, twist, w - external, external), accel, atol=1e-10)


@pytest.mark.parametrize("name", NAMES)
def test_required_force_is_mass_times_acceleration_minus_weight(name: str) -> None:
    robot = load_robot(name)
    rng = np.random.default_rng(5)
    R = random_rotations(6)[2]
    twist = rng.normal(size=6)
    accel = rng.normal(size=dof(robot))
    force = required_wrench(robot, R, twist, accel)[:3]
    assert np.allclose(force, robot.mass * (accel[:3] - np.array([0.0, 0.0, -G])))


def angular_momentum(robot: Robot, R: Array, w: Array) -> Array:
    """L = R I Rᵀ ω, computed in the body frame and rotated out."""
    return R @ (robot.inertia @ (R.T @ w))


@pytest.mark.parametrize("name", [n for n in NAMES if load_robot(n).mode != "point_mass"])
def test_moment_is_the_rate_of_angular_momentum(name: str) -> None:
    """Euler: the moment needed is dL/dt. Along ω(t) = ω₀ + α t, R(t) ≈ exp(ω₀ t) R₀ (error O(t²), even
    in t), so a central difference of L gives dL/dt to O(h²)."""
    robot = load_robot(name)
    rng = np.random.default_rng(8)
    h = 1e-5
    for R0 in random_rotations(9):
        w0 = rng.normal(size=3)
        for alpha in (np.zeros(3), rng.normal(size=3)):
            plus = angular_momentum(robot, rotvec_to_matrix(w0 * h) @ R0, w0 + alpha * h)
            minus = angular_momentum(robot, rotvec_to_matrix(-w0 * h) @ R0, w0 - alpha * h)
            dL = (plus - minus) / (2 * h)
            twist = np.r_[0.0, 0.0, 0.0, w0]
            moment = required_wrench(robot, R0, twist, np.r_[0.0, 0.0, 0.0, alpha])[3:]
            scale = np.abs(robot.inertia).max() * (1.0 + w0 @ w0 + np.abs(alpha).max())
            assert np.allclose(moment, dL, atol=1e-6 * scale)
            if not alpha.any():
                assert np.allclose(coriolis_wrench(robot, R0, twist)[3:], dL, atol=1e-6 * scale)
                assert np.allclose(coriolis_wrench(robot, R0, twist)[:3], 0.0)


def test_gyroscopic_moment_vanishes_about_a_principal_axis() -> None:
    robot = load_robot("caroca")  # diagonal inertia
    for axis in np.eye(3):
        assert np.allclose(coriolis_wrench(robot, np.eye(3), np.r_[0.0, 0.0, 0.0, 3.0 * axis]), 0.0)
    # Off a principal axis it is ω × I ω, here for ω = (1, 1, 0): (0, 0, Iyy − Ixx).
    c = coriolis_wrench(robot, np.eye(3), [0, 0, 0, 1.0, 1.0, 0.0])
    assert np.allclose(c, [0, 0, 0, 0, 0, 20.0 - 6.5])


def test_point_mass_has_no_rotational_dynamics() -> None:
    robot = load_robot("point_mass_4")
    twist = np.array([0.1, 0.2, 0.3, 4.0, 5.0, 6.0])
    assert np.array_equal(coriolis_wrench(robot, rotvec_to_matrix([0.3, 0.2, 0.1]), twist), np.zeros(3))
    wrench = required_wrench(robot, np.eye(3), twist, [1.0, 2.0, 3.0])
    assert np.allclose(wrench, robot.mass * np.array([1.0, 2.0, 3.0 + G]))


def test_planar_motion_stays_in_the_plane() -> None:
    """Moving in the x–z plane and turning about y needs no force along y nor moment about x or z."""
    robot = load_robot("kntu_planar")
    rng = np.random.default_rng(10)
    for pitch in (0.0, 0.3, -0.5):
        R = rotvec_to_matrix([0.0, pitch, 0.0])
        twist = np.array([rng.normal(), 0.0, rng.normal(), 0.0, rng.normal(), 0.0])
        accel = np.array([rng.normal(), 0.0, rng.normal(), 0.0, rng.normal(), 0.0])
        w = required_wrench(robot, R, twist, accel)
        assert np.allclose(w[[1, 3, 5]], 0.0)
        assert w[4] == pytest.approx(robot.inertia[1, 1] * accel[4])


def test_world_inertia_rotates_the_body_inertia() -> None:
    robot = load_robot("cogiro")  # full inertia matrix
    R = rotvec_to_matrix([0.2, -0.4, 0.9])
    Iw = world_inertia(robot, R)
    u = np.array([0.3, -0.2, 0.5])
    # The moment of inertia about a world axis u equals the body one about Rᵀ u.
    assert u @ Iw @ u == pytest.approx((R.T @ u) @ robot.inertia @ (R.T @ u))


# --- Robot.with_mass, Robot.with_payload --------------------------------------------------------------


def gauss(n: int, lo: float, hi: float) -> tuple[Array, Array]:
    x, w = np.polynomial.legendre.leggauss(n)
    return 0.5 * (hi - lo) * x + 0.5 * (hi + lo), 0.5 * (hi - lo) * w


def quadrature_inertia(shape: Shape, mass: float) -> Array:
    """∫ (‖p‖² I − p pᵀ) dm over the uniform solid (Gauss–Legendre in lengths, uniform in angles)."""
    if shape.type == "box":
        axes = [gauss(4, -s / 2, s / 2) for s in shape.size]
        x, y, z = np.meshgrid(*(a[0] for a in axes), indexing="ij")
        wx, wy, wz = np.meshgrid(*(a[1] for a in axes), indexing="ij")
        dv = wx * wy * wz
    elif shape.type == "cylinder":
        radius, length = shape.size
        (r, wr), (z1, wz1) = gauss(8, 0.0, radius), gauss(4, -length / 2, length / 2)
        th = np.linspace(0.0, 2 * np.pi, 16, endpoint=False)
        r, th, z = np.meshgrid(r, th, z1, indexing="ij")
        wr, _, wz = np.meshgrid(wr, th[0, :, 0], wz1, indexing="ij")
        x, y, dv = r * np.cos(th), r * np.sin(th), wr * wz * r * (2 * np.pi / 16)
    else:  # sphere: r, cos(polar), azimuth
        (radius,) = shape.size
        (r, wr), (c, wc) = gauss(8, 0.0, radius), gauss(8, -1.0, 1.0)
        ph = np.linspace(0.0, 2 * np.pi, 16, endpoint=False)
        r, c, ph = np.meshgrid(r, c, ph, indexing="ij")
        wr, wc, _ = np.meshgrid(wr, wc, ph[0, 0], indexing="ij")
        s = np.sqrt(1.0 - c * c)
        x, y, z, dv = r * s * np.cos(ph), r * s * np.sin(ph), r * c, wr * wc * r * r * (2 * np.pi / 16)
    p = np.stack([x.ravel(), y.ravel(), z.ravel()], axis=1)
    dm = dv.ravel() * mass / dv.sum()
    squared = np.einsum("ki,ki->k", p, p)
    per_point = squared[:, None, None] * np.eye(3) - p[:, :, None] * p[:, None, :]
    return np.einsum("k,kij->ij", dm, per_point)


def test_with_mass_box_inertia_matches_the_caroca_numbers() -> None:
    """robots.md: CAROCA's 150 kg 1.2 × 0.6 × 0.4 box has principal inertia (6.5, 20, 22.5)."""
    robot = load_robot("caroca")
    assert np.allclose(robot.with_mass(150.0).inertia, np.diag([6.5, 20.0, 22.5]))
    assert np.allclose(robot.with_mass(15.0).inertia, np.diag([0.65, 2.0, 2.25]))


@pytest.mark.parametrize(
    "shape",
    [Shape("box", (0.32, 0.42, 0.21)), Shape("cylinder", (0.3, 0.2)), Shape("sphere", (0.2,))],
    ids=lambda s: s.type,
)
def test_with_mass_uses_the_solid_shape_inertia(shape: Shape) -> None:
    robot = load_robot("caroca_original").replace(shape=shape)
    heavier = robot.with_mass(42.0)
    assert heavier.mass == 42.0
    assert np.allclose(heavier.inertia, quadrature_inertia(shape, 42.0), rtol=1e-10, atol=1e-12)
    assert not heavier.inertia.flags.writeable
    # Only the mass and the inertia change, and the original robot is untouched.
    assert np.array_equal(heavier.platform_points, robot.platform_points)
    assert np.array_equal(heavier.tmin, robot.tmin)
    assert np.array_equal(heavier.tmax, robot.tmax)
    assert heavier.name == robot.name
    assert robot.mass == 150.0
    assert np.array_equal(robot.inertia, np.diag([6.5, 20.0, 22.5]))


@pytest.mark.parametrize("name", NAMES)
def test_with_payload_adds_mass_and_keeps_the_inertia(name: str) -> None:
    robot = load_robot(name)
    loaded = robot.with_payload(15.0)
    assert loaded.mass == pytest.approx(robot.mass + 15.0)
    assert np.array_equal(loaded.inertia, robot.inertia)
    assert np.array_equal(loaded.frame_points, robot.frame_points)
    assert robot.with_payload(0.0).mass == robot.mass
    assert load_robot(name).mass == robot.mass  # the loaded file is not changed
    M = mass_matrix(loaded, robot.home_rotation)
    assert np.allclose(M[:3, :3], (robot.mass + 15.0) * np.eye(3))


@pytest.mark.parametrize("mass", [0.0, -1.0, math.nan, math.inf])
def test_with_mass_rejects_a_mass_that_is_not_positive_and_finite(mass: float) -> None:
    with pytest.raises(InputError, match="mass"):
        load_robot("caroca").with_mass(mass)


@pytest.mark.parametrize("payload", [-0.5, math.nan, math.inf])
def test_with_payload_rejects_a_payload_that_is_negative_or_not_finite(payload: float) -> None:
    with pytest.raises(InputError, match="payload"):
        load_robot("caroca").with_payload(payload)
