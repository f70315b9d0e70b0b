"""The clock's pure logic: which steps may be granted, windows, pausing, resending, realtime deadlines,
statistics."""

from __future__ import annotations

from cdpr_clock.core import ClockCore


def drain(core: ClockCore, now: float) -> list[tuple[int, int, bool]]:
    out = []
    while (grant := core.next_grant(now)) is not None:
        core.issue(grant[0], now, grant[1])
        out.append(grant)
    return out


def test_nothing_while_waiting_for_participants() -> None:
    core = ClockCore(total_steps=5, dt=0.001, lookahead=1)
    assert drain(core, 0.0) == []
    core.resume(0.0)
    assert drain(core, 0.0) == [(0, 0, True)]


def test_the_first_step_is_a_handshake() -> None:
    # tick 0 grants step 0 alone and asks for a report; nothing more until state 1 shows the loop is closed
    core = ClockCore(total_steps=1000, dt=0.001, lookahead=100)
    core.resume(0.0)
    assert drain(core, 0.0) == [(0, 0, True)]
    assert core.handshaking
    core.on_state(0, 0.001)  # state 0 (published on tick 0): the controller's answer is still to come
    assert drain(core, 0.001) == []
    assert core.handshaking
    core.on_state(1, 0.002)
    assert not core.handshaking
    assert core.handshake_repeat_due() is None
    assert drain(core, 0.002) == [(1, 101, True)]


def test_tick_0_is_repeated_sooner_and_sooner_less_often_until_state_1() -> None:
    core = ClockCore(total_steps=10, dt=0.001)
    assert core.handshake_repeat_due() is None  # nothing issued yet
    core.resume(0.0)
    drain(core, 10.0)
    due = []
    for _ in range(7):
        due.append(core.handshake_repeat_due(first=0.05, most=1.0))
        core.handshake_repeats += 1
    assert [round(d - 10.0, 6) for d in due] == [0.05, 0.1, 0.2, 0.4, 0.8, 1.0, 1.0]
    core.pause(10.0)
    assert core.handshake_repeat_due() is None  # a missing participant: the pause handles it


def test_lookahead_one_keeps_one_step_ahead_of_the_sim() -> None:
    core = ClockCore(total_steps=5, dt=0.001, lookahead=1)
    core.resume(0.0)
    assert drain(core, 0.0) == [(0, 0, True)]
    core.on_state(1, 0.0)  # the handshake's report
    assert drain(core, 0.0) == [(1, 2, True)]
    core.on_state(2, 0.0)
    assert drain(core, 0.0) == [(3, 3, True)]
    core.on_state(4, 0.0)  # a block may report several steps at once: the grant catches up
    assert drain(core, 0.0) == [(4, 4, False)]  # the last step, below the lookahead edge
    assert not core.finished
    core.on_state(5, 0.0)
    assert drain(core, 0.0) == []  # no tick 5 of a 5-step session
    assert core.finished


def test_lookahead_zero_is_a_strict_handshake() -> None:
    core = ClockCore(total_steps=3, dt=0.001, lookahead=0)
    core.resume(0.0)
    assert drain(core, 0.0) == [(0, 0, True)]  # flush: the sim reports as soon as step 0 is done
    assert drain(core, 0.0) == []
    core.on_state(0, 0.0)
    assert drain(core, 0.0) == []  # step 0 is not complete until state 1
    core.on_state(1, 0.0)
    assert drain(core, 0.0) == [(1, 1, True)]


def test_fast_mode_grants_windows_ahead_of_the_reports() -> None:
    core = ClockCore(total_steps=1000, dt=0.001, lookahead=100)
    core.resume(0.0)
    assert drain(core, 0.0) == [(0, 0, True)]
    core.on_state(1, 0.0)
    assert drain(core, 0.0) == [(1, 101, True)]  # one message for the next 100 steps
    core.on_state(50, 0.0)  # a telemetry block: the sim is at step 50
    assert drain(core, 0.0) == [(102, 150, True)]
    core.on_state(51, 0.0)
    assert drain(core, 0.0) == [(151, 151, True)]
    core.on_state(950, 0.0)
    assert drain(core, 0.0) == [(152, 999, False)]  # never past the last step
    assert drain(core, 0.0) == []


def test_pause_stops_ticks_and_resume_repeats_the_unfinished_steps() -> None:
    core = ClockCore(total_steps=10, dt=0.001, lookahead=1)
    core.resume(0.0)
    drain(core, 0.0)
    core.on_state(1, 0.0)
    assert drain(core, 0.0) == [(1, 2, True)]
    core.on_state(2, 0.0)
    core.pause(0.0)
    assert drain(core, 0.0) == []
    assert core.resume(2.0) == (2, 2)  # step 2 was granted and is not complete
    assert core.paused_time == 2.0
    assert drain(core, 2.0) == [(3, 3, True)]


def test_realtime_grants_one_step_at_its_deadline_and_counts_late_ticks() -> None:
    core = ClockCore(total_steps=10, dt=0.001, realtime=True, lookahead=1)
    core.resume(0.0)
    assert drain(core, 100.0) == [(0, 0, True)]  # tick 0 at once
    assert core.wait_time(100.0) is None  # then the handshake: no deadline before state 1
    core.on_state(1, 100.01)  # the loop's first step took 10 ms: the deadlines start now
    assert drain(core, 100.01) == [(1, 1, False)]
    assert core.next_grant(100.0105) is None
    assert abs(core.wait_time(100.0105) - 0.0005) < 1e-12
    assert drain(core, 100.0111) == [(2, 2, True)]
    core.on_state(2, 100.011)
    assert drain(core, 100.0145) == [(3, 3, True)]  # 2.5 ms late
    stats = core.stats(100.015)
    assert core.late_ticks == 1
    assert stats["late_ticks"] == 1
    assert abs(stats["lateness_max_ms"] - 2.5) < 1e-6
    assert abs(stats["on_time_fraction"] - 3 / 4) < 1e-9


def test_realtime_with_a_lookahead_asks_for_a_report_only_at_the_edge() -> None:
    core = ClockCore(total_steps=10, dt=0.001, realtime=True, lookahead=3)
    core.resume(0.0)
    assert drain(core, 100.0) == [(0, 0, True)]
    core.on_state(1, 100.002)
    grants = [drain(core, 100.002 + 0.001 * k)[0] for k in range(4)]
    assert grants == [(1, 1, False), (2, 2, False), (3, 3, False), (4, 4, True)]  # 4 − 3 = state 1: report due
    assert drain(core, 100.007) == []  # nothing more until the sim reports
    core.on_state(4, 100.007)
    assert drain(core, 100.007) == [(5, 5, False), (6, 6, False)]  # both due by now
    assert drain(core, 100.008) == [(7, 7, True)]


def test_stats_rate_and_rtf() -> None:
    core = ClockCore(total_steps=1000, dt=0.001)
    core.resume(0.0)
    drain(core, 0.0)
    core.on_state(500, 0.25)
    stats = core.stats(0.25)
    assert stats["steps"] == 500
    assert abs(stats["rate"] - 2000.0) < 1e-9
    assert abs(stats["rtf"] - 2.0) < 1e-9
