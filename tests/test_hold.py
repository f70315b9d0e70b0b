"""Which command acts on a step (cdpr_sim.hold), the clock's free-running grants and statistics, and the
messages' new fields: pure logic, no I/O."""

from __future__ import annotations

import numpy as np
import pytest

from cdpr.config.scenario import CommandLatencySpec, WatchdogSpec, load_scenario
from cdpr.errors import InputError
from cdpr.mechanics.dynamics import gravity_wrench
from cdpr.mechanics.kinematics import inverse_kinematics
from cdpr.protocol import Command, ProtocolError, State, Telemetry, Tick
from cdpr.protocol.messages import pack
from cdpr_clock.core import FREE_AHEAD, ClockCore
from cdpr_sim.hold import CommandHold, LatencyModel, StaticPolicy


def test_the_newest_command_that_may_act_holds() -> None:
    hold: CommandHold[str] = CommandHold(watchdog_steps=100)
    assert hold.select(0).command is None
    assert hold.select(0).age == 1
    hold.offer("c0", 0, acts_from=2)
    hold.offer("c1", 1, acts_from=2)
    a = hold.select(1)
    assert a.command is None
    assert not a.watchdog
    a = hold.select(2)
    assert (a.command, a.answered, a.age) == ("c1", 1, 1)
    assert hold.late == 1  # c0 was overtaken by c1 at the same step: never acted
    assert hold.select(5).age == 4  # held: zero-order hold, ageing


def test_a_command_older_than_one_offered_is_late_and_a_repeat_is_not() -> None:
    hold: CommandHold[str] = CommandHold(watchdog_steps=100)
    assert hold.offer("c5", 5, 5)
    assert not hold.offer("c5 again", 5, 6)  # a repeated answer (a resend)
    assert not hold.offer("c3", 3, 6)  # arrived after a newer one
    assert hold.late == 1
    assert hold.select(6).command == "c5"


def test_the_watchdog_trips_after_its_steps_without_a_new_command_and_clears_on_the_next() -> None:
    hold: CommandHold[str] = CommandHold(watchdog_steps=3)
    hold.offer("c0", 0, 0)
    assert [hold.select(k).watchdog for k in range(5)] == [False, False, False, True, True]
    hold.offer("c4", 4, 5)
    a = hold.select(5)
    assert a.command == "c4"
    assert not a.watchdog
    assert a.age == 1


def test_watchdog_steps_round_up() -> None:
    assert WatchdogSpec(timeout_ms=100.0).steps(0.001) == 100
    assert WatchdogSpec(timeout_ms=0.5).steps(0.001) == 1
    assert WatchdogSpec(timeout_ms=2.5).steps(0.001) == 3


def test_the_latency_model_is_a_function_of_its_seed() -> None:
    spec = CommandLatencySpec(steps=5, jitter=3, loss=0.2, seed=7)
    first, second = LatencyModel(spec), LatencyModel(spec)
    a = [first.delay() for _ in range(2000)]
    assert a == [second.delay() for _ in range(2000)]
    assert {d for d in a if d is not None} == {5, 6, 7, 8}
    assert 0.15 < a.count(None) / len(a) < 0.25
    other = LatencyModel(CommandLatencySpec(steps=5, jitter=3, loss=0.2, seed=8))
    assert [other.delay() for _ in range(2000)] != a
    fixed = LatencyModel(CommandLatencySpec(steps=4))
    assert [fixed.delay() for _ in range(3)] == [4, 4, 4]


def test_static_tensions_hold_the_pose_against_gravity_and_brake_a_moving_platform() -> None:
    scenario = load_scenario("caroca_15kg")
    robot = scenario.robot
    policy = StaticPolicy(robot, "6dof", decay=10.0, kind="tensions")
    position, R = np.array([0.2, -0.1, 0.6]), np.eye(3)
    W = inverse_kinematics(robot, position, R).wrench_matrix
    f = policy.tensions(position, R, np.zeros(6))
    assert np.all(f >= robot.tmin - 1e-9)
    assert np.all(f <= robot.tmax + 1e-9)
    assert np.allclose(W @ f, -gravity_wrench(robot), atol=1e-5)  # at rest: exactly the weight
    twist = np.array([0.3, 0.0, -0.2, 0.0, 0.0, 0.0])
    g = policy.tensions(position, R, twist)
    net = W @ g + gravity_wrench(robot)
    assert np.allclose(net[:3], -10.0 * robot.mass * twist[:3], atol=1e-4)  # decelerates at 10/s


def test_free_running_grants_windows_marked_free_and_counts_the_sims_lateness() -> None:
    core = ClockCore(total_steps=10_000, dt=0.001, realtime=True, lookahead=100, free=True)
    assert core.lookahead == round(FREE_AHEAD / 0.001)
    core.paused = False
    assert core.next_grant(0.0) == (0, 0, True)  # the handshake, as in lock-step
    core.issue(0, 0.0)
    assert core.next_grant(0.01) is None
    core.on_state(1, 0.02)
    first, until, flush = core.next_grant(0.02)  # type: ignore[misc]
    assert (first, until, flush) == (1, 1 + core.lookahead, False)
    core.issue(first, 0.02, until)
    assert core.lateness == []  # a window is not late: the sim reports its steps' lateness
    core.on_lateness([0.0001, 0.0005, 0.003], 0.5)
    st = core.stats(0.5)
    assert st["late_ticks"] == 1
    assert st["on_time_fraction"] == pytest.approx(2 / 3)
    core.on_ages([0, 2, 2, 3], watchdog=1)
    st = core.stats(0.5)
    assert (st["command_age_p50"], st["command_age_max"], st["watchdog_steps"]) == (2, 3, 1)


def test_the_late_share_looks_at_the_last_second() -> None:
    core = ClockCore(total_steps=100, dt=0.001, realtime=True, free=True)
    core.on_lateness([0.01] * 5, 0.0)
    core.on_lateness([0.0] * 15, 1.5)
    assert core.late_share(1.6) == (0.0, 15)
    core.on_lateness([0.01] * 5, 1.7)
    assert core.late_share(1.7) == (0.25, 20)


def test_the_new_fields_round_trip_and_a_bad_one_is_named() -> None:
    tick = Tick(5, 0.005, 300, free=True)
    assert Tick.decode(tick.encode()) == tick
    assert Tick.decode(Tick(5, 0.005).encode()).free is False
    with pytest.raises(ProtocolError, match="free: expected true/false"):
        Tick.decode(pack({"step": 1, "t": 0.001, "free": 1}))
    s = State(3, 0.003, (0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0), (0.0,) * 6, (1.0, 2.0), (3.0, 4.0), 0, 4, 1)
    assert State.decode(s.encode(), 2) == s
    block = Telemetry((s,), (Command(2, 0.002, (3.0, 4.0)),), (1e-4,), (), (2.5e-4,))
    assert Telemetry.decode(block.encode(), 2) == block
    assert Telemetry.decode(Telemetry((s,), (Command(2, 0.002, (3.0, 4.0)),), (1e-4,)).encode(), 2).lateness == ()


def test_a_command_too_old_when_due_never_acts() -> None:
    hold: CommandHold[str] = CommandHold(watchdog_steps=10)
    hold.offer("c0", 0, 0)
    hold.select(0)
    hold.offer("c3", 3, 13)  # would act 10 steps after its state: not new
    a = hold.select(13)
    assert a.command == "c0"
    assert a.watchdog
    assert hold.late == 1
    hold.offer("c12", 12, 14)
    assert hold.select(14).command == "c12"


def test_a_huge_command_age_is_counted_not_allocated() -> None:
    core = ClockCore(total_steps=100, dt=0.001, realtime=True, free=True)
    core.on_ages([2**63, 1, 1], watchdog=0)  # a bad sim's number: the clock stays up
    st = core.stats(1.0)
    assert (st["command_age_p50"], st["command_age_max"]) == (1, 2**63)


def test_a_latency_the_watchdog_would_refuse_is_a_scenario_error() -> None:
    with pytest.raises(InputError, match=r"sim.command_latency: steps \+ jitter = 100 steps must stay below"):
        load_scenario("caroca_15kg", {"sim": {"command_latency": {"steps": 90, "jitter": 10}}})
    load_scenario("caroca_15kg", {"sim": {"command_latency": {"steps": 90, "jitter": 10},
                                          "watchdog": {"timeout_ms": 101.0}}})


def test_the_clock_refuses_free_running_or_max_lateness_in_fast_mode() -> None:
    import argparse

    from cdpr.protocol import Keys
    from cdpr_clock.node import ClockNode

    parser = argparse.ArgumentParser()
    ClockNode.add_arguments(parser)
    scenario = load_scenario("caroca_15kg")
    for argv, message in ((["--sync", "free"], "--sync free: free-running needs --mode realtime"),
                          (["--max-lateness", "1"], "--max-lateness: only realtime sessions")):
        with pytest.raises(InputError, match=message):
            ClockNode.from_args(scenario, Keys("s"), parser.parse_args(argv))
    node = ClockNode.from_args(scenario, Keys("s"), parser.parse_args(["--mode", "realtime", "--sync", "free"]))
    assert node.core.free
