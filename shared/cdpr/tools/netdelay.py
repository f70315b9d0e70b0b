"""A TCP forwarding proxy that delays each direction by a fixed time: a slow link on one machine.

``cdpr delay-proxy --listen 127.0.0.1:7448 --to 127.0.0.1:7447 --delay-ms 1`` forwards every connection
made to ``--listen`` to ``--to``, each chunk of bytes leaving ``delay`` seconds after it arrived, in order
(what ``tc netem delay`` does to a link, for kernels without netem). A Zenoh participant in client mode
connected to the proxy (``--connect tcp/127.0.0.1:7448``) then sees its router across a link whose
round trip is at least twice the delay (docs/realtime.md). Two threads per direction: one reads and
stamps, one sleeps until each chunk is due and writes it.
"""

from __future__ import annotations

import collections
import contextlib
import socket
import threading
import time
from dataclasses import dataclass, field

CHUNK = 65536


def parse_address(text: str) -> tuple[str, int]:
    """``HOST:PORT`` (IPv6 in brackets) as a socket address; ValueError naming the text if it is not one."""
    host, _, port = text.rpartition(":")
    if not host or not port.isdigit():
        raise ValueError(f"expected HOST:PORT, got {text!r}")
    return host.strip("[]"), int(port)


@dataclass
class _Direction:
    """One direction of one connection: chunks stamped with the time they are due."""

    source: socket.socket
    target: socket.socket
    delay: float
    queue: collections.deque[tuple[float, bytes]] = field(default_factory=collections.deque)
    ready: threading.Condition = field(default_factory=threading.Condition)
    closed: bool = False

    def read(self) -> None:
        try:
            while data := self.source.recv(CHUNK):
                with self.ready:
                    self.queue.append((time.monotonic() + self.delay, data))
                    self.ready.notify()
        except OSError:
            pass
        with self.ready:
            self.closed = True
            self.ready.notify()

    def write(self) -> None:
        try:
            while True:
                with self.ready:
                    while not self.queue and not self.closed:
                        self.ready.wait()
                    if not self.queue:
                        break
                    due, data = self.queue.popleft()
                wait = due - time.monotonic()
                if wait > 0:
                    time.sleep(wait)
                self.target.sendall(data)
        except OSError:
            pass
        finally:
            for s in (self.source, self.target):
                with contextlib.suppress(OSError):
                    s.shutdown(socket.SHUT_RDWR)


class DelayProxy:
    """Forward connections to ``listen`` to ``target``, each direction delayed by ``delay`` seconds.

    ``with DelayProxy(("127.0.0.1", 0), ("127.0.0.1", 7447), 0.001) as proxy:`` serves in background
    threads; ``proxy.port`` is the port it listens on."""

    def __init__(self, listen: tuple[str, int], target: tuple[str, int], delay: float) -> None:
        if not delay >= 0:
            raise ValueError(f"delay must be >= 0 s, got {delay}")
        self.target, self.delay = target, delay
        self._server = socket.create_server(listen, reuse_port=False)
        self.port = self._server.getsockname()[1]
        self._stop = False
        self._sockets: list[socket.socket] = []
        self._thread = threading.Thread(target=self._accept, name="delay-proxy", daemon=True)

    def __enter__(self) -> DelayProxy:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()

    def _accept(self) -> None:
        while not self._stop:
            try:
                client, _ = self._server.accept()
            except OSError:
                return
            try:
                upstream = socket.create_connection(self.target)
            except OSError:
                client.close()
                continue
            for s in (client, upstream):
                s.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
            self._sockets += [client, upstream]
            for d in (_Direction(client, upstream, self.delay), _Direction(upstream, client, self.delay)):
                threading.Thread(target=d.read, daemon=True).start()
                threading.Thread(target=d.write, daemon=True).start()

    def close(self) -> None:
        self._stop = True
        with contextlib.suppress(OSError):
            self._server.shutdown(socket.SHUT_RDWR)  # wakes the accept() under way (Linux)
        self._server.close()
        for s in self._sockets:
            with contextlib.suppress(OSError):
                s.shutdown(socket.SHUT_RDWR)
            s.close()

