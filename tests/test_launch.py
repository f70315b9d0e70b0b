"""How `cdpr run` starts its services: forked from the launcher (the default), or each a new
interpreter (``CDPR_START_METHOD=spawn``); either way the same processes, names and states."""

from __future__ import annotations

import os
import subprocess
import time
from pathlib import Path

from conftest import CDPR, last_json_line, processes_mentioning

LOOP = {"clock", "sim", "trajectory", "controller"}


def _run_and_look(session_id: str, method: str) -> tuple[dict, dict[str, tuple[str, str, int]], int]:
    """A 3 s session; while it runs, each service's (comm, command line, parent pid)."""
    env = dict(os.environ, CDPR_START_METHOD=method)
    run = subprocess.Popen([*CDPR, "run", "caroca_15kg", "--duration", "3", "--session", session_id],
                           stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env)
    seen: dict[str, tuple[str, str, int]] = {}
    try:
        deadline = time.monotonic() + 60
        while set(seen) != LOOP and time.monotonic() < deadline and run.poll() is None:
            for pid in processes_mentioning(f"--session {session_id}"):
                try:
                    cmdline = Path(f"/proc/{pid}/cmdline").read_bytes().replace(b"\0", b" ").decode().split()
                    comm = Path(f"/proc/{pid}/comm").read_text().strip()
                    ppid = int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[1])
                except (OSError, ValueError):
                    continue
                if "cdpr.runtime" in cmdline:
                    seen[cmdline[cmdline.index("cdpr.runtime") + 1]] = (comm, " ".join(cmdline), ppid)
            time.sleep(0.05)
        out, err = run.communicate(timeout=120)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    assert run.returncode == 0, err
    return last_json_line(out), seen, run.pid


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


def test_an_unknown_start_method_is_refused_in_one_line() -> None:
    proc = subprocess.run([*CDPR, "run", "caroca_15kg", "--duration", "0.01"], capture_output=True, text=True,
                          timeout=60, env=dict(os.environ, CDPR_START_METHOD="forkserver"))
    assert proc.returncode == 2
    assert proc.stderr.strip() == "cdpr: error: $CDPR_START_METHOD: fork or spawn, got 'forkserver'"
