"""The controller service's step function (pure): state + setpoint → tensions."""

from __future__ import annotations

import numpy as np
from msgspec.structs import replace

from cdpr.config.scenario import load_scenario
from cdpr.laws.feedback_linearisation import ControllerCore
from cdpr.mechanics.control import feedback_linearisation
from cdpr.mechanics.kinematics import inverse_kinematics
from cdpr.mechanics.rotation import quat_to_matrix
from cdpr_sim.core import PlatformSim, state_message
from cdpr_trajectory.core import setpoint_at


def test_the_tensions_produce_the_law_wrench_plus_damping_compensation() -> None:
    sc = load_scenario("caroca_15kg")
    core = ControllerCore.from_scenario(sc)
    setpoint = setpoint_at(sc.trajectory, 5000, sc.dt)
    twist = np.array(setpoint.twist) + np.array([0.001, -0.0005, 0.002, 0.0001, 0.0, -0.0002])
    sim = PlatformSim(sc.robot, sc.dt, np.array(setpoint.pose[:3]) + 1e-4, np.eye(3), twist=twist)
    state = state_message(sim.state(), 0)
    result = core.step(state, setpoint)
    assert result.feasible
    R = quat_to_matrix(state.pose[3:])
    W = inverse_kinematics(sc.robot, state.pose[:3], R).wrench_matrix
    law = feedback_linearisation(sc.robot, state.pose[:3], R, state.twist, setpoint.pose[:3],
                                 quat_to_matrix(setpoint.pose[3:]), setpoint.twist, setpoint.accel, sc.gains)
    damping = sc.robot.cable_damping * sim.state().cable_rates  # what the sim adds along each cable
    assert sc.robot.cable_damping > 0
    # tensions plus the sim's damping forces give exactly the wrench the law asks for
    assert np.allclose(W @ (result.tensions + damping), law, atol=1e-6)


def test_same_inputs_same_tensions() -> None:
    sc = load_scenario("caroca_15kg")
    a, b = ControllerCore.from_scenario(sc), ControllerCore.from_scenario(sc)
    sim = PlatformSim(sc.robot, sc.dt, sc.initial_position, sc.initial_rotation)
    for k in range(50):
        st, sp = state_message(sim.state(), 0), setpoint_at(sc.trajectory, k, sc.dt)
        ra, rb = a.step(st, sp), b.step(st, sp)
        assert np.array_equal(ra.tensions, rb.tensions)
        sim.step(ra.tensions)


def test_warm_up_leaves_the_answers_unchanged() -> None:
    """A warmed-up controller answers bit for bit like a fresh one (continuity, whose answer depends on
    the previous one, included)."""
    for name in ("caroca_15kg", "caroca_15kg_continuity"):
        sc = load_scenario(name)
        fresh, warmed = ControllerCore.from_scenario(sc), ControllerCore.from_scenario(sc)
        sim = PlatformSim(sc.robot, sc.dt, sc.initial_position, sc.initial_rotation)
        warmed.warm_up(state_message(sim.state(), 0), setpoint_at(sc.trajectory, 3000, sc.dt))
        for k in range(30):
            state, setpoint = state_message(sim.state(), 0), setpoint_at(sc.trajectory, k, sc.dt)
            a, b = fresh.step(state, setpoint), warmed.step(state, setpoint)
            assert np.array_equal(a.tensions, b.tensions)
            assert a.status == b.status
            sim.step(a.tensions)


def test_a_zero_quaternion_is_an_invalid_input_not_a_crash() -> None:
    sc = load_scenario("caroca_15kg")
    core = ControllerCore.from_scenario(sc)
    sim = PlatformSim(sc.robot, sc.dt, sc.initial_position, sc.initial_rotation)
    good_state, good_sp = state_message(sim.state(), 0), setpoint_at(sc.trajectory, 0, sc.dt)
    core.step(good_state, good_sp)
    zero = (0.0, 0.0, 0.0, 0.0)
    for state, setpoint in (
        (replace(good_state, pose=(*good_state.pose[:3], *zero)), good_sp),
        (good_state, replace(good_sp, pose=(*good_sp.pose[:3], *zero))),
        (replace(good_state, pose=(*good_state.pose[:3], 1e-200, 0.0, 0.0, 0.0)), good_sp),  # squares underflow
    ):
        result = core.step(state, setpoint)
        assert result.status == "invalid_input"
        assert not result.feasible
        assert np.isfinite(result.tensions).all()  # the last feasible tensions, sent instead
