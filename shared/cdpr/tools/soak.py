"""`cdpr soak`: run sessions over and over while killing the controller and spraying bad payloads.

Each round starts ``cdpr up SCENARIO --without controller`` on a private loopback endpoint, a watcher
(a Zenoh client recording every ``sim/state``), and a controller that is killed with SIGKILL and
replaced at random moments; random garbage is published on the command key meanwhile. A round passes
when the session finishes, every step 0…N was published, and every re-published state is
byte-identical to the first (no step lost, none integrated twice). The report counts all of it.
"""

from __future__ import annotations

import contextlib
import json
import random
import signal
import subprocess
import sys
import time
from collections import defaultdict
from typing import Any

import zenoh

from cdpr.config.scenario import load_scenario
from cdpr.protocol import Keys, ProtocolError, State, Status
from cdpr.runtime.transport import StopFlag, log, zenoh_config
from cdpr.tools.launch import free_port


class SessionWatcher:
    """A Zenoh client that records every sim/state payload by step and the latest clock/status."""

    def __init__(self, session: zenoh.Session, keys: Keys) -> None:
        self.states: dict[int, list[bytes]] = defaultdict(list)
        self.status: Status | None = None
        self._subs = [
            session.declare_subscriber(keys.state, self._on_state),
            session.declare_subscriber(keys.status, self._on_status),
        ]

    def _on_state(self, sample: zenoh.Sample) -> None:
        payload = sample.payload.to_bytes()
        with contextlib.suppress(ProtocolError):
            self.states[State.decode(payload).step].append(payload)

    def _on_status(self, sample: zenoh.Sample) -> None:
        with contextlib.suppress(ProtocolError):
            self.status = Status.decode(sample.payload.to_bytes())

    @property
    def state(self) -> str:
        return self.status.state if self.status is not None else "none"

    def check(self, total_steps: int) -> tuple[list[int], list[int]]:
        """(lost steps, steps published with different contents)."""
        lost = [k for k in range(total_steps + 1) if k not in self.states]
        doubled = [k for k, p in self.states.items() if len(set(p)) > 1]
        return lost, doubled


def _cdpr(*args: str, **kw: Any) -> subprocess.Popen[bytes]:
    return subprocess.Popen([sys.executable, "-m", "cdpr", *args], **kw)


def soak(scenario: str, minutes: float, duration: float, seed: int, stop: StopFlag) -> dict[str, Any]:
    rng = random.Random(seed)
    report: dict[str, Any] = {"scenario": scenario, "seed": seed, "rounds": 0, "rounds_ok": 0, "steps": 0,
                              "controller_kills": 0, "controller_restarts": 0, "noise_payloads": 0,
                              "lost_steps": 0, "doubled_steps": 0, "failures": []}
    end = time.monotonic() + minutes * 60.0
    total_steps = load_scenario(scenario, {"duration": duration}).total_steps
    while time.monotonic() < end and not stop:
        rnd = report["rounds"]
        report["rounds"] += 1
        session = f"soak{seed}x{rnd}"
        endpoint = f"tcp/127.0.0.1:{free_port()}"
        common = [scenario, "--duration", repr(duration), "--session", session]
        quiet = {"stdout": subprocess.DEVNULL, "stderr": subprocess.DEVNULL}
        up = _cdpr("up", *common, "--without", "controller", "--listen", endpoint, "--quiet", **quiet)
        ctrl_args = ["controller", *common, "--zenoh-mode", "client", "--connect", endpoint]
        procs = [up]
        try:
            with zenoh.open(zenoh_config("client", connect=[endpoint])) as z:
                watch = SessionWatcher(z, Keys(session))
                ctrl = _cdpr(*ctrl_args, **quiet)
                procs.append(ctrl)
                kills = rng.randint(1, 3)
                deadline = time.monotonic() + 120.0
                while watch.state not in ("finished", "aborted") and time.monotonic() < deadline and not stop:
                    time.sleep(rng.uniform(0.2, 1.5))
                    if kills and watch.state == "running" and ctrl.poll() is None:
                        ctrl.send_signal(signal.SIGKILL)
                        ctrl.wait()
                        kills -= 1
                        report["controller_kills"] += 1
                        time.sleep(rng.uniform(0.0, 1.0))
                        ctrl = _cdpr(*ctrl_args, **quiet)
                        procs.append(ctrl)
                        report["controller_restarts"] += 1
                    for _ in range(rng.randint(0, 20)):
                        z.put(Keys(session).command, rng.randbytes(rng.randint(0, 40)))
                        report["noise_payloads"] += 1
                up.wait(timeout=30)
                ok_state = watch.state
                lost, doubled = watch.check(total_steps)
        except Exception as exc:  # a round that breaks is a finding, not a reason to stop soaking
            report["failures"].append(f"round {rnd}: {type(exc).__name__}: {exc}")
            continue
        finally:
            for p in procs:
                if p.poll() is None:
                    p.send_signal(signal.SIGTERM)
            for p in procs:
                try:
                    p.wait(timeout=10)
                except subprocess.TimeoutExpired:
                    p.kill()
        report["steps"] += max(watch.states, default=0)
        report["lost_steps"] += len(lost)
        report["doubled_steps"] += len(doubled)
        if ok_state == "finished" and not lost and not doubled and up.returncode == 0:
            report["rounds_ok"] += 1
        else:
            report["failures"].append(
                f"round {rnd}: state {ok_state}, up exit {up.returncode}, lost {lost[:5]}, doubled {doubled[:5]}"
            )
        log("soak", f"round {rnd}: {ok_state}, {report['steps']} steps so far, "
            f"{report['controller_kills']} kills, {len(report['failures'])} failures")
    return report


def run_soak(scenario: str, minutes: float, duration: float, seed: int) -> int:
    stop = StopFlag().install()
    report = soak(scenario, minutes, duration, seed, stop)
    print(json.dumps(report), flush=True)
    return 0 if not report["failures"] and report["rounds_ok"] > 0 else 1
