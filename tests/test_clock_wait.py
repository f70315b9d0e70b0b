"""The clock before the start: it says who it is waiting for, and gives up after ``--join-timeout``.

The clock runs alone as a process (a Zenoh peer listening on a free loopback port); a participant, when
there is one, is a real trajectory process connected to it.
"""

from __future__ import annotations

import re
import signal
import subprocess
import sys
import time

import pytest

from conftest import free_port

PY = sys.executable


def clock(session_id: str, port: int, *args: str) -> subprocess.Popen[str]:
    return subprocess.Popen(
        [PY, "-m", "cdpr_clock", "caroca_1kg", "--session", session_id, "--zenoh-mode", "peer",
         "--listen", f"tcp/127.0.0.1:{port}", *args],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )


def waiting_lines(stderr: str) -> list[tuple[str, int]]:
    """The clock's "waiting for X, Y to join session 's' (N s)" lines, as (missing, N)."""
    return [(m.group(1), int(m.group(2)))
            for m in re.finditer(r"^\[clock\] waiting for (.+) to join session '\w+' \((\d+) s\)$", stderr, re.M)]


def test_join_timeout_aborts_naming_the_missing_participant(session_id: str) -> None:
    port = free_port()
    started = time.monotonic()
    clk = clock(session_id, port, "--expect", "sim,trajectory", "--join-timeout", "7.5")
    traj = subprocess.Popen(
        [PY, "-m", "cdpr_trajectory", "caroca_1kg", "--session", session_id, "--zenoh-mode", "peer",
         "--connect", f"tcp/127.0.0.1:{port}"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )
    try:
        _, err = clk.communicate(timeout=60)
        elapsed = time.monotonic() - started
        _, traj_err = traj.communicate(timeout=30)
    finally:
        for p in (clk, traj):
            if p.poll() is None:
                p.kill()
                p.wait()
    assert clk.returncode == 1, err
    # From the start, every few seconds: at 2 s (the trajectory may still be starting), then at 7 s. Each line
    # gives the seconds waited, rounded, when the clock's idle turn came: a busy machine can make it late by a
    # second; and a 7 s line more than 0.5 s late is overtaken by the abort at 7.5 s.
    lines = waiting_lines(err)
    assert 1 <= len(lines) <= 2, err
    assert lines[0][1] in (2, 3), err
    assert lines[0][0] in ("sim, trajectory", "sim"), err
    if len(lines) == 2:
        assert lines[1] in (("sim", 7), ("sim", 8)), err
    # the token it did not see, and that the router's access rules may deny it (docs/security.md)
    reason = (f"sim did not join session '{session_id}' within 7.5 s (joined: trajectory; nothing came on "
              f"cdpr/{session_id}/alive/sim; if the router enforces access rules (the secure profile), they may deny "
              "it: `cdpr router --log-denials` logs each denial (docs/security.md))")
    assert err.strip().splitlines()[-1] == f"[clock] aborted: {reason}", err
    assert 7.5 < elapsed < 7.5 + 15, elapsed  # start-up, the timeout, at most LINGER s for the trajectory
    # The participant that came learns why the session ended, and stops.
    assert f"session aborted by the clock: {reason}" in traj_err, traj_err


def test_without_a_timeout_the_clock_keeps_waiting(session_id: str) -> None:
    clk = clock(session_id, free_port(), "--expect", "sim")
    assert clk.stderr is not None
    seen: list[str] = []
    try:
        deadline = time.monotonic() + 60
        while not waiting_lines("".join(seen)) and time.monotonic() < deadline:
            line = clk.stderr.readline()
            if not line:
                break
            seen.append(line)
        still_running = clk.poll() is None
        clk.send_signal(signal.SIGTERM)
        _, rest = clk.communicate(timeout=30)
    finally:
        if clk.poll() is None:
            clk.kill()
            clk.wait()
    err = "".join(seen) + rest
    assert still_running, err
    # the first line 2 s after the start (its turn may come a second late); no abort by default
    assert waiting_lines(err) in ([("sim", 2)], [("sim", 3)]), err
    assert "aborted" not in err
    assert clk.returncode == 128 + signal.SIGTERM


@pytest.mark.parametrize("flag", ["--join-timeout", "--rejoin-timeout"])
def test_join_timeouts_must_not_be_negative(flag: str) -> None:
    proc = subprocess.run([PY, "-m", "cdpr_clock", "caroca_1kg", flag, "-1"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.strip() == f"cdpr: error: {flag}: must be 0 (no limit) or a number of seconds, got -1.0"
