"""The monolithic loop, sessions as subprocesses (CPU from /proc), realtime, scaling."""

from __future__ import annotations

import contextlib
import json
import os
import re
import statistics
import subprocess
import sys
import tempfile
import threading
import time
import uuid
from collections.abc import Sequence
from pathlib import Path
from typing import IO, Any

import numpy as np
import yaml

from cdpr.config.scenario import Scenario, load_scenario
from cdpr.protocol import TELEMETRY_EVERY, Command, Setpoint, Setpoints, State, Telemetry, Tick
from cdpr.tools.bench.robots import robot_spec, scenario_yaml

# --------------------------------------------------------------------------------------------------
# 1. The monolithic loop


MONOLITHIC_WINDOW = 100  # steps per grant, as the clock's default --lookahead grants them in fast mode


def monolithic_steps(scenario: Scenario, steps: int, timers: dict[str, float] | None = None) -> float:
    """Run ``steps`` steps of the loop in this process; returns the wall time (s).

    Exactly the work of the services in fast mode minus the transport, message for message as protocol 2
    sends them: per window of :data:`MONOLITHIC_WINDOW` steps the clock's tick (encoded, decoded by the sim
    and the trajectory) and the trajectory's block of setpoints (encoded, decoded by the controller); per
    step the sim's state (encoded, decoded by the controller), the controller's step and command (encoded,
    decoded by the sim) and the sim's step; per :data:`cdpr.protocol.TELEMETRY_EVERY` steps the sim's
    telemetry block (encoded, decoded by the clock). With ``timers`` the time of each part is added to it
    (``sim``, ``controller``, ``trajectory``, ``messages``), at the price of a few clock reads per step.
    """
    from cdpr.runtime.registry import node_class

    sim = node_class("sim").make_core(scenario)
    core = node_class("controller").make_core(scenario)
    setpoints_between = node_class("trajectory").make_block_core(scenario)
    m, dt = scenario.robot.m, scenario.dt
    clock = time.perf_counter
    parts = dict.fromkeys(("sim", "controller", "trajectory", "messages"), 0.0)
    states: list[State] = []
    commands: list[Command] = []
    setpoints: tuple[Setpoint, ...] = ()
    timed = timers is not None
    t0 = mark = clock()

    def lap(part: str) -> None:
        """The time since the last lap goes to ``part`` (only with ``timers``: a clock read per part)."""
        nonlocal mark
        now = clock()
        parts[part] += now - mark
        mark = now

    for k in range(steps):
        if k % MONOLITHIC_WINDOW == 0:  # the clock grants a window, the trajectory sends its setpoints
            until = min(steps, k + MONOLITHIC_WINDOW) - 1
            tick = Tick(k, k * dt, until).encode()
            Tick.decode(tick)
            granted = Tick.decode(tick)
            if timed:
                lap("messages")
            block = Setpoints(setpoints_between(granted.step, granted.until))
            if timed:
                lap("trajectory")
            setpoints = Setpoints.decode(block.encode()).items
            if timed:
                lap("messages")
        st_msg = sim.message(0)
        if timed:
            lap("sim")
        st = State.decode(st_msg.encode(), m)
        if timed:
            lap("messages")
        result = core.step(st, setpoints[k % MONOLITHIC_WINDOW])
        if timed:
            lap("controller")
        command = Command(st.step, st.t, tuple(result.tensions.tolist()), result.feasible, result.status)
        tensions = np.asarray(Command.decode(command.encode(), m).tensions)
        if timed:
            lap("messages")
        sim.step(tensions)
        if timed:
            lap("sim")
        states.append(st_msg)
        commands.append(command)
        if len(states) == TELEMETRY_EVERY or k == steps - 1:  # the sim's report, read by the clock
            Telemetry.decode(Telemetry(tuple(states), tuple(commands), (0.0,) * len(commands)).encode(), m)
            states, commands = [], []
            if timed:
                lap("messages")
    elapsed = clock() - t0
    if timers is not None:
        for name, value in parts.items():
            timers[name] += value
    return elapsed


def monolithic_timers(scenario: Scenario, steps: int) -> dict[str, float]:
    """Microseconds per step of each part of the monolithic loop (one timed run)."""
    steps = min(steps, scenario.total_steps)
    timers = dict.fromkeys(("sim", "controller", "trajectory", "messages"), 0.0)
    monolithic_steps(scenario, steps, timers)
    return {k: 1e6 * v / steps for k, v in timers.items()}


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


def _thread_waits(pid: int) -> dict[int, float]:
    """Seconds each thread of ``pid`` has spent runnable but waiting for a CPU, by thread id (``/proc/PID/task/*/
    schedstat``, its second field; none where the kernel keeps no such statistics)."""
    out: dict[int, float] = {}
    try:
        for task in os.listdir(f"/proc/{pid}/task"):
            with contextlib.suppress(OSError, IndexError, ValueError), open(f"/proc/{pid}/task/{task}/schedstat") as f:
                out[int(task)] = int(f.read().split()[1]) / 1e9
    except OSError:
        pass
    return out


def _waited(before: dict[int, float], after: dict[int, float]) -> float:
    """Seconds the threads of a process waited for a CPU between two readings of :func:`_thread_waits`: each
    thread of the second since the first, or since it started (a thread that ended between them is left out:
    the sum of the threads alive at each reading would fall when one ends)."""
    return sum(w - b if (b := before.get(tid, 0.0)) <= w else w for tid, w in after.items())


def _tree(root: int, waits: bool = False) -> dict[int, tuple[str, float, dict[int, float]]] | None:
    """The processes of ``root``'s tree (``root`` included): pid -> (role: ``run``, ``sim``, …; CPU seconds,
    user + system; with ``waits``, its threads' :func:`_thread_waits`). None once one of them has exited (a
    zombie: its command line, hence its role, and its threads' waits are gone)."""
    tick = os.sysconf("SC_CLK_TCK")
    out: dict[int, tuple[str, float, dict[int, float]]] = {}
    todo = [root]
    while todo:
        pid = todo.pop()
        todo += _children(pid)
        try:
            with open(f"/proc/{pid}/stat") as f:
                fields = f.read().rsplit(")", 1)[1].split()
            with open(f"/proc/{pid}/cmdline") as f:
                argv = f.read().replace("\0", " ").split()  # the arguments, or the title of a forked service
        except (OSError, IndexError):
            continue
        if fields[0] == "Z":
            return None
        # `python -m cdpr run …` is "run"; its services are `python -m cdpr.runtime NAME …`
        launcher = next((a for a in ("cdpr", "cdpr.runtime") if a in argv[:-1]), None)
        role = argv[argv.index(launcher) + 1] if launcher is not None else "other"
        out[pid] = (role, (int(fields[11]) + int(fields[12])) / tick, _thread_waits(pid) if waits else {})
    return out


def _process_cpu(root: int, waits: dict[str, float] | None = None) -> dict[str, float] | None:
    """CPU seconds (user + system) of ``root`` and its descendants, by role (``run``, ``sim``, …);
    with ``waits``, their seconds waiting for a CPU, by role, added to it. None once one of them has
    exited (a zombie: its command line, hence its role, and its threads' waits are gone)."""
    tree = _tree(root, waits is not None)
    if tree is None:
        return None
    out: dict[str, float] = {}
    for role, cpu, wait in tree.values():
        out[role] = out.get(role, 0.0) + cpu
        if waits is not None:
            waits[role] = waits.get(role, 0.0) + sum(wait.values())
    return out


def _pid_cpu(pid: int) -> float | None:
    """CPU seconds (user + system) of one process (None once it has exited)."""
    try:
        with open(f"/proc/{pid}/stat") as f:
            fields = f.read().rsplit(")", 1)[1].split()
        return None if fields[0] == "Z" else (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")
    except (OSError, IndexError, ValueError):
        return None


_PROGRESS = re.compile(r"\[cdpr\] step (\d+)/(\d+)")
_FINISHED = re.compile(r"\[clock\] finished (\d+) steps in (\d+(?:\.\d*)?) s")
READ_EVERY = 0.05  # s between two readings of a session's processes (until two progress lines have given marks)
_WALL_ROUNDING = 0.01  # s: the clock's line gives the loop's wall time to 0.01 s

# A reading of a session's processes: pid -> (role, CPU seconds, its threads' waits; None: a process of
# SessionRun.also, whose waits are not counted)
Reading = dict[int, tuple[str, float, dict[int, float] | None]]


class SessionRun:
    """``cdpr run`` in a subprocess, and the CPU its processes spend per step in the steady state: each process's
    CPU (``/proc``) between its first and its last reading within the loop, over the steps between them.

    The readings are those taken as the progress lines come (a second apart at least, the step from the line),
    the first and the last while the loop runs; for a session too short to print two (a few hundred steps),
    those taken every :data:`READ_EVERY` seconds, the first and the last within its loop — which the clock's
    line at its end dates (its wall time, up to when the line came) — each one's step the loop's share of its
    wall time by then.
    """

    def __init__(self, args: Sequence[str], session: str, command: str = "run",
                 env: dict[str, str] | None = None) -> None:
        self.session = session
        self.also: dict[str, int] = {}  # processes outside the session's tree measured with it: role -> pid
        self.proc = subprocess.Popen(
            [sys.executable, "-m", "cdpr", command, *args, "--session", session],
            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=env,
        )
        self._marks: list[tuple[int, Reading]] = []  # (step, reading) at each progress line within the loop
        self._readings: list[tuple[float, Reading]] = []  # (time.monotonic(), reading) every READ_EVERY s
        self._finished: tuple[float, int, float] | None = None  # when the clock's last line came, steps, wall s
        # the readings start with the first progress line, once the services are released (in-process, the
        # launcher prints none before the loop has ended: from the start)
        self._started = "--in-process" in args
        self._done = threading.Event()
        self._stderr: list[str] = []
        self._reader = threading.Thread(target=self._read, args=(self.proc.stderr,), daemon=True)
        self._reader.start()
        self._sampler = threading.Thread(target=self._sample, daemon=True)
        self._sampler.start()

    def _read(self, stream: IO[str]) -> None:
        for line in stream:
            match = _PROGRESS.search(line)
            if match:  # a mark while the loop runs (not the last line, which comes once it has ended)
                self._started = True
                k, n = int(match.group(1)), int(match.group(2))
                if 0 < k < n and self._finished is None and (reading := self._reading()) is not None:
                    self._marks.append((k, reading))  # (None once the services leave)
                continue
            self._stderr.append(line)
            if (end := _FINISHED.search(line)) is not None:
                self._finished = (time.monotonic(), int(end.group(1)), float(end.group(2)))
                if len(self._marks) < 2 and (reading := self._reading()) is not None:
                    self._readings.append((self._finished[0], reading))  # the loop's end (if all are still there)

    def _sample(self) -> None:
        """A reading every :data:`READ_EVERY` s from the services' start to the loop's end (the clock's line),
        unless two progress lines have given marks."""
        while not self._done.wait(READ_EVERY):
            if len(self._marks) >= 2 or self._finished is not None or self.proc.poll() is not None:
                return
            now = time.monotonic()
            if self._started and (reading := self._reading()) is not None:
                self._readings.append((now, reading))

    def _reading(self) -> Reading | None:
        """The CPU of every process of the session (and of :attr:`also`); None once one has exited."""
        if not (tree := _tree(self.proc.pid, waits=True)):  # None: one has exited; empty: all have
            return None
        reading: Reading = dict(tree)
        for role, pid in list(self.also.items()):
            if (cpu := _pid_cpu(pid)) is None:
                return None
            reading[pid] = (role, cpu, None)
        return reading

    def _within(self) -> list[tuple[float, Reading]]:
        """The readings within the loop, in order, each with its step: the progress lines' marks, or else (a
        session too short for two) the regular readings inside the loop's wall time."""
        marks: list[tuple[float, Reading]] = [(float(k), r) for k, r in self._marks]
        if len(marks) < 2 and self._finished is not None and self._finished[2] > 0:
            end, steps, wall = self._finished
            marks = sorted(((steps * (t - end + wall) / wall, r) for t, r in self._readings
                            if end - wall + _WALL_ROUNDING <= t <= end), key=lambda m: m[0])
        return marks

    def result(self, timeout: float) -> dict[str, Any]:
        """Wait for the session; its summary plus ``cpu_us_per_step`` (None when it ran too briefly)."""
        try:
            self.proc.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            raise
        finally:
            self._done.set()
        assert self.proc.stdout is not None
        out = self.proc.stdout.read()
        self._reader.join(timeout=5.0)
        self._sampler.join(timeout=5.0)
        lines = [ln for ln in out.splitlines() if ln.strip()]
        try:
            summary: dict[str, Any] = json.loads(lines[-1])
        except (IndexError, json.JSONDecodeError):
            tail = "".join(self._stderr[-5:]).strip()
            raise RuntimeError(f"cdpr run (session {self.session}) printed no summary: {tail}") from None
        summary["cpu_us_per_step"] = None
        summary["cpu_us_per_step_by_process"] = {}
        summary["wait_us_per_step_by_process"] = {}  # runnable, waiting for a CPU
        # each process over its own first and last reading within the loop (one may be missed by a reading:
        # taken as it forked, or as the session ended), its role as the last of them says (a forked service
        # takes its title as it starts)
        cpu: dict[str, float] = {}
        waits: dict[str, float] = {}
        within = self._within()
        for pid in {pid for _, r in within for pid in r}:
            seen = [(k, r[pid]) for k, r in within if pid in r]
            (k0, (_, c0, w0)), (k1, (role, c1, w1)) = seen[0], seen[-1]
            if k1 > k0:
                cpu[role] = cpu.get(role, 0.0) + 1e6 * (c1 - c0) / (k1 - k0)
                if w1 is not None:
                    waits[role] = waits.get(role, 0.0) + 1e6 * _waited(w0 or {}, w1) / (k1 - k0)
        if cpu:
            summary["cpu_us_per_step_by_process"] = cpu
            summary["cpu_us_per_step"] = sum(cpu.values())
            summary["wait_us_per_step_by_process"] = waits
        return summary


def _run_sessions(args_list: Sequence[Sequence[str]], tag: str, timeout: float) -> list[dict[str, Any]]:
    """Start the sessions together, wait for all; their summaries (a failed session raises)."""
    runs = [SessionRun(args, f"bench{tag}{i}-{uuid.uuid4().hex[:6]}") for i, args in enumerate(args_list)]
    results = [r.result(timeout) for r in runs]
    for r in results:
        if not r.get("exit_ok"):
            raise RuntimeError(f"session {r.get('session')} did not finish cleanly: {r.get('exit_codes')}")
    return results


LOOP_VARIANTS: dict[str, tuple[str, ...]] = {
    "multi_process": (),  # every node its own process, no recording
    "multi_process_recording": ("--rrd", "{tmp}/bench.rrd"),  # and the recorder writing an .rrd
    # the recorder writing an .rrd and an .mcap (Foxglove schemas) from the same batches
    "multi_process_recording_both": ("--rrd", "{tmp}/bench_both.rrd", "--mcap", "{tmp}/bench_both.mcap"),
    "in_process": ("--in-process",),  # every node in one process (composition), no recording
}


def bench_loop_variants(scenario: Scenario, duration: float | None, rounds: int, mono_steps: int,
                        mono_repeats: int) -> tuple[dict[str, Any], dict[str, Any]]:
    """The monolithic loop and the distributed loop in each of :data:`LOOP_VARIANTS`, interleaved:
    ``rounds`` rounds of M A M B M C M D (M: the monolithic loop, ``mono_repeats`` times), so that every
    figure samples the same minutes of a machine whose speed changes within a minute. A variant's ratio
    is the median of its runs over the median of all the monolithic runs. (Not run by run: the
    distributed loop does not follow the monolithic loop's swings — on 2026-11-25 three runs gave
    1 115–1 121 steps/s while the monolithic runs right before them gave 1 461–2 248 — so the ratio of
    a pair mostly measured the monolithic run's luck.) Returns ``(monolithic, variants)``."""
    steps = min(mono_steps, scenario.total_steps)
    extra = [] if duration is None else ["--duration", repr(duration)]
    mono: list[float] = []
    runs: dict[str, list[dict[str, Any]]] = {name: [] for name in LOOP_VARIANTS}
    with tempfile.TemporaryDirectory(prefix="cdpr-bench-") as tmp:
        for _ in range(rounds):
            for name, args in LOOP_VARIANTS.items():
                mono += [steps / monolithic_steps(scenario, steps) for _ in range(mono_repeats)]
                argv = [scenario.source, *extra, *(a.format(tmp=tmp) for a in args)]
                runs[name].append(_run_sessions([argv], name.replace("_", ""), 900.0)[0])
    monolithic: dict[str, Any] = {"steps": steps, "repeats": len(mono), "steps_per_s": statistics.median(mono),
                  "runs_steps_per_s": mono, "us_per_step": monolithic_timers(scenario, steps)}
    return monolithic, {name: _loop_result(r, monolithic["steps_per_s"]) for name, r in runs.items()}


def _loop_result(runs: list[dict[str, Any]], monolithic: float) -> dict[str, Any]:
    repeats = len(runs)
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


def bench_startup(scenario: str, repeats: int, steps: int = 50) -> dict[str, Any]:
    """Wall time of a whole ``cdpr run SCENARIO --duration steps·dt`` command, from the command's start
    to its exit, multi-process and in-process (median of ``repeats``, interleaved)."""
    duration = repr(steps * load_scenario(scenario).dt)
    walls: dict[str, list[float]] = {"multi_process": [], "in_process": []}
    for _ in range(repeats):
        for name, args in (("multi_process", []), ("in_process", ["--in-process"])):
            started = time.perf_counter()
            proc = subprocess.run([sys.executable, "-m", "cdpr", "run", scenario, "--duration", duration, "--quiet",
                                   "--session", f"benchstart-{uuid.uuid4().hex[:6]}", *args],
                                  capture_output=True, text=True, timeout=120, check=False)
            walls[name].append(time.perf_counter() - started)
            if proc.returncode != 0:
                raise RuntimeError(f"cdpr run --duration {duration} {' '.join(args)} failed: {proc.stderr[-500:]}")
    return {"steps": steps, "repeats": repeats,
            **{f"{k}_s": statistics.median(v) for k, v in walls.items()},
            **{f"{k}_runs_s": v for k, v in walls.items()}}


def count_deliveries(scenario: Scenario, steps: int) -> dict[str, Any]:
    """Messages per step and topic in fast mode, and the deliveries they make (one per subscriber, from
    the wiring table, plus ``cdpr run``'s monitor): a session composed in this process, with one more
    subscriber on every key of the session that counts what goes by (it is not counted itself)."""
    from cdpr.protocol import Keys
    from cdpr.protocol.wiring import TOPICS, subscribers
    from cdpr.runtime.main import build_node
    from cdpr.runtime.service import serve_composed
    from cdpr.runtime.transport import StopFlag, isolated_config, open_session

    keys = Keys(f"benchcount{uuid.uuid4().hex[:6]}")
    sc = load_scenario(scenario.source, {"duration": steps * scenario.dt})
    by_key = {f"{keys.prefix}/{t.key.split('/{')[0]}": name for name, t in TOPICS.items()}
    counts: dict[str, int] = dict.fromkeys(TOPICS, 0)
    monitor = {"telemetry", "setpoints", "status", "stats"}  # what cdpr run's monitor subscribes to

    def on_sample(sample: Any) -> None:
        key = str(sample.key_expr)
        name = by_key.get(key) or by_key.get(key.rsplit("/", 1)[0])
        if name is not None:
            counts[name] += 1

    import zenoh

    with open_session(isolated_config(), "bench") as session:
        sub = session.declare_subscriber(f"{keys.prefix}/**", zenoh.handlers.Callback(on_sample, indirect=False))
        argv = [sc.source, "--duration", repr(sc.duration)]
        nodes = [build_node("clock", sc, keys, [*argv, "--expect", "sim,trajectory,controller"])]
        nodes += [build_node(name, sc, keys, argv) for name in ("sim", "trajectory", "controller")]
        code = serve_composed(nodes, session, StopFlag())
        sub.undeclare()
    if code != 0:
        raise RuntimeError(f"the counting session ended with code {code}")
    n = sc.total_steps
    # the stack's subscribers (the ros2 node runs only with cdpr up --ros2: not in this session)
    per_topic = {name: {"messages_per_step": c / n,
                        "deliveries_per_step": c * (len([s for s in subscribers(name) if s != "ros2"])
                                                    + (name in monitor)) / n}
                 for name, c in counts.items() if c}
    return {"steps": n, "topics": per_topic,
            "deliveries_per_step": sum(v["deliveries_per_step"] for v in per_topic.values()),
            "loop_deliveries_per_step": sum(v["deliveries_per_step"] for k, v in per_topic.items()
                                            if k not in ("status", "stats"))}


def _cpu_stat() -> dict[str, int]:
    """The machine's CPU time so far (``/proc/stat``, in ticks): idle, steal, and the total."""
    with open("/proc/stat") as f:
        fields = [int(x) for x in f.readline().split()[1:]]
    return {"idle": fields[3] + fields[4], "steal": fields[7] if len(fields) > 7 else 0, "total": sum(fields[:8])}


_PROBE = """
import sys, time
period = float(sys.argv[1])
lat, nxt = [], time.monotonic()
while True:
    nxt += period
    time.sleep(max(0.0, nxt - time.monotonic()))
    lat.append(time.monotonic() - nxt)
    if len(lat) % 1000 == 0 and sys.stdin in __import__("select").select([sys.stdin], [], [], 0)[0]:
        break
print(sum(x <= period for x in lat) / max(1, len(lat)), 1e3 * max(lat, default=0.0))
"""


class SleeperProbe:
    """A process that sleeps until each deadline, ``period`` seconds apart (a step), and counts how often it
    woke more than a period late: the lateness the machine itself gives a sleeping thread (what is left is
    the loop's own)."""

    def __init__(self, period: float = 0.001) -> None:
        self.period = period

    def __enter__(self) -> SleeperProbe:
        self.proc = subprocess.Popen([sys.executable, "-c", _PROBE, repr(self.period)], stdin=subprocess.PIPE,
                                     stdout=subprocess.PIPE, text=True)
        self.on_time_fraction: float | None = None
        self.max_ms: float | None = None
        return self

    def __exit__(self, *exc: object) -> None:
        assert self.proc.stdin is not None
        self.proc.stdin.write("stop\n")
        self.proc.stdin.close()
        try:
            self.proc.wait(timeout=30)
            assert self.proc.stdout is not None
            on_time, worst = (float(x) for x in self.proc.stdout.read().split())
            self.on_time_fraction, self.max_ms = on_time, worst
        except (subprocess.TimeoutExpired, ValueError):
            self.proc.kill()
            self.proc.wait()


RT_PRIORITY = 10  # the SCHED_FIFO priority of the second realtime run, when the system allows it


def rt_priority_allowed(priority: int = RT_PRIORITY) -> bool:
    """Whether this process may use SCHED_FIFO (tried in a child process, which then exits)."""
    probe = f"import os; os.sched_setscheduler(0, os.SCHED_FIFO, os.sched_param({priority}))"
    try:
        return subprocess.run([sys.executable, "-c", probe], capture_output=True, timeout=30).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return False


def cpu_latency_allowed() -> bool:
    """Whether this process may hold the PM QoS CPU latency limit (``--cpu-latency``: /dev/cpu_dma_latency)."""
    return os.access("/dev/cpu_dma_latency", os.W_OK)


def bench_realtime(scenario: str, duration: float) -> dict[str, Any]:
    """The realtime runs of ``scenario`` (its dt: 1 or 2 kHz): with the defaults (the normal scheduler, the
    CPUs free to sleep), then where permitted with ``--cpu-latency 0`` (``cpu_latency``), and with
    ``--rt-priority`` (``rt_priority``: with ``--cpu-latency 0`` too where permitted). A sleeping probe beside
    each run wakes every dt, as the loop must."""
    keys = ("on_time_fraction", "lateness_p50_ms", "lateness_p99_ms", "lateness_p999_ms", "lateness_max_ms")
    dt = load_scenario(scenario).dt

    def one(extra: list[str]) -> dict[str, Any]:
        args = [scenario, "--mode", "realtime", "--duration", repr(duration), *extra]
        stat0 = _cpu_stat()
        with SleeperProbe(dt) as probe:
            s = _run_sessions([args], "rt", 900.0)[0]
        stat1 = _cpu_stat()
        busy = {k: (stat1[k] - stat0[k]) / max(1, stat1["total"] - stat0["total"]) for k in ("steal", "idle")}
        return {"duration_s": duration, "dt": dt, "steps": s["steps"], "late_ticks": s["late_ticks"],
                **{k: s[k] for k in keys},
                # the profile of the run: what each process costs per step, how long it waited for a
                # CPU; the machine's idle and stolen shares; a sleeping probe's own wake-up lateness
                "cpu_us_per_step_by_process": s["cpu_us_per_step_by_process"],
                "wait_us_per_step_by_process": s["wait_us_per_step_by_process"],
                "machine_idle_fraction": busy["idle"], "machine_steal_fraction": busy["steal"],
                "probe_on_time_fraction": probe.on_time_fraction, "probe_max_ms": probe.max_ms}

    result = one([])
    awake = cpu_latency_allowed()
    result["cpu_latency"] = one(["--cpu-latency", "0"]) | {"microseconds": 0} if awake else None
    result["rt_priority"] = (one(["--rt-priority", str(RT_PRIORITY), *(["--cpu-latency", "0"] if awake else [])])
                             | {"priority": RT_PRIORITY, "cpu_latency_us": 0 if awake else None}
                             if rt_priority_allowed() else None)
    return result


# --------------------------------------------------------------------------------------------------
# 6. Scaling


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
