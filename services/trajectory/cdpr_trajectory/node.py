"""The trajectory node: setpoints ahead of the clock's grants, in blocks on ``trajectory/setpoints``.

The trajectory does not depend on the state, so it runs ahead: when a tick grants steps up to ``until``
and fewer than :data:`AHEAD`/2 setpoints are out beyond it, the next block goes out, up to ``until`` +
:data:`AHEAD` (never past the last step). A ``resend`` tick publishes again everything from its step
on (a controller that came back has lost them).
"""

from __future__ import annotations

import functools
from collections.abc import Callable
from typing import Any

import zenoh

from cdpr.config.scenario import Scenario
from cdpr.protocol import Keys, Setpoint, Setpoints
from cdpr.runtime.service import Node
from cdpr.runtime.transport import Event, Inbox
from cdpr_trajectory.core import setpoint_at, setpoints_between

AHEAD = 100  # setpoints published beyond the last granted step


class TrajectoryNode(Node):
    name = "trajectory"
    direct = True  # handled on Zenoh's receive thread: no hand-off between a message and its answer

    @classmethod
    def make_core(cls, scenario: Scenario) -> Callable[[int], Setpoint]:
        """Step k → setpoint k."""
        return functools.partial(setpoint_at, scenario.trajectory, dt=scenario.dt)

    @classmethod
    def make_block_core(cls, scenario: Scenario) -> Callable[[int, int], tuple[Setpoint, ...]]:
        """Steps first … last → their setpoints (what the node publishes: :func:`setpoints_between`)."""
        return functools.partial(setpoints_between, scenario.trajectory, dt=scenario.dt)

    def __init__(self, scenario: Scenario, keys: Keys) -> None:
        super().__init__(keys)
        self.trajectory = scenario.trajectory
        self.dt = scenario.dt
        self.last_step = scenario.total_steps - 1
        self.published = -1  # the last setpoint published
        self._pub: zenoh.Publisher | None = None

    def declare(self, session: zenoh.Session, inbox: Inbox) -> list[Any]:
        self._pub = self.publishers["setpoints"]
        return []

    def handle(self, event: Event) -> None:
        tick = self.decode(event)
        if tick is None:
            return
        if tick.resend:
            self.publish(tick.step, self.published)
        if tick.until > self.published - AHEAD // 2 and self.published < self.last_step:
            self.publish(self.published + 1, min(tick.until + AHEAD, self.last_step))

    def publish(self, first: int, last: int) -> None:
        assert self._pub is not None
        if last >= first:
            self._pub.put(Setpoints(setpoints_between(self.trajectory, first, last, self.dt)).encode())
            self.published = max(self.published, last)
