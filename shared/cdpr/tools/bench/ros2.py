"""``cdpr bench``'s ROS 2 part: one session with a ROS 2 controller, the same with the cdpr controller.

Both are ``cdpr up SCENARIO --without controller`` and a controller in a process of its own connected to the
session's router: the cdpr controller (``cdpr controller``), or the ROS 2 controller of
:mod:`cdpr.tools.bench.ros2_controller` (written with zenoh-ros2-sdk, no cdpr import) behind ``--ros2`` (the
ros2 node in the sim's process, ``sim+ros2``). Runs alternate (cdpr, ROS 2, cdpr, …) so that both sample the
same minutes of a shared machine. The ROS 2 side's CPU per step is the ros2 node's plus the ROS 2
controller's, over the steady state (:class:`~cdpr.tools.bench.loops.SessionRun`); the node's is the
``sim+ros2`` process's less the sim's in the cdpr-controlled runs (an estimate: the two sims do not exchange
the same messages).
Needs the ``bench`` extra (zenoh-ros2-sdk, rosbags).
"""

from __future__ import annotations

import os
import signal
import statistics
import subprocess
import sys
import tempfile
import uuid
from importlib.util import find_spec
from pathlib import Path
from typing import Any

from cdpr.tools.bench.loops import SessionRun
from cdpr.tools.launch import free_port

TIMEOUT = 900.0
CONTROLLER = Path(__file__).with_name("ros2_controller.py")  # run by its path: no cdpr import


def bench_ros2(scenario: str, duration: float | None, rounds: int) -> dict[str, Any]:
    """The two sessions ``rounds`` times each (module docstring); rates, CPU per step and their ratio."""
    if find_spec("zenoh_ros2_sdk") is None:  # the ROS 2 controller's library (in its process: not imported here)
        return {"available": False, "reason": "zenoh_ros2_sdk is not installed (pip install 'cdpr[bench]')"}
    try:
        from cdpr.tools.bench.ros2_messages import make_cache
    except ImportError as exc:
        return {"available": False, "reason": f"{exc.name} is not installed (pip install 'cdpr[bench]')"}
    runs: dict[str, list[dict[str, Any]]] = {"cdpr": [], "ros2": []}
    with tempfile.TemporaryDirectory(prefix="cdpr-bench-ros2-") as tmp:
        (Path(tmp) / "gitconfig").write_text("")
        env = {**os.environ, "ZENOH_ROS2_SDK_CACHE": str(make_cache(Path(tmp) / "cache")),
               "GIT_CONFIG_GLOBAL": str(Path(tmp) / "gitconfig")}
        for _ in range(rounds):
            for kind in runs:
                runs[kind].append(_session(scenario, duration, kind, env, CONTROLLER))
    out: dict[str, Any] = {"available": True, "scenario": scenario, "steps": runs["cdpr"][0]["steps"],
                           "repeats": rounds}
    for kind, rs in runs.items():
        cpu = [r["cpu_us_per_step_by_process"] for r in rs if r["cpu_us_per_step_by_process"]]
        roles = {k for c in cpu for k in c}
        out[kind] = {
            "steps_per_s": statistics.median(r["rate"] for r in rs),
            "runs_steps_per_s": [r["rate"] for r in rs],
            "rms_position_error": statistics.median(r["rms_position_error"] for r in rs),
            "cpu_us_per_step_by_process": {k: statistics.median(c.get(k, 0.0) for c in cpu) for k in sorted(roles)},
        }
    by = out["ros2"]["cpu_us_per_step_by_process"]
    node = by["ros2"] if "ros2" in by else \
        by.get("sim+ros2", 0.0) - out["cdpr"]["cpu_us_per_step_by_process"].get("sim", 0.0)
    out["ros2"]["ros2_node_cpu_us_per_step"] = node
    out["ros2"]["ros2_side_cpu_us_per_step"] = node + by.get("ros2_controller", 0.0)
    out["ratio"] = out["ros2"]["steps_per_s"] / out["cdpr"]["steps_per_s"]
    return out


def _session(scenario: str, duration: float | None, kind: str, env: dict[str, str], controller: Path
             ) -> dict[str, Any]:
    port = free_port()
    endpoint = f"tcp/127.0.0.1:{port}"
    session = f"benchros2{kind}-{uuid.uuid4().hex[:6]}"
    timing = [] if duration is None else ["--duration", repr(duration)]
    # the topics under /cdpr, where the ROS 2 controller looks by default (the session id, with its "-", is no
    # ROS 2 name: the ros2 node's default namespace, /cdpr/<session>, cannot be made of it)
    ros2 = ["--ros2", "--ros-namespace", "/cdpr"] if kind == "ros2" else []
    args = [scenario, "--without", "controller", "--listen", endpoint, *timing, *ros2]
    run = SessionRun(args, session, command="up", env=env)
    if kind == "ros2":
        argv = [sys.executable, str(controller), "--router-port", str(port)]
    else:
        argv = [sys.executable, "-m", "cdpr", "controller", scenario, "--session", session, "--zenoh-mode", "client",
                "--connect", endpoint, *timing]
    ctl = subprocess.Popen(argv, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    run.also["ros2_controller" if kind == "ros2" else "controller"] = ctl.pid
    try:
        summary = run.result(TIMEOUT)
    finally:
        if ctl.poll() is None:
            ctl.send_signal(signal.SIGTERM)
        try:
            _, err = ctl.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            ctl.kill()
            _, err = ctl.communicate()
    if not summary.get("exit_ok"):
        raise RuntimeError(f"the {kind}-controlled session did not finish cleanly: {summary.get('exit_codes')}; "
                           f"its controller said: {err.strip()[-500:]}")
    return summary
