"""The trajectory node: on every ``clock/tick`` k, publish ``trajectory/setpoint`` k."""

from __future__ import annotations

from typing import Any

import zenoh

from cdpr.protocol import Keys, ProtocolError, Tick
from cdpr.scenario import Scenario
from cdpr.service import Node
from cdpr.transport import PUBLISH_OPTS, Event, Inbox, RateLimitedLog
from cdpr_trajectory.core import setpoint_at


class TrajectoryNode(Node):
    name = "trajectory"
    direct = True  # handled on Zenoh's receive thread: no hand-off between a message and its answer

    def __init__(self, scenario: Scenario, keys: Keys) -> None:
        super().__init__(keys)
        self.trajectory = scenario.trajectory
        self.dt = scenario.dt
        self.warn = RateLimitedLog(self.name)
        self._pub: zenoh.Publisher | None = None

    def declare(self, session: zenoh.Session, inbox: Inbox) -> list[Any]:
        self._pub = session.declare_publisher(self.keys.setpoint, **PUBLISH_OPTS)
        return [inbox.subscribe(session, self.keys.tick, "tick"), self._pub]

    def handle(self, event: Event) -> None:
        try:
            tick = Tick.decode(event.payload)
        except ProtocolError as exc:
            self.count("bad_ticks")
            self.warn("bad_tick", f"dropped a bad clock/tick: {exc}")
            return
        assert self._pub is not None
        self._pub.put(setpoint_at(self.trajectory, tick.step, self.dt).encode())
