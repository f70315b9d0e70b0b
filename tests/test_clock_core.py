"""The clock's pure logic: which steps may be granted, windows, pausing, resending, realtime windows,
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


def test_realtime_grants_windows_after_the_handshake_and_counts_the_sims_lateness() -> None:
    core = ClockCore(total_steps=1000, dt=0.001, realtime=True, lookahead=1)
    assert core.lookahead == 250  # at least FREE_AHEAD (0.25 s) of steps ahead, whatever was asked
    core.resume(0.0)
    assert drain(core, 100.0) == [(0, 0, True)]  # tick 0 at once, then the handshake
    assert drain(core, 100.005) == []  # nothing before state 1
    core.on_state(1, 100.01)  # the loop's first step took 10 ms: the paced grant goes out now
    assert drain(core, 100.01) == [(1, 251, False)]  # one window, no report asked (the sim reports as it goes)
    core.on_state(51, 100.06)
    assert drain(core, 100.06) == [(252, 301, False)]
    # the sim keeps the wall clock and says how late each step started: 2 of 4 beyond dt
    core.on_lateness([0.0001, 0.0025, 0.0009, 0.0011], 100.06)
    stats = core.stats(100.06)
    assert stats["late_ticks"] == 2
    assert abs(stats["lateness_max_ms"] - 2.5) < 1e-6
    assert abs(stats["on_time_fraction"] - 2 / 4) < 1e-9
    assert core.late_share(100.06) == (0.5, 4)
    assert abs(stats["rtf"] - 0.050 / 0.050) < 1e-9  # from state 1: 50 steps of 1 ms in 50 ms
    assert core.behind(100.2) < 0.0 < core.behind(100.5)  # behind once unheard of beyond a block (0.25 s)


def test_stats_rate_and_rtf() -> None:
    core = ClockCore(total_steps=1000, dt=0.001)
    core.resume(0.0)
    drain(core, 0.0)
    core.on_state(500, 0.25)
    stats = core.stats(0.25)
    assert stats["steps"] == 500
    assert abs(stats["rate"] - 2000.0) < 1e-9
    assert abs(stats["rtf"] - 2.0) < 1e-9
