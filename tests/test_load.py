"""Lock-step results do not depend on the machine's load: a session beside a CPU burner on both cores gives the
state stream of a quiet run, bit for bit (its digest), whoever the controller is — the built-in one, the SDK
example, the plain Zenoh example, a ROS 2 controller written with zenoh-ros2-sdk (stamped, unstamped, and
unstamped with a slow start that makes the session repeat state 0), and a Gymnasium environment in session mode.

Load slows every process, so the handshake's repeats, resends and the order in which Zenoh's threads deliver
change from run to run; what a participant computes must not. The burners are plain busy loops at normal
priority, one per core, for the loaded runs only.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
from collections.abc import Iterator
from pathlib import Path

import pytest

from cdpr.ros2.topics import default_namespace
from cdpr.tools.bench import ros2_controller
from conftest import CDPR, ROOT, free_port, last_json_line
from test_compose import Processes

EXAMPLES = ROOT / "examples"
DURATION = "0.3"  # 300 steps: the handshake, the first telemetry blocks and the setpoints' first blocks
TIMEOUT = 300.0  # a bound on a session under load (never a measurement)

# kind -> the reference (the quiet run whose digest a loaded run must give) and how it is run
KINDS = {
    "built-in": "built-in",
    "gym-session": "built-in",  # the zero residual is the scenario's own law: the built-in controller's states
    "sdk": "sdk",
    "plain-zenoh": "plain-zenoh",
    "ros2-stamped": "ros2-stamped",
    "ros2-unstamped": "ros2-stamped",  # the same law; each command bound to its own state
    "ros2-unstamped-slow-start": "ros2-stamped",
}


def run_session(kind: str, session: str, tmp: Path, env: dict[str, str]) -> dict:
    """One ``caroca_15kg`` session of DURATION with the controller ``kind``: its summary."""
    tmp.mkdir(parents=True, exist_ok=True)
    common = ["--duration", DURATION, "--session", session, "--quiet"]
    if kind in ("built-in", "gym-session"):
        policy = ["--policy", "cdpr.gym.policy:zero"] if kind == "gym-session" else []
        proc = subprocess.run([*CDPR, "run", "caroca_15kg", *common, *policy], capture_output=True, text=True,
                              timeout=TIMEOUT, check=False)
        assert proc.returncode == 0, proc.stderr[-3000:]
        return last_json_line(proc.stdout)
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    ros2 = kind.startswith("ros2")
    if kind == "sdk":
        controller = [sys.executable, str(EXAMPLES / "remote_controller.py"), "--connect", endpoint, "--session",
                      session]
    elif kind == "plain-zenoh":
        controller = [sys.executable, str(EXAMPLES / "plain_zenoh_controller.py"), "--connect", endpoint,
                      "--session", session]
    else:
        controller = [sys.executable, ros2_controller.__file__, "--router-port", str(port), "--namespace",
                      default_namespace(session)]
        controller += ["--unstamped"] if "unstamped" in kind else []
        controller += ["--slow-start", "1.5"] if "slow-start" in kind else []
    procs = Processes()
    try:
        procs.start("up", [*CDPR, "up", "caroca_15kg", *common, "--without", "controller", "--listen", endpoint,
                           "--join-timeout", "120", *(["--ros2"] if ros2 else [])], tmp, tmp / "up.log", env=env)
        ctl = procs.start("controller", controller, tmp, tmp / "controller.log", env=env)
        codes = procs.wait(["up"], timeout=TIMEOUT)
        assert codes == {"up": 0}, procs.report()
        if ros2:  # a ROS 2 node runs until it is stopped
            ctl.send_signal(signal.SIGTERM)
        assert procs.wait(["controller"], timeout=60) == {"controller": 0}, procs.report()
    finally:
        procs.close()
    return last_json_line(procs.log("up"))


@pytest.fixture(scope="module")
def quiet(tmp_path_factory: pytest.TempPathFactory, sdk_env: dict[str, str]) -> dict[str, dict]:
    """The reference runs, each kind of law once, before any burner runs."""
    tmp = tmp_path_factory.mktemp("quiet")
    return {kind: run_session(kind, f"q{os.getpid()}{i}", tmp / kind, sdk_env)
            for i, kind in enumerate(sorted(set(KINDS.values())))}


@pytest.fixture
def burners() -> Iterator[list[subprocess.Popen[bytes]]]:
    """A plain busy loop at normal priority on each core, for the length of the test."""
    procs = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(os.cpu_count() or 2)]
    try:
        yield procs
    finally:
        for p in procs:
            p.kill()
            p.wait()


@pytest.mark.slow
@pytest.mark.parametrize("kind", list(KINDS))
def test_a_loaded_machine_gives_the_quiet_runs_states(kind: str, quiet: dict[str, dict], burners: list,
                                                      sdk_env: dict[str, str], session_id: str,
                                                      tmp_path: Path) -> None:
    reference = quiet[KINDS[kind]]
    s = run_session(kind, session_id, tmp_path, sdk_env)
    assert all(p.poll() is None for p in burners)  # the load was there all along
    assert s["exit_ok"], s
    assert s["steps"] == s["total_steps"] == reference["steps"] == 300
    assert s["state_digest"] == reference["state_digest"], (kind, s["faults"], s.get("stats"))
    # a ROS 2 controller's repeated answers, if any, were recognised as such and dropped, never applied
    assert set(s["faults"].get("ros2", {})) <= {"unmatched_ros2_commands", "repeated_ros2_commands"}, s["faults"]
