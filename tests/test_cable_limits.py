"""Per-cable limits (#32): a robot file's cables may have their own tmin, tmax and max_length.

Every tension distribution keeps each cable within its own limits (hypothesis, against the bounds alone), the
sim clamps each cable to its own tmax, `session/info` carries them to a remote controller, and a real session
of a robot whose limits bind keeps every cable inside them.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from cdpr.config.robot import load_robot
from cdpr.config.scenario import load_scenario
from cdpr.errors import InputError
from cdpr.mechanics.kinematics import inverse_kinematics
from cdpr.mechanics.rotation import rpy_to_matrix
from cdpr.mechanics.tda import METHODS, make_tda
from cdpr.protocol.session import robot_from_summary
from cdpr_sim.core import clamp_tensions, tension_ceiling
from conftest import cdpr, last_json_line

ROBOT = Path(__file__).parent / "robots" / "valid" / "per_cable_limits.yaml"
SCENARIO = Path(__file__).parent / "scenarios" / "per_cable_limits.yaml"


def test_a_cable_overrides_the_robots_limits_and_the_others_keep_them() -> None:
    robot = load_robot(ROBOT)
    assert robot.tmin.tolist() == [20.0, 20.0] + [1.0] * 6
    assert robot.tmax.tolist() == [500.0] * 6 + [25.0, 25.0]
    assert robot.max_length.tolist() == [6.0] * 5 + [5.5, 6.0, 6.0]
    assert not robot.uniform_limits
    assert robot.common_tension_range == (20.0, 25.0)
    assert robot.tension_limits_text().startswith("[20, 500]/[20, 500]/[1, 500]")
    assert load_robot("caroca").uniform_limits


def test_session_info_carries_each_cables_limits() -> None:
    robot = load_robot(ROBOT)
    summary = robot.summary()
    assert summary["tension_limits"] == [20.0, 25.0]  # what holds for every cable
    assert summary["cable_limits"] == {"tmin": robot.tmin.tolist(), "tmax": robot.tmax.tolist(),
                                       "max_length": robot.max_length.tolist()}
    again = robot_from_summary(summary)
    for name in ("tmin", "tmax", "max_length"):
        assert np.array_equal(getattr(again, name), getattr(robot, name))
    # a map without per-cable limits (a hand-written or older one): one range for every cable
    del summary["cable_limits"]
    assert robot_from_summary(summary).tmax.tolist() == [25.0] * 8


def test_a_cables_tmin_above_its_tmax_names_the_cable(tmp_path: Path) -> None:
    text = ROBOT.read_text().replace("tmax: 25.0}", "tmax: 0.5}", 1)
    bad = tmp_path / "bad.yaml"
    bad.write_text(text)
    with pytest.raises(InputError, match=r"bad.yaml: cables.6: tmin \(1.0\) must not exceed tmax \(0.5\)"):
        load_robot(bad)


def test_the_sim_clamps_each_cable_to_its_own_tmax() -> None:
    robot = load_robot(ROBOT)
    commanded = np.array([30.0, -1.0, 600.0, 20.0, 20.0, 20.0, 26.0, 24.0])
    applied, low, high = clamp_tensions(commanded, tension_ceiling(robot))
    assert applied.tolist() == [30.0, 0.0, 500.0, 20.0, 20.0, 20.0, 25.0, 24.0]
    assert (low, high) == (1, 2)
    uniform = load_robot("caroca")
    assert isinstance(tension_ceiling(uniform), float)
    assert clamp_tensions(uniform.tmax + 1.0, tension_ceiling(uniform))[2] == 8
    assert clamp_tensions(np.array([5.0, 150.0]), 100)[0].tolist() == [5.0, 100.0]  # any number as tmax


@st.composite
def problems(draw: st.DrawFn) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, bool]:
    """A robot's wrench matrix at a random pose, random per-cable bounds, and a wrench: either one that
    tensions within the bounds produce (feasible) or an arbitrary one."""
    robot = load_robot(ROBOT)
    p = [draw(st.floats(-0.5, 0.5)), draw(st.floats(-0.5, 0.5)), draw(st.floats(0.8, 2.0))]
    rpy = [draw(st.floats(-0.3, 0.3)) for _ in range(3)]
    W = inverse_kinematics(robot, p, rpy_to_matrix(*rpy)).wrench_matrix
    seed = draw(st.integers(0, 2**32 - 1))
    rng = np.random.default_rng(seed)
    lb = rng.uniform(0.0, 50.0, robot.m) * (rng.random(robot.m) < 0.7)
    ub = lb + rng.uniform(0.0, 200.0, robot.m) * (rng.random(robot.m) < 0.9)  # some cables pinned
    feasible = draw(st.booleans())
    w = W @ rng.uniform(lb, ub) if feasible else rng.normal(0.0, 200.0, 6)
    return W, w, lb, ub, feasible


@pytest.mark.parametrize("method", sorted(METHODS))
@settings(max_examples=60, deadline=None, suppress_health_check=[HealthCheck.too_slow])
@given(problem=problems())
def test_every_distribution_keeps_each_cable_within_its_own_limits(method: str, problem: tuple) -> None:
    W, w, lb, ub, feasible = problem
    result = make_tda(method).solve(W, w, lb, ub)
    assert np.all(result.tensions >= lb)
    assert np.all(result.tensions <= ub)
    if result.feasible:
        assert float(np.linalg.norm(W @ result.tensions - w)) <= 1e-6 * max(1.0, float(np.abs(w).max()))
    if feasible and method in ("qp", "continuity"):  # the exact methods find tensions wherever some exist
        assert result.feasible, result.status


def test_a_session_keeps_every_cable_within_its_own_limits() -> None:
    """A real session (separate processes) where cables 6 and 7 start at their own 25 N tmax and cables 0 and 1
    must stay above their 20 N: the controller's distribution keeps to them, the sim never clamps."""
    scenario = load_scenario(SCENARIO)
    assert not scenario.robot.uniform_limits
    proc = cdpr("run", str(SCENARIO), timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = last_json_line(proc.stdout)
    lows, highs = np.array(summary["cable_tension_min"]), np.array(summary["cable_tension_max"])
    tmin, tmax = scenario.robot.tmin, scenario.robot.tmax
    assert np.all(lows >= tmin - 1e-9), lows
    assert np.all(highs <= tmax + 1e-9), highs
    assert highs[6:].tolist() == pytest.approx([25.0, 25.0], abs=1e-6)  # they bind
    assert highs[6] < 26.0 < highs[2]  # another cable carries what 6 and 7 cannot
    assert (summary["clamped_commands"], summary["infeasible_commands"]) == (0, 0)
    assert summary["max_position_error"] < 1e-3
