"""Swivelling exit pulleys (#32): the closed form of cdpr.mechanics.pulley against a computation written here —
the cable's path over the wheel as the shortest one from the swivel axis to the platform point (the swivel angle
and the tangent angle found by Newton's method on the length's gradient) — and the kinematics built on it."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import yaml

from cdpr import recording
from cdpr.config.robot import load_robot
from cdpr.config.scenario import SagSpec
from cdpr.mechanics.catenary import cable_planes, platform_forces, solve_catenary
from cdpr.mechanics.dynamics import forward_dynamics, gravity_wrench
from cdpr.mechanics.kinematics import WrenchMatrix, cable_geometry, inverse_kinematics
from cdpr.mechanics.pulley import Pulleys, pulley_geometry
from cdpr.mechanics.robot import Robot
from cdpr.mechanics.rotation import rotvec_to_matrix
from cdpr.mechanics.tda import make_tda
from cdpr.mechanics.workspace import wrench_matrices
from cdpr.protocol.session import robot_from_summary
from cdpr.tools.report import read_recording
from cdpr_sim.core import PlatformSim
from cdpr_sim.elastic import ElasticSim
from cdpr_sim.sag import SagSim
from cdpr_sim.ups import UpsSim
from conftest import cdpr, cdpr_in_one_process, last_json_line

SHIPPED = Path(__file__).parents[1] / "shared" / "cdpr"


def frame_of(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Two unit vectors p, q with (p, q, u) right-handed."""
    p = np.cross(u, [0.3, 0.5, 0.8])
    p /= np.linalg.norm(p)
    return p, np.cross(u, p)


def dot(x: np.ndarray, y: np.ndarray) -> np.ndarray:
    return np.einsum("...i,...i->...", x, y)


def frames_of(u: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """:func:`frame_of` of every row of u (..., 3)."""
    p = np.cross(u, [0.3, 0.5, 0.8])
    p /= np.linalg.norm(p, axis=-1, keepdims=True)
    return p, np.cross(u, p)


def wheel(x: np.ndarray, a: np.ndarray, u: np.ndarray, r: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """For the swivel angle σ and the angle φ on the wheel in x (..., 2): (e, the wheel's centre, the point at φ),
    for every problem at once (a, u (..., 3), r (...))."""
    sigma, phi = x[..., 0, None], x[..., 1, None]
    p, q = frames_of(u)
    e = np.cos(sigma) * p + np.sin(sigma) * q
    centre = a + r[..., None] * e
    return e, centre, centre + r[..., None] * (np.cos(phi) * e + np.sin(phi) * u)


def conditions(x: np.ndarray, a: np.ndarray, u: np.ndarray, r: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Zero where the wheel's plane holds B and the cable leaves the wheel at a tangent (radius ⟂ free span)."""
    e, centre, T = wheel(x, a, u, r)
    return np.stack([dot(B - a, np.cross(u, e)), dot(T - centre, T - B)], axis=-1)


def shortest_paths(a: np.ndarray, u: np.ndarray, r: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For each of n problems (a, u, B (n, 3), r (n,)), the path a → arc → T → B: the tangent points by Newton's
    method on :func:`conditions` (numerical Jacobian) from several starts, facing B; of the two tangents the one
    with the shorter path (the cable wraps the wheel from the axis over to B, not the long way round). Every
    problem and start iterates at once (arrays (n, starts, ...)), each on its own. Returns (lengths, T)."""
    n = len(a)
    starts = np.array([-np.pi / 2, 0.0, np.pi / 2, np.pi])
    p, q = frames_of(u)
    v = B - a
    x = np.stack(np.broadcast_arrays(np.arctan2(dot(v, q), dot(v, p))[:, None], starts[None]), axis=-1)
    a, u, r, B = (np.repeat(y[:, None], len(starts), axis=1) for y in (a, u, r, B))
    for _ in range(50):
        F = conditions(x, a, u, r, B)
        J = np.stack([(conditions(x + 1e-7 * np.eye(2)[k], a, u, r, B) - F) / 1e-7 for k in range(2)], axis=-1)
        x = x - np.linalg.solve(J, F[..., None])[..., 0]
    unsolved = np.abs(conditions(x, a, u, r, B)).max(axis=-1) > 1e-12
    e, _, T = wheel(x, a, u, r)
    wrap = (np.pi - x[..., 1]) % (2 * np.pi)  # from a (at π) back to T
    length = r * wrap + np.linalg.norm(B - T, axis=-1)
    facing = ~unsolved & (dot(B - a, e) > 0)
    assert facing.any(axis=1).all()
    best = np.argmin(np.where(facing, length, np.inf), axis=1)  # the first of the shortest, start by start
    return length[np.arange(n), best], T[np.arange(n), best]


def random_case(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray, float, np.ndarray]:
    a = rng.uniform(-3.0, 3.0, 3)
    u = rng.normal(size=3)
    u /= np.linalg.norm(u)
    r = rng.uniform(0.02, 0.15)
    p, q = frame_of(u)
    # a platform point ahead of the wheel: away from the axis, not back along the incoming cable
    B = a + rng.uniform(0.8, 3.0) * (np.cos(s := rng.uniform(0, 2 * np.pi)) * p + np.sin(s) * q) \
        + rng.uniform(-2.0, 2.0) * u
    return a, u, r, B


def test_lengths_and_directions_equal_the_shortest_path_over_the_wheel() -> None:
    rng = np.random.default_rng(32)
    cases = [random_case(rng) for _ in range(200)]
    shortest = shortest_paths(*(np.array([case[k] for case in cases]) for k in range(4)))
    for (a, u, r, B), length, T in zip(cases, *shortest, strict=True):
        g = pulley_geometry(a[None], Pulleys(np.array([r]), u[None]), B[None])
        assert abs(g.lengths[0] - length) <= 1e-9
        np.testing.assert_allclose(g.tangent_points[0], T, rtol=0, atol=1e-9)
        np.testing.assert_allclose(g.free_spans[0] / g.free_lengths[0], (T - B) / np.linalg.norm(T - B),
                                   rtol=0, atol=1e-9)
        assert 0.0 < g.wrap[0] < 2 * np.pi


def test_no_radius_is_the_point_model() -> None:
    rng = np.random.default_rng(3)
    a, B = rng.uniform(-3, 3, (8, 3)), rng.uniform(-1, 1, (8, 3))
    u = rng.normal(size=(8, 3))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    g = pulley_geometry(a, Pulleys(np.zeros(8), u), B)
    np.testing.assert_array_equal(g.tangent_points, a)
    np.testing.assert_array_equal(g.free_spans, a - B)
    np.testing.assert_array_equal(g.lengths, np.linalg.norm(a - B, axis=1))
    np.testing.assert_array_equal(g.wrap, np.zeros(8))
    # and a small radius is close to it
    small = pulley_geometry(a, Pulleys(np.full(8, 1e-9), u), B)
    np.testing.assert_allclose(small.lengths, g.lengths, atol=1e-8)


@pytest.mark.parametrize("on_axis", [True, False])
def test_a_platform_point_on_the_swivel_axis_has_a_finite_answer(on_axis: bool) -> None:
    a, u = np.zeros(3), np.array([0.0, 0.0, -1.0])  # the cable runs down into the pulley
    B = np.array([0.0, 0.0, -2.0]) if on_axis else np.array([1e-13, 0.0, -2.0])
    g = pulley_geometry(a[None], Pulleys(np.array([0.05]), u[None]), B[None])
    assert np.all(np.isfinite(g.lengths))
    assert np.all(np.isfinite(g.free_spans))


# -- a robot with pulleys ---------------------------------------------------------------------------------


def pulley_robot() -> Robot:
    return load_robot("caroca_pulleys")


def random_pose(rng: np.random.Generator) -> tuple[np.ndarray, np.ndarray]:
    return rng.uniform([-1.5, -1.0, 0.5], [1.5, 1.0, 2.5]), rotvec_to_matrix(rng.normal(0.0, 0.2, 3))


def test_the_robot_s_kinematics_run_over_its_pulleys() -> None:
    """inverse_kinematics, WrenchMatrix, wrench_matrices and the winch models' cable_geometry: the pulleys'
    lengths and free-span directions (W's columns [d; (R b) × d])."""
    robot = pulley_robot()
    assert robot.pulleys is not None
    rng = np.random.default_rng(5)
    for _ in range(20):
        p, R = random_pose(rng)
        arms = robot.platform_points @ R.T
        g = pulley_geometry(robot.frame_points, robot.pulleys, p + arms)
        d = g.free_spans / g.free_lengths[:, None]
        W = np.vstack([d.T, np.cross(arms, d).T])
        ik = inverse_kinematics(robot, p, R)
        np.testing.assert_allclose(ik.lengths, g.lengths, rtol=0, atol=1e-12)
        np.testing.assert_allclose(ik.wrench_matrix, W, rtol=0, atol=1e-12)
        np.testing.assert_allclose(WrenchMatrix(robot)(p, R), W, rtol=0, atol=1e-12)
        np.testing.assert_allclose(wrench_matrices(robot, p[None], R)[0], W, rtol=0, atol=1e-12)
        _, lengths, directions, _, _, spans = cable_geometry(robot.frame_points, robot.platform_points, p, R,
                                                      np.zeros(3), np.zeros(3), robot.pulleys)
        np.testing.assert_allclose(lengths, g.lengths, rtol=0, atol=1e-12)
        np.testing.assert_allclose(directions, d, rtol=0, atol=1e-12)
        np.testing.assert_allclose(spans, g.free_spans, rtol=0, atol=1e-12)
        assert np.all(g.lengths > np.linalg.norm(robot.frame_points - p - arms, axis=1))  # the wrap adds length


def test_length_rates_are_the_wrench_matrix_rows_times_the_twist() -> None:
    """d(length)/dt by central differences along a twist equals −Wᵀ v, over random poses and twists (1e-6)."""
    robot = pulley_robot()
    rng = np.random.default_rng(11)
    h = 1e-6
    for _ in range(50):
        p, R = random_pose(rng)
        v = rng.normal(0.0, 0.5, 6)

        def lengths(s: float, p: np.ndarray = p, R: np.ndarray = R, v: np.ndarray = v) -> np.ndarray:
            return inverse_kinematics(robot, p + s * v[:3], rotvec_to_matrix(s * v[3:]) @ R).lengths

        numeric = (lengths(h) - lengths(-h)) / (2 * h)
        W = inverse_kinematics(robot, p, R).wrench_matrix
        np.testing.assert_allclose(numeric, -W.T @ v, rtol=0, atol=1e-6)


def test_a_radius_of_zero_is_the_point_model(tmp_path: Path) -> None:
    spec = yaml.safe_load((SHIPPED / "robots" / "caroca_pulleys.yaml").read_text())
    for cable in spec["cables"]:
        cable["pulley"]["radius"] = 0.0
    path = tmp_path / "zero.yaml"
    path.write_text(yaml.safe_dump(spec))
    zero, plain = load_robot(path), load_robot("caroca")
    assert zero.pulleys is None
    p, R = np.array([0.3, -0.2, 1.1]), np.eye(3)
    np.testing.assert_array_equal(inverse_kinematics(zero, p, R).lengths, inverse_kinematics(plain, p, R).lengths)


def test_the_sim_applies_the_cables_along_their_free_spans() -> None:
    """The ideal sim (Plücker rows through T_i) and the elastic one (cable_geometry): state lengths and rates
    as the kinematics has them, and one step's acceleration as W f gives it (forward dynamics)."""
    robot = pulley_robot().with_mass(15.0).replace(cable_damping=0.0)
    rng = np.random.default_rng(2)
    p, R = random_pose(rng)
    twist = np.r_[0.2, -0.1, 0.05, 0.1, -0.2, 0.3]
    sim = PlatformSim(robot, 1e-4, p, R, twist)
    s = sim.state()
    ik = inverse_kinematics(robot, s.position, s.rotation)
    np.testing.assert_allclose(s.cable_lengths, ik.lengths, rtol=1e-13)
    np.testing.assert_allclose(s.cable_rates, ik.jacobian @ s.twist, rtol=1e-10, atol=1e-12)
    f = rng.uniform(50.0, 200.0, robot.m)
    sim.step(f)
    expected = forward_dynamics(robot, s.rotation, s.twist, ik.wrench_matrix @ f)
    measured = (sim.state().twist - s.twist) / 1e-4
    np.testing.assert_allclose(measured, expected, rtol=1e-10, atol=1e-9)


def test_the_paper_s_u_p_s_legs_swivel_over_their_pulleys() -> None:
    """ups: a pulley leg is swivel → fork → axle → arm → prismatic along the free span, ball-joined to the
    platform, the wrap's torque r f on the axle. Its lengths are the kinematics' (the span plus the wrap) and,
    driven by the same tensions, it moves as the ideal model over the same pulleys (as closely as the U-P-S
    legs without pulleys do, the links' mass)."""
    robot = pulley_robot().with_mass(15.0).replace(tmin=1.0, tmax=6500.0)
    p0 = np.array([0.9, 0.9, 0.2])
    ideal, ups = PlatformSim(robot, 1e-3, p0), UpsSim(robot, 1e-3, p0)
    np.testing.assert_allclose(ups.state().cable_lengths, inverse_kinematics(robot, p0, np.eye(3)).lengths,
                               rtol=0, atol=1e-12)
    W = inverse_kinematics(robot, p0, np.eye(3)).wrench_matrix
    f0 = make_tda("qp").solve(W, -gravity_wrench(robot), robot.tmin, robot.tmax).tensions
    for k in range(100):
        f = f0 * (1.0 + 0.2 * np.sin(0.01 * k + np.arange(robot.m)))
        ideal.step(f)
        ups.step(f)
    a, b = ideal.state(), ups.state()
    assert np.abs(a.position - p0).max() > 1e-4  # it moved
    assert np.abs(a.position - b.position).max() < 1e-5  # 2.6e-6 m, as for caroca's U-P-S legs
    lengths = inverse_kinematics(robot, b.position, b.rotation).lengths
    assert np.abs(b.cable_lengths - lengths).max() < 1e-5
    assert ups.closure_errors().max() < 1e-5


def _session_run(tmp_path: Path, model: str) -> list[str]:
    """`cdpr run` of caroca_15kg_pulleys cut to 4 s with the sim's cable ``model``, in-process, recorded to an .rrd."""
    base = yaml.safe_load((SHIPPED / "scenarios" / "caroca_15kg_pulleys.yaml").read_text())
    file = tmp_path / f"{model}.yaml"
    file.write_text(yaml.safe_dump({**base, "name": f"pulleys_{model}", "duration": 4.0,
                                    "sim": {"cable_model": model}}))
    return ["run", str(file), "--in-process", "--rrd", str(tmp_path / f"{model}.rrd")]


def test_the_u_p_s_session_over_pulleys_follows_the_ideal_one(tmp_path: Path) -> None:
    """The paper's cable model cross-check (docs/results.md: within 0.1 mm), over exit pulleys."""
    models = ("ideal", "ups")
    positions = {}
    procs = cdpr_in_one_process([_session_run(tmp_path, model) for model in models], tmp_path / "runs.json",
                                timeout=600)  # the two sessions one after the other in one process
    for model, proc in zip(models, procs, strict=True):
        assert proc.returncode == 0, proc.stderr[-3000:]
        positions[model] = read_recording(tmp_path / f"{model}.rrd").get(recording.ACTUAL_POSITION).values
    ideal, ups = positions["ideal"], positions["ups"]
    assert ideal.shape == ups.shape
    assert np.abs(ideal - ups).max() < 1e-4


def test_a_session_with_pulleys_tracks() -> None:
    """caroca_15kg_pulleys as separate processes: sim and controller both model the pulleys."""
    proc = cdpr("run", "caroca_15kg_pulleys", timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    s = last_json_line(proc.stdout)
    assert s["exit_ok"]
    assert s["max_position_error"] < 1e-4, s  # as caroca_15kg (0.067 mm)
    assert (s["clamped_commands"], s["infeasible_commands"]) == (0, 0)


def test_session_info_carries_the_pulleys_to_a_remote_controller() -> None:
    robot = pulley_robot()
    again = robot_from_summary(robot.summary())
    assert again.pulleys is not None
    np.testing.assert_array_equal(again.pulleys.radius, robot.pulleys.radius)
    np.testing.assert_array_equal(again.pulleys.axis, robot.pulleys.axis)
    p, R = np.array([0.2, 0.1, 1.2]), rotvec_to_matrix([0.1, 0.0, 0.2])
    np.testing.assert_array_equal(WrenchMatrix(again)(p, R), WrenchMatrix(robot)(p, R))


def test_the_stretching_and_sagging_models_hang_their_cables_from_the_pulleys() -> None:
    """Held at their start lengths, the elastic and the sag models keep the pulley robot still; the sag model's
    catenaries hang from the tangent points T_i with l0 less the wrap, and their platform ends carry the weight."""
    robot = pulley_robot().with_mass(15.0).replace(tmin=1.0, tmax=6500.0)  # (caroca_15kg's limits)
    p0 = np.array([0.9, 0.9, 0.2])
    params = SagSpec(mass_per_length=0.05)
    for sim in (ElasticSim(robot, 1e-3, p0, command="lengths"),
                SagSim(robot, 1e-3, p0, params=params, command="lengths")):
        l0 = sim.encoder_lengths().copy()
        for _ in range(300):
            sim.step(l0)
        s = sim.state()
        assert np.abs(s.position - p0).max() < 1e-9, type(sim).__name__
        assert sim.fallbacks == 0
        np.testing.assert_allclose(s.cable_lengths, inverse_kinematics(robot, s.position, s.rotation).lengths,
                                   rtol=1e-12)
    arms = robot.platform_points @ s.rotation.T
    over = pulley_geometry(robot.frame_points, robot.pulleys, s.position + arms)
    span, rise, e_h = cable_planes(over.tangent_points, s.position + arms)
    cat = solve_catenary(span, rise, sim.encoder_lengths() - (over.lengths - over.free_lengths),
                         params.weight_per_length, params.EA)
    pull = platform_forces(cat, e_h)
    np.testing.assert_allclose(pull.sum(axis=0), [0.0, 0.0, robot.mass * 9.81], atol=1e-3)
