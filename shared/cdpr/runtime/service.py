"""The shell every service shares: open Zenoh, declare, hold a liveliness token, run one event loop.

A service is a :class:`Node`: it declares what it reads and writes in :meth:`Node.declare`, handles one
:class:`~cdpr.runtime.transport.Event` at a time in :meth:`Node.handle`, and says when it is done. :func:`serve`
does the rest, the same way for every service: subscribers are declared before the liveliness token
(so whoever sees the token can already reach the service), the session ends on ``clock/status``
finished/aborted, on SIGINT/SIGTERM, or when the parent process that launched it is gone.

Two ways to run a node, one event at a time either way:

* queued (the default): Zenoh's receive thread puts events on a queue, the service's main thread takes
  them out, handles them and calls :meth:`Node.idle`;
* direct (``Node.direct = True``, the lock-step services): the receive thread handles each event itself,
  under the node's lock, then calls :meth:`Node.idle` — no thread hand-off between a message and its
  answer. The main thread only wakes for the node's deadlines (:meth:`Node.timeout`), the once-a-second
  chores, a signal and the end. A deadline is met by sleeping until shortly before it, then polling
  the clock until it has passed (:data:`SPIN`), instead of trusting the OS timer's slack — unless the
  process runs under SCHED_FIFO (``--rt-priority``), whose timers have no slack and wake it at once.
"""

from __future__ import annotations

import argparse
import contextlib
import ctypes
import faulthandler
import gc
import math
import os
import signal
import struct
import threading
import time
from collections import deque
from collections.abc import Callable, Iterable
from typing import TYPE_CHECKING, Any

import zenoh

from cdpr import protocol
from cdpr.errors import InputError
from cdpr.protocol import Keys, ProtocolError, ServiceStats, Status
from cdpr.protocol.wiring import TOPICS, WIRING, check_node
from cdpr.runtime.transport import PUBLISH_OPTS, Event, Inbox, RateLimitedLog, StopFlag, log, open_session

if TYPE_CHECKING:
    from cdpr.config.scenario import Scenario
    from cdpr.protocol import Setpoint, State
    from cdpr.protocol.pairing import Pairing
    from cdpr.runtime.feedback import SensorFeedback

PARENT_ENV = "CDPR_PARENT_PID"


class Node:
    """Base class of a service's node. Subclasses set ``name`` and override the hooks."""

    name = "node"
    direct = False  # handle events on Zenoh's receive thread (see the module docstring)
    # queued (not direct): put on the queue by Zenoh's receive thread itself, so that the node sees its topics in
    # the order they came (a publisher's messages keep their order per priority); by default each subscriber's
    # samples are queued by a thread of the binding's, one per subscriber, and two topics may swap (the recorder
    # once took the session's last telemetry before a camera image the sim had put first, and lost the image)
    ordered = False
    # The topics this node reads and writes (names of cdpr.protocol.wiring.TOPICS): its row of the wiring
    # table, set for each subclass from its ``name``; serve() declares them. Events arrive with the topic
    # name as their ``topic``; publishers wait in ``self.publishers[topic]``.
    subscribes: tuple[str, ...] = ()
    publishes: tuple[str, ...] = ()

    def __init_subclass__(cls, **kwargs: Any) -> None:
        super().__init_subclass__(**kwargs)
        if (row := WIRING.get(cls.name)) is not None:
            cls.subscribes, cls.publishes = row.subscribes, row.publishes
    # Queued nodes: topics of which only the newest event of a batch is handled (ROS's "keep last 1"): a
    # controller that fell behind answers the newest state, not a backlog of old ones.
    keep_last: tuple[str, ...] = ()
    # What this node checks of its scenario when it loads it (cdpr.config.scenario.load_scenario).
    scenario_checks: tuple[str, ...] = ()

    def __init__(self, keys: Keys) -> None:
        self.keys = keys
        self.done = False
        self.exit_code = 0
        self.final_status: Status | None = None
        self.counters: dict[str, int] = {}  # fault counters, published on stats/{name}
        self.publishers: dict[str, zenoh.Publisher] = {}
        self.warn = RateLimitedLog(self.name)

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        """Add this node's own command-line options (``python -m cdpr_<name>``, ``cdpr <name>``)."""

    @classmethod
    def from_args(cls, scenario: Scenario, keys: Keys, args: argparse.Namespace) -> Node:
        """The node for ``scenario`` from the parsed command line (see :mod:`cdpr.runtime.main`)."""
        return cls(scenario, keys)  # type: ignore[call-arg, arg-type]  # a node of the (scenario, keys) kind

    @classmethod
    def make_core(cls, scenario: Scenario) -> Any:
        """The node's pure step object for ``scenario``, without Zenoh (the same math in one process:
        ``cdpr bench``'s monolithic loop). Nodes whose work is only messaging have none."""
        raise NotImplementedError(f"the {cls.name} node has no pure core")

    @classmethod
    def make_block_core(cls, scenario: Scenario) -> Callable[[int, int], tuple[Setpoint, ...]]:
        """The node's pure block function for ``scenario``: steps ``first`` … ``last`` → the setpoints it
        publishes for them in one block (the trajectory node's ``trajectory/setpoints``), without Zenoh (the
        gym's local loop, ``cdpr bench``'s loops). Nodes that publish no setpoints have none."""
        raise NotImplementedError(f"the {cls.name} node publishes no setpoints: it has no block core")

    @classmethod
    def make_sensors(cls, scenario: Scenario) -> Any:
        """The node's simulated sensors for ``scenario`` (the sim's ``cdpr_sim.sensors.SensorSuite``: ``read(model)``
        once per step), None without: the gym's local loop reads them as the sim node does."""
        return None

    def configure(self, conf: zenoh.Config) -> None:
        """Adjust the Zenoh config of the node's own process before its session opens (what a feature of the
        node needs from Zenoh: the ros2 node's timestamps)."""

    def decode(self, event: Event, *args: Any) -> Any:
        """The event's message, decoded and checked as its topic says (``cdpr.protocol.wiring.TOPICS``; ``args``
        go to its ``decode``: the number of cables, …). A payload that fails is counted under the topic's
        fault counter, logged in one line naming the field (rate-limited), and None is returned."""
        topic = TOPICS[event.topic]
        try:
            return getattr(protocol, topic.message).decode(event.payload, *args)
        except ProtocolError as exc:
            self.count(topic.bad)
            self.warn(topic.bad, f"dropped a bad {topic.key.split('/{')[0]}: {exc}")
            return None

    def leave_out(self, *topics: str) -> None:
        """Do not subscribe to these optional topics of the node's row (nothing is then sent to it: a controller
        that is no visual servo takes no camera frames); :func:`declare_topics` checks that they are optional."""
        self.subscribes = tuple(t for t in self.subscribes if t not in topics)

    def count(self, what: str) -> None:
        self.counters[what] = self.counters.get(what, 0) + 1

    def declare(self, session: zenoh.Session, inbox: Inbox) -> list[Any]:
        """Called once the listed topics are declared (``self.publishers`` is filled): declare anything
        else (a liveliness watch) and return it, to be kept alive and undeclared at the end."""
        return []

    def reply(self, topic: str) -> bytes:
        """The answer to a ``get`` on a queryable topic this node publishes (``session/info``)."""
        raise NotImplementedError(topic)

    def handle(self, event: Event) -> None:
        """One event from the inbox (never a ``status`` event: :func:`serve` handles those)."""

    def idle(self, now: float) -> None:
        """Called after each event (direct nodes; on whichever thread handled it) or batch of events
        (queued nodes), and at least every ``Node.idle_period`` seconds."""

    def timeout(self, now: float) -> float:
        """How long the loop may wait for the next event before calling :meth:`idle`."""
        return self.idle_period

    def on_status(self, status: Status) -> None:
        if status.state in ("finished", "aborted"):
            self.final_status = status
            self.done = True
            if status.state == "aborted":
                log(self.name, f"session aborted by the clock: {status.reason}")

    def close(self) -> None:
        """Last words before the session closes (flush files, print statistics)."""

    idle_period = 0.1


def pair(node: Node, pairing: Pairing, event: Event, m: int | None) -> tuple[State, Setpoint] | None:
    """A controller's ``state`` or ``setpoints`` event, decoded (a bad one counted and dropped) and given to
    ``pairing``: the (state, setpoint) pair it makes due, if any (the controller node and the SDK's)."""
    if event.topic == "state":
        state = node.decode(event, m)
        return None if state is None else pairing.on_state(state)
    if event.topic != "setpoints":
        return None  # (a camera's frames: an image-based servo's, cdpr_controller.ibvs)
    block = node.decode(event)
    return None if block is None else pairing.on_setpoints(block)


def pair_sensors(node: Node, pairing: Pairing, feedback: SensorFeedback, event: Event,
                 m: int | None) -> tuple[State, Setpoint] | None:
    """A controller's ``sensors`` event (``feedback: sensors``), decoded (a bad one counted and dropped), its
    estimated state given to ``pairing``: the (state, setpoint) pair it makes due, if any (the controller node
    and the SDK's). A reading without encoder lengths is counted (``sensors_without_encoders``) and left."""
    reading = node.decode(event, m)
    if reading is None:
        return None
    state = feedback.state(reading)
    if state is None:
        node.count("sensors_without_encoders")
        return None
    return pairing.on_state(state)


def newest_only(events: Iterable[Event], topics: tuple[str, ...]) -> Iterable[Event]:
    """``events`` without those of ``topics`` that a later event of the same topic supersedes (all of them
    when ``topics`` is empty)."""
    if not topics:
        return events
    batch = list(events)
    last = {e.topic: i for i, e in enumerate(batch) if e.topic in topics}
    return [e for i, e in enumerate(batch) if e.topic not in topics or last[e.topic] == i]


def set_realtime_priority(priority: int, inherited: bool = True) -> None:
    """Run this process under SCHED_FIFO at ``priority`` (1–99), like a ROS 2 realtime executor.

    Call it before opening the Zenoh session: the threads made afterwards (Zenoh's) inherit it;
    processes started afterwards too, unless ``inherited`` is False (SCHED_RESET_ON_FORK). A
    SCHED_FIFO thread runs before every normal one on its CPU, so the loop's steps are no longer
    delayed by other programs; Linux still keeps 5 % of each second for normal threads
    (``kernel.sched_rt_runtime_us``). Needs CAP_SYS_NICE or an rtprio resource limit; otherwise
    an InputError saying so.
    """
    if not 1 <= priority <= 99:
        raise InputError(f"--rt-priority: must be between 1 and 99, got {priority}")
    if not hasattr(os, "sched_setscheduler"):
        raise InputError("--rt-priority: this system has no SCHED_FIFO scheduling (Linux only)")
    try:
        policy = os.SCHED_FIFO if inherited else os.SCHED_FIFO | os.SCHED_RESET_ON_FORK
        os.sched_setscheduler(0, policy, os.sched_param(priority))
    except OSError as exc:
        raise InputError(
            f"--rt-priority: SCHED_FIFO priority {priority} not permitted ({exc.strerror}); it needs "
            "CAP_SYS_NICE or an rtprio limit (ulimit -r, or docker's --cap-add SYS_NICE --ulimit rtprio=99)"
        ) from None


_cpu_latency_requests: list[int] = []  # the open /dev/cpu_dma_latency: the limit holds while it is open


def hold_cpu_latency(microseconds: int) -> None:
    """Hold Linux's PM QoS CPU latency limit at ``microseconds`` for as long as this process lives: the
    kernel keeps every CPU out of idle states slower to leave than that. With 0 an idle CPU polls instead
    of halting, so the thread a message wakes runs at once instead of after the CPU (in a virtual machine:
    the vCPU) comes back from sleep — tens of µs per hop, every step. The setting of realtime Linux
    benchmarks (cyclictest) and of tuned's ``latency-performance`` profile; it costs power (idle CPUs stay
    busy). Needs root, or write access to ``/dev/cpu_dma_latency`` (Docker: map the device); otherwise an
    InputError saying so."""
    if microseconds < 0:
        raise InputError(f"--cpu-latency: must be 0 or more microseconds, got {microseconds}")
    try:
        fd = os.open("/dev/cpu_dma_latency", os.O_WRONLY)
    except OSError as exc:
        raise InputError(f"--cpu-latency: cannot open /dev/cpu_dma_latency ({exc.strerror}): it needs root or "
                         "write access to the device (docker: --device /dev/cpu_dma_latency)") from None
    os.write(fd, struct.pack("i", microseconds))
    _cpu_latency_requests.append(fd)


def _realtime_scheduled() -> bool:
    """Whether the calling thread runs under SCHED_FIFO (see :func:`set_realtime_priority`)."""
    if not hasattr(os, "sched_getscheduler"):
        return False
    return os.sched_getscheduler(0) & ~getattr(os, "SCHED_RESET_ON_FORK", 0) == os.SCHED_FIFO


def _parent_alive(pid: int | None) -> bool:
    if pid is None:
        return True
    return os.getppid() == pid


SPIN = 2e-4  # seconds before a deadline at which the main thread stops sleeping and starts polling


class _Dispatcher:
    """Runs a node's handlers one at a time, on whichever thread calls it (Zenoh's or the main one).

    Every event goes into a queue first, and the thread that holds the lock handles the queue. A thread that
    finds the lock taken leaves its event there and returns at once: Zenoh's receiving thread never waits for
    another thread's handler (the main thread's chores, a deadline's step), it goes on receiving. A call
    made while the same thread is already inside a handler (a publication delivered synchronously to a
    subscriber of the same process) is queued too and run right after the current handler, never nested.
    A thread that releases the lock looks at the queue again, so that an event left while it was releasing
    is not stranded. The first exception stops the dispatcher and is kept for the main thread to raise.
    """

    def __init__(self, node: Node, on_event: Callable[[Event], None], wake: threading.Event,
                 stop: StopFlag) -> None:
        self._node = node
        self._on_event = on_event
        self._wake = wake
        self._stop = stop
        self._lock = threading.RLock()
        self._busy = False  # a thread is inside (read without the lock: see _pump)
        self._backlog: deque[Event] = deque()
        self.error: BaseException | None = None
        self.closed = False

    def __call__(self, event: Event) -> None:
        """Handle one event (or leave it to the thread handling events now), then let the node act on it
        (:meth:`Node.idle`)."""
        self._backlog.append(event)
        self._pump()

    def _pump(self) -> None:
        """Handle the queue if no thread is inside (this one included); else leave it to that thread, which
        looks at the queue again once it has released the lock. Nothing is handled once the node is done."""
        while self._backlog and not self._busy:
            if self._node.done:
                self._wake.set()  # the main thread must notice the end
                return
            if not self._lock.acquire(blocking=False):
                return  # another thread is about to release it, and will look again
            try:
                if self.closed or self._stop:  # after a signal, nothing more is handled
                    self._backlog.clear()
                    return
                self._busy = True
                self._handle()
            finally:
                self._busy = False
                self._lock.release()

    def _handle(self) -> None:
        node = self._node
        try:
            while True:
                self._drain()
                now = time.monotonic()
                node.idle(now)  # which may publish to this very process: drained in the next turn
                if not self._backlog or node.done or self._stop:  # (after a signal nothing is drained)
                    break
            if node.done or node.timeout(now) < node.idle_period:
                self._wake.set()  # the main thread has a deadline to meet, or the end to handle
        except BaseException as exc:
            self.error, self.closed = exc, True
            self._backlog.clear()
            self._wake.set()

    def _drain(self) -> None:
        """Handle the queued events (not after the end or a signal)."""
        while self._backlog and not self._node.done and not self._stop:
            self._on_event(self._backlog.popleft())

    def run(self, fn: Callable[[], None]) -> float:
        """Run ``fn`` (the main thread's chores) under the lock; the node's timeout afterwards."""
        with self._lock:
            if self.closed:
                return 0.0
            self._busy = True
            try:
                fn()
                self._drain()
                timeout = self._node.timeout(time.monotonic())
            except BaseException as exc:
                self.error, self.closed = exc, True
                return 0.0
            finally:
                self._busy = False
        self._pump()  # what came while the chores ran
        return 0.0 if self.closed else timeout

    def close(self) -> None:
        with self._lock:
            self.closed = True


def _sleep_until(wake: threading.Event, deadline: float, precise: bool) -> None:
    """Sleep until ``deadline`` (time.monotonic) or until ``wake`` is set, whichever comes first.

    ``precise``: sleep only until :data:`SPIN` before the deadline, then poll the clock (releasing
    the GIL at every turn, the CPU kept) until it has passed — the OS timer alone may wake a thread
    late by its slack and the scheduler's latency. Not under SCHED_FIFO: there the timer has no slack
    and the woken thread runs at once, and polling would keep normal processes off that CPU.
    """
    rest = deadline - time.monotonic()
    if not precise or _realtime_scheduled():
        wake.wait(max(rest, 0.0))
        return
    if rest > SPIN and wake.wait(rest - SPIN):
        return
    while time.monotonic() < deadline and not wake.is_set():
        time.sleep(0)


_PR_SET_TIMERSLACK = 29  # prctl(2)
_precise_threads = threading.local()


def sleep_precisely(seconds: float) -> None:
    """Sleep ``seconds`` (a realtime step or less) on the calling thread, its timer slack set to 1 µs first
    (Linux's default lets a sleeping thread wake up to 50 µs late; the setting is per thread, made once)."""
    if not getattr(_precise_threads, "set", False):
        _precise_threads.set = True
        with contextlib.suppress(OSError, AttributeError):
            ctypes.CDLL(None, use_errno=True).prctl(_PR_SET_TIMERSLACK, 1, 0, 0, 0)
    time.sleep(seconds)


def declare_topics(node: Node, session: zenoh.Session, inbox: Inbox) -> list[Any]:
    """Declare what ``node`` lists (checked against the wiring table), then its own extras, then
    ``status`` (every node's); return what must be kept alive."""
    check_node(type(node).name, node.subscribes, node.publishes)  # the role (an instance may rename itself)
    keys = node.keys
    keep: list[Any] = []  # publishers, subscribers, queryables: kept alive as long as the node serves
    def on_ping(query: zenoh.Query) -> None:  # an echo, answered on Zenoh's thread (never waits for the node)
        query.reply(query.key_expr, b"" if query.payload is None else query.payload.to_bytes())

    # The queries are answered on Zenoh's thread (indirect=False), not on a Python thread of the binding's: such a
    # thread ends only after its queryable is gone, and one still ending while the interpreter exits is killed
    # inside the binding, which aborts the process ("FATAL: exception not rethrown", exit code -6) after a
    # session that went well.
    keep.append(session.declare_queryable(keys.topic("ping", node.name),
                                          zenoh.handlers.Callback(on_ping, indirect=False)))
    for topic in node.publishes:
        if TOPICS[topic].transport == "queryable":
            def on_query(query: zenoh.Query, topic: str = topic) -> None:
                query.reply(query.key_expr, node.reply(topic))

            keep.append(session.declare_queryable(keys.topic(topic), zenoh.handlers.Callback(on_query, indirect=False)))
        elif "{" not in TOPICS[topic].key:  # a key per instance (sim/camera/<name>): the node declares them
            node.publishers[topic] = session.declare_publisher(keys.topic(topic, node.name), **PUBLISH_OPTS)
    keep.extend(node.publishers.values())
    keep.extend(inbox.subscribe(session, keys.topic(topic), topic) for topic in node.subscribes)
    keep.extend(node.declare(session, inbox))
    keep.append(inbox.subscribe(session, keys.status, "status"))
    return keep


def _event_handler(node: Node) -> Callable[[Event], None]:
    """The node's handler: ``clock/status`` decoded for :meth:`Node.on_status`, the rest to :meth:`Node.handle`."""

    def on_event(event: Event) -> None:
        if event.topic == "status":
            if (status := node.decode(event)) is not None:
                node.on_status(status)
        else:
            node.handle(event)

    return on_event


class _ServedNode:
    """One node on an open session: its topics, its stats publisher and liveliness token, its chores."""

    def __init__(self, node: Node, session: zenoh.Session, inbox: Inbox, parent: int | None) -> None:
        self.node, self.parent = node, parent
        self.keep = declare_topics(node, session, inbox)
        self.stats_pub = session.declare_publisher(node.keys.stats(node.name))
        self.token = session.liveliness().declare_token(node.keys.alive(node.name))
        self.published: dict[str, int] = {}
        self.last_stats = time.monotonic()

    def publish_stats(self) -> None:
        self.last_stats = time.monotonic()
        if self.node.counters != self.published:
            self.published = dict(self.node.counters)
            self.stats_pub.put(ServiceStats(self.node.name, self.published).encode())

    def chores(self) -> None:
        """Once per turn of the main loop: the node's idle hook, the stats, the parent's check."""
        node, now = self.node, time.monotonic()
        node.idle(now)
        if now - self.last_stats >= 1.0:
            self.publish_stats()
        if not _parent_alive(self.parent):
            log(node.name, "the process that launched this service is gone; stopping")
            node.done = True

    def close(self) -> None:
        self.node.close()
        self.publish_stats()
        self.token.undeclare()
        self.stats_pub.undeclare()
        for entity in reversed(self.keep):  # the node's extras (declared last) before what they hang on
            undeclare = getattr(entity, "undeclare", None)
            if undeclare is not None:
                undeclare()


def _freeze() -> None:
    """Everything made so far (modules, the nodes, their models) lives as long as the process: out of
    the garbage collector's sight, a full collection no longer scans ~70 000 objects (~30 ms, with the
    GIL held: a stalled step). Called before the node's liveliness token is declared: this collection
    itself takes tens of milliseconds, during which no Zenoh callback of the process can run (tick 0
    reached a sim 47 ms late when it came after the token)."""
    gc.collect()
    gc.freeze()


def _exit_code(nodes: list[Node], stop: StopFlag) -> int:
    if stop.signal is not None:
        return 128 + stop.signal
    return max((n.exit_code for n in nodes), default=0)


def serve(node: Node, conf: zenoh.Config, stop: StopFlag | None = None) -> int:
    """Run ``node`` until it is done; return the process exit code (0 ok, 1 failure, 130/143 signal)."""
    stop = stop or StopFlag().install()
    faulthandler.register(signal.SIGUSR1, all_threads=True)  # SIGUSR1: every thread's stack on stderr
    parent = _launcher_pid()
    try:
        session = open_session(conf, node.name)
    except InputError as exc:
        log(node.name, str(exc))
        return 2
    on_event = _event_handler(node)
    with session:
        wake = threading.Event()
        dispatcher = _Dispatcher(node, on_event, wake, stop) if node.direct else None
        stop.on_set(wake.set)  # a signal wakes the main thread at once
        inbox = Inbox(dispatcher, direct=node.ordered)
        if dispatcher is None:
            stop.on_set(inbox.wake)  # a queued node: ends the main thread's wait for the next event
        _freeze()  # before the token: a peer that sees it may send at once, and the collection holds the GIL
        host = _ServedNode(node, session, inbox, parent)
        try:
            if dispatcher is not None:
                while not node.done and not stop and dispatcher.error is None:
                    wake.clear()  # before the chores: a wake-up from now on ends the sleep below
                    timeout = dispatcher.run(host.chores)
                    if node.done or stop or dispatcher.error is not None:
                        break
                    now = time.monotonic()
                    _sleep_until(wake, now + min(timeout, node.idle_period), timeout < node.idle_period)
                dispatcher.close()
                if dispatcher.error is not None:
                    raise dispatcher.error
            else:
                while not node.done and not stop:
                    for event in newest_only(inbox.drain(node.timeout(time.monotonic())), node.keep_last):
                        on_event(event)
                        if node.done or stop:  # a signal must not wait for a backlog to drain
                            break
                    host.chores()
        finally:
            if dispatcher is not None:
                dispatcher.close()
            host.close()
    return _exit_code([node], stop)


def _launcher_pid() -> int | None:
    """The process that launched this one (``$CDPR_PARENT_PID``), whose end ends the service."""
    return int(os.environ[PARENT_ENV]) if os.environ.get(PARENT_ENV, "").isdigit() else None


def serve_group(nodes: list[Node], conf: zenoh.Config, stop: StopFlag | None = None) -> int:
    """:func:`serve` for several nodes in this process (``python -m cdpr.runtime sim+ros2``): one Zenoh
    session opened from ``conf``, the nodes composed on it (:func:`serve_composed`); the exit code."""
    stop = stop or StopFlag().install()
    faulthandler.register(signal.SIGUSR1, all_threads=True)
    parent = _launcher_pid()
    name = "+".join(n.name for n in nodes)
    try:
        session = open_session(conf, name)
    except InputError as exc:
        log(name, str(exc))
        return 2
    with session:
        return serve_composed(nodes, session, stop, parent=parent)


def serve_composed(nodes: list[Node], session: zenoh.Session, stop: StopFlag | None = None,
                   on_turn: Callable[[], None] | None = None, freeze: bool = True, parent: int | None = None) -> int:
    """Run ``nodes`` in this process on one open Zenoh ``session`` until every one is done (ROS 2's
    composition, Drake's diagram): the same node classes as their own processes, the same topics and
    messages, delivered by Zenoh within the session (synchronously, on the publishing thread). Every
    node is handled directly (each by its own dispatcher: a node's handlers never overlap, a node that
    publishes to itself gets the message after its handler returns). ``on_turn`` runs once per turn of
    the main loop (the launcher's progress line). The exit code: 128 + signal, else the nodes' worst.
    ``freeze=False`` leaves the garbage collector alone (a library serving a node per episode, :mod:`cdpr.gym`).
    ``parent``: the launcher's pid, watched as :func:`serve` does.
    """
    stop = stop or StopFlag().install()
    wake = threading.Event()
    stop.on_set(wake.set)
    runners: list[tuple[Node, _Dispatcher, _ServedNode]] = []
    closed: set[int] = set()

    def close(i: int) -> None:  # a node that is done leaves at once (its token goes: the clock sees it)
        if i not in closed:
            closed.add(i)
            _, dispatcher, host = runners[i]
            dispatcher.close()
            host.close()

    try:
        if freeze:
            _freeze()  # before the first token (see serve)
        for node in nodes:
            dispatcher = _Dispatcher(node, _event_handler(node), wake, stop)
            runners.append((node, dispatcher, _ServedNode(node, session, Inbox(dispatcher), parent)))
        while not stop:
            wake.clear()  # before the turn: a wake-up from now on ends the sleep below
            timeout = math.inf
            for i, (node, dispatcher, host) in enumerate(runners):
                if i not in closed:
                    timeout = min(timeout, dispatcher.run(host.chores))
                    if dispatcher.error is not None:
                        raise dispatcher.error
                    if node.done:
                        close(i)
            if on_turn is not None:
                on_turn()
            live = [node for i, (node, _, _) in enumerate(runners) if i not in closed]
            if not live:
                break
            idle = min(n.idle_period for n in live)
            if not any(n.done for n in live):
                _sleep_until(wake, time.monotonic() + min(timeout, idle), timeout < idle)
    finally:
        for i in reversed(range(len(runners))):
            close(i)
    return _exit_code(nodes, stop)
