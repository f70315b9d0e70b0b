"""How `cdpr run` starts its services: forked from the launcher (the default), or each a new
interpreter (``CDPR_START_METHOD=spawn``); either way the same processes, names and states."""

from __future__ import annotations

import os
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import pytest

from conftest import CDPR, last_json_line, processes_mentioning

LOOP = {"clock", "sim", "trajectory", "controller"}


def _while_running(args: list[str], look: Callable[[], bool], env: dict[str, str] | None = None,
                   every: float = 0.05, command: str = "run") -> tuple[str, int]:
    """Run ``cdpr COMMAND ARGS``, calling ``look`` every ``every`` s while it runs until it returns True (at most
    2 000 times); the summary line's stdout and the launcher's pid, once it has exited 0."""
    run = subprocess.Popen([*CDPR, command, *args], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                           env=env)
    try:
        for _ in range(2000):
            if run.poll() is not None or look():
                break
            time.sleep(every)
        out, err = run.communicate(timeout=120)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    assert run.returncode == 0, err
    return out, run.pid


def _run_and_look(session_id: str, method: str) -> tuple[dict, dict[str, tuple[str, str, int]], int]:
    """A 3 s session; while it runs, each service's (comm, command line, parent pid)."""
    env = dict(os.environ, CDPR_START_METHOD=method)
    seen: dict[str, tuple[str, str, int]] = {}

    def look() -> bool:
        for pid in processes_mentioning(f"--session {session_id}"):
            try:
                cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode().split()
                comm = Path(f"/proc/{pid}/comm").read_text().strip()
                ppid = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError):
                continue
            if "cdpr.runtime" in cmdline:
                seen[cmdline[cmdline.index("cdpr.runtime") + 1]] = (comm, " ".join(cmdline), ppid)
        return set(seen) == LOOP

    out, pid = _while_running(["caroca_15kg", "--duration", "3", "--session", session_id], look, env)
    return last_json_line(out), seen, pid


def test_forked_and_spawned_services_are_the_same_processes_with_the_same_states(session_id: str) -> None:
    forked, fork_seen, fork_launcher = _run_and_look(session_id + "f", "fork")
    spawned, spawn_seen, spawn_launcher = _run_and_look(session_id + "s", "spawn")
    assert set(fork_seen) == set(spawn_seen) == LOOP
    for name in LOOP:
        comm, cmdline, ppid = fork_seen[name]
        assert comm == f"cdpr-{name}"[:15]  # what top shows
        assert f"-m cdpr.runtime {name} " in cmdline
        assert "--zenoh-mode peer" in cmdline
        assert ppid == fork_launcher
        comm, cmdline, ppid = spawn_seen[name]
        assert comm.startswith("python")  # a new interpreter
        assert f"-m cdpr.runtime {name} " in cmdline
        assert ppid == spawn_launcher
    assert forked["exit_ok"]
    assert spawned["exit_ok"]
    assert forked["steps"] == spawned["steps"] == 3000
    assert forked["state_digest"] == spawned["state_digest"]


def test_the_ros2_node_runs_in_the_sim_s_process_unless_the_sim_is_elsewhere() -> None:
    from cdpr.config.scenario import load_scenario
    from cdpr.tools.launch import RunOptions, node_argv

    sc = load_scenario("caroca_15kg")
    argv = node_argv(sc, RunOptions(ros2=True, without=("controller",)), "tcp/127.0.0.1:7447")
    assert set(argv) == {"clock", "trajectory", "sim+ros2"}
    assert "--observe" not in argv["sim+ros2"]  # the controller's role
    assert "--ros-namespace" not in argv["sim+ros2"]  # the node's own default, from the session id
    named = node_argv(sc, RunOptions(ros2=True, without=("controller",), ros_namespace="/lab"), "tcp/127.0.0.1:7447")
    assert named["sim+ros2"][-2:] == ["--ros-namespace", "/lab"]
    assert node_argv(sc, RunOptions(ros2=True), "tcp/127.0.0.1:7447")["sim+ros2"][-1] == "--observe"
    alone = node_argv(sc, RunOptions(ros2=True, without=("controller", "sim")), "tcp/127.0.0.1:7447")
    assert set(alone) == {"clock", "trajectory", "ros2"}
    # a participant besides the controller elsewhere: the services are clients of the router, the node a peer
    clients = node_argv(sc, RunOptions(ros2=True, without=("controller", "trajectory")), "tcp/127.0.0.1:7447")
    assert set(clients) == {"clock", "sim", "ros2"}
    assert "--zenoh-mode client" in " ".join(clients["sim"])
    assert "--zenoh-mode peer" in " ".join(clients["ros2"])


def test_a_spawned_sim_and_ros2_node_share_a_process(session_id: str) -> None:
    """``python -m cdpr.runtime sim+ros2``: the composition as a new interpreter (CDPR_START_METHOD=spawn); the
    launcher's processes are the summary's exit codes, and the sim in sim+ros2 ran every step."""
    out, _ = _while_running(["caroca_15kg", "--duration", "1", "--ros2", "--quiet", "--session", session_id],
                            lambda: False, dict(os.environ, CDPR_START_METHOD="spawn"), command="up")
    s = last_json_line(out)
    assert s["exit_codes"] == {"clock": 0, "sim+ros2": 0, "trajectory": 0, "controller": 0}
    assert s["steps"] == 1000


@pytest.mark.parametrize(("name", "says"), [("sim+sim", "'sim+sim': a node named twice"),
                                            ("sim+nope", "no node called 'nope' is registered")])
def test_a_bad_composition_is_refused_in_one_line(name: str, says: str) -> None:
    proc = subprocess.run([sys.executable, "-m", "cdpr.runtime", name, "caroca_15kg"], capture_output=True, text=True,
                          timeout=60)
    assert proc.returncode == 2
    assert proc.stderr.startswith(f"cdpr: error: {says}")
    assert len(proc.stderr.strip().splitlines()) == 1


def test_an_unknown_start_method_is_refused_in_one_line() -> None:
    proc = subprocess.run([*CDPR, "run", "caroca_15kg", "--duration", "0.01"], capture_output=True, text=True,
                          timeout=60, env=dict(os.environ, CDPR_START_METHOD="forkserver"))
    assert proc.returncode == 2
    assert proc.stderr.strip() == "cdpr: error: $CDPR_START_METHOD: fork or spawn, got 'forkserver'"


def _cpu_latency_limit() -> int:
    """The system-wide PM QoS CPU latency limit now (µs): what /dev/cpu_dma_latency reads."""
    return int.from_bytes(Path("/dev/cpu_dma_latency").read_bytes()[:4], "little", signed=True)


@pytest.mark.skipif(not os.access("/dev/cpu_dma_latency", os.W_OK), reason="needs write access to /dev/cpu_dma_latency")
def test_cpu_latency_holds_the_limit_while_the_session_runs_and_not_after(session_id: str) -> None:
    before = _cpu_latency_limit()
    seen: list[int] = []

    def look() -> bool:
        seen.append(_cpu_latency_limit())
        return seen[-1] == 0

    out, _ = _while_running(["caroca_15kg", "--duration", "2", "--mode", "realtime", "--cpu-latency", "0", "--quiet",
                             "--session", session_id], look, every=0.005)
    assert 0 in seen  # held while the session ran
    assert last_json_line(out)["steps"] == 2000
    assert _cpu_latency_limit() == before  # and let go with the process


def test_cpu_latency_without_access_says_what_it_needs(monkeypatch: pytest.MonkeyPatch) -> None:
    from cdpr.errors import InputError
    from cdpr.runtime import service

    def refuse(path: str, flags: int) -> int:
        raise PermissionError(13, "Permission denied", path)

    monkeypatch.setattr(service.os, "open", refuse)
    with pytest.raises(InputError, match=r"--cpu-latency: cannot open /dev/cpu_dma_latency \(Permission denied\): "
                                         r"it needs root or write access to the device"):
        service.hold_cpu_latency(0)
    with pytest.raises(InputError, match="--cpu-latency: must be 0 or more microseconds"):
        service.hold_cpu_latency(-1)


def test_the_monitor_waits_for_the_sims_last_telemetry_and_says_when_it_never_comes(
        capsys: pytest.CaptureFixture[str]) -> None:
    """A child's exit does not mean the launcher's router has handled what the child sent: the summary waits
    for the telemetry of the clock's last step (CI, 2026-11-28: a 400-step run summarised as 201 steps)."""
    import threading

    from cdpr.protocol import State, Telemetry
    from cdpr.tools.launch import Tape

    pose = (0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0)

    def block(first: int, last: int) -> bytes:
        return Telemetry(tuple(State(k, k / 1000, pose, (0.0,) * 6, (1.0,) * 4, (0.0,) * 4)
                               for k in range(first, last + 1))).encode()

    tape = Tape()
    tape.items += [("telemetry", block(0, 49)), ("setpoints", b"\x80")]
    assert tape.reached(4) == 49
    rest = [("telemetry", block(50, 99)), ("telemetry", block(100, 100))]
    late = threading.Timer(0.3, lambda: tape.items.extend(rest))
    late.start()
    assert tape.await_step(100, 4, timeout=60.0)  # returns once the last block is in, not after the timeout
    late.join()
    assert tape.reached(4) == 100
    assert not tape.await_step(101, 4, timeout=0.05)  # never comes: said, not waited for forever
    assert "telemetry came up to step 100 of 101" in capsys.readouterr().err
