"""Zenoh plumbing shared by every service: the config builder, session opening, subscriptions.

The only place that builds a ``zenoh.Config`` (from CLI flags, ``ZENOH_CONFIG`` or ``--zenoh-config``)
and that sets Zenoh's thread pools (:data:`ZENOH_RUNTIME`). :class:`Inbox` turns samples into
:class:`Event` s, queued for a loop or handed to a handler on Zenoh's thread; how a service runs its
loop on them is :func:`cdpr.runtime.service.serve`'s business.
"""

from __future__ import annotations

import ctypes
import json
import os
import queue
import re
import signal
import sys
import threading
import time
from collections.abc import Callable, Iterator, Sequence
from dataclasses import dataclass
from types import FrameType
from typing import Any

import zenoh

from cdpr.errors import InputError

# Publications of the lock-step loop are small and must never be dropped: reliable, blocking
# congestion control, express (no batching delay).
PUBLISH_OPTS: dict[str, Any] = {
    "congestion_control": zenoh.CongestionControl.BLOCK,
    "priority": zenoh.Priority.REAL_TIME,
    "express": True,
    "reliability": zenoh.Reliability.RELIABLE,
}


CONNECT_TIMEOUT = 30.0  # seconds a client keeps trying to reach its endpoints before giving up

# Where Zenoh's access control logs each message a router's rules drop ("<zid> on …+Username(observer)+… is
# unauthorized to Put (ingress) on <key>"): `cdpr router --log-denials`, or this as RUST_LOG.
DENIALS_LOG = "zenoh::net::routing::interceptor::access_control=trace"


def may_be_denied(key: str) -> str:
    """The end of a diagnosis that names a stream that did not come: the secure profile's access rules may have
    dropped it (docs/security.md), and how to see it."""
    return (f"nothing came on {key}; if the router enforces access rules (the secure profile), they may deny "
            "it: `cdpr router --log-denials` logs each denial (docs/security.md)")


def zenoh_config(
    mode: str = "peer",
    connect: Sequence[str] = (),
    listen: Sequence[str] = (),
    config_file: str | None = None,
    connect_timeout: float = CONNECT_TIMEOUT,
) -> zenoh.Config:
    """A Zenoh config: a JSON5 file (``config_file`` or ``$ZENOH_CONFIG``) plus the given overrides.

    With explicit endpoints, multicast scouting is switched off so that sessions on one machine never
    join each other by accident; without any, Zenoh's defaults apply (multicast discovery on the LAN).
    A client keeps retrying its endpoints for ``connect_timeout`` seconds, so a service may be started
    before the router it connects to.
    """
    path = config_file or os.environ.get("ZENOH_CONFIG")
    if path:
        try:
            conf = zenoh.Config.from_file(path)
        except Exception as exc:  # zenoh raises ZError with the parser's message
            raise InputError(f"{path}: not a valid Zenoh JSON5 config: {str(exc).splitlines()[0]}") from None
    else:
        conf = zenoh.Config()
    if mode not in ("peer", "client", "router"):
        raise InputError(f"--mode: Zenoh mode must be peer, client or router, got {mode!r}")
    if not path or mode != "peer":
        conf.insert_json5("mode", json.dumps(mode))
    if not path:
        # Zenoh puts a payload above 3 KB through shared memory when the peer is on the same machine. The
        # second such put of a process sets the shared memory up: ~5 ms of the publishing thread (the sim's
        # loop: its second telemetry block, step 100, started a burst of late steps in every realtime
        # session), and every such put costs more than a copy through the socket (40 vs 20 µs for 20 KB).
        # The session's payloads are small: off, unless a config file says otherwise.
        conf.insert_json5("transport/shared_memory/enabled", "false")
    if connect:
        conf.insert_json5("connect/endpoints", json.dumps(list(connect)))
        conf.insert_json5("connect/timeout_ms", json.dumps({mode: int(connect_timeout * 1000)}))
        conf.insert_json5(
            "connect/retry", json.dumps({"period_init_ms": 100, "period_max_ms": 1000, "period_increase_factor": 2})
        )
    if listen:
        conf.insert_json5("listen/endpoints", json.dumps(list(listen)))
    if connect or listen:
        conf.insert_json5("scouting/multicast/enabled", "false")
        if mode == "router" and not path:
            # Zenoh's open() waits scouting/delay (500 ms) for peers found by scouting; with multicast off
            # a router finds nobody, it is connected to: no reason to wait before it can serve
            conf.insert_json5("scouting/delay", "0")
    return conf


def isolated_config() -> zenoh.Config:
    """A Zenoh peer that neither listens, connects nor scouts: a session private to this process (the
    in-process composition of ``cdpr run --in-process``)."""
    conf = zenoh.Config()
    conf.insert_json5("mode", json.dumps("peer"))
    conf.insert_json5("listen/endpoints", "[]")
    conf.insert_json5("scouting/multicast/enabled", "false")
    conf.insert_json5("scouting/gossip/enabled", "false")
    return conf


# Zenoh's thread pools for a cdpr process (unless $ZENOH_RUNTIME says otherwise): one worker thread
# receives, routes and runs the subscribers' callbacks (rx, and the rarely used acceptor and
# housekeeping pools, handed over to it), one transmits. Zenoh's default (two rx workers, plus app,
# acc, net, tx) wakes several threads per message, which on a small machine costs more CPU than the
# message itself. Transmission keeps its own thread, which never needs Python's GIL: a put() waits for it
# when the queue is full, perhaps holding the GIL that a callback on the receiving worker waits for.
# (Handing transmission over to the receiving worker too was faster — 2 kHz realtime 95-96 -> 97-99 %
# of the steps on time, fast mode +10 % — until exactly that happened: a free-running sim's put() of a
# telemetry block through a router stalled the process until Zenoh closed the link, 5 s later.)
ZENOH_RUNTIME = (
    "(rx: (handover: app), acc: (handover: app), net: (handover: app), "
    "app: (worker_threads: 1), tx: (worker_threads: 1))"
)


def open_session(conf: zenoh.Config, what: str) -> zenoh.Session:
    """Open a Zenoh session, turning a bad endpoint or a port in use into one InputError line.

    The first session of the process fixes Zenoh's thread pools: :data:`ZENOH_RUNTIME`, unless the
    environment variable of that name is set.
    """
    os.environ.setdefault("ZENOH_RUNTIME", ZENOH_RUNTIME)
    try:
        return zenoh.open(conf)
    except Exception as exc:
        text = str(exc).strip().splitlines()[0] if str(exc).strip() else type(exc).__name__
        text = re.sub(r"\s+at /\S+\.rs:\d+\.?", "", text)  # Rust source locations mean nothing to a user
        if "Address already in use" in text:
            where = re.search(r"bound to (\S+?):?\s", text + " ")
            text = f"{where.group(1) if where else 'the listen endpoint'} is already in use (choose another port)"
        elif "Unable to connect" in text:
            text = f"no Zenoh router or peer answered at {', '.join(_endpoints(conf))} ({text})"
        raise InputError(f"{what}: cannot open the Zenoh session: {text}") from None


def _endpoints(conf: zenoh.Config) -> list[str]:
    try:
        return list(json.loads(conf.get_json("connect/endpoints")))
    except Exception:  # a config without explicit endpoints
        return ["the configured endpoints"]


@dataclass(frozen=True, slots=True)
class Event:
    """One thing that happened to a service: a message on a key, or a liveliness change."""

    topic: str  # the topic's name (wiring.TOPICS: "tick", "state", …), or "alive" / "gone": a token came or went
    payload: bytes
    key: str
    received: float  # time.monotonic() at receipt, for statistics only (never for the simulation)


_WAKE = Event("wake", b"", "", 0.0)  # put by Inbox.wake: ends a wait, is never handed out


class _ThreadStatePin(threading.local):
    """Gives the Zenoh thread that runs a callback a Python thread state for the rest of its life.

    Zenoh's receive threads are not Python threads: for every callback, the binding creates a Python
    thread state and deletes it afterwards, and deleting one frees its frame stack with ``munmap`` —
    a TLB shootdown on every CPU, per message. One extra ``PyGILState_Ensure`` (never released) keeps
    the thread state, so the following callbacks reuse it. Called with the GIL held; idempotent.
    """

    pinned = False

    def __call__(self) -> None:
        if not self.pinned:
            ctypes.pythonapi.PyGILState_Ensure()
            self.pinned = True


pin_thread_state = _ThreadStatePin()


class Inbox:
    """Events from Zenoh's subscribers, for a service's single loop.

    By default each event is put on a queue that the service's loop takes out (:meth:`get`,
    :meth:`drain`). With a ``handler``, Zenoh's receive thread hands each event to it right there (no
    Python thread in between, the binding's ``indirect=False``) and the queue stays empty (see
    :func:`cdpr.runtime.service.serve`). ``direct``: queued, but by the thread that delivers the sample,
    as with a handler — for a session whose publishers all live in this process (the in-process
    composition), that is the publishing thread: the event is queued before ``put`` returns.
    """

    def __init__(self, handler: Callable[[Event], None] | None = None, direct: bool = False) -> None:
        self._q: queue.SimpleQueue[Event] = queue.SimpleQueue()
        self._deliver: Callable[[Event], None] = handler if handler is not None else self._q.put
        # Queued, the callback runs on a Python thread of the binding's (its "indirect" mode): Zenoh's
        # receive thread then never waits for this process's GIL — in `cdpr run` that thread is the
        # session's router, and the launcher's main thread may hold the GIL for a while (a garbage
        # collection of everything it has gathered). With a handler, the callback runs on Zenoh's
        # thread itself: nothing between the message and its handler.
        self._indirect = handler is None and not direct

    def subscribe(self, session: zenoh.Session, key: str, topic: str) -> zenoh.Subscriber:
        deliver, monotonic, pin = self._deliver, time.monotonic, pin_thread_state

        def on_sample(sample: zenoh.Sample) -> None:
            pin()
            deliver(Event(topic, sample.payload.to_bytes(), str(sample.key_expr), monotonic()))

        return session.declare_subscriber(key, zenoh.handlers.Callback(on_sample, indirect=self._indirect))

    def watch_liveliness(self, session: zenoh.Session, key: str) -> zenoh.Subscriber:
        """Liveliness tokens matching ``key``: events ``alive``/``gone``, current ones included."""
        deliver = self._deliver

        def on_token(sample: zenoh.Sample) -> None:
            pin_thread_state()
            came = "alive" if sample.kind == zenoh.SampleKind.PUT else "gone"
            deliver(Event(came, b"", str(sample.key_expr), time.monotonic()))

        return session.liveliness().declare_subscriber(
            key, zenoh.handlers.Callback(on_token, indirect=self._indirect), history=True
        )

    def wake(self) -> None:
        """End a wait in :meth:`get` now (it returns None, as on a timeout). Safe in a signal handler:
        a signal whose handler returns can leave an interrupted ``SimpleQueue.get(timeout=…)`` waiting
        for the next item with no timeout at all (CPython 3.11), so a stop must put one in."""
        self._q.put(_WAKE)

    def get(self, timeout: float | None) -> Event | None:
        try:
            ev = self._q.get(timeout=timeout) if timeout is None or timeout > 0 else self._q.get_nowait()
        except queue.Empty:
            return None
        return None if ev is _WAKE else ev

    def drain(self, timeout: float) -> Iterator[Event]:
        """Wait up to ``timeout`` for one event, then yield it and everything already queued."""
        ev = self.get(timeout)
        while ev is not None:
            yield ev
            ev = self.get(0)


class StopFlag:
    """Set by SIGINT/SIGTERM (or by the service itself); the loop checks it between events."""

    def __init__(self) -> None:
        self._event = threading.Event()
        self.signal: int | None = None
        self._listeners: list[Callable[[], None]] = []

    def on_set(self, listener: Callable[[], None]) -> None:
        """Call ``listener`` (on the signalled thread) whenever the flag is set, e.g. to wake a wait."""
        self._listeners.append(listener)

    def install(self) -> StopFlag:
        if threading.current_thread() is threading.main_thread():
            for sig in (signal.SIGINT, signal.SIGTERM):
                signal.signal(sig, self._on_signal)
        return self

    def _on_signal(self, signum: int, _frame: FrameType | None) -> None:
        self.signal = signum
        self.set()

    def set(self) -> None:
        self._event.set()
        for listener in self._listeners:
            listener()

    def __bool__(self) -> bool:
        return self._event.is_set()


def log(service: str, message: str) -> None:
    """One line on stderr, prefixed with the service name (services' human-readable log)."""
    sys.stderr.write(f"[{service}] {message}\n")  # one write, so lines of several processes don't mix
    sys.stderr.flush()


class RateLimitedLog:
    """Logs the first occurrences of a problem, then one line per interval with a count."""

    def __init__(self, service: str, every: float = 5.0, first: int = 5) -> None:
        self.service, self.every, self.first = service, every, first
        self.counts: dict[str, int] = {}
        self._last: dict[str, float] = {}

    def __call__(self, what: str, message: str) -> None:
        n = self.counts.get(what, 0) + 1
        self.counts[what] = n
        now = time.monotonic()
        if n <= self.first or now - self._last.get(what, 0.0) >= self.every:
            self._last[what] = now
            suffix = f" ({n} so far)" if n > self.first else ""
            log(self.service, f"{message}{suffix}")
