"""Elastic and sagging cables on winches, the catenary, the length command and the length controller.

Independent references: Hooke's law for a hanging mass (stretch = m g l0 / EA), the textbook catenary
``z = a cosh((x − x0)/a)`` built by hand, a numerical integration of the elastic cable's equilibrium ODE
(scipy ``solve_ivp``), ``cdpr_sim.core.PlatformSim`` (the ideal cables, for the tension mode),
``cdpr.mechanics.dynamics.forward_dynamics`` and ``cdpr.mechanics.kinematics``. Small test robots are built here.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest
from scipy.integrate import solve_ivp

from cdpr.config.robot import load_robot
from cdpr.config.scenario import ElasticSpec, SagSpec, WinchSpec, load_scenario
from cdpr.errors import InputError
from cdpr.laws.feedback_linearisation import ControllerCore, stretch_compensated_lengths
from cdpr.mechanics.catenary import (
    CatenaryError,
    cable_planes,
    end_point,
    inextensible_catenary,
    solve_catenary,
    solve_catenary_tension,
    unstretched_lengths,
)
from cdpr.mechanics.dynamics import forward_dynamics, gravity_wrench
from cdpr.mechanics.kinematics import inverse_kinematics
from cdpr.mechanics.robot import Robot
from cdpr.mechanics.rotation import rpy_to_matrix
from cdpr.mechanics.tda import make_tda
from cdpr.protocol import PROTOCOL_VERSION, Command, ProtocolError
from cdpr.protocol.session import session_info
from cdpr_sim.core import PlatformSim
from cdpr_sim.elastic import ElasticSim, elastic_tensions
from cdpr_sim.models import make_sim
from cdpr_sim.sag import SagSim
from cdpr_sim.winch import WinchState, drive_torque, drum_step, substeps_for

G = 9.81
DT = 1e-3


def caroca15() -> Robot:
    return load_robot("caroca").with_mass(15.0).replace(tmin=1.0, tmax=6500.0)


def hanging_robot(mass: float, top: float = 3.0) -> Robot:
    """A point mass on one vertical cable from (0, 0, top): built with ``replace`` (one cable cannot hold
    three DOF, so the robot loader would refuse it; the sims do not need it to)."""
    base = load_robot("point_mass_4")
    return base.replace(
        name="test_hanging",
        frame_points=np.array([[0.0, 0.0, top]]),
        platform_points=np.zeros((1, 3)),
        mass=mass,
        tmin=0.0,
        tmax=1e4,
        cable_damping=0.0,
        home_position=np.array([0.0, 0.0, 1.0]),
        home_rotation=np.eye(3),
    )


# --------------------------------------------------------------------------------------------------
# Elastic cables


def test_elastic_law() -> None:
    EA, c = 1e5, 50.0
    # taut: k (l − l0) + c (l̇ − l̇0) with k = EA/l0
    lengths, rates = [2.01, 2.01, 1.99, 2.0001], [0.0, 0.1, 0.5, -1.0]
    f = elastic_tensions(lengths, rates, [2.0] * 4, [0.0, 0.05, 0.0, 0.0], EA, c)
    assert f[0] == pytest.approx(EA / 2.0 * 0.01)
    assert f[1] == pytest.approx(EA / 2.0 * 0.01 + c * 0.05)
    assert f[2] == 0.0  # slack: no force, whatever the rate
    assert f[3] == 0.0  # shortening fast: would push, pulls nothing
    l0 = unstretched_lengths([3.0, 3.0], [0.0, 200.0], EA)
    assert l0[0] == 3.0
    assert EA / l0[1] * (3.0 - l0[1]) == pytest.approx(200.0, rel=1e-12)  # the static law, inverted


@pytest.mark.parametrize(("mass", "EA", "l0"), [(10.0, 2e4, 1.9), (4.0, 5e3, 1.5)])
def test_static_stretch_of_a_hanging_mass_is_m_g_l0_over_ea(mass: float, EA: float, l0: float) -> None:
    """A winch holds l0 of cable; the mass settles where the cable has stretched by m g l0 / EA."""
    robot = hanging_robot(mass)
    sim = ElasticSim(robot, DT, [0.0, 0.0, 1.0], params=ElasticSpec(EA=EA, damping=200.0), command="lengths")
    assert sim.encoder_lengths()[0] == pytest.approx(2.0 * EA / (EA + mass * G))  # starts holding it
    for _ in range(5000):
        sim.step(np.array([l0]))
    s = sim.state()
    assert np.abs(s.twist).max() < 1e-9  # settled
    stretch = s.cable_lengths[0] - sim.encoder_lengths()[0]
    assert sim.encoder_lengths()[0] == pytest.approx(l0, abs=1e-12)  # the drive's integral removed its error
    assert stretch == pytest.approx(mass * G * l0 / EA, rel=1e-9)
    assert s.tensions[0] == pytest.approx(mass * G, rel=1e-9)
    assert s.position[:2] == pytest.approx([0.0, 0.0], abs=1e-12)


def test_tension_mode_is_the_ideal_model_without_damping() -> None:
    """Tension-controlled winches on straight elastic cables apply the commanded tensions along the chords:
    the same motion as PlatformSim's ideal cables (whose damping is set to 0, as these cables have none)."""
    robot = caroca15()
    p0 = np.array([0.9, 0.9, 0.2])
    elastic = ElasticSim(robot, DT, p0)
    ideal = PlatformSim(robot.replace(cable_damping=0.0), DT, p0)
    assert elastic.substeps == 1
    tda = make_tda("qp")
    W = inverse_kinematics(robot, p0).wrench_matrix
    f0 = tda.solve(W, -gravity_wrench(robot), robot.tmin, robot.tmax).tensions
    for k in range(400):
        f = f0 * (1.0 + 0.05 * np.sin(0.02 * k + np.arange(8)))
        elastic.step(f)
        ideal.step(f)
    a, b = elastic.state(), ideal.state()
    assert a.step == b.step == 400
    assert np.abs(a.position - b.position).max() < 1e-12
    assert np.abs(a.twist - b.twist).max() < 1e-10
    assert np.array_equal(a.tensions, b.tensions)
    # the winches paid out what holds these tensions: l0 = l EA / (EA + f) at the start of the last step
    assert np.all(elastic.encoder_lengths() < a.cable_lengths)


def test_one_tension_step_matches_newton_euler() -> None:
    robot = caroca15()
    R = rpy_to_matrix(0.05, -0.03, 0.1)
    twist = np.array([0.1, -0.2, 0.05, 0.3, -0.1, 0.2])
    sim = ElasticSim(robot, DT, [0.2, -0.1, 1.0], R, twist)
    before = sim.state()
    f = np.linspace(20.0, 60.0, 8)
    sim.step(f)
    after = sim.state()
    W = inverse_kinematics(robot, before.position, before.rotation).wrench_matrix
    accel = forward_dynamics(robot, before.rotation, before.twist, W @ f)
    assert (after.twist - before.twist) / DT == pytest.approx(accel, abs=1e-6)


def test_interface_time_reset_bad_inputs_determinism() -> None:
    robot = caroca15()
    sims = [ElasticSim(robot, DT, [0.0, 0.0, 1.0], command="lengths") for _ in range(2)]
    l0 = sims[0].encoder_lengths().copy()
    for sim in sims:
        for k in range(50):
            sim.step(l0 * (1.0 - 1e-4 * math.sin(0.1 * k)))
    a, b = sims[0].state(), sims[1].state()
    assert a.step == sims[0].step_count == 50
    assert a.t == 50 * DT
    for name in ("position", "twist", "tensions", "cable_lengths"):
        x, y = getattr(a, name), getattr(b, name)
        assert np.array_equal(x, y)  # bit-identical
    with pytest.raises(ValueError, match="expected 8 lengths"):
        sims[0].step(np.ones(7))
    with pytest.raises(ValueError, match="> 0"):
        sims[0].step(np.r_[l0[:7], 0.0])
    with pytest.raises(ValueError, match="command must be"):
        ElasticSim(robot, DT, command="torques")  # type: ignore[arg-type]
    with pytest.raises(ValueError, match="EA"):
        ElasticSpec(EA=0.0)
    sims[0].reset([0.0, 0.0, 1.0])
    s = sims[0].state()
    assert s.step == 0
    assert s.t == 0.0
    assert np.all(s.tensions == 0.0)
    assert sims[0].encoder_lengths() == pytest.approx(l0, abs=1e-15)
    # clamping: a length beyond the robot's max_length is clamped and counted
    report = sims[0].step(np.r_[l0[:7], robot.max_length[7] + 1.0])
    assert report.clamped_high == 1
    assert report.clamped_low == 0


def test_state_lengths_and_rates_match_kinematics() -> None:
    robot = caroca15()
    R = rpy_to_matrix(0.1, 0.0, -0.2)
    twist = np.array([0.3, 0.1, -0.2, 0.1, 0.2, -0.3])
    s = ElasticSim(robot, DT, [0.1, 0.2, 1.1], R, twist).state()
    kin = inverse_kinematics(robot, s.position, s.rotation)
    assert s.cable_lengths == pytest.approx(kin.lengths, abs=1e-14)
    assert s.cable_rates == pytest.approx(kin.jacobian @ s.twist, abs=1e-13)


def test_substeps_keep_the_stiff_cables_stable_at_1_ms() -> None:
    """The default CAROCA winch robot needs sub-steps; with them, holding the start lengths stays put."""
    robot = caroca15()
    p0 = np.array([0.9, 0.9, 0.2])
    sim = ElasticSim(robot, DT, p0, command="lengths")
    assert sim.substeps == substeps_for(robot, DT, 1e6 / inverse_kinematics(robot, p0).lengths, WinchSpec(),
                                        200.0, p0, np.eye(3))
    assert 2 <= sim.substeps <= 10
    l0 = sim.encoder_lengths().copy()
    for _ in range(1000):
        sim.step(l0)
    s = sim.state()
    assert np.abs(s.position - p0).max() < 1e-12  # it started in equilibrium, and stays there
    assert sim.saturated == 0


def test_winch_drive() -> None:
    p = WinchSpec(radius=0.1, inertia=0.01, friction=0.0, torque_max=5.0, kp=100.0, ki=10.0, kd=1.0)
    s = WinchState(np.zeros(2), np.zeros(2), np.zeros(2))
    torque, integral, saturated = drive_torque(p, s, np.array([0.01, 1.0]), np.zeros(2), 1e-3)
    assert torque == pytest.approx([1.0, 5.0])  # kp·e, then the limit
    assert list(saturated) == [False, True]
    assert integral == pytest.approx([1e-5, 0.0])  # anti-windup: no integration while saturated outwards
    nxt = drum_step(p, s, torque, np.array([10.0, 0.0]), integral, 1e-3)
    # J θ̈ = τ + r f: (1 + 0.1·10)/0.01 = 200 rad/s² and 5/0.01 = 500 rad/s²
    assert nxt.speed == pytest.approx([0.2, 0.5])
    assert nxt.angle == pytest.approx([0.2e-3, 0.5e-3])  # semi-implicit: moves with the new speed


# --------------------------------------------------------------------------------------------------
# The catenary


def test_inextensible_catenary_matches_the_textbook_curve() -> None:
    """z = a cosh((x − x0)/a): ends at x = 0 (platform) and x = span; H = w a, V(x) = H sinh((x − x0)/a)."""
    w, H = 2.0, 50.0
    a = H / w
    for x0, span in ((1.3, 4.0), (-2.0, 3.0), (6.0, 5.0)):  # lowest point inside, before, beyond the span
        rise = a * (math.cosh((span - x0) / a) - math.cosh(-x0 / a))
        length = a * (math.sinh((span - x0) / a) - math.sinh(-x0 / a))
        V0, V1 = H * math.sinh(-x0 / a), H * math.sinh((span - x0) / a)
        Hc, Vc = inextensible_catenary(span, rise, length, w)
        assert Hc[0] == pytest.approx(H, rel=1e-10)
        assert Vc[0] == pytest.approx(V0, abs=1e-9)
        sol = solve_catenary(span, rise, length, w, EA=1e13)  # practically inextensible
        assert sol.horizontal[0] == pytest.approx(H, rel=1e-6)
        assert sol.vertical_platform[0] == pytest.approx(V0, abs=1e-5 * H)
        assert sol.vertical_frame[0] == pytest.approx(V1, abs=1e-5 * H)
        assert sol.tension_frame[0] == pytest.approx(w * a * math.cosh((span - x0) / a), rel=1e-6)  # T = w y


@pytest.mark.parametrize(("span", "rise", "L0", "w", "EA"),
                         [(4.0, 1.0, 4.5, 2.0, 5e3), (5.6, 3.3, 6.5, 0.5, 1e6), (3.0, -1.5, 3.2, 1.0, 2e4),
                          (0.5, 4.0, 4.02, 0.3, 1e5)])
def test_elastic_catenary_matches_the_integrated_cable(span: float, rise: float, L0: float, w: float,
                                                        EA: float) -> None:
    """Integrate dx/ds = H/T + H/EA, dz/ds = V/T + V/EA, V = V0 + w s along the unstretched length: the
    solver's (H, V0) must bring the cable's end onto the frame point."""
    sol = solve_catenary(span, rise, L0, w, EA)
    H, V0 = float(sol.horizontal[0]), float(sol.vertical_platform[0])

    def slope(s: float, _y: np.ndarray) -> list[float]:
        V = V0 + w * s
        T = math.hypot(H, V)
        return [H / T + H / EA, V / T + V / EA]

    end = solve_ivp(slope, (0.0, L0), [0.0, 0.0], rtol=1e-12, atol=1e-13).y[:, -1]
    assert end == pytest.approx([span, rise], abs=1e-8)
    assert np.allclose(end_point(H, V0, L0, w, EA), [[span], [rise]], atol=1e-12)
    # the same cable, solved from its tension at either end, gives back its length
    for where, T in (("platform", sol.tension_platform), ("frame", sol.tension_frame)):
        back = solve_catenary_tension(span, rise, T, w, EA, end=where)
        assert back.unstretched_length == pytest.approx([L0], rel=1e-9)
        assert back.horizontal == pytest.approx([H], rel=1e-7)


def test_catenary_vectorised_and_failures() -> None:
    rng = np.random.default_rng(3)
    n = 300
    span, rise = rng.uniform(0.01, 6.0, n), rng.uniform(-3.0, 3.0, n)
    L0 = np.hypot(span, rise) * rng.uniform(0.95, 1.5, n)
    w, EA = rng.uniform(0.1, 10.0, n), rng.uniform(1e3, 1e7, n)
    sol = solve_catenary(span, rise, L0, w, EA)
    s, z = end_point(sol.horizontal, sol.vertical_platform, L0, w, EA)
    assert np.abs(s - span).max() < 1e-8
    assert np.abs(z - rise).max() < 1e-8
    assert np.all(sol.horizontal > 0.0)
    with pytest.raises(ValueError, match="must be > 0"):
        solve_catenary(1.0, 1.0, 1.0, 0.0, 1e5)
    with pytest.raises(CatenaryError, match="did not converge"):  # 1 N cannot lift 50 N of cable 4 m up
        solve_catenary_tension(2.0, 4.0, 1.0, 10.0, 1e5, end="frame")


# --------------------------------------------------------------------------------------------------
# Sagging cables in the sim


def test_sag_sim_holds_its_weight_on_catenaries() -> None:
    """Held at the start lengths, the platform stays put; the catenaries' platform ends carry its weight."""
    robot = caroca15()
    params = SagSpec(mass_per_length=0.05)
    p0 = np.array([0.9, 0.9, 0.2])
    sim = SagSim(robot, DT, p0, params=params, command="lengths")
    l0 = sim.encoder_lengths().copy()
    for _ in range(300):
        sim.step(l0)
    s = sim.state()
    assert np.abs(s.position - p0).max() < 1e-9
    assert sim.fallbacks == 0
    # (1e-9 m on cables of 1e5 N/m is 1e-4 N: the forces are checked at the state's own pose, to the
    # 1e-4 N of what is left of the start's tiny oscillation: m·a and the damping c·l̇ are not counted)
    arms = robot.platform_points @ s.rotation.T
    span, rise, e_h = cable_planes(robot.frame_points, s.position + arms)
    cat = solve_catenary(span, rise, sim.encoder_lengths(), params.weight_per_length, params.EA)
    forces = cat.horizontal[:, None] * e_h
    forces[:, 2] += cat.vertical_platform
    assert forces.sum(axis=0) == pytest.approx([0.0, 0.0, robot.mass * G], abs=1e-4)
    assert np.cross(arms, forces).sum(axis=0) == pytest.approx(np.zeros(3), abs=1e-4)
    # the winches carry the platform and the cables: Σ V1 = m g + w Σ l0 (to the same 1e-4 N), and the
    # load cells read |T1|
    carried = robot.mass * G + params.weight_per_length * l0.sum()
    assert cat.vertical_frame.sum() == pytest.approx(carried, abs=1e-4)
    assert sim.load_cell_tensions() == pytest.approx(cat.tension_frame, rel=1e-6)
    # each cable pulls the platform below its chord
    d = inverse_kinematics(robot, p0).directions
    assert np.all(cat.vertical_platform < cat.tension_platform * d[:, 2])


def test_sag_tension_mode_holds_the_command_at_the_platform_end() -> None:
    robot = caroca15()
    sim = SagSim(robot, DT, [0.0, 0.0, 1.0], params=SagSpec(mass_per_length=0.05))
    f = np.linspace(15.0, 50.0, 8)
    sim.step(f)
    assert sim.state().tensions == pytest.approx(f, rel=1e-9)
    assert np.all(sim.load_cell_tensions() > f)  # the frame end also lifts the cable
    frame = SagSim(robot, DT, [0.0, 0.0, 1.0], params=SagSpec(mass_per_length=0.05, tension_at="frame"))
    frame.step(f)
    assert frame.load_cell_tensions() == pytest.approx(f, rel=1e-9)
    assert np.all(frame.state().tensions < f)
    zero = SagSim(robot, DT, [0.0, 0.0, 1.0])
    zero.step(np.r_[0.0, f[1:]])
    assert zero.state().tensions[0] == 0.0  # a cable commanded to 0 hangs from the frame, pulling nothing


def test_light_sagging_cables_behave_like_straight_ones() -> None:
    robot = caroca15()
    p0 = np.array([0.3, -0.2, 0.8])
    # 0.1 g/m: the sag lengthens a 5 m cable at 10 N by w² l³ / (24 T²) ≈ 5e-8 m
    sag = SagSim(robot, DT, p0, params=SagSpec(mass_per_length=1e-4), command="lengths")
    straight = ElasticSim(robot, DT, p0, command="lengths")
    l0 = straight.encoder_lengths().copy()
    assert sag.encoder_lengths() == pytest.approx(l0, abs=1e-6)
    for k in range(300):
        target = l0 * (1.0 + 2e-4 * math.sin(0.02 * k))
        sag.step(target)
        straight.step(target)
    assert np.abs(sag.state().position - straight.state().position).max() < 1e-6
    heavy = SagSim(robot, DT, p0, params=SagSpec(mass_per_length=0.05), command="lengths")
    assert np.abs(heavy.encoder_lengths() - l0).max() > 1e-4  # while 50 g/m sag by much more


@pytest.mark.parametrize("off", [0.0, 1e-9, 1e-6, 1e-4])  # m: the anchor's horizontal offset
def test_sag_cable_right_under_its_anchor_holds_a_mass_without_fallback(off: float) -> None:
    """A 1 kg mass on 2 m of the sag scenario's rope (0.05 kg/m, EA 1 MN), vertical or within 5e-5 rad of
    it, held at its start length: the hanging elastic rod. It stays put, the platform end holds m g, the
    winch m g and the cable's weight (the old solver fell back to a straight, weightless cable here)."""
    robot = hanging_robot(1.0).replace(frame_points=np.array([[off, 0.0, 3.0]]))
    params = SagSpec(mass_per_length=0.05)
    sim = SagSim(robot, DT, [0.0, 0.0, 1.0], params=params, command="lengths")
    l0 = sim.encoder_lengths().copy()
    for _ in range(300):
        sim.step(l0)
    s = sim.state()
    assert sim.fallbacks == 0
    assert sim.fallback_reason is None
    assert s.position[2] == pytest.approx(1.0, abs=2e-9)
    assert s.tensions[0] == pytest.approx(1.0 * G, rel=1e-6)
    assert sim.load_cell_tensions()[0] == pytest.approx(1.0 * G + params.weight_per_length * l0[0], rel=1e-6)
    # the rod's stretch by Hooke's law, by hand: ∫ V/EA ds with V = m g + w s
    w = params.weight_per_length
    assert s.cable_lengths[0] - l0[0] == pytest.approx((G * l0[0] + w * l0[0] ** 2 / 2.0) / params.EA, rel=1e-4)


def test_sag_steps_outside_the_domain_are_counted_not_silent() -> None:
    """Frame-end tensions too small to lift the cable (a 5 kg/m rope: ~50 N/m) have no catenary: those
    cables, and only those, are straight elastic cables with the commanded tension, and each such step
    is counted once (however many cables), with the reason."""
    robot = caroca15()
    params = SagSpec(mass_per_length=5.0, tension_at="frame")
    sim = SagSim(robot, DT, [0.0, 0.0, 1.0], params=params)
    assert sim.fallbacks == 0
    f = np.full(8, 400.0)
    f[[2, 5]] = 20.0  # far below the ~150 N of cable each lifts
    for k in range(3):
        sim.step(f)
        assert sim.fallbacks == k + 1
    assert "cable(s) [2, 5]" in (sim.fallback_reason or "")
    assert sim.load_cell_tensions() == pytest.approx(f, rel=1e-9)  # every winch holds its command
    platform = sim.state().tensions
    assert platform[[2, 5]] == pytest.approx([20.0, 20.0], rel=1e-12)  # straight: the same at both ends
    others = np.delete(np.arange(8), [2, 5])
    assert np.all(platform[others] < f[others] - 100.0)  # catenaries: the frame end also lifts the cable
    sim.step(np.full(8, 400.0))
    assert sim.fallbacks == 3  # back in the domain: not counted
    sim.reset()
    assert sim.fallbacks == 0


def test_a_catenary_the_solver_misses_falls_back_for_that_cable_only(monkeypatch: pytest.MonkeyPatch) -> None:
    """Lengths mode: should the solver ever fail (it does not in its domain: here it is made to, for the
    two cables 3.70 m across and 2.7 m up: 3 and 4), those cables alone are straight elastic ones, and
    the step is counted once."""
    import cdpr_sim.sag as sag

    robot = caroca15()
    sim = SagSim(robot, DT, [0.0, 0.0, 1.0], params=SagSpec(mass_per_length=0.05), command="lengths")
    straight = ElasticSim(robot, DT, [0.0, 0.0, 1.0], command="lengths")
    real = sag.solve_catenary

    def failing(span: Any, rise: Any, L0: Any, *args: Any, **kwargs: Any) -> Any:
        if np.any((np.abs(np.asarray(span) - math.hypot(2.9, 2.3)) < 1e-3) & (np.abs(np.asarray(rise) - 2.7) < 1e-3)):
            raise CatenaryError("catenary: made to fail for cables 3 and 4")
        return real(span, rise, L0, *args, **kwargs)

    monkeypatch.setattr(sag, "solve_catenary", failing)
    l0 = sim.encoder_lengths().copy()
    for k in range(3):
        sim.step(l0)
        assert sim.fallbacks == k + 1
    assert sim.fallback_reason == "catenary: made to fail for cables 3 and 4"
    # cables 3 and 4 pull along their chords like straight elastic cables of that length, the others do not
    g = sim._read()
    forces = sim._law(g, l0, np.zeros(8)).forces
    chords = straight._law(g, l0, np.zeros(8)).forces
    assert forces[[3, 4]] == pytest.approx(chords[[3, 4]], rel=1e-12)
    others = [0, 1, 2, 5, 6, 7]
    assert np.all(np.abs(forces[others] - chords[others]).max(axis=1) > 1e-3)


# --------------------------------------------------------------------------------------------------
# Elastic cables and winch drives, regime by regime


def test_elastic_cable_goes_slack_and_taut_again() -> None:
    """Paying out 5 cm under a 10 kg mass on an undamped cable: it falls freely (exactly g, DART's
    gravity) while the cable is slack, is caught, bounces, and goes slack and taut again, repeatedly."""
    sim = ElasticSim(hanging_robot(10.0), DT, [0.0, 0.0, 1.0], params=ElasticSpec(EA=2e4, damping=0.0),
                     command="lengths")
    l0 = sim.encoder_lengths().copy()
    tensions, speeds = [], []
    for _ in range(3000):
        sim.step(l0 + 0.05)
        s = sim.state()
        tensions.append(s.tensions[0])
        speeds.append(s.twist[2])
    T = np.array(tensions)
    slack = T == 0.0
    assert np.count_nonzero(np.diff(slack.astype(int)) == 1) >= 5  # taut → slack, again and again
    assert np.count_nonzero(np.diff(slack.astype(int)) == -1) >= 5  # and slack → taut
    free = slack[1:] & slack[:-1]  # whole steps without tension: free fall
    assert np.diff(np.array(speeds))[free] / DT == pytest.approx(np.full(np.count_nonzero(free), -G), abs=1e-9)
    assert T.max() > 3.0 * 10.0 * G  # caught: the cable stretches well past the static load
    assert sim.fallbacks == 0


def test_elastic_law_over_stretch_and_zero_length() -> None:
    EA = 1e5
    # over-stretch: Hooke's law stays linear (no yield, no rupture), finite, and invertible
    f = elastic_tensions([1.5, 3.0, 11.0], [0.0] * 3, [1.0] * 3, [0.0] * 3, EA, 0.0)
    assert f == pytest.approx([0.5 * EA, 2.0 * EA, 10.0 * EA], rel=1e-12)
    assert unstretched_lengths([1.5, 3.0, 11.0], f, EA) == pytest.approx([1.0] * 3, rel=1e-12)
    # no length: refused, not a division by zero
    with pytest.raises(ValueError, match="unstretched lengths must be > 0"):
        elastic_tensions([1.0], [0.0], [0.0], [0.0], EA, 0.0)
    with pytest.raises(ValueError, match="unstretched lengths must be > 0"):
        elastic_tensions([1.0], [0.0], [-0.1], [0.0], EA, 0.0)


def test_winding_a_cable_in_to_nothing_falls_back_to_the_shortest_cable_the_model_follows() -> None:
    """A mass 5 cm under its anchor, the winch commanded to wind in to 1 mm: below ``min_length`` the
    stiffness EA/l0 outruns the sub-steps, so the law takes the cable as min_length long (counted, with
    the reason), and the mass settles where a cable of min_length holds it."""
    robot = hanging_robot(10.0, top=1.05)
    sim = ElasticSim(robot, DT, [0.0, 0.0, 1.0], command="lengths")
    assert 0.0 < sim.min_length < 0.05
    for _ in range(2000):
        sim.step(np.array([1e-3]))
    assert sim.encoder_lengths()[0] == pytest.approx(1e-3, abs=1e-9)  # the drum did wind it in
    assert sim.fallbacks > 1500  # every step since the drum passed min_length
    assert "below the" in (sim.fallback_reason or "")
    s = sim.state()
    assert s.position[2] == pytest.approx(1.05 - sim.min_length * (1.0 + 10.0 * G / 1e6), abs=1e-9)
    assert s.tensions[0] == pytest.approx(10.0 * G, rel=1e-6)


def test_winch_torque_saturation_and_anti_windup() -> None:
    """Reeling in 30 cm at once: the drive saturates, the drum slews at its torque limit, and (the
    integral held while saturated) arrives with a small overshoot and settles on the command. Without the
    anti-windup the same move overshoots by ~1.7 m."""
    sim = ElasticSim(hanging_robot(10.0), DT, [0.0, 0.0, 1.0], command="lengths")
    target = sim.encoder_lengths()[0] - 0.3
    encoder = []
    for _ in range(2000):
        sim.step(np.array([target]))
        encoder.append(sim.encoder_lengths()[0])
    e = np.array(encoder) - target
    assert sim.saturated > 100
    assert e.min() > -5e-3  # overshoot below 5 mm
    assert 0.05 <= np.argmax(e < 1e-3) * DT <= 0.2  # the slew takes a while (torque-limited), not forever
    assert abs(e[-1]) < 1e-6


def test_winch_reverses_smoothly() -> None:
    """A 1 Hz, ±5 cm sinusoidal length command: once the start-up transient has died out (0.5 s), the
    drum reverses exactly where the command does (twice per period, no chatter), tracks within a
    millimetre, never saturates, and the cable stays taut with a smooth tension."""
    sim = ElasticSim(hanging_robot(10.0), DT, [0.0, 0.0, 1.0], command="lengths")
    l0 = sim.encoder_lengths()[0]
    encoder, errors, tensions = [l0], [], []
    for k in range(3000):
        command = l0 + 0.05 * math.sin(2.0 * math.pi * k * DT)
        sim.step(np.array([command]))
        encoder.append(sim.encoder_lengths()[0])
        errors.append(encoder[-1] - command)
        tensions.append(sim.state().tensions[0])
    v = np.diff(encoder)[500:]
    turns = 500 + np.flatnonzero(v[1:] * v[:-1] < 0.0)
    assert np.abs(turns - np.array([750, 1250, 1750, 2250, 2750])).max() <= 5  # the command's extremes
    assert np.abs(errors[500:]).max() < 1e-3
    assert sim.saturated == 0
    T = np.array(tensions[1500:])
    assert T.min() > 0.5 * 10.0 * G
    assert np.abs(np.diff(T)).max() < 1.0  # N per ms: no jumps at the reversals


def test_winch_length_limits() -> None:
    """Commands beyond max_length are clamped (counted), and the drum stops there; a drive too weak for
    its load is dragged out to the end of its cable, and the end stop holds the load there."""
    robot = hanging_robot(10.0).replace(max_length=2.2)
    sim = ElasticSim(robot, DT, [0.0, 0.0, 1.0], command="lengths")
    for _ in range(2000):
        report = sim.step(np.array([5.0]))
        assert report.clamped_high == 1
    assert sim.encoder_lengths()[0] == 2.2
    assert sim.stopped > 0
    with pytest.raises(ValueError, match="> 0"):
        sim.step(np.array([0.0]))
    weak = ElasticSim(robot, DT, [0.0, 0.0, 1.0], command="lengths", winch=WinchSpec(torque_max=1.0))
    start = weak.encoder_lengths()[0]
    for _ in range(3000):
        weak.step(np.array([start]))  # 1 N·m cannot hold m g r = 4.9 N·m
    s = weak.state()
    assert weak.encoder_lengths()[0] == 2.2
    assert weak.stopped > 0
    assert s.position[2] == pytest.approx(3.0 - 2.2 * (1.0 + 10.0 * G / 1e6), abs=1e-4)
    assert abs(s.twist[2]) < 1e-3  # held at the stop
    assert s.tensions[0] == pytest.approx(10.0 * G, rel=1e-3)


# --------------------------------------------------------------------------------------------------
# Length commands and the length controller


def test_length_command_on_the_wire() -> None:
    cmd = Command(4, 0.004, (), True, "optimal", (4.5,) * 8)
    raw = msgpack.unpackb(cmd.encode())
    assert "lengths" in raw
    assert "tensions" not in raw
    back = Command.decode(cmd.encode(), cables=8, expect="lengths")
    assert back == cmd
    assert back.kind == "lengths"
    assert back.values == (4.5,) * 8
    tension_cmd = Command(4, 0.004, (10.0,) * 8)
    assert Command.decode(tension_cmd.encode(), 8).kind == "tensions"

    def bad(expect: str | None = None, **fields: object) -> str:
        base: dict[str, object] = {"v": PROTOCOL_VERSION, "step": 1, "t": 0.001}
        base.update(fields)
        with pytest.raises(ProtocolError) as err:
            Command.decode(msgpack.packb(base), cables=8, expect=expect)
        return str(err.value)

    both = bad(tensions=[1.0] * 8, lengths=[1.0] * 8)
    assert both.startswith("lengths: a command carries tensions or lengths")
    assert bad(lengths=[1.0] * 7).startswith("lengths: expected 8 numbers")
    assert bad(lengths=[1.0] * 7 + [0.0]).startswith("lengths[7]: must be > 0")
    assert bad(lengths=[1.0] * 7 + [math.inf]).startswith("lengths[7]: must be finite")
    wrong_kind = bad("tensions", lengths=[1.0] * 8)
    assert wrong_kind.startswith("lengths: this session's controller commands tensions")
    assert bad("lengths", tensions=[1.0] * 8).startswith("lengths: missing")
    assert bad().startswith("tensions: missing")


def test_stretch_compensated_lengths() -> None:
    robot = caroca15()
    p, R = np.array([0.2, 0.1, 1.0]), rpy_to_matrix(0.0, 0.05, 0.1)
    f = np.linspace(10.0, 80.0, 8)
    EA = 2e5
    l0 = stretch_compensated_lengths(robot, p, R, f, EA)
    lengths = inverse_kinematics(robot, p, R).lengths
    assert lengths - l0 == pytest.approx(f * l0 / EA, rel=1e-12)  # Hooke: stretch = f l0 / EA
    with pytest.raises(ValueError, match="axial_stiffness"):
        ControllerCore(robot, ControllerCore.from_scenario(load_scenario("caroca_15kg")).gains, "6dof",
                       make_tda("qp"), output="lengths")


def test_commanded_lengths_hold_the_platform_at_another_pose() -> None:
    """The winches start holding the platform at one pose; moving the commands smoothly, in 1 s, to the
    lengths that hold it at another (its static tensions through the stretch compensation) brings it
    there, and holds it with those tensions."""
    robot = caroca15()
    start, goal = np.array([0.0, 0.0, 1.0]), np.array([0.03, -0.02, 1.04])
    sim = ElasticSim(robot, DT, start, command="lengths")
    W = inverse_kinematics(robot, goal).wrench_matrix
    f = make_tda("qp").solve(W, -gravity_wrench(robot), robot.tmin, robot.tmax).tensions
    l0 = stretch_compensated_lengths(robot, goal, np.eye(3), f, 1e6)
    first = sim.encoder_lengths().copy()
    for k in range(5000):
        s = min(k / 1000.0, 1.0)
        sim.step(first + s * s * (3.0 - 2.0 * s) * (l0 - first))
    state = sim.state()
    assert state.position == pytest.approx(goal, abs=1e-7)
    assert state.tensions == pytest.approx(f, abs=0.01)
    assert sim.saturated == 0


def test_scenarios_choose_models_and_outputs(tmp_path: Path) -> None:
    winch = load_scenario("caroca_15kg_winch")
    assert winch.output == "lengths"
    assert winch.cable_model == "elastic"
    info = session_info(winch)
    assert info["controller"]["output"] == "lengths"
    assert info["sim"]["elastic"]["EA"] == 1e6
    sim = make_sim(winch)
    assert isinstance(sim, ElasticSim)
    assert sim.command == "lengths"
    core = ControllerCore.from_scenario(winch)
    assert core.output == "lengths"
    assert core.axial_stiffness == 1e6
    sag = make_sim(load_scenario("caroca_15kg_sag"))
    assert isinstance(sag, SagSim)
    assert sag.command == "tensions"
    assert sag.params.mass_per_length == 0.05
    assert load_scenario("caroca_15kg").output == "tensions"

    text = (tmp_path / "base.yaml")
    source = load_scenario("caroca_15kg_winch").source
    original = Path(source).read_text(encoding="utf-8")
    for change, message in (
        (("cable_model: elastic", "cable_model: ideal"), "elastic: used by cable_model elastic only"),
        (("  elastic: {EA: 1.0e+6, damping: 200.0}\n", ""), None),
        (("EA: 1.0e+6", "EA: -1.0"), "sim.elastic.EA"),
        (("bias: 0.2}", "bias: [1, 2]}"), "sim.sensors.load_cells.bias: expected one number or 8"),
    ):
        text.write_text(original.replace(*change), encoding="utf-8")
        if message is None:
            assert load_scenario(text).spec.sim.elastic.EA == 1e6  # defaults
        else:
            with pytest.raises(InputError, match=message):
                load_scenario(text)
    ideal = original.replace("cable_model: elastic", "cable_model: ideal")
    ideal = ideal.replace("  elastic: {EA: 1.0e+6, damping: 200.0}\n", "")
    text.write_text(ideal.replace("  winch: {", "  # winch: {"), encoding="utf-8")
    with pytest.raises(InputError, match=r"controller\.output: lengths needs sim\.cable_model elastic"):
        load_scenario(text)


def test_every_cable_model_of_the_scenario_table_has_a_sim() -> None:
    from cdpr.config.scenario import CABLE_MODELS
    from cdpr_sim.models import SIM_MODELS

    assert list(SIM_MODELS) == list(CABLE_MODELS)
    for name, model in CABLE_MODELS.items():
        scenario = load_scenario("caroca_15kg", {"duration": 0.01, "sim": {"cable_model": name}})
        sim = make_sim(scenario)
        assert sim.robot is scenario.robot
        assert (model.params is None) == (scenario.spec.sim.cable_params is None)
        assert session_info(scenario)["sim"] == (
            {"cable_model": name} if model.params is None
            else {"cable_model": name, name: scenario.spec.sim.cable_params.model_dump()})
    with pytest.raises(InputError, match=r"sim\.cable_model: .*unknown cable model 'rubber' \(known: ideal, ups, "):
        load_scenario("caroca_15kg", {"sim": {"cable_model": "rubber"}})


def test_a_cable_model_is_its_module_and_a_row_in_each_table(monkeypatch: pytest.MonkeyPatch,
                                                              capsys: pytest.CaptureFixture[str]) -> None:
    """What adding a cable model takes (docs/cable-models.md): a row in cdpr.config.scenario.CABLE_MODELS (and a
    parameters section there, if it has parameters) and one in cdpr_sim.models.SIM_MODELS; the scenario's
    validation, session/info, the sim node and the launcher follow. Here a test-only model (the ideal cable's
    physics under another name) runs a whole in-process session: the same states as the ideal cables."""
    from cdpr.config import scenario as scenario_config
    from cdpr.tools.launch import RunOptions, run_session
    from cdpr_sim import models
    from conftest import last_json_line

    monkeypatch.setitem(scenario_config.CABLE_MODELS, "twin", scenario_config.CableModel("the ideal cable again"))
    monkeypatch.setitem(models.SIM_MODELS, "twin", f"{__name__}:TwinSim")
    summaries = {}
    for name in ("ideal", "twin"):
        scenario = load_scenario("caroca_15kg", {"duration": 0.2, "sim": {"cable_model": name}})
        assert session_info(scenario)["sim"] == {"cable_model": name}
        assert run_session(scenario, RunOptions(session_id=f"model-{name}", quiet=True, in_process=True)) == 0
        summaries[name] = last_json_line(capsys.readouterr().out)
    assert isinstance(make_sim(load_scenario("caroca_15kg", {"sim": {"cable_model": "twin"}})), TwinSim)
    assert summaries["twin"]["steps"] == summaries["ideal"]["steps"] == 200
    assert summaries["twin"]["state_digest"] == summaries["ideal"]["state_digest"]


class TwinSim(PlatformSim):
    """The test-only cable model of the test above: the ideal cables' physics under another name."""
