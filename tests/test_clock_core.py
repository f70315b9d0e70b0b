"""The clock's pure logic: when ticks may go out, pausing, resending, realtime deadlines, statistics."""

from __future__ import annotations

from cdpr_clock.core import ClockCore


def drain(core: ClockCore, now: float) -> list[int]:
    out = []
    while (k := core.next_tick(now)) is not None:
        core.issue(k, now)
        out.append(k)
    return out


def test_nothing_while_waiting_for_participants() -> None:
    core = ClockCore(total_steps=5, dt=0.001)
    assert drain(core, 0.0) == []
    core.resume(0.0)
    assert drain(core, 0.0) == [0]


def test_lookahead_one_keeps_one_tick_ahead_of_the_sim() -> None:
    core = ClockCore(total_steps=4, dt=0.001, lookahead=1)
    core.resume(0.0)
    assert drain(core, 0.0) == [0]
    core.on_state(0, 0.0)  # state 0 (published on tick 0)
    assert drain(core, 0.0) == [1]
    core.on_state(1, 0.0)
    assert drain(core, 0.0) == [2]
    core.on_state(2, 0.0)
    assert drain(core, 0.0) == [3]
    core.on_state(3, 0.0)
    assert drain(core, 0.0) == []  # no tick 4 of a 4-step session
    assert not core.finished
    core.on_state(4, 0.0)
    assert core.finished


def test_lookahead_zero_is_a_strict_handshake() -> None:
    core = ClockCore(total_steps=3, dt=0.001, lookahead=0)
    core.resume(0.0)
    assert drain(core, 0.0) == [0]
    assert drain(core, 0.0) == []
    core.on_state(0, 0.0)
    assert drain(core, 0.0) == []  # step 0 is not complete until state 1
    core.on_state(1, 0.0)
    assert drain(core, 0.0) == [1]


def test_pause_stops_ticks_and_resume_repeats_the_unfinished_step() -> None:
    core = ClockCore(total_steps=10, dt=0.001)
    core.resume(0.0)
    drain(core, 0.0)
    core.on_state(0, 0.0)
    drain(core, 0.0)
    core.on_state(1, 0.0)
    core.pause(0.0)
    assert drain(core, 0.0) == []
    assert core.resume(2.0) == [1]  # tick 1 was issued, step 1 is not complete
    assert core.paused_time == 2.0
    assert drain(core, 2.0) == [2]


def test_realtime_waits_for_deadlines_and_counts_late_ticks() -> None:
    core = ClockCore(total_steps=10, dt=0.001, realtime=True)
    core.resume(0.0)
    assert drain(core, 100.0) == [0]  # tick 0 defines t0 = 100
    core.on_state(0, 100.0)
    assert core.next_tick(100.0005) is None
    assert abs(core.wait_time(100.0005) - 0.0005) < 1e-12
    assert drain(core, 100.001) == [1]
    core.on_state(1, 100.001)
    assert drain(core, 100.0045) == [2]  # 2.5 ms late
    stats = core.stats(100.005)
    assert core.late_ticks == 1
    assert stats["late_ticks"] == 1
    assert abs(stats["lateness_max_ms"] - 2.5) < 1e-6
    assert abs(stats["on_time_fraction"] - 2 / 3) < 1e-9


def test_stats_rate_and_rtf() -> None:
    core = ClockCore(total_steps=1000, dt=0.001)
    core.resume(0.0)
    drain(core, 0.0)
    core.on_state(500, 0.25)
    stats = core.stats(0.25)
    assert stats["steps"] == 500
    assert abs(stats["rate"] - 2000.0) < 1e-9
    assert abs(stats["rtf"] - 2.0) < 1e-9
