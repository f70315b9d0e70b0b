"""A live Foxglove view of a session: foxglove-sdk's WebSocket server (``foxglove.websocket.v1``).

Foxglove (the app, or any client of Foxglove's WebSocket protocol) connects to it as to a robot and
subscribes to the channels of :class:`cdpr.recording.mcap.FoxgloveSink`, which logs the same messages
as into an MCAP file. The server advertises the ``time`` capability: after each batch it broadcasts the
simulation time of the latest message, so the viewer's clock follows the simulation, not the wall clock.
It listens on 127.0.0.1 unless told otherwise.
"""

from __future__ import annotations

import threading
import time
from typing import Any

from foxglove.websocket import ServerListener

from cdpr.errors import InputError

DEFAULT_PORT = 8765  # Foxglove's usual WebSocket port
DEFAULT_HOST = "127.0.0.1"
LINGER = 1.0  # seconds the server stays up after the last batch while a client is subscribed: its queue
#              of messages is sent by the server's own threads, and closing the channels or stopping the
#              server drops what is still queued


class _Subscriptions(ServerListener):
    """The server's listener: which (client, channel) pairs are subscribed right now."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.pairs: set[tuple[int, int]] = set()

    def on_subscribe(self, client: Any, channel: Any) -> None:
        with self.lock:
            self.pairs.add((client.id, channel.id))

    def on_unsubscribe(self, client: Any, channel: Any) -> None:
        with self.lock:
            self.pairs.discard((client.id, channel.id))

    def __bool__(self) -> bool:
        with self.lock:
            return bool(self.pairs)


class LiveServer:
    """A Foxglove WebSocket server with a context of its own; ``port`` 0 picks a free port."""

    def __init__(self, port: int = DEFAULT_PORT, host: str = DEFAULT_HOST, name: str = "cdpr",
                 backlog: int = 1 << 15) -> None:
        import foxglove
        from foxglove.websocket import Capability

        if not 0 <= port <= 65535:
            raise InputError(f"--foxglove: port must be between 0 and 65535, got {port}")
        self.host = host
        self.context = foxglove.Context()
        self.subscriptions = _Subscriptions()
        try:
            self.server: Any = foxglove.start_server(
                name=name, host=host, port=port, context=self.context, capabilities=[Capability.Time],
                message_backlog_size=backlog, server_listener=self.subscriptions,
            )
        except Exception as exc:  # the SDK raises RuntimeError for a port in use or an unknown host
            first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
            raise InputError(f"--foxglove: cannot listen on {host}:{port}: {first}") from None
        self.port = int(self.server.port)

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    def broadcast_time(self, ns: int) -> None:
        self.server.broadcast_time(int(ns))

    def linger(self, seconds: float = LINGER) -> None:
        """Before the end (channels closed, server stopped): a subscribed client gets ``seconds`` to receive
        what is still queued for it."""
        if self.subscriptions:
            time.sleep(seconds)

    def close(self) -> None:
        self.server.stop()
