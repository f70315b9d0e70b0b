"""Which command acts on step k: zero-order hold, a command latency and the watchdog. No I/O.

In lock-step without a latency, the command answering state k acts on step k, and the sim does not use
this module. Otherwise every command is *offered* with the step it may act from:

* free-running realtime (``--sync free``): the step the sim integrates next when the command arrives;
* a deterministic latency (scenario ``sim.command_latency``): ``k + steps + j``, ``j`` drawn uniformly in
  ``[0, jitter]``, or never if it is lost (probability ``loss``), by :class:`LatencyModel`.

Step k then applies the *newest* command that may act (the highest answered state among those whose
step has come): a zero-order hold, like a motor drive's. A command older than one already acting is
never used (counted as late). The **command age** of step k is ``k − j`` for the command answering state
j; before any command acts it counts from step −1 (and the sim applies its ``static`` tensions). The
**watchdog** trips on the steps where no new command has started acting for ``watchdog_steps`` steps:
the sim then applies its policy (:data:`cdpr.config.scenario.WATCHDOG_POLICIES`) instead of the held
command. A command that would act ``watchdog_steps`` or more steps after the state it answered is not new:
it never acts (counted as late), like a drive that refuses a setpoint older than its timeout — a controller
working through a backlog of old states (a restart, a stall) cannot throw the platform with them.
"""

from __future__ import annotations

import heapq
from dataclasses import dataclass, field
from typing import Generic, TypeVar

import numpy as np

from cdpr.config.scenario import CommandLatencySpec
from cdpr.mechanics.control import Variant, controlled_rows
from cdpr.mechanics.dynamics import required_wrench
from cdpr.mechanics.kinematics import WrenchMatrix
from cdpr.mechanics.outputs import CommandKind
from cdpr.mechanics.robot import Robot
from cdpr.mechanics.rotation import Array
from cdpr.mechanics.tda import TensionDistributor, make_tda

C = TypeVar("C")  # the command (cdpr.protocol.Command in the sim; anything in tests)


@dataclass(frozen=True)
class Applied(Generic[C]):
    """What acts on one step: the held command (None before the first acts), its age and whether the
    watchdog has tripped (the policy replaces the command)."""

    command: C | None
    answered: int  # the state it answered (-1: none yet)
    age: int  # k - answered
    watchdog: bool


@dataclass
class CommandHold(Generic[C]):
    """The commands offered so far and the one acting (module docstring)."""

    watchdog_steps: int  # steps without a new command before the watchdog trips (>= 1)
    held: C | None = None
    answered: int = -1  # the state the held command answered
    fresh_from: int = 0  # the step from which the held command acts
    late: int = 0  # commands older than one already offered, overtaken, or too old when due: never used
    newest: int = -1  # the newest state answered by a command offered
    _pending: list[tuple[int, int, int, C]] = field(default_factory=list, repr=False)  # (from, -answered, n, cmd)
    _n: int = 0  # offers so far (a heap tie-breaker)

    def offer(self, command: C, answered: int, acts_from: int) -> bool:
        """``command`` answers state ``answered`` and may act from step ``acts_from``; False if a command
        answering the same state (a repeat: ignored) or a newer one (counted as late: it will never act)
        was offered before it."""
        if answered <= self.newest:
            self.late += answered < self.newest
            return False
        self.newest = answered
        self._n += 1
        heapq.heappush(self._pending, (acts_from, -answered, self._n, command))
        return True

    def select(self, k: int) -> Applied[C]:
        """What acts on step ``k`` (steps are selected in increasing order)."""
        pending = self._pending
        while pending and pending[0][0] <= k:
            acts_from, neg, _, command = heapq.heappop(pending)
            if -neg > self.answered and k + neg < self.watchdog_steps:
                self.held, self.answered, self.fresh_from = command, -neg, max(acts_from, 0)
            else:  # overtaken by a newer command that acted first (jitter), or too old to be trusted
                self.late += 1
        tripped = self.held is not None and k - self.fresh_from >= self.watchdog_steps
        return Applied(self.held, self.answered, k - self.answered, tripped)


class LatencyModel:
    """How many steps each command is delayed, or whether it is lost (:class:`cdpr.config.scenario.CommandLatencySpec`):
    the command answering state k acts from step k + delay in lock-step, from its arrival + delay in
    free-running realtime. One draw per command, in the order they come (lock-step answers every state once,
    in order): the same scenario gives the same delays."""

    def __init__(self, spec: CommandLatencySpec) -> None:
        self.spec = spec
        self._rng = np.random.default_rng([spec.seed, 0x1A7E])

    def delay(self) -> int | None:
        """The next command's delay in steps (``steps`` + its jitter), or None if it is lost."""
        s = self.spec
        jitter = int(self._rng.integers(0, s.jitter + 1)) if s.jitter else 0
        lost = bool(self._rng.random() < s.loss) if s.loss > 0.0 else False
        return None if lost else s.steps + jitter


class StaticPolicy:
    """The watchdog's ``static`` command for the platform's current state.

    Tensions: the wrench that holds the pose against gravity and makes the twist decay at ``decay`` (1/s),
    ``M·(−decay·v) + C(v) − w_g`` (:func:`cdpr.mechanics.dynamics.required_wrench`) on the controlled rows,
    distributed by the 2-norm QP within [tmin, tmax] (the nearest admissible tensions where none is exact).
    Lengths (a winch sim): the cables' current lengths, as the encoders read them (the winches stop).
    """

    def __init__(self, robot: Robot, variant: Variant, decay: float, kind: CommandKind) -> None:
        self.robot, self.decay, self.kind = robot, float(decay), kind
        self.rows = list(controlled_rows(robot, variant))
        self._W = WrenchMatrix(robot)
        self._tda: TensionDistributor | None = None  # made on first use (the QP stack takes ~0.3 s to import)

    def warm_up(self) -> None:
        """Import and set up the QP now (a first call takes ~0.3 s, which a realtime step cannot spare)."""
        if self._tda is None:
            self._tda = make_tda("qp")
            self._tda.solve(self._W(np.zeros(3), np.eye(3))[self.rows], np.zeros(len(self.rows)), 0.0, 1.0)
            self._tda.reset()

    def tensions(self, position: Array, R: Array, twist: Array) -> Array:
        if self._tda is None:
            self.warm_up()
        assert self._tda is not None
        wrench = required_wrench(self.robot, R, twist, -self.decay * np.asarray(twist, dtype=float))
        if wrench.shape[0] == 6:
            wrench = wrench[self.rows]
        W = self._W(position, R)[self.rows]
        return self._tda.solve(W, wrench, self.robot.tmin, self.robot.tmax).tensions
