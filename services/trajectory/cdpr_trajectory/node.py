"""The trajectory node: on every ``clock/tick`` k, publish ``trajectory/setpoint`` k."""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import zenoh

from cdpr.config.scenario import Scenario
from cdpr.protocol import Keys, ProtocolError, Setpoint, Tick
from cdpr.runtime.service import Node
from cdpr.runtime.transport import Event, Inbox, RateLimitedLog
from cdpr_trajectory.core import setpoint_at


class TrajectoryNode(Node):
    name = "trajectory"
    direct = True  # handled on Zenoh's receive thread: no hand-off between a message and its answer

    @classmethod
    def make_core(cls, scenario: Scenario) -> Callable[[int], Setpoint]:
        """Step k → setpoint k."""
        return functools.partial(setpoint_at, scenario.trajectory, dt=scenario.dt)

    def __init__(self, scenario: Scenario, keys: Keys) -> None:
        super().__init__(keys)
        self.trajectory = scenario.trajectory
        self.dt = scenario.dt
        self.warn = RateLimitedLog(self.name)
        self._pub: zenoh.Publisher | None = None

    subscribes = ("tick",)
    publishes = ("setpoint",)

    def declare(self, session: zenoh.Session, inbox: Inbox) -> list[Any]:
        self._pub = self.publishers["setpoint"]
        return []

    def handle(self, event: Event) -> None:
        try:
            tick = Tick.decode(event.payload)
        except ProtocolError as exc:
            self.count("bad_ticks")
            self.warn("bad_tick", f"dropped a bad clock/tick: {exc}")
            return
        assert self._pub is not None
        self._pub.put(setpoint_at(self.trajectory, tick.step, self.dt).encode())
