"""`cdpr run` and `cdpr up`: start a session's services as child processes and watch it to the end.

The launcher hosts the session's Zenoh router in its own process (listening on loopback by default),
so no external router is needed. When every service runs on this machine (`cdpr run`, `cdpr up`
without ``--without``) the loop's children are Zenoh peers: each connects to the router, learns the
others from it and links to them directly on loopback, so a message of the loop takes one hop; the
recorder stays a client of the router (see :func:`node_argv`). With remote participants every service
is a client of the router, like the remote ones. Either way a service declares its subscribers
before its liveliness token, so when the clock sees the token the service can be reached (a peer may
learn of a new peer's subscribers a moment later: the clock's first step is a handshake, see
:mod:`cdpr_clock.core`). The launcher's own monitor subscribes (on the router itself) before any
service starts, computes the run summary, and prints it as the last line of stdout.

The services are forked from the launcher once it has loaded the scenario, before its router opens
(:class:`Forked`): each starts with numpy, pydantic, Zenoh's bindings and the scenario's models
already imported, which was most of a short session's start-up. Where the launcher cannot fork (a
thread besides the main one, a platform without ``fork``), or with ``CDPR_START_METHOD=spawn`` in the
environment, each service is a new interpreter.
"""

from __future__ import annotations

import contextlib
import gc
import itertools
import json
import os
import signal
import socket
import subprocess
import sys
import threading
import time
import traceback
from collections.abc import Iterable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, NoReturn

import setproctitle
import zenoh

from cdpr.config.scenario import Scenario
from cdpr.errors import InputError
from cdpr.protocol import Keys, ProtocolError, ServiceStats, Setpoints, Status, Telemetry
from cdpr.runtime.main import build_node
from cdpr.runtime.options import RECORDER_OPTIONS, options_argv
from cdpr.runtime.service import PARENT_ENV, hold_cpu_latency, serve_composed, set_realtime_priority
from cdpr.runtime.transport import (
    Inbox,
    StopFlag,
    isolated_config,
    log,
    open_session,
    pin_thread_state,
    zenoh_config,
)
from cdpr.tools.metrics import RunMetrics

PEER_LISTEN = "tcp/127.0.0.1:0"  # where a local child listens for its peers: loopback, any free port
STOP_GRACE = 4.0  # seconds a child gets to stop after SIGTERM before it is killed
STOP_SIGNALS = {signal.SIGINT, signal.SIGTERM}
FINISH_GRACE = 60.0  # after the clock's end, seconds the services get to leave by themselves (the recorder
#                     may still be writing a large file)
TELEMETRY_GRACE = 10.0  # after the services have left, seconds the monitor waits for the sim's last telemetry


def free_port() -> int:
    with socket.socket(socket.AF_INET, socket.SOCK_STREAM) as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def local_endpoint(listen: str) -> str:
    """The endpoint a local child connects to, for a listen endpoint (0.0.0.0 → 127.0.0.1)."""
    proto, _, addr = listen.partition("/")
    host, _, port = addr.rpartition(":")
    if host in ("0.0.0.0", "[::]", ""):
        host = "127.0.0.1"
    return f"{proto}/{host}:{port}"


def service_command(name: str, args: list[str]) -> list[str]:
    """The command line that runs service ``name`` as its own process."""
    return [sys.executable, "-m", "cdpr.runtime", name, *args]


START_METHOD_ENV = "CDPR_START_METHOD"  # "fork" (the default where possible) or "spawn"


def can_fork() -> bool:
    """Whether this process may fork its services: not asked to spawn them (``$CDPR_START_METHOD``),
    POSIX, and no thread besides this one (a forked child has only the thread that forked; a lock
    another thread held would stay locked in it)."""
    method = os.environ.get(START_METHOD_ENV, "fork")
    if method not in ("fork", "spawn"):
        raise InputError(f"${START_METHOD_ENV}: fork or spawn, got {method!r}")
    if method == "spawn" or not hasattr(os, "fork") or threading.active_count() != 1:
        return False
    try:
        return len(os.listdir("/proc/self/task")) == 1  # native threads too (OpenBLAS's pool, Zenoh's)
    except OSError:
        return False


class Forked:
    """A service forked from the launcher, with the part of :class:`subprocess.Popen` that
    :class:`Children` uses (``poll``, ``wait``, ``send_signal``, ``returncode``).

    The launcher has imported numpy, pydantic and Zenoh's bindings and validated the scenario; a
    forked service starts from there instead of a fresh interpreter (~0.4 s of CPU each: five of them
    on two cores were most of a short session's wall time). The child is what ``python -m
    cdpr.runtime NAME ARGS`` would be, with that command line as its process title (``ps``, ``top``):
    it parses ``ARGS``, loads the scenario, builds its node, then waits on ``gate`` (a pipe the
    launcher closes once the session's router listens: the launcher must not have Zenoh's threads
    when it forks) before it opens its own session. It never returns into the launcher's code: it
    leaves with ``os._exit`` once served (its Zenoh session is closed by then, sockets included).
    """

    def __init__(self, name: str, args: list[str], gate: tuple[int, int]) -> None:
        self.returncode: int | None = None
        sys.stdout.flush()
        sys.stderr.flush()
        # SIGINT/SIGTERM held until the child has its own handlers (the launcher's would swallow them)
        held = signal.pthread_sigmask(signal.SIG_BLOCK, STOP_SIGNALS)
        try:
            pid = os.fork()
            if pid == 0:  # pragma: no cover (the child process: measured by the session it serves)
                _forked_service(name, args, gate, held)
        finally:
            signal.pthread_sigmask(signal.SIG_SETMASK, held)
        self.pid = pid

    def poll(self) -> int | None:
        if self.returncode is None:
            pid, status = os.waitpid(self.pid, os.WNOHANG)
            if pid == self.pid:
                self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def wait(self) -> int:
        if self.returncode is None:
            _, status = os.waitpid(self.pid, 0)
            self.returncode = os.waitstatus_to_exitcode(status)
        return self.returncode

    def send_signal(self, sig: int) -> None:
        if self.returncode is None:
            with contextlib.suppress(ProcessLookupError):
                os.kill(self.pid, sig)


def _forked_service(name: str, args: list[str], gate: tuple[int, int], mask: Iterable[int]) -> NoReturn:
    """The forked child: serve ``name`` as ``python -m cdpr.runtime`` would, then leave."""
    code = 1
    try:
        for sig in STOP_SIGNALS:
            signal.signal(sig, signal.SIG_DFL)  # a stop ends it at once, until its serve loop takes them
        signal.pthread_sigmask(signal.SIG_SETMASK, mask)  # (one that came since the fork: now)
        read_end, write_end = gate
        os.close(write_end)  # the launcher's alone: its closing is the signal
        os.dup2(sys.stderr.fileno(), sys.stdout.fileno())  # stdout is the launcher's summary: services log
        os.environ[PARENT_ENV] = str(os.getppid())
        setproctitle.setproctitle(" ".join(service_command(name, args)))
        setproctitle.setthreadtitle(f"cdpr-{name}"[:15])  # the short name (top, ps -o comm)

        def wait_for_router() -> None:
            os.read(read_end, 1)  # end of file: the router listens (or the launcher is gone: then the
            os.close(read_end)  # session cannot be reached, and the service says so and ends)

        from cdpr.runtime.main import node_main

        node_main(name, args, before_serve=wait_for_router)
    except SystemExit as exc:
        if isinstance(exc.code, str):
            print(exc.code, file=sys.stderr)
        code = exc.code if isinstance(exc.code, int) else (0 if exc.code is None else 1)
    except BaseException:
        traceback.print_exc()
    finally:
        with contextlib.suppress(Exception):
            sys.stdout.flush()
            sys.stderr.flush()
        os._exit(code)


class Children:
    """The service processes of one session; stops them all, whatever happens.

    ``fork``: the services are forked from this process (:class:`Forked`) before the session's router
    opens, and wait until :meth:`release`; otherwise each is a new interpreter, started by
    :meth:`release` once the router listens.
    """

    def __init__(self, argv: dict[str, list[str]], fork: bool) -> None:
        self.argv = argv
        self.procs: dict[str, subprocess.Popen[bytes] | Forked] = {}
        self._gate: tuple[int, int] | None = None
        if fork:
            self._gate = os.pipe()
            for name, args in argv.items():
                self.procs[name] = Forked(name, args, self._gate)
            os.close(self._gate[0])

    def release(self) -> None:
        """The router listens: the forked services may open their sessions (or the others start)."""
        if self._gate is not None:
            os.close(self._gate[1])
            self._gate = None
        elif not self.procs:
            env = dict(os.environ, **{PARENT_ENV: str(os.getpid())})
            for name, args in self.argv.items():
                self.procs[name] = subprocess.Popen(service_command(name, args), stdout=sys.stderr.fileno(), env=env)

    def failed(self) -> list[tuple[str, int]]:
        return [(n, code) for n, p in self.procs.items() if (code := p.poll()) is not None and code != 0]

    def stop(self, wait_first: float) -> dict[str, int]:
        """Give the children ``wait_first`` seconds to end by themselves, then SIGTERM, then SIGKILL."""
        for sig, grace in ((None, wait_first), (signal.SIGTERM, STOP_GRACE), (signal.SIGKILL, 2.0)):
            if sig == signal.SIGKILL:
                for name, p in self.procs.items():
                    if p.poll() is None:  # where it is stuck, on its stderr (cdpr.runtime.service: faulthandler)
                        log("cdpr", f"{name} did not stop within {STOP_GRACE:g} s of SIGTERM; killing it")
                        p.send_signal(signal.SIGUSR1)
                time.sleep(0.2)
            for p in self.procs.values():
                if sig is not None and p.poll() is None:
                    p.send_signal(sig)
            deadline = time.monotonic() + grace
            while time.monotonic() < deadline and any(p.poll() is None for p in self.procs.values()):
                time.sleep(0.005)
            if all(p.poll() is not None for p in self.procs.values()):
                break
        return {n: p.wait() for n, p in self.procs.items()}


class Tape:
    """The loop's messages as the launcher's monitor receives them, kept raw and decoded after the run.

    Each sample is appended right in Zenoh's callback, on the thread that received it (the binding's
    ``indirect=False``): a (topic, bytes) pair per message, no thread woken, no queue. In
    ``cdpr run`` that thread is the session router's, so the callback must never wait long for this
    process's GIL: the launcher's main thread only wakes a few times a second while the loop runs,
    and its long-lived objects are frozen out of the garbage collector's sight (``gc.freeze``).
    """

    def __init__(self) -> None:
        self.items: list[tuple[str, bytes]] = []  # (topic, payload) in arrival order

    def reached(self, cables: int) -> int:
        """The newest state step in the last telemetry block received (-1 before any): one link delivers in
        order, so every block the sim sent before it is in too."""
        for topic, payload in reversed(self.items):
            if topic == "telemetry":
                with contextlib.suppress(ProtocolError):
                    states = Telemetry.decode(payload, cables).states
                    if states:
                        return max(s.step for s in states)
        return -1

    def await_step(self, step: int, cables: int, timeout: float, stop: StopFlag | None = None) -> bool:
        """Wait until the telemetry has reached ``step`` (the clock's last), at most ``timeout`` s. A child's
        exit does not mean that this process's router has handled what the child sent before it: the bytes
        may still be in the socket, read later by Zenoh's thread — after the subscriber has gone."""
        deadline = time.monotonic() + timeout
        while (reached := self.reached(cables)) < step:
            if stop:
                return False
            if time.monotonic() >= deadline:
                log("cdpr", f"the sim's telemetry came up to step {reached} of {step} within {timeout:g} s of the "
                    "end: the summary's figures cover those steps only")
                return False
            time.sleep(0.01)
        return True

    def subscribe(self, session: zenoh.Session, key: str, topic: str) -> zenoh.Subscriber:
        add, pin = self.items.append, pin_thread_state

        def on_sample(sample: zenoh.Sample) -> None:
            pin()
            add((topic, sample.payload.to_bytes()))  # one append: atomic, whichever thread runs it

        return session.declare_subscriber(key, zenoh.handlers.Callback(on_sample, indirect=False))


class _Monitor:
    """The launcher's view of the session: the clock's status, the services' stats, the progress line."""

    def __init__(self, inbox: Inbox, total_steps: int, quiet: bool) -> None:
        self.inbox, self.total_steps, self.quiet = inbox, total_steps, quiet
        self.final: Status | None = None
        self.raw: list[tuple[str, bytes]] = []
        self.last_progress, self.last_step = 0.0, -1

    @property
    def ended(self) -> bool:
        return self.final is not None and self.final.state in ("finished", "aborted")

    @property
    def finished(self) -> bool:
        return self.final is not None and self.final.state == "finished"

    def poll(self, timeout: float) -> None:
        for ev in self.inbox.drain(timeout):
            if ev.topic == "status":
                with contextlib.suppress(ProtocolError):
                    self.final = Status.decode(ev.payload)
            else:
                self.raw.append((ev.topic, ev.payload))
        final, now = self.final, time.monotonic()
        k = final.step if final is not None else 0
        if not self.quiet and now - self.last_progress >= 1.0 and k != self.last_step:  # no repeats while waiting
            self.last_progress, self.last_step = now, k
            n = self.total_steps
            rate = final.stats.get("rate", 0.0) if final is not None else 0.0
            log("cdpr", f"step {max(k, 0)}/{n} ({100.0 * max(k, 0) / n:.0f} %), {rate:.0f} steps/s")


@dataclass(frozen=True)
class RunOptions:
    """How ``cdpr run`` / ``cdpr up`` run a session (their command-line options, by the same names)."""

    session_id: str = "default"
    mode: str = "fast"  # "fast" or "realtime" (the clock's --mode)
    sync: str = "lock"  # realtime: "lock" or "free" (the clock's --sync)
    max_lateness: float | None = None  # the clock's --max-lateness (None: never abort)
    rrd: str | None = None
    spawn: bool = False
    connect_viewer: str | None = None
    summary: str | None = None  # also write the JSON summary here
    quiet: bool = False  # no progress line
    without: tuple[str, ...] = ()  # participants that join from elsewhere
    listen: tuple[str, ...] = ()  # where they connect (the session's router)
    join_timeout: float | None = None
    rejoin_timeout: float | None = None  # the clock's --rejoin-timeout (None: its default)
    rt_priority: int | None = None
    cpu_latency: int | None = None  # µs: the PM QoS CPU latency limit the launcher holds (system-wide)
    in_process: bool = False
    mcap: str | None = None
    foxglove: int | None = None
    foxglove_host: str = "127.0.0.1"
    ros2: bool = False  # also run the ros2 node (the controller's role when the controller joins from elsewhere)
    ros_namespace: str | None = None  # the ros2 node's (None: its default, from the session id)

    @property
    def recording(self) -> bool:
        return bool(self.rrd or self.spawn or self.connect_viewer or self.mcap or self.foxglove is not None)

    def listen_endpoints(self) -> list[str]:
        """The session router's endpoints: given, or 7447 on loopback for remote participants, or any port."""
        return list(self.listen) or [f"tcp/127.0.0.1:{7447 if self.without else free_port()}"]


def node_argv(scenario: Scenario, opts: RunOptions, router: str) -> dict[str, list[str]]:
    """Every node's command line (the in-process composition parses the same options), for a session
    whose router is reached at ``router``.

    All on this machine, the children are peers, linked to each other directly on loopback (a message
    takes one hop instead of two through the router, which the launcher's process would have to
    forward); the router then only introduces them and serves the monitor. With remote participants,
    every service is a client of the router, as the remote ones are.
    """
    # a ROS 2 controller (through the ros2 node, a peer as rmw_zenoh's nodes are) needs no client of the router
    remote = bool(opts.without) and not (opts.ros2 and set(opts.without) == {"controller"})
    mode_args = ["--zenoh-mode", "client"] if remote else ["--zenoh-mode", "peer", "--listen", PEER_LISTEN]
    session_args = [scenario.source, "--session", opts.session_id, "--duration", repr(scenario.duration)]
    loop = [*session_args, *mode_args, "--connect", router]
    if opts.rt_priority is not None and not opts.in_process:
        loop += ["--rt-priority", str(opts.rt_priority)]
    expected = ["sim", "trajectory", "controller"] + (["recorder"] if opts.recording else [])
    clock = [] if opts.rejoin_timeout is None else ["--rejoin-timeout", repr(opts.rejoin_timeout)]
    if opts.sync != "lock":
        clock += ["--sync", opts.sync]
    if opts.max_lateness is not None:
        clock += ["--max-lateness", repr(opts.max_lateness)]
    argv = {"clock": [*loop, "--mode", opts.mode, "--expect", ",".join(expected), *clock]}
    argv.update({name: loop for name in ("sim", "trajectory", "controller") if name not in opts.without})
    if opts.ros2:
        observe = [] if "controller" in opts.without else ["--observe"]  # never a second controller
        ros2 = [*(["--ros-namespace", opts.ros_namespace] if opts.ros_namespace else []), *observe]
        if "sim" in argv and not remote:
            # hosted by the sim's process, as gazebo_ros's plugins are by Gazebo's server: a state reaches it
            # and a ROS 2 command the sim within the process (docs/ros2.md), two hops fewer per step (a peer: with
            # other participants elsewhere the services are clients of the router, and the node stays a peer)
            argv["sim+ros2"] = [*argv.pop("sim"), *ros2]
        else:  # a peer of the ROS 2 nodes, which connect to the router (rmw_zenoh's default)
            argv["ros2"] = [*session_args, "--zenoh-mode", "peer", "--listen", PEER_LISTEN, "--connect", router, *ros2]
    if opts.recording:
        # The recorder is a client of the router even among local peers: it takes a few blocks a second
        # (no hop to save), and the router declares its subscribers to every peer before it passes its
        # liveliness token on to the clock, so the sim's first telemetry block (the handshake's report)
        # cannot miss it; a peer learns of a peer only once their direct link is up, a moment later.
        argv["recorder"] = [*session_args, "--zenoh-mode", "client", "--connect", router, *_recorder_args(opts)]
    return argv


def _recorder_args(opts: RunOptions) -> list[str]:
    for path in (opts.rrd, opts.mcap):
        if path:
            Path(path).parent.mkdir(parents=True, exist_ok=True)
    return options_argv(RECORDER_OPTIONS, opts)


def run_session(scenario: Scenario, opts: RunOptions | None = None) -> int:
    """Run a session of ``scenario`` to its end; print (and write to ``opts.summary``) its JSON summary;
    return the exit code (0: finished; 1: failed or aborted; 128 + N: stopped by signal N).

    Multi-process (the default): every node a child process. ``opts.in_process``: every node in this
    process on one private Zenoh session (:func:`cdpr.runtime.service.serve_composed`), the same
    node classes and messages; no remote participant can join it.
    """
    opts = opts or RunOptions()
    try:
        keys = Keys(opts.session_id)
    except ValueError as exc:
        raise InputError(f"--session: {exc}") from None
    if opts.in_process and (opts.without or opts.listen or opts.ros2):
        raise InputError("--in-process: every node runs in this process; --without/--listen/--ros2 need processes")
    if (note := scenario.start_note()) is not None:  # said even with --quiet: not progress, a fact of the session
        log("cdpr", note)
    listen_eps = opts.listen_endpoints()
    argv = node_argv(scenario, opts, local_endpoint(listen_eps[0]))
    if opts.rt_priority is not None:
        # the session's router (this process); each loop service sets its own (--rt-priority above),
        # the recorder keeps the normal scheduling (it writes in bursts: no CPU to take from the loop)
        set_realtime_priority(opts.rt_priority, inherited=opts.in_process)
    if opts.cpu_latency is not None:
        hold_cpu_latency(opts.cpu_latency)  # for every CPU, as long as this process lives: the whole session
    stop = StopFlag().install()
    conf = isolated_config() if opts.in_process else zenoh_config("router", listen=listen_eps)
    # The services are forked now, before the router's threads exist, and wait for it (Forked).
    children = Children({} if opts.in_process else argv, fork=not opts.in_process and can_fork())
    try:
        router = open_session(conf, "cdpr run")
    except BaseException:
        children.stop(wait_first=0.0)
        raise
    with router as session:
        # In-process, the clock's statuses are queued as it publishes them: its last one is in once the
        # nodes are done (through the binding's thread it could come after the final look).
        inbox = Inbox(direct=opts.in_process)
        stop.on_set(inbox.wake)
        tape = Tape()
        subs = [
            tape.subscribe(session, keys.telemetry, "telemetry"),
            tape.subscribe(session, keys.setpoints, "setpoints"),
            inbox.subscribe(session, keys.status, "status"),
            inbox.subscribe(session, keys.stats_all, "stats"),
        ]
        monitor = _Monitor(inbox, scenario.total_steps, opts.quiet)
        try:
            if opts.in_process:
                nodes = [build_node(name, scenario, keys, args) for name, args in argv.items()]
                codes = {"in-process": serve_composed(nodes, session, stop, on_turn=lambda: monitor.poll(0.0))}
                monitor.poll(0.0)
            else:
                codes = _watch_children(children, monitor, stop, opts, listen_eps)
            if monitor.finished and monitor.final is not None and monitor.final.step >= scenario.total_steps:
                tape.await_step(monitor.final.step, scenario.robot.m, TELEMETRY_GRACE, stop)  # the whole run's
        finally:
            for s in subs:
                s.undeclare()
    result = session_summary(scenario, opts, monitor, tape, codes, interrupted=stop.signal is not None)
    if stop.signal is not None:
        log("cdpr", "interrupted; every service stopped")
    _print_summary(result, opts.summary)
    if stop.signal is not None:
        return 128 + stop.signal
    return 0 if result["exit_ok"] else 1


def _print_summary(result: dict[str, Any], path: str | None) -> None:
    """The summary as the last line of stdout, and indented in ``path``."""
    if path:
        Path(path).parent.mkdir(parents=True, exist_ok=True)
        Path(path).write_text(json.dumps(result, indent=2) + "\n", encoding="utf-8")
    print(json.dumps(result), flush=True)


def _watch_children(children: Children, monitor: _Monitor, stop: StopFlag, opts: RunOptions,
                    listen_eps: list[str]) -> dict[str, int]:
    """Release the forked (or start the) services and watch the session until it ends, a service fails,
    the participants do not join in time or a stop signal comes; then stop the services. Their exit codes."""
    started = time.monotonic()
    # What the launcher made so far lives as long as the run: out of the garbage collector's sight
    # (a full collection would otherwise scan it all, holding the GIL the tape's callbacks need).
    gc.collect()
    gc.freeze()
    try:
        if opts.without:
            log("cdpr", f"waiting for {', '.join(opts.without)} to join session {opts.session_id!r} "
                f"at {', '.join(listen_eps)}")
        children.release()
        while not stop:
            monitor.poll(0.2)
            if monitor.ended:
                break
            if failed := children.failed():
                log("cdpr", "stopping: " + ", ".join(f"{n} exited with code {c}" for n, c in failed))
                break
            joined = monitor.final is not None and monitor.final.state != "waiting"
            if opts.join_timeout is not None and not joined and time.monotonic() - started > opts.join_timeout:
                log("cdpr", f"stopping: participants did not join within {opts.join_timeout:g} s")
                break
    finally:
        # After the clock's end (finished or aborted) the services leave by themselves; otherwise they are told to.
        codes = children.stop(wait_first=FINISH_GRACE if monitor.ended else 0.0)
        monitor.raw.extend((ev.topic, ev.payload) for ev in monitor.inbox.drain(0.05))  # the services' last words
    return codes


def _replay(scenario: Scenario, items: Iterable[tuple[str, bytes]]) -> tuple[RunMetrics, dict[str, dict[str, int]]]:
    """The run's metrics from the telemetry and setpoints it saw, and each service's fault counters."""
    metrics = RunMetrics()
    faults: dict[str, dict[str, int]] = {}
    m = scenario.robot.m
    for topic, payload in items:
        try:
            if topic == "telemetry":
                block = Telemetry.decode(payload, m)
                for state in block.states:
                    metrics.add_state(state)
                for cmd in block.commands:
                    metrics.add_command(cmd)
            elif topic == "setpoints":
                for sp in Setpoints.decode(payload).items:
                    metrics.add_setpoint(sp)
            elif topic == "stats":
                stats_msg = ServiceStats.decode(payload)
                faults[stats_msg.service] = stats_msg.counters
        except ProtocolError:
            pass  # the services log and count bad messages; the summary ignores them
    return metrics, faults


_CLOCK_FIGURES = ("lateness_p50_ms", "lateness_p99_ms", "lateness_p999_ms", "lateness_max_ms", "on_time_fraction",
                  "command_age_p50", "command_age_p99", "command_age_max", "watchdog_steps")


def session_summary(scenario: Scenario, opts: RunOptions, monitor: _Monitor, tape: Tape, codes: dict[str, int],
                    interrupted: bool) -> dict[str, Any]:
    """The run's JSON summary (docs: README "Quick start"): what the clock reported, the metrics of
    what the monitor saw, the services' faults and exit codes."""
    metrics, faults = _replay(scenario, itertools.chain(tape.items, monitor.raw))
    stats = monitor.final.stats if monitor.final is not None else {}
    children_ok = all(c == 0 for c in codes.values())
    result: dict[str, Any] = {
        "scenario": scenario.name,
        "session": opts.session_id,
        "mode": opts.mode,
        "sync": opts.sync,
        "in_process": opts.in_process,
        "steps": metrics.last_step if metrics.last_step >= 0 else 0,
        "total_steps": scenario.total_steps,
        "sim_time": max(metrics.last_step, 0) * scenario.dt,
        "wall_time": stats.get("wall_time"),
        "rate": stats.get("rate"),
        "rtf": stats.get("rtf"),
        **metrics.summary(),
        "late_ticks": stats.get("late_ticks"),
        "faults": {k: v for k, v in {**stats.get("faults", {}), **faults}.items() if v},
        "resends": stats.get("resends"),
        "handshake_repeats": stats.get("handshake_repeats"),
        "rrd": opts.rrd,
        "mcap": opts.mcap,
        "exit_codes": codes,
        "exit_ok": bool(monitor.finished and children_ok and not interrupted),
    }
    result.update({key: stats[key] for key in _CLOCK_FIGURES if key in stats})
    return result
