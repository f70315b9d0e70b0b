"""Run one point: one session of ``python -m cdpr run`` (or ``up`` + a separate controller), in a temp folder.

This is what a Ray task executes, on whichever node Ray chose: the point's YAML files travel with the
task (nothing is read from the driver's disk), the session gets a unique ``--session`` id and its own
loopback Zenoh network (``cdpr run`` hosts a private router), and the task returns the session's
summary, the node it ran on, and the recording's bytes when asked for.
"""

from __future__ import annotations

import contextlib
import functools
import json
import os
import signal
import socket
import subprocess
import sys
import tempfile
import time
import uuid
from pathlib import Path
from typing import Any

CDPR = [sys.executable, "-m", "cdpr"]
JOIN_TIMEOUT = 60.0  # a separate controller must join within this (split points)


@functools.cache
def in_process_available() -> bool:
    """Whether this installation's ``cdpr run`` has ``--in-process`` (all nodes in one process)."""
    proc = subprocess.run([*CDPR, "run", "--help"], capture_output=True, text=True, check=False, timeout=120)
    return "--in-process" in proc.stdout


def resolve_mode(mode: str) -> str:
    if mode == "auto":
        return "in-process" if in_process_available() else "multi-process"
    if mode == "in-process" and not in_process_available():
        from cdpr.errors import InputError

        raise InputError("mode: in-process: this installation's `cdpr run` has no --in-process")
    return mode


def node_identity() -> tuple[str, str]:
    """(Ray node id or '', host name) of the process running this."""
    node = ""
    with contextlib.suppress(Exception):
        import ray

        if ray.is_initialized():
            node = ray.get_runtime_context().get_node_id()
    return node, socket.gethostname()


def _free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def _stop(proc: subprocess.Popen[str]) -> None:
    """Stop a child we started (and its own children: it leads its process group)."""
    if proc.poll() is not None:
        return
    for sig, wait in ((signal.SIGTERM, 8.0), (signal.SIGKILL, 5.0)):
        with contextlib.suppress(ProcessLookupError):
            os.killpg(proc.pid, sig)
        with contextlib.suppress(subprocess.TimeoutExpired):
            proc.wait(wait)
            return


def _error_line(stderr: str, code: int | None) -> str:
    lines = [ln.strip() for ln in stderr.splitlines() if ln.strip()]
    interesting = [ln for ln in lines if "error" in ln.lower() or "Traceback" in ln or "stopping" in ln]
    last = (interesting or lines or [""])[-1]
    return f"exit code {code}: {last}"[:500] if last else f"exit code {code}"


def run_point(task: dict[str, Any]) -> dict[str, Any]:
    """Run one point. ``task``: id, files (name → YAML text), mode, split, record, timeout.

    Never raises for a failing session: the result says ``status: failed`` and why.
    """
    node, host = node_identity()
    started = time.monotonic()
    session = f"st-{task['id'][:16]}-{uuid.uuid4().hex[:8]}"
    result: dict[str, Any] = {"id": task["id"], "node": node, "host": host, "session": session}
    with tempfile.TemporaryDirectory(prefix="cdpr-point-") as tmp:
        folder = Path(tmp)
        for name, text in task["files"].items():
            (folder / name).write_text(text, encoding="utf-8")
        summary_file = folder / "summary.json"
        rrd = folder / "point.rrd"
        args = [str(folder / "scenario.yaml"), "--quiet", "--session", session, "--summary", str(summary_file)]
        if task.get("record"):
            args += ["--rrd", str(rrd)]
        procs: list[subprocess.Popen[str]] = []
        logs = [folder / "run.log", folder / "controller.log"]
        try:
            if task.get("split"):
                port = _free_port()
                endpoint = f"tcp/127.0.0.1:{port}"
                up = [*CDPR, "up", *args, "--without", "controller", "--listen", endpoint,
                      "--join-timeout", repr(JOIN_TIMEOUT)]
                ctl = [*CDPR, "controller", str(folder / "controller.yaml"), "--session", session,
                       "--zenoh-mode", "client", "--connect", endpoint]
                commands = [up, ctl]
            else:
                commands = [[*CDPR, "run", *args, *(["--in-process"] if task["mode"] == "in-process" else [])]]
            for cmd, log_file in zip(commands, logs, strict=False):
                with open(log_file, "w", encoding="utf-8") as out:
                    procs.append(subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=out, text=True,
                                                  cwd=tmp, start_new_session=True))
            deadline = started + float(task.get("timeout", 900.0))
            codes: list[int | None] = []
            for proc in procs:
                try:
                    codes.append(proc.wait(max(0.1, deadline - time.monotonic())))
                except subprocess.TimeoutExpired:
                    codes.append(None)
                    break
        finally:
            for proc in procs:
                _stop(proc)
        stderr = logs[0].read_text(encoding="utf-8", errors="replace") if logs[0].exists() else ""
        summary: dict[str, Any] = {}
        if summary_file.is_file():
            with contextlib.suppress(ValueError):
                summary = json.loads(summary_file.read_text(encoding="utf-8"))
        result["summary"] = summary
        if None in codes:
            result.update(status="failed", error=f"timed out after {task.get('timeout')} s")
        elif codes and codes[0] == 0 and summary.get("exit_ok"):
            result.update(status="ok", error=None)
        else:
            result.update(status="failed", error=_error_line(stderr, codes[0] if codes else None))
        if len(codes) > 1 and codes[1] not in (0, None) and result["status"] == "ok":
            result.update(status="failed", error=f"controller exited with code {codes[1]}")
        if task.get("record") and rrd.is_file():
            result["rrd_bytes"] = rrd.read_bytes()
        result["stderr_tail"] = stderr[-2000:]
    result["wall_s"] = time.monotonic() - started
    return result
