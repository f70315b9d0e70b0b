"""The shell every service shares: open Zenoh, declare, hold a liveliness token, run one event loop.

A service is a :class:`Node`: it declares what it reads and writes in :meth:`Node.declare`, handles one
:class:`~cdpr.transport.Event` at a time in :meth:`Node.handle`, and says when it is done. :func:`serve`
does the rest, the same way for every service: subscribers are declared before the liveliness token
(so whoever sees the token can already reach the service), the session ends on ``clock/status``
finished/aborted, on SIGINT/SIGTERM, or when the parent process that launched it is gone.
"""

from __future__ import annotations

import os
import time
from typing import Any

import zenoh

from cdpr.errors import InputError
from cdpr.protocol import Keys, ProtocolError, ServiceStats, Status
from cdpr.transport import Event, Inbox, StopFlag, log, open_session

PARENT_ENV = "CDPR_PARENT_PID"


class Node:
    """Base class of a service's node. Subclasses set ``name`` and override the hooks."""

    name = "node"

    def __init__(self, keys: Keys) -> None:
        self.keys = keys
        self.done = False
        self.exit_code = 0
        self.final_status: Status | None = None
        self.counters: dict[str, int] = {}  # fault counters, published on stats/{name}

    def count(self, what: str) -> None:
        self.counters[what] = self.counters.get(what, 0) + 1

    def declare(self, session: zenoh.Session, inbox: Inbox) -> list[Any]:
        """Declare subscribers (through ``inbox``) and publishers; return them to keep them alive."""
        return []

    def handle(self, event: Event) -> None:
        """One event from the inbox (never a ``status`` event: :func:`serve` handles those)."""

    def idle(self, now: float) -> None:
        """Called after each batch of events, and at least every ``Node.idle_period`` seconds."""

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


def _parent_alive(pid: int | None) -> bool:
    if pid is None:
        return True
    return os.getppid() == pid


def serve(node: Node, conf: zenoh.Config, stop: StopFlag | None = None) -> int:
    """Run ``node`` until it is done; return the process exit code (0 ok, 1 failure, 130/143 signal)."""
    stop = stop or StopFlag().install()
    parent = int(os.environ[PARENT_ENV]) if os.environ.get(PARENT_ENV, "").isdigit() else None
    try:
        session = open_session(conf, node.name)
    except InputError as exc:
        log(node.name, str(exc))
        return 2
    with session:
        inbox = Inbox()
        keep = node.declare(session, inbox)
        keep.append(inbox.subscribe(session, node.keys.status, "status"))
        stats_pub = session.declare_publisher(node.keys.stats(node.name))
        token = session.liveliness().declare_token(node.keys.alive(node.name))
        published: dict[str, int] = {}
        last_stats = time.monotonic()

        def publish_stats() -> None:
            nonlocal published, last_stats
            last_stats = time.monotonic()
            if node.counters != published:
                published = dict(node.counters)
                stats_pub.put(ServiceStats(node.name, published).encode())

        try:
            while not node.done and not stop:
                for event in inbox.drain(node.timeout(time.monotonic())):
                    if event.kind == "status":
                        try:
                            node.on_status(Status.decode(event.payload))
                        except ProtocolError as exc:
                            node.count("bad_status")
                            log(node.name, f"dropped a bad clock/status message: {exc}")
                    else:
                        node.handle(event)
                    if node.done or stop:  # a signal must not wait for a backlog to drain
                        break
                node.idle(time.monotonic())
                if time.monotonic() - last_stats >= 1.0:
                    publish_stats()
                if not _parent_alive(parent):
                    log(node.name, "the process that launched this service is gone; stopping")
                    break
        finally:
            node.close()
            publish_stats()
            token.undeclare()
            stats_pub.undeclare()
            for entity in keep:
                undeclare = getattr(entity, "undeclare", None)
                if undeclare is not None:
                    undeclare()
    if stop.signal is not None:
        return 128 + stop.signal
    return node.exit_code
