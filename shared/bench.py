"""`cdpr bench`: where the lock-step loop's time goes, every figure measured side by side in one run.

One invocation measures, one after the other on the same machine (so that their ratios hold even
when the machine is shared and its absolute speed drifts):

1. ``monolithic``: the services' per-step work in one process, without messaging — DART step
   (:class:`cdpr_sim.core.PlatformSim`), controller core (feedback linearisation + tension
   distribution), trajectory setpoint and the encoding/decoding of the four messages of a step: the
   ceiling of the distributed loop;
2. ``distributed``: ``cdpr run SCENARIO`` (fast mode) as a subprocess: steps/s, RTF, its ratio to (1),
   and the CPU each process spends per step;
3. ``zenoh_rtt``: a raw Zenoh round trip with the project's settings — two processes on loopback,
   each answering in its :class:`cdpr.transport.Inbox` callback, ``PUBLISH_OPTS``; as clients of a
   router (how remote participants talk) and as peers linked directly (how ``cdpr run``'s services
   talk): the floor of one hop;
4. ``realtime``: ``cdpr run SCENARIO --mode realtime --duration D``: the share of ticks issued within
   1 ms of their deadline and the lateness percentiles;
5. ``tda``: the tension distribution's solve time per method for 4, 8, 12 and 16 cables, along a
   smooth path (as in the loop: warm), on random well-conditioned robots built here;
6. ``scaling``: steps/s and CPU per step with 1, 2, 4, 8 concurrent sessions, and with 4 → 16 cables
   (generated robot and scenario files in a temporary directory).

Medians over repeats; ``--quick`` runs every part, shorter, in under two minutes. Results are printed
as a table and written as JSON. The Linux ``/proc`` file system gives the per-process CPU figures
(elsewhere they are left out).
"""

from __future__ import annotations

import json
import math
import os
import platform
import re
import statistics
import struct
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from collections.abc import Callable, Sequence
from dataclasses import asdict, dataclass
from pathlib import Path
from typing import IO, Any

import numpy as np
import yaml

from cdpr.kinematics import cable_kinematics
from cdpr.protocol import Command, Setpoint, State, Tick
from cdpr.robot import GRAVITY, Robot, RobotSpec, robot_from_spec
from cdpr.rotation import rpy_to_matrix
from cdpr.scenario import Scenario, load_scenario
from cdpr.tda import METHODS, make_tda

BENCH_VERSION = 1


@dataclass(frozen=True)
class BenchPlan:
    """How much of each part to run."""

    mono_steps: int  # steps of the monolithic loop (capped at the scenario's)
    mono_repeats: int
    loop_duration: float | None  # sim seconds of the distributed run (None: the whole scenario)
    loop_repeats: int
    rtt_count: int  # timed round trips
    realtime_duration: float  # sim seconds in realtime mode
    tda_sizes: tuple[int, ...]
    tda_calls: int  # solves per method and size
    session_counts: tuple[int, ...]
    session_duration: float
    cable_counts: tuple[int, ...]
    cable_duration: float


FULL = BenchPlan(
    mono_steps=11000, mono_repeats=3, loop_duration=None, loop_repeats=3, rtt_count=20000,
    realtime_duration=60.0, tda_sizes=(4, 8, 12, 16), tda_calls=3000,
    session_counts=(1, 2, 4, 8), session_duration=6.0, cable_counts=(4, 8, 12, 16), cable_duration=6.0,
)
QUICK = BenchPlan(
    mono_steps=2000, mono_repeats=3, loop_duration=4.0, loop_repeats=1, rtt_count=2000,
    realtime_duration=3.0, tda_sizes=(4, 8, 16), tda_calls=400,
    session_counts=(1, 2, 4), session_duration=3.0, cable_counts=(4, 16), cable_duration=3.0,
)


def _log(message: str) -> None:
    sys.stderr.write(f"[bench] {message}\n")
    sys.stderr.flush()


# --------------------------------------------------------------------------------------------------
# 1. The monolithic loop


def monolithic_steps(scenario: Scenario, steps: int, timers: dict[str, float] | None = None) -> float:
    """Run ``steps`` steps of the loop in this process; returns the wall time (s).

    Per step, exactly the work of the services minus the messaging: the clock's tick (encoded, decoded
    by the sim and the trajectory), the trajectory's setpoint, the sim's state (decoded by the clock and
    the controller), the controller's step and command, the sim's decoding of it and its DART step.
    With ``timers`` the time of each part is added to it (``sim``, ``controller``, ``trajectory``,
    ``messages``), at the price of a few clock reads per step.
    """
    from cdpr_controller.core import ControllerCore
    from cdpr_sim.node import make_sim, state_message
    from cdpr_trajectory.core import setpoint_at

    sim = make_sim(scenario)
    core = ControllerCore.from_scenario(scenario)
    m, dt, trajectory = scenario.robot.m, scenario.dt, scenario.trajectory
    clock = time.perf_counter
    if timers is None:
        t0 = clock()
        for k in range(steps):
            tick = Tick(k, k * dt).encode()
            Tick.decode(tick)
            setpoint = setpoint_at(trajectory, Tick.decode(tick).step, dt).encode()
            state = state_message(sim.state(), 0).encode()
            State.decode(state)  # the clock
            st, sp = State.decode(state, m), Setpoint.decode(setpoint)
            result = core.step(st, sp)
            command = Command(st.step, st.t, tuple(result.tensions.tolist()), result.feasible, result.status)
            sim.step(np.asarray(Command.decode(command.encode(), m).tensions))
        return clock() - t0
    t0 = clock()
    for k in range(steps):
        a = clock()
        tick = Tick(k, k * dt).encode()
        Tick.decode(tick)
        step = Tick.decode(tick).step
        b = clock()
        sp_msg = setpoint_at(trajectory, step, dt)
        c = clock()
        setpoint = sp_msg.encode()
        d = clock()
        st_msg = state_message(sim.state(), 0)
        e = clock()
        state = st_msg.encode()
        State.decode(state)
        st, sp = State.decode(state, m), Setpoint.decode(setpoint)
        f = clock()
        result = core.step(st, sp)
        g = clock()
        command = Command(st.step, st.t, tuple(result.tensions.tolist()), result.feasible, result.status)
        tensions = np.asarray(Command.decode(command.encode(), m).tensions)
        h = clock()
        sim.step(tensions)
        i = clock()
        timers["messages"] += (b - a) + (d - c) + (f - e) + (h - g)
        timers["trajectory"] += c - b
        timers["sim"] += (e - d) + (i - h)
        timers["controller"] += g - f
    return clock() - t0


def bench_monolithic(scenario: Scenario, steps: int, repeats: int) -> dict[str, Any]:
    steps = min(steps, scenario.total_steps)
    rates = [steps / monolithic_steps(scenario, steps) for _ in range(repeats)]
    timers = dict.fromkeys(("sim", "controller", "trajectory", "messages"), 0.0)
    monolithic_steps(scenario, steps, timers)
    return {
        "steps": steps,
        "repeats": repeats,
        "steps_per_s": statistics.median(rates),
        "runs_steps_per_s": rates,
        "us_per_step": {k: 1e6 * v / steps for k, v in timers.items()},
    }


# --------------------------------------------------------------------------------------------------
# 2, 4, 6. Sessions as subprocesses, with their CPU read from /proc


def _children(pid: int) -> list[int]:
    out: list[int] = []
    try:
        for task in os.listdir(f"/proc/{pid}/task"):
            with open(f"/proc/{pid}/task/{task}/children") as f:
                out += [int(x) for x in f.read().split()]
    except OSError:
        pass
    return out


def _process_cpu(root: int) -> dict[str, float]:
    """CPU seconds (user + system) of ``root`` and its descendants, by role (``run``, ``sim``, …)."""
    tick = os.sysconf("SC_CLK_TCK")
    out: dict[str, float] = {}
    todo = [root]
    while todo:
        pid = todo.pop()
        todo += _children(pid)
        try:
            with open(f"/proc/{pid}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            with open(f"/proc/{pid}/cmdline") as f:
                argv = f.read().split("\0")
        except (OSError, IndexError):
            continue
        role = argv[argv.index("cdpr") + 1] if "cdpr" in argv[:-1] else "other"
        out[role] = out.get(role, 0.0) + (int(fields[11]) + int(fields[12])) / tick
    return out


_PROGRESS = re.compile(r"\[cdpr\] step (\d+)/")


class SessionRun:
    """``cdpr run`` in a subprocess; reads its progress lines to measure the CPU of the steady state."""

    def __init__(self, args: Sequence[str], session: str) -> None:
        self.session = session
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "cdpr", "run", *args, "--session", session],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
        )
        self._marks: list[tuple[int, dict[str, float]]] = []
        self._stderr: list[str] = []
        self._reader = threading.Thread(target=self._read, args=(self.proc.stderr,), daemon=True)
        self._reader.start()

    def _read(self, stream: IO[str]) -> None:
        for line in stream:
            match = _PROGRESS.search(line)
            if match and int(match.group(1)) > 0:
                self._marks.append((int(match.group(1)), _process_cpu(self.proc.pid)))
            elif not match:
                self._stderr.append(line)

    def result(self, timeout: float) -> dict[str, Any]:
        """Wait for the session; its summary plus ``cpu_us_per_step`` (None when it ran too briefly)."""
        try:
            self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            raise
        assert self.proc.stdout is not None
        out = self.proc.stdout.read()
        self._reader.join(timeout=5.0)
        lines = [ln for ln in out.splitlines() if ln.strip()]
        try:
            summary: dict[str, Any] = json.loads(lines[-1])
        except (IndexError, json.JSONDecodeError):
            tail = "".join(self._stderr[-5:]).strip()
            raise RuntimeError(f"cdpr run (session {self.session}) printed no summary: {tail}") from None
        summary["cpu_us_per_step"] = None
        summary["cpu_us_per_step_by_process"] = {}
        if len(self._marks) >= 2:
            (k0, c0), (k1, c1) = self._marks[0], self._marks[-1]
            if k1 > k0:
                by = {r: 1e6 * (c1.get(r, 0.0) - c0.get(r, 0.0)) / (k1 - k0) for r in c1}
                summary["cpu_us_per_step_by_process"] = by
                summary["cpu_us_per_step"] = sum(by.values())
        return summary


def _run_sessions(args_list: Sequence[Sequence[str]], tag: str, timeout: float) -> list[dict[str, Any]]:
    """Start the sessions together, wait for all; their summaries (a failed session raises)."""
    runs = [SessionRun(args, f"bench{tag}{i}-{uuid.uuid4().hex[:6]}") for i, args in enumerate(args_list)]
    results = [r.result(timeout) for r in runs]
    for r in results:
        if not r.get("exit_ok"):
            raise RuntimeError(f"session {r.get('session')} did not finish cleanly: {r.get('exit_codes')}")
    return results


def bench_distributed(
    scenario: str, duration: float | None, repeats: int, monolithic: float
) -> dict[str, Any]:
    extra = [] if duration is None else ["--duration", repr(duration)]
    runs = [_run_sessions([[scenario, *extra]], "loop", 900.0)[0] for _ in range(repeats)]
    rate = statistics.median(r["rate"] for r in runs)
    cpu = [r["cpu_us_per_step"] for r in runs if r["cpu_us_per_step"] is not None]
    by_process: dict[str, list[float]] = {}
    for r in runs:
        for k, v in r["cpu_us_per_step_by_process"].items():
            by_process.setdefault(k, []).append(v)
    return {
        "steps": runs[0]["steps"],
        "repeats": repeats,
        "steps_per_s": rate,
        "rtf": statistics.median(r["rtf"] for r in runs),
        "ratio_to_monolithic": rate / monolithic,
        "runs_steps_per_s": [r["rate"] for r in runs],
        "cpu_us_per_step": statistics.median(cpu) if cpu else None,
        "cpu_us_per_step_by_process": {k: statistics.median(v) for k, v in by_process.items()},
        "state_digest": runs[0]["state_digest"],
    }


RT_PRIORITY = 10  # the SCHED_FIFO priority of the second realtime run, when the system allows it


def rt_priority_allowed(priority: int = RT_PRIORITY) -> bool:
    """Whether this process may use SCHED_FIFO (tried in a child process, which then exits)."""
    probe = f"import os; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param({priority}))"
    try:
        return subprocess.run([sys.executable, "-c", probe], capture_output=True, timeout=30).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


def bench_realtime(scenario: str, duration: float) -> dict[str, Any]:
    """The realtime run with the normal scheduler, then (if permitted) with ``--rt-priority``."""
    keys = ("on_time_fraction", "lateness_p50_ms", "lateness_p99_ms", "lateness_p999_ms", "lateness_max_ms")

    def one(extra: list[str]) -> dict[str, Any]:
        args = [scenario, "--mode", "realtime", "--duration", repr(duration), *extra]
        s = _run_sessions([args], "rt", 900.0)[0]
        return {"duration_s": duration, "steps": s["steps"], "late_ticks": s["late_ticks"],
                **{k: s[k] for k in keys}}

    result = one([])
    result["rt_priority"] = (one(["--rt-priority", str(RT_PRIORITY)]) | {"priority": RT_PRIORITY}
                             if rt_priority_allowed() else None)
    return result


# --------------------------------------------------------------------------------------------------
# 3. The Zenoh round trip: `python -m cdpr.bench echo|ping ENDPOINT ...`

_PING, _PONG = "cdpr/bench-rtt/ping", "cdpr/bench-rtt/pong"
_RTT_PAYLOAD = 240  # bytes, about a state message of 8 cables


def _rtt_config(endpoint: str, mode: str) -> Any:
    """Clients of the router at ``endpoint``, or peers that meet through it and link directly (as the
    services of ``cdpr run`` do)."""
    from cdpr.launch import PEER_LISTEN
    from cdpr.transport import zenoh_config

    if mode == "peer":
        return zenoh_config("peer", connect=[endpoint], listen=[PEER_LISTEN])
    return zenoh_config("client", connect=[endpoint])


def _rtt_echo(endpoint: str, mode: str) -> None:
    """Answer every ping with the same payload, from the Inbox callback (as the services do)."""
    from cdpr.transport import PUBLISH_OPTS, Inbox, open_session

    done = threading.Event()
    with open_session(_rtt_config(endpoint, mode), "bench echo") as session:
        pub = session.declare_publisher(_PONG, **PUBLISH_OPTS)

        def on_ping(event: Any) -> None:
            if event.payload == b"stop":
                done.set()
            else:
                pub.put(event.payload)

        sub = Inbox(on_ping).subscribe(session, _PING, "ping")
        c0 = time.process_time()
        done.wait(600.0)
        print(json.dumps({"cpu_s": time.process_time() - c0}), flush=True)
        sub.undeclare()
        pub.undeclare()


def _rtt_ping(endpoint: str, count: int, mode: str, warmup: int = 300) -> None:
    """Ping-pong ``count`` times (after ``warmup``), the next ping sent from the pong's callback."""
    from cdpr.transport import PUBLISH_OPTS, Inbox, open_session

    rtts: list[float] = []
    seq = [-1]  # the sequence number in flight; negative while probing for the echo
    sent_at = [0.0]
    started, done = threading.Event(), threading.Event()
    cpu = [0.0]
    with open_session(_rtt_config(endpoint, mode), "bench ping") as session:
        pub = session.declare_publisher(_PING, **PUBLISH_OPTS)
        pad = bytes(_RTT_PAYLOAD - 8)

        def send(i: int) -> None:
            seq[0] = i
            sent_at[0] = time.perf_counter()
            pub.put(struct.pack("<q", i) + pad)

        def on_pong(event: Any) -> None:
            now = time.perf_counter()
            (i,) = struct.unpack_from("<q", event.payload)
            if i != seq[0]:
                return  # a late answer to an earlier probe
            if i < 0:  # a probe came back: the echo listens, the sequence starts
                started.set()
                nxt = 0
            else:
                if i >= warmup:
                    rtts.append(now - sent_at[0])
                nxt = i + 1
            if nxt == warmup:
                cpu[0] = time.process_time()
            if nxt >= warmup + count:
                cpu[0] = time.process_time() - cpu[0]
                done.set()
                return
            send(nxt)

        sub = Inbox(on_pong).subscribe(session, _PONG, "pong")
        probe = -1
        while not started.is_set():  # the echo may not be listening yet
            send(probe)
            started.wait(0.2)
            probe -= 1
        done.wait(600.0)
        pub.put(b"stop")
        time.sleep(0.2)
        sub.undeclare()
        pub.undeclare()
    rtts.sort()
    print(json.dumps({
        "count": len(rtts),
        "median_us": 1e6 * statistics.median(rtts),
        "p99_us": 1e6 * rtts[min(len(rtts) - 1, int(0.99 * len(rtts)))],
        "min_us": 1e6 * rtts[0],
        "ping_cpu_us": 1e6 * cpu[0] / max(len(rtts), 1),
    }), flush=True)


def bench_zenoh_rtt(count: int) -> dict[str, Any]:
    """A router in this process, the echo and the pinger as two processes on loopback: first as clients
    of the router (two hops each way: how remote participants talk), then as peers linked directly
    (one hop each way: how the services of ``cdpr run`` talk, under ``peers``)."""
    result = _zenoh_rtt(count, "client")
    result["peers"] = _zenoh_rtt(count, "peer")
    return result


def _zenoh_rtt(count: int, mode: str) -> dict[str, Any]:
    from cdpr.launch import free_port
    from cdpr.transport import open_session, zenoh_config

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    module = [sys.executable, "-m", __name__]
    with open_session(zenoh_config("router", listen=[endpoint]), "bench router"):
        echo = subprocess.Popen([*module, "echo", endpoint, mode], stdout=subprocess.PIPE, text=True)
        try:
            ping = subprocess.run([*module, "ping", endpoint, str(count), mode], capture_output=True,
                                  text=True, timeout=600, check=False)
            echo_out, _ = echo.communicate(timeout=30)
        finally:
            if echo.poll() is None:
                echo.kill()
    if ping.returncode != 0 or not ping.stdout.strip():
        raise RuntimeError(f"the Zenoh ping ({mode}) failed: {ping.stderr.strip()[-500:]}")
    result: dict[str, Any] = json.loads(ping.stdout.strip().splitlines()[-1])
    echo_cpu = json.loads(echo_out.strip().splitlines()[-1])["cpu_s"] if echo_out.strip() else math.nan
    result["echo_cpu_us"] = 1e6 * echo_cpu / max(result["count"], 1)
    result["one_way_us"] = result["median_us"] / 2.0
    result["payload_bytes"] = _RTT_PAYLOAD
    return result


# --------------------------------------------------------------------------------------------------
# 5. Generated robots, and the TDA solve times on them

_FRAME_HALF = np.array([3.5, 2.5, 2.0])  # the frame box, centred at _CENTRE
_CENTRE = np.array([0.0, 0.0, 2.0])
_PLATFORM_HALF = np.array([0.3, 0.2, 0.15])  # the platform box (0.6 × 0.4 × 0.3 m)
_MASS = 15.0
_TMIN, _TMAX = 1.0, 6500.0


def _on_box(direction: np.ndarray, half: np.ndarray) -> np.ndarray:
    """The point where the ray from the box's centre along ``direction`` leaves the box."""
    return direction * float(np.min(half / np.maximum(np.abs(direction), 1e-12)))


def robot_spec(m: int, seed: int = 0) -> dict[str, Any]:
    """A robot file's content: ``m`` cables, frame points on a box, platform points on a smaller box.

    ``m = 4`` gives a point-mass robot (4 top corners; a rigid body needs at least 7 cables), larger
    ``m`` a spatial one whose cables surround the platform (anchors above and below) with a twist
    between each frame point and its platform point, so that the cables also hold moments. The first
    seed (from ``seed`` on) whose robot passes :func:`_well_conditioned` is taken: deterministic.
    """
    if m < 7:
        rng = np.random.default_rng(seed)
        corners = np.array([[-1, -1], [-1, 1], [1, 1], [1, -1]] * ((m + 3) // 4))[:m] * _FRAME_HALF[:2]
        frame = np.column_stack([corners + rng.uniform(-0.2, 0.2, (m, 2)), np.full(m, 4.0)])
        cables = [{"frame": a.round(4).tolist(), "platform": [0.0, 0.0, 0.0]} for a in frame]
        return _spec(m, "point_mass", cables, seed)
    for attempt in range(seed, seed + 200):
        rng = np.random.default_rng(attempt)
        # directions spread over the sphere (Fibonacci lattice, randomly turned), jittered
        i = np.arange(m) + 0.5
        z = 1.0 - 2.0 * i / m
        phi = i * math.pi * (3.0 - math.sqrt(5.0)) + rng.uniform(0, 2 * math.pi)
        u = np.column_stack([np.sqrt(1 - z * z) * np.cos(phi), np.sqrt(1 - z * z) * np.sin(phi), z])
        u += rng.normal(0.0, 0.08, u.shape)
        u /= np.linalg.norm(u, axis=1)[:, None]
        frame = _CENTRE + np.array([_on_box(d, _FRAME_HALF) for d in u])
        twist = rng.choice([-1.0, 1.0], m) * rng.uniform(0.6, 1.1, m)  # rad about z, alternating sense
        turned = np.column_stack([np.cos(twist) * u[:, 0] - np.sin(twist) * u[:, 1],
                                  np.sin(twist) * u[:, 0] + np.cos(twist) * u[:, 1], u[:, 2]])
        plat = np.array([_on_box(d, _PLATFORM_HALF) for d in turned])
        cables = [{"frame": a.round(4).tolist(), "platform": b.round(4).tolist()}
                  for a, b in zip(frame, plat, strict=True)]
        spec = _spec(m, "spatial", cables, attempt)
        if _well_conditioned(_robot(spec)):
            return spec
    raise RuntimeError(f"no well-conditioned {m}-cable robot found from seed {seed}")


def _spec(m: int, mode: str, cables: list[dict[str, Any]], seed: int) -> dict[str, Any]:
    box = {"type": "box", "size": (2 * _PLATFORM_HALF).tolist()}
    shape = {"type": "sphere", "size": [0.2]} if mode == "point_mass" else box
    home_z = 2.6 if mode == "point_mass" else float(_CENTRE[2])
    return {
        "name": f"bench_{m}",
        "description": f"generated by cdpr bench: {m} cables, seed {seed}",
        "source": "cdpr.bench.robot_spec",
        "mode": mode,
        "platform": {"mass": _MASS, "inertia": [0.5, 0.5, 0.5], "shape": shape},
        "limits": {"tmin": _TMIN, "tmax": _TMAX, "max_length": 12.0, "max_speed": 10.0},
        "damping": {"cable": 1.0, "passive": 0.0},
        "cables": cables,
        "home": {"position": [0.0, 0.0, home_z], "rpy": [0.0, 0.0, 0.0]},
        "frame_box": {"min": (_CENTRE - _FRAME_HALF).tolist(), "max": (_CENTRE + _FRAME_HALF).tolist()},
    }


def _robot(spec: dict[str, Any]) -> Robot:
    return robot_from_spec(RobotSpec.model_validate(spec), "<cdpr bench>").with_mass(_MASS)


def _well_conditioned(robot: Robot) -> bool:
    """Moments and forces both within reach: σ_min/σ_max of W (moment rows scaled by the platform size)
    above 0.15, and the min-norm tensions along :func:`tda_path` all inside the limits."""
    a, b = robot.frame_points, robot.platform_points
    W = cable_kinematics(a, b, robot.home_position, np.eye(3)).wrench_matrix
    sv = np.linalg.svd(W * np.r_[1, 1, 1, 1 / 0.3, 1 / 0.3, 1 / 0.3][:, None], compute_uv=False)
    if sv[-1] / sv[0] < 0.15:
        return False
    tda = make_tda("qp")
    return all(tda.solve(Wk, wk, robot.tmin, robot.tmax).status == "optimal"
               for Wk, wk in tda_path(robot, 200))


def tda_path(robot: Robot, n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    """``n`` (W, w) pairs along a smooth 10 s path around the home pose, as the loop would see them:
    a Lissajous of ±0.3 m and ±0.1 rad, and the wrench of the platform's motion and weight."""
    rows = list(robot.controlled_rows)
    t = np.linspace(0.0, 10.0, n)
    w0 = 2 * math.pi / 10.0
    out = []
    for tk in t:
        s, c = math.sin(w0 * tk), math.cos(w0 * tk)
        s2 = math.sin(2 * w0 * tk)
        p = robot.home_position + np.array([0.3 * s, 0.2 * s2, 0.15 * c])
        acc = np.array([-0.3 * s, -0.8 * s2, -0.15 * c]) * w0 * w0
        angles = np.array([0.1 * s2, 0.05 * s, 0.1 * c]) if robot.mode == "spatial" else np.zeros(3)
        R = rpy_to_matrix(*angles)
        alpha = -np.array([0.4 * s2, 0.05 * s, 0.1 * c]) * w0 * w0 if robot.mode == "spatial" else np.zeros(3)
        W = cable_kinematics(robot.frame_points, robot.platform_points, p, R).wrench_matrix
        force = robot.mass * (acc - GRAVITY)
        moment = R @ robot.inertia @ R.T @ alpha
        out.append((np.ascontiguousarray(W[rows]), np.r_[force, moment][rows]))
    return out


def bench_tda(sizes: Sequence[int], calls: int) -> dict[str, Any]:
    """Median and 90th-percentile µs per ``solve`` for every method, along :func:`tda_path`.

    ``qp`` is also solved without its warm active set (the QP solver on every call: ``qp_solver``),
    and the largest difference between the two answers is reported (``qp_max_difference_N``).
    """
    out: list[dict[str, Any]] = []
    for m in sizes:
        robot = _robot(robot_spec(m))
        path = tda_path(robot, calls)
        lo, hi = float(robot.tmin), float(robot.tmax)
        methods: dict[str, dict[str, Any]] = {}
        answers: dict[str, list[np.ndarray]] = {}
        for name in sorted(METHODS):
            methods[name], answers[name] = _time_solves(make_tda(name), path, lo, hi)
        few = path[:: max(1, len(path) // 100)]
        solver = make_tda("qp", warm_active_set=False)
        methods["qp_solver"], cold = _time_solves(solver, few, lo, hi)
        warm = answers["qp"][:: max(1, len(path) // 100)]
        out.append({
            "cables": m,
            "mode": robot.mode,
            "rows": len(robot.controlled_rows),
            "calls": len(path),
            "methods": methods,
            "qp_max_difference_N": max(float(np.abs(a - b).max()) for a, b in zip(warm, cold, strict=True)),
        })
    return {"sizes": out}


def _time_solves(tda: Any, path: Sequence[tuple[np.ndarray, np.ndarray]], lo: float, hi: float
                 ) -> tuple[dict[str, Any], list[np.ndarray]]:
    times, answers, statuses = [], [], {}
    clock = time.perf_counter
    for W, w in path:
        a = clock()
        r = tda.solve(W, w, lo, hi)
        times.append(clock() - a)
        answers.append(r.tensions)
        statuses[r.status] = statuses.get(r.status, 0) + 1
    times.sort()
    stats: dict[str, Any] = {
        "median_us": 1e6 * statistics.median(times),
        "p90_us": 1e6 * times[int(0.9 * (len(times) - 1))],
        "statuses": statuses,
    }
    if hasattr(tda, "solver_calls"):
        stats["solver_calls"] = tda.solver_calls
    return stats, answers


# --------------------------------------------------------------------------------------------------
# 6. Scaling


def scenario_yaml(robot_file: str, m: int, duration: float) -> dict[str, Any]:
    """A scenario for the generated ``m``-cable robot: a small quintic move from home, then holding."""
    home = [0.0, 0.0, 2.6] if m < 7 else _CENTRE.tolist()
    goal = [home[0] + 0.3, home[1] + 0.2, home[2] + 0.1]
    return {
        "name": f"bench_{m}",
        "description": f"cdpr bench: {m} cables",
        "robot": robot_file,
        "platform": {"mass": _MASS},
        "limits": {"tmin": _TMIN, "tmax": _TMAX},
        "dt": 0.001,
        "duration": duration,
        "trajectory": {"type": "quintic", "waypoints": [
            {"t": 0.0, "position": home}, {"t": max(duration - 0.5, 0.5), "position": goal}]},
        "controller": {"variant": "6dof", "kp": 1500.0, "kd": 1500.0, "tda": {"method": "qp"}},
    }


def bench_sessions(scenario: str, counts: Sequence[int], duration: float) -> list[dict[str, Any]]:
    out = []
    for n in counts:
        runs = _run_sessions([[scenario, "--duration", repr(duration)]] * n, f"s{n}x", 1800.0)
        steps = sum(r["steps"] for r in runs)
        cpu = [r["cpu_us_per_step"] for r in runs if r["cpu_us_per_step"] is not None]
        out.append({
            "sessions": n,
            "median_steps_per_s": statistics.median(r["rate"] for r in runs),
            "aggregate_steps_per_s": sum(r["rate"] for r in runs),
            "steps": steps,
            "cpu_us_per_step": statistics.median(cpu) if cpu else None,
        })
    return out


def bench_cables(counts: Sequence[int], duration: float) -> list[dict[str, Any]]:
    out = []
    with tempfile.TemporaryDirectory(prefix="cdpr-bench-") as tmp:
        for m in counts:
            robot_file = Path(tmp) / f"bench_{m}_robot.yaml"
            robot_file.write_text(yaml.safe_dump(robot_spec(m), sort_keys=False), encoding="utf-8")
            scenario_file = Path(tmp) / f"bench_{m}.yaml"
            scenario = scenario_yaml(robot_file.name, m, duration)
            scenario_file.write_text(yaml.safe_dump(scenario, sort_keys=False), encoding="utf-8")
            run = _run_sessions([[str(scenario_file)]], f"c{m}x", 900.0)[0]
            out.append({
                "cables": m,
                "steps_per_s": run["rate"],
                "steps": run["steps"],
                "cpu_us_per_step": run["cpu_us_per_step"],
                "infeasible_commands": run.get("infeasible_commands"),
                "rms_position_error": run.get("rms_position_error"),
            })
    return out


# --------------------------------------------------------------------------------------------------
# The whole run


def machine() -> dict[str, Any]:
    model = ""
    try:
        with open("/proc/cpuinfo") as f:
            model = next((ln.split(":", 1)[1].strip() for ln in f if ln.startswith("model name")), "")
    except OSError:
        pass
    import zenoh

    return {
        "nproc": os.cpu_count(),
        "cpu_model": model or platform.processor(),
        "loadavg": list(os.getloadavg()),
        "python": platform.python_version(),
        "zenoh": getattr(zenoh, "__version__", None) or _dist_version("eclipse-zenoh"),
        "platform": platform.platform(),
    }


def _dist_version(name: str) -> str | None:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(name)
    except PackageNotFoundError:
        return None


def targets(result: dict[str, Any]) -> dict[str, dict[str, Any]]:
    """The project's performance targets, each with the measured figure and whether it is met."""
    dist, rt = result["distributed"], result["realtime"]

    def target(value: float, met: bool, **extra: Any) -> dict[str, Any]:
        return {"value": value, "met": bool(met), **extra}

    out = {
        "distributed_steps_per_s>=2000": target(dist["steps_per_s"], dist["steps_per_s"] >= 2000),
        "distributed/monolithic>=0.6": target(ratio := dist["ratio_to_monolithic"], ratio >= 0.6),
        "realtime_on_time>=0.999": target(rt["on_time_fraction"], rt["on_time_fraction"] >= 0.999,
                                          over_s=rt["duration_s"]),
    }
    if (fifo := rt.get("rt_priority")) is not None:
        out["realtime_on_time_rt_priority>=0.999"] = target(
            fifo["on_time_fraction"], fifo["on_time_fraction"] >= 0.999, over_s=fifo["duration_s"])
    tda8 = next((s for s in result["tda"]["sizes"] if s["cables"] == 8), None)
    if tda8 is not None:
        qp, diff = tda8["methods"]["qp"]["median_us"], tda8["qp_max_difference_N"]
        out["qp_8_cables_median_us<=50"] = target(qp, qp <= 50.0)
        out["qp_same_optimum<=1e-6"] = target(diff, diff <= 1e-6)
    return out


def run_bench(plan: BenchPlan, scenario: str = "caroca_15kg", out: Path | None = Path("bench.json"),
              log: Callable[[str], None] = _log) -> dict[str, Any]:
    """Run every part of ``plan``; returns the results (and writes them to ``out`` as JSON)."""
    started = time.monotonic()
    sc = load_scenario(scenario)
    result: dict[str, Any] = {
        "version": BENCH_VERSION,
        "quick": plan == QUICK,
        "scenario": sc.name,
        "plan": asdict(plan),
        "machine": machine(),
        "started": time.strftime("%Y-%m-%dT%H:%M:%S%z"),
    }
    load: dict[str, float] = {}  # the 1-minute load average as each part starts: the machine may be shared
    result["machine"]["loadavg_by_part"] = load

    def part(name: str, message: str) -> None:
        load[name] = os.getloadavg()[0]
        log(f"{len(load)}/6 {message}")

    part("monolithic", f"monolithic loop ({plan.mono_steps} steps x {plan.mono_repeats})")
    result["monolithic"] = bench_monolithic(sc, plan.mono_steps, plan.mono_repeats)
    part("distributed", f"distributed loop (cdpr run {scenario} x {plan.loop_repeats})")
    result["distributed"] = bench_distributed(scenario, plan.loop_duration, plan.loop_repeats,
                                              result["monolithic"]["steps_per_s"])
    part("zenoh_rtt", f"Zenoh round trip ({plan.rtt_count})")
    result["zenoh_rtt"] = bench_zenoh_rtt(plan.rtt_count)
    part("realtime", f"realtime mode ({plan.realtime_duration:g} s)")
    result["realtime"] = bench_realtime(scenario, plan.realtime_duration)
    part("tda", f"tension distribution ({', '.join(map(str, plan.tda_sizes))} cables)")
    result["tda"] = bench_tda(plan.tda_sizes, plan.tda_calls)
    part("scaling", f"scaling ({', '.join(map(str, plan.session_counts))} sessions; "
                    f"{', '.join(map(str, plan.cable_counts))} cables)")
    result["scaling"] = {
        "sessions": bench_sessions(scenario, plan.session_counts, plan.session_duration),
        "cables": bench_cables(plan.cable_counts, plan.cable_duration),
    }
    result["machine"]["loadavg_end"] = list(os.getloadavg())
    result["elapsed_s"] = time.monotonic() - started
    result["targets"] = targets(result)
    if out is not None:
        out.parent.mkdir(parents=True, exist_ok=True)
        out.write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    return result


def _fmt(x: Any, digits: int = 0) -> str:
    if x is None:
        return "-"
    if isinstance(x, float):
        return f"{x:,.{digits}f}"
    return str(x)


def table(r: dict[str, Any]) -> str:
    """The results as a plain-text table (what `cdpr bench` prints)."""
    mono, dist, rtt, rt, mach = r["monolithic"], r["distributed"], r["zenoh_rtt"], r["realtime"], r["machine"]
    rows: list[tuple[str, str]] = [
        ("1 monolithic loop, steps/s", _fmt(mono["steps_per_s"])),
        *((f"    {k}, us/step", _fmt(v, 1)) for k, v in mono["us_per_step"].items()),
        ("2 distributed loop (fast), steps/s", _fmt(dist["steps_per_s"])),
        ("    RTF", _fmt(dist["rtf"], 2)),
        ("    ratio to the monolithic loop", _fmt(dist["ratio_to_monolithic"], 2)),
        ("    CPU of all processes, us/step", _fmt(dist["cpu_us_per_step"])),
        *((f"      {k}", _fmt(v)) for k, v in dist["cpu_us_per_step_by_process"].items()),
        ("3 Zenoh round trip, clients through the router, median us", _fmt(rtt["median_us"], 1)),
        ("    p99 us", _fmt(rtt["p99_us"], 1)),
        ("    one message (half), us", _fmt(rtt["one_way_us"], 1)),
        ("  peers linked directly (as in cdpr run), median us", _fmt(rtt["peers"]["median_us"], 1)),
        ("    p99 us", _fmt(rtt["peers"]["p99_us"], 1)),
        ("    one message (half), us", _fmt(rtt["peers"]["one_way_us"], 1)),
        (f"4 realtime 1 kHz, {rt['duration_s']:g} s: ticks within 1 ms",
         f"{100 * rt['on_time_fraction']:.3f} %"),
        ("    lateness p50 / p99 / p99.9 / max, ms",
         " / ".join(f"{rt[f'lateness_{p}_ms']:.3f}" for p in ("p50", "p99", "p999", "max"))),
    ]
    if (fifo := rt.get("rt_priority")) is not None:
        rows += [
            (f"  with --rt-priority {fifo['priority']} (SCHED_FIFO): ticks within 1 ms",
             f"{100 * fifo['on_time_fraction']:.3f} %"),
            ("    lateness p50 / p99 / p99.9 / max, ms",
             " / ".join(f"{fifo[f'lateness_{p}_ms']:.3f}" for p in ("p50", "p99", "p999", "max"))),
        ]
    else:
        rows.append(("  with --rt-priority", "not permitted here"))
    lines = [
        f"cdpr bench{' --quick' if r['quick'] else ''}: {r['scenario']}, "
        f"{mach['nproc']} x {mach['cpu_model']}, "
        f"load {mach['loadavg'][0]:.2f} -> {mach['loadavg_end'][0]:.2f}, {r['elapsed_s']:.0f} s",
        "load as each part started: " + ", ".join(f"{k} {v:.1f}" for k, v in mach["loadavg_by_part"].items()),
        "",
        *(f"{name:52s} {value:>22s}" for name, value in rows),
        "",
        "5 tension distribution, median us per solve (p90)",
    ]
    sizes = r["tda"]["sizes"]
    lines.append(f"    {'method':24s}" + "".join(f"{str(s['cables']) + ' cables':>16s}" for s in sizes))
    for name in sizes[0]["methods"] if sizes else ():
        stats = [s["methods"][name] for s in sizes]
        cells = (f"{_fmt(t['median_us'], 1)} ({_fmt(t['p90_us'])})" for t in stats)
        lines.append(f"    {name:24s}" + "".join(f"{c:>16s}" for c in cells))
    lines.append(f"    {'qp vs qp_solver, max |df|':24s}"
                 + "".join(f"{s['qp_max_difference_N']:>14.1e} N" for s in sizes))
    lines += ["", "6 scaling",
              f"    {'sessions':10s}{'steps/s each':>16s}{'aggregate':>12s}{'CPU us/step':>14s}"]
    for s in r["scaling"]["sessions"]:
        lines.append(f"    {s['sessions']:<10d}{_fmt(s['median_steps_per_s']):>16s}"
                     f"{_fmt(s['aggregate_steps_per_s']):>12s}{_fmt(s['cpu_us_per_step']):>14s}")
    lines.append(f"    {'cables':10s}{'steps/s':>16s}{'':>12s}{'CPU us/step':>14s}")
    for c in r["scaling"]["cables"]:
        lines.append(f"    {c['cables']:<10d}{_fmt(c['steps_per_s']):>16s}{'':>12s}"
                     f"{_fmt(c['cpu_us_per_step']):>14s}")
    lines += ["", "targets"]
    for name, t in r["targets"].items():
        lines.append(f"    {name:36s} {_fmt(t['value'], 4):>14s}  {'met' if t['met'] else 'MISSED'}")
    return "\n".join(lines)


if __name__ == "__main__":  # helper processes of the round-trip benchmark
    role, *rest = sys.argv[1:]
    if role == "echo":
        _rtt_echo(rest[0], rest[1])
    elif role == "ping":
        _rtt_ping(rest[0], int(rest[1]), rest[2])
    else:
        raise SystemExit(f"unknown role {role!r}")
