"""The wrench-feasible workspace (cdpr.mechanics.workspace), the scenario check built on it and `cdpr workspace`.

Oracles: a linear program per problem (scipy's HiGHS), the project's QP tension distribution, and a
closed form for the 4-cable point-mass robot on its vertical axis.
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import linprog

from cdpr import recording
from cdpr.config.robot import load_robot, shipped_robots
from cdpr.config.scenario import load_scenario, shipped_scenarios
from cdpr.errors import InputError
from cdpr.mechanics.control import controlled_rows
from cdpr.mechanics.dynamics import gravity_wrench, required_wrench
from cdpr.mechanics.kinematics import inverse_kinematics
from cdpr.mechanics.rotation import rpy_to_matrix
from cdpr.mechanics.tda import make_tda
from cdpr.mechanics.trajectory import QuinticWaypoints
from cdpr.mechanics.workspace import (
    compute_workspace,
    first_violation,
    grid_points,
    sample_times,
    wrench_feasible,
    wrench_matrices,
    wrenches_feasible,
)
from conftest import cdpr, cdpr_here, last_json_line

HERE = Path(__file__).parent
BAD_STATIC = HERE / "scenarios" / "leaves_workspace.yaml"
BAD_DYNAMIC = HERE / "scenarios" / "falls_too_fast.yaml"


def lp_feasible(W: np.ndarray, w: np.ndarray, lo: float | np.ndarray, hi: float | np.ndarray) -> bool:
    m = W.shape[1]
    bounds = np.column_stack([np.broadcast_to(lo, (m,)), np.broadcast_to(hi, (m,))])
    return linprog(np.zeros(m), A_eq=W, b_eq=w, bounds=bounds, method="highs").status == 0


# --------------------------------------------------------------------------------------------------
# The test itself, on random problems


@pytest.mark.parametrize(
    ("k", "m"), [(1, 3), (6, 4), (3, 3), (3, 4), (3, 8), (2, 5), (4, 9), (6, 6), (6, 7), (6, 8), (6, 10)]
)
def test_matches_a_linear_program_on_random_problems(k: int, m: int) -> None:
    rng = np.random.default_rng(100 * k + m)
    n = 300
    W = rng.normal(size=(n, k, m))
    lb = rng.uniform(0.0, 1.0, m)
    ub = lb + rng.uniform(0.5, 3.0, m)
    f = rng.uniform(lb - 0.6, ub + 0.6, (n, m))  # some inside the box, some not
    w = np.einsum("nkm,nm->nk", W, f)
    got = wrenches_feasible(W, w, lb, ub)
    want = np.array([lp_feasible(W[i], w[i], lb, ub) for i in range(n)])
    assert 0 < want.sum() < n  # both answers occur
    np.testing.assert_array_equal(got, want)


def test_the_boundary_is_feasible_and_just_beyond_is_not() -> None:
    """For a direction n, f* = f_m + r·sign(Wᵀn) (every tension on a bound) produces the wrench of the
    zonotope farthest along n; 1e-6 further along n nothing produces it (support function)."""
    rng = np.random.default_rng(7)
    for k, m in [(6, 8), (3, 8), (3, 4)]:
        W = rng.normal(size=(100, k, m))
        n = rng.normal(size=(100, k))
        f = np.where(np.einsum("nk,nkm->nm", n, W) > 0.0, 6500.0, 1.0)
        w = np.einsum("nkm,nm->nk", W, f)
        assert wrenches_feasible(W, w, 1.0, 6500.0).all()
        reach = np.einsum("nk,nk->n", n, w - W.sum(axis=2) * 3250.5)  # nᵀ(w − W f_m)
        beyond = w + (1e-6 * reach / np.einsum("nk,nk->n", n, n))[:, None] * n
        assert not wrenches_feasible(W, beyond, 1.0, 6500.0).any()


def test_rank_deficient_and_invalid_problems() -> None:
    rng = np.random.default_rng(3)
    W = rng.normal(size=(40, 3, 5))
    W[:, 2, :] = 0.0  # no cable acts along z
    f = rng.uniform(1.0, 2.0, (40, 5))
    w = np.einsum("nkm,nm->nk", W, f)
    assert wrenches_feasible(W, w, 1.0, 2.0).all()
    w[:, 2] = 0.5  # a z component nothing produces
    assert not wrenches_feasible(W, w, 1.0, 2.0).any()
    W[0, 0, 0] = np.nan
    assert not wrenches_feasible(W[:1], np.zeros(3), 0.0, 1.0)[0]
    with pytest.raises(ValueError, match="tmin <= tmax"):
        wrenches_feasible(W[1:2], np.zeros(3), 2.0, 1.0)


# --------------------------------------------------------------------------------------------------
# Robots


def test_wrench_matrices_are_the_kinematics_ones() -> None:
    robot = load_robot("cogiro")
    rng = np.random.default_rng(0)
    positions = rng.uniform(robot.frame_min, robot.frame_max, (5, 3))
    rotations = np.array([rpy_to_matrix(*rng.uniform(-0.5, 0.5, 3)) for _ in range(5)])
    W = wrench_matrices(robot, positions, rotations)
    for i in range(5):
        np.testing.assert_allclose(
            W[i], inverse_kinematics(robot, positions[i], rotations[i]).wrench_matrix, atol=1e-14
        )
    point_mass = load_robot("point_mass_4")
    W0 = wrench_matrices(point_mass, point_mass.frame_points[:1])[0]  # cable 0 has zero length there
    assert np.isnan(W0[:, 0]).all()
    assert np.isfinite(W0[:, 1:]).all()
    assert not wrench_feasible(point_mass, point_mass.frame_points[:1])[0]


@pytest.mark.parametrize("name", shipped_robots())
def test_static_workspace_agrees_with_the_qp_and_an_lp(name: str) -> None:
    """Random poses (QP and LP) and a sample of the grid of `cdpr workspace` (LP): same answers.

    The grid matters: CAROCA's paired frame points make some rows of W's null-space basis dependent
    at every pose, which random matrices never do."""
    robot = load_robot(name)
    rng = np.random.default_rng(sum(map(ord, name)))
    positions = rng.uniform(robot.frame_min, robot.frame_max, (150, 3))
    if robot.mode == "planar":
        positions[:, robot.normal_axis] = 0.0
    R = np.eye(3) if robot.mode != "spatial" else rpy_to_matrix(0.05, -0.1, 0.2)
    payload = 2.0
    got = wrench_feasible(robot, positions, R, payload=payload)
    rows = list(robot.controlled_rows)
    w = -gravity_wrench(robot.with_payload(payload))
    w = w if robot.mode == "point_mass" else w[rows]
    qp, lp = [], []
    for p in positions:
        W = inverse_kinematics(robot, p, R).wrench_matrix[rows]
        qp.append(make_tda("qp").solve(W, w, robot.tmin, robot.tmax).feasible)
        lp.append(lp_feasible(W, w, robot.tmin, robot.tmax))
    assert 0 < got.sum() < len(got)
    np.testing.assert_array_equal(got, lp)
    np.testing.assert_array_equal(got, qp)

    grid, _, _ = grid_points(robot, 0.1)
    grid = grid[:: max(1, len(grid) // 400)]
    got = wrench_feasible(robot, grid, payload=payload)
    lp = [
        lp_feasible(inverse_kinematics(robot, p).wrench_matrix[rows], w, robot.tmin, robot.tmax) for p in grid
    ]
    assert 0 < got.sum() < len(got)
    np.testing.assert_array_equal(got, lp)


def test_caroca_15kg_grid_matches_an_lp() -> None:
    """The experiments' robot (15 kg, tensions in [1, 6500] N) on every 300th point of its 0.1 m grid:
    (-0.85, 1.85, 2.555) and (3.35, -1.85, 0.070) are feasible with 6.7 N and 0.8 N to spare; an early
    version, which took rounding noise for the normal of a degenerate cable triple, rejected them."""
    robot = load_robot("caroca").with_mass(15.0).replace(tmin=1.0, tmax=6500.0)
    grid, _, _ = grid_points(robot, 0.1)
    grid = grid[::300]
    got = wrench_feasible(robot, grid)
    w = -gravity_wrench(robot)
    lp = [lp_feasible(inverse_kinematics(robot, p).wrench_matrix, w, 1.0, 6500.0) for p in grid]
    np.testing.assert_array_equal(got, lp)
    assert wrench_feasible(robot, [[-0.85, 1.85, 2.55542857], [3.35, -1.85, 0.06971429]]).all()


def axis_limits(mass: float, tmin: float, tmax: float) -> tuple[float, float]:
    """point_mass_4 on its vertical axis: the four tensions are equal, t = m g L / (4 h), h = 4 − z,
    L = √(8 + h²); the 1-D null space (1, −1, 1, −1) can only lower one pair, so the pose is feasible
    iff tmin ≤ t ≤ tmax: h ≤ √8 / √((4 tmin / m g)² − 1) and h ≥ √8 / √((4 tmax / m g)² − 1)
    (for 4 tmin > m g, as here)."""
    g = 9.81
    low = 4.0 - math.sqrt(8.0) / math.sqrt((4 * tmin / (mass * g)) ** 2 - 1.0)
    high = 4.0 - math.sqrt(8.0) / math.sqrt((4 * tmax / (mass * g)) ** 2 - 1.0)
    return low, high


@pytest.mark.parametrize("payload", [0.0, 0.3, 0.5])
def test_point_mass_axis_against_the_closed_form(payload: float) -> None:
    robot = load_robot("point_mass_4")
    low, high = axis_limits(robot.mass + payload, float(robot.tmin[0]), float(robot.tmax[0]))
    assert 0.0 < low < high < 4.0
    z = np.array([low - 1e-3, low + 1e-3, 0.5 * (low + high), high - 1e-3, high + 1e-3])
    got = wrench_feasible(robot, np.column_stack([np.zeros(5), np.zeros(5), z]), payload=payload)
    np.testing.assert_array_equal(got, [False, True, True, True, False])


def test_grid_points_cover_the_frame_box() -> None:
    robot = load_robot("caroca")
    points, shape, spacing = grid_points(robot, 0.3)
    assert points.shape == (np.prod(shape), 3)
    assert np.all(spacing <= 0.3 + 1e-12)
    assert np.all(spacing > 0.3 * 0.9)
    np.testing.assert_allclose(points.min(axis=0), robot.frame_min + spacing / 2)
    np.testing.assert_allclose(points.max(axis=0), robot.frame_max - spacing / 2)
    planar, shape2, spacing2 = grid_points(load_robot("kntu_planar"), 0.1)
    assert shape2[1] == 1
    assert spacing2[1] == 0.0
    assert np.all(planar[:, 1] == 0.0)
    with pytest.raises(ValueError, match="step"):
        grid_points(robot, 0.0)


def test_workspace_summary() -> None:
    robot = load_robot("point_mass_4")
    ws = compute_workspace(robot, 0.25)
    assert ws.fraction == pytest.approx(ws.feasible.sum() / len(ws.points))
    lo, hi = ws.bounding_box()
    good = ws.points[ws.feasible]
    assert np.all(good >= lo)
    assert np.all(good <= hi)
    assert compute_workspace(robot, 0.25, tmin=500.0, tmax=600.0).bounding_box() is None


# --------------------------------------------------------------------------------------------------
# Scenarios


@pytest.mark.parametrize("name", shipped_scenarios())
def test_shipped_scenarios_stay_in_the_workspace(name: str) -> None:
    sc = load_scenario(name)  # raises if not
    assert first_violation(sc.robot, sc.trajectory, sc.variant) is None


def test_sample_times_hit_every_waypoint() -> None:
    traj = QuinticWaypoints([0.0, 0.33, 1.0], [[0, 0, 1], [0, 0, 2], [1, 0, 2]])
    t = sample_times(traj, 0.05)
    assert {0.0, 0.33, 1.0} <= set(t.tolist())
    assert np.all(np.diff(t) > 0)
    assert np.diff(t).max() <= 0.05 + 1e-12
    assert len(t) == 22


def first_bad_sample_by_lp(path: Path) -> tuple[float, np.ndarray, str]:
    """The first sample (same sample times) whose static or dynamic wrench an LP finds infeasible."""
    import yaml

    from cdpr.config.trajectory import trajectory_from_spec

    spec = yaml.safe_load(path.read_text())
    robot = load_robot(spec["robot"]).with_mass(spec["platform"]["mass"])
    lo, hi = spec["limits"]["tmin"], spec["limits"]["tmax"]
    traj = trajectory_from_spec(spec["trajectory"])
    rows = list(controlled_rows(robot, "6dof"))
    for t in sample_times(traj):
        s = traj.sample(t)
        W = inverse_kinematics(robot, s.position, s.rotation).wrench_matrix[rows]
        if not lp_feasible(W, -gravity_wrench(robot)[rows], lo, hi):
            return float(t), s.position, "static"
        if not lp_feasible(W, required_wrench(robot, s.rotation, s.twist, s.accel)[rows], lo, hi):
            return float(t), s.position, "dynamic"
    raise AssertionError(f"{path} stays in the workspace")


@pytest.mark.parametrize(("path", "kind"), [(BAD_STATIC, "static"), (BAD_DYNAMIC, "dynamic")])
def test_a_trajectory_out_of_the_workspace_is_rejected_at_load(path: Path, kind: str) -> None:
    t_bad, p_bad, kind_bad = first_bad_sample_by_lp(path)
    assert kind_bad == kind
    with pytest.raises(InputError) as info:
        load_scenario(path)
    msg = str(info.value)
    assert "\n" not in msg
    position = ", ".join(f"{x:.3f}" for x in p_bad)
    assert msg.startswith(
        f"{path}: trajectory: leaves the wrench-feasible workspace at t = {t_bad:.2f} s "
        f"(position [{position}]): no tensions in [1, 6500] N "
    ), msg


def test_the_dynamic_failure_is_where_the_platform_would_fall_faster_than_gravity() -> None:
    """falls_too_fast: statically fine everywhere; rejected at the first sample where cables, which can
    only pull from above, would have to push: the desired downward acceleration exceeds g (less the
    little the 1 N minimum tensions add)."""
    robot = load_robot("caroca").with_mass(15.0).replace(tmin=1.0, tmax=6500.0)
    traj = QuinticWaypoints([0.0, 0.4], [[0.9, 0.9, 1.2], [0.9, 0.9, 0.2]])
    times = sample_times(traj)
    positions = np.array([traj.sample(t).position for t in times])
    assert wrench_feasible(robot, positions).all()
    v = first_violation(robot, traj)
    assert v is not None
    assert v.kind == "dynamic"
    az = np.array([traj.sample(t).accel[2] for t in times])
    first_faster_than_g = times[np.argmax(az < -9.81)]
    assert v.t == first_faster_than_g
    np.testing.assert_allclose(v.position, traj.sample(v.t).position)


def test_cli_run_refuses_the_scenario_in_one_line() -> None:
    proc = cdpr("run", str(BAD_STATIC), "--quiet", timeout=60)
    assert proc.returncode == 2
    lines = proc.stderr.strip().splitlines()
    assert len(lines) == 1
    assert "leaves the wrench-feasible workspace at t = " in lines[0]
    assert proc.stdout == ""


# --------------------------------------------------------------------------------------------------
# cdpr workspace


def test_cli_workspace_json_and_recording(tmp_path: Path) -> None:
    from rerun.chunk import RrdReader

    rrd = tmp_path / "ws.rrd"
    proc = cdpr(
        "workspace", "point_mass_4", "--step", "0.25", "--payload", "0.5", "--rrd", str(rrd), check=True
    )
    out = last_json_line(proc.stdout)
    ws = compute_workspace(load_robot("point_mass_4").with_payload(0.5), 0.25)
    assert out["points"] == len(ws.points) == 16**3
    assert out["grid"] == [16, 16, 16]
    assert out["feasible"] == int(ws.feasible.sum()) > 0
    assert out["fraction"] == pytest.approx(ws.fraction)
    assert out["mass"] == 1.5
    assert out["problems"] == []
    np.testing.assert_allclose(out["bounding_box"]["min"], ws.bounding_box()[0])
    counts: dict[str, int] = {}
    for chunk in RrdReader(str(rrd)).stream().to_chunks():
        entity = chunk.entity_path.lstrip("/")
        batch = chunk.to_record_batch()
        if "Points3D:positions" in batch.schema.names:
            counts[entity] = counts.get(entity, 0) + sum(
                len(row) for row in batch.column("Points3D:positions").to_pylist()
            )
    assert counts[recording.WORKSPACE_FEASIBLE] == out["feasible"]
    assert counts[recording.WORKSPACE_INFEASIBLE] == out["points"] - out["feasible"]
    assert counts[recording.FRAME_ANCHORS] == 4


def test_cli_workspace_rejects_bad_arguments() -> None:
    for args, text in [
        (("--step", "0"), "--step"),
        (("--tmin", "10", "--tmax", "5"), "--tmin/--tmax"),
        (("--payload", "-1"), "payload"),
    ]:
        if args[0] == "--step":  # the first as the real command's process, the others in this process
            proc = cdpr("workspace", "point_mass_4", *args, timeout=60)
        else:
            proc = cdpr_here("workspace", "point_mass_4", *args)
        assert proc.returncode == 2, proc.stderr
        assert text in proc.stderr, proc.stderr
