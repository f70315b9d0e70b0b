"""The session's first step is a handshake: a tick 0 that went unheard is repeated within a tenth of a
second (not after the 1 s stall period), and nothing beyond step 0 is granted before state 1.

The clock runs alone as a process; the sim is this test's own Zenoh session on loopback, which takes
no notice of the first tick 0 (as a peer that has just joined may not know of the clock's publisher yet).
"""

from __future__ import annotations

import queue
import signal
import subprocess
import sys
import time

import zenoh

from cdpr.protocol import Keys, State, Status, Telemetry, Tick
from cdpr.runtime.transport import zenoh_config
from conftest import free_port

M = 8  # caroca_1kg's cables


def state(step: int) -> State:
    return State(step, step * 0.001, (0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0), (0.0,) * 6, (1.0,) * M, (0.0,) * M)


def test_an_unheard_tick_0_is_repeated_at_once_and_nothing_runs_ahead_of_state_1(session_id: str) -> None:
    port = free_port()
    keys = Keys(session_id)
    clk = subprocess.Popen(
        [sys.executable, "-m", "cdpr_clock", "caroca_1kg", "--session", session_id, "--expect", "sim",
         "--zenoh-mode", "peer", "--listen", f"tcp/127.0.0.1:{port}"],
        stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True,
    )
    ticks: queue.SimpleQueue[tuple[float, Tick]] = queue.SimpleQueue()
    try:
        with zenoh.open(zenoh_config("peer", connect=[f"tcp/127.0.0.1:{port}"])) as z:
            sub = z.declare_subscriber(
                keys.tick, lambda s: ticks.put((time.monotonic(), Tick.decode(s.payload.to_bytes()))))
            statuses: queue.SimpleQueue[Status] = queue.SimpleQueue()
            status_sub = z.declare_subscriber(keys.status, lambda s: statuses.put(Status.decode(s.payload.to_bytes())))
            telemetry = z.declare_publisher(keys.telemetry)
            token = z.liveliness().declare_token(keys.alive("sim"))
            _, first = ticks.get(timeout=30)  # not answered
            assert (first.step, first.until, first.flush, first.resend) == (0, 0, True, False)
            _, again = ticks.get(timeout=5)
            assert (again.step, again.until, again.resend) == (0, 0, True)
            # The clock counts it as a handshake repeat (after 50 ms), not as a stall's resend (after 1 s).
            counted = statuses.get(timeout=30).stats
            while counted["handshake_repeats"] == 0:
                counted = statuses.get(timeout=30).stats
            assert counted["resends"] == 0, counted
            with_1 = Telemetry((state(0), state(1)))
            telemetry.put(with_1.encode())
            _, grant = ticks.get(timeout=5)
            while grant.resend:  # a repeat already on its way when state 1 was sent
                _, grant = ticks.get(timeout=5)
            assert (grant.step, grant.resend) == (1, False)  # the windows begin
            token.undeclare()
            status_sub.undeclare()
            sub.undeclare()
            telemetry.undeclare()
        clk.send_signal(signal.SIGTERM)
        try:
            _, err = clk.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            clk.send_signal(signal.SIGUSR1)  # every thread's stack (faulthandler), for the report
            time.sleep(1.0)
            clk.kill()
            _, err = clk.communicate()
            raise AssertionError(f"the clock ignored SIGTERM for 30 s:\n{err}") from None
    finally:
        if clk.poll() is None:
            clk.kill()
            clk.wait()
    assert "no progress" not in err, err  # the handshake's repeats are not stalls
