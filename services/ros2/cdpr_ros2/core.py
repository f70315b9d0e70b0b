"""The ros2 node's step, without Zenoh: a session's messages as ROS 2 messages, and ROS 2 commands back.

:class:`Bridge` turns state k with setpoint k into the payloads of every ROS 2 topic of that step
(:meth:`Bridge.step_messages`), the sensors into theirs, and a ROS 2 controller's command into the
session's :class:`~cdpr.protocol.Command` (:meth:`Bridge.command`): a ``joint_commands`` JointState is bound
to the state whose stamp it carries, a ``tension_commands`` Float64MultiArray to the oldest state not yet
answered (free-running: the newest published, answered or not, so that it acts at once, as a command does
under Gazebo) — unless it is a repeated answer to the state answered last (below). Anything else raises
:class:`RosCommandError` with a one-line reason naming the field. docs/ros2.md.

An unstamped command says nothing of the state it answers, and a state may be published more than once (the
clock repeats state 0 until the loop has been heard once, and asks for a state again after a stall): a
controller then answers it once or more (once when its callbacks merge the copies). A second answer that
comes after the next state went out must not be taken for that state's (every later command would be one
state late: the platform is thrown). So, lock-step, the bridge counts the publications of the state it took
an unstamped command for last, and the commands it took or dropped for it: while fewer than the
publications, a command bit-identical to the one it took is a repeat, dropped (``repeated_ros2_commands``);
any other command answers the state awaiting one. Once the clock asks again for the state awaiting its
command (a stall), no repeat of the state before it is expected any more.

"""

from __future__ import annotations

from collections import OrderedDict
from collections.abc import Container
from typing import Any

import numpy as np

from cdpr.config.scenario import Scenario
from cdpr.mechanics.kinematics import length_rates
from cdpr.mechanics.outputs import CommandKind
from cdpr.mechanics.robot import Robot
from cdpr.mechanics.rotation import quat_to_matrix
from cdpr.protocol import PROTOCOL_VERSION, Command, Sensors, Setpoint, State
from cdpr.protocol.session import session_info
from cdpr.ros2 import messages as ros
from cdpr.ros2.cdr import CdrError, finite, stamp
from cdpr.ros2.topics import (
    STEP_TOPICS,
    Payloads,
    cable_names,
    info_message,
    sensor_delays,
    sensor_messages,
    setpoint_messages,
    state_messages,
)

MAX_PENDING = 1000  # states kept for a late stamped command (free-running: older ones are dropped)


class RosCommandError(ValueError):
    """A ROS 2 command that cannot be applied; ``counter`` is the fault counter it goes under."""

    def __init__(self, message: str, counter: str = "bad_ros2_commands") -> None:
        super().__init__(message)
        self.counter = counter


class Bridge:
    """One session's ROS 2 view (module docstring). ``free``: the session is free-running."""

    def __init__(self, robot: Robot, output: CommandKind, info: dict[str, Any]) -> None:
        """``info``: the session/info map (:func:`cdpr.protocol.session.session_info`)."""
        self.robot = robot
        self.m = robot.m
        self.output = output  # "tensions" or "lengths": what a command carries
        self.names = cable_names(self.m)
        self._order = {name: i for i, name in enumerate(self.names)}
        self.info = {"v": PROTOCOL_VERSION, **info}
        self.delays = sensor_delays(info)  # each sensor kind's latency: its messages are stamped when measured
        self.free = False
        self.newest: State | None = None  # the last state published with its setpoint
        self.pending: OrderedDict[tuple[int, int], State] = OrderedDict()  # published, not answered: by stamp
        # unstamped lock-step commands (module docstring): each state's publications to the controller (from the
        # state answered last on), the step and values of the command taken last, the answers still possible
        # to it (its publications, less the commands taken or dropped as its repeats)
        self.copies: dict[int, int] = {}
        self.taken: tuple[int, tuple[float, ...]] | None = None
        self.repeats = 0

    @classmethod
    def from_scenario(cls, scenario: Scenario) -> Bridge:
        return cls(scenario.robot, scenario.output, session_info(scenario))

    def info_message(self) -> bytes:
        """``session_info`` (:func:`cdpr.ros2.topics.info_message`)."""
        return info_message(self.info, self.m)

    def length_rates(self, state: State) -> list[float]:
        """The cables' length rates at ``state`` (the length Jacobian of the ideal geometry times the twist)."""
        pose = np.asarray(state.pose)
        return length_rates(self.robot, pose[:3], quat_to_matrix(pose[3:]), state.twist).tolist()

    def state_messages(self, state: State, wanted: Container[str] = STEP_TOPICS) -> Payloads:
        """State k's own topics among ``wanted``: /clock, joint_states, the platform's pose and twist, /tf."""
        rates = self.length_rates(state) if "joint_states" in wanted else None
        return state_messages(state.t, self.names, state.pose, state.twist, state.cable_lengths, rates,
                              state.tensions, wanted)

    def step_messages(self, state: State, setpoint: Setpoint | None,
                      wanted: Container[str] = STEP_TOPICS) -> Payloads:
        """Setpoint k and state k as (topic, payload) for the topics of :data:`STEP_TOPICS` among ``wanted``, the
        setpoint's first, stamped with the state's time (``setpoint`` None: it went out ahead,
        :meth:`setpoint_messages`); state k now awaits its command (whatever is wanted)."""
        t = stamp(state.t)
        self.newest = state
        self.pending[t] = state
        self.pending.move_to_end(t)
        while len(self.pending) > MAX_PENDING:
            self.pending.popitem(last=False)
        if "joint_states" in wanted and not self.free:
            copies = self.copies[state.step] = self.copies.get(state.step, 0) + 1
            if copies > 1 and (self.taken is None or state.step > self.taken[0]):
                self.repeats = 0  # asked for again while awaiting its command: nothing more comes for the one before
        if setpoint is None:
            return self.state_messages(state, wanted)
        return [*setpoint_messages(state.t, setpoint.pose, setpoint.twist, setpoint.accel, wanted),
                *self.state_messages(state, wanted)]

    def new_controller(self) -> None:
        """Another controller took the role: it answers the publications from now on (the state awaiting its
        command is published again when the session resumes)."""
        self.copies.clear()
        self.taken, self.repeats = None, 0

    def setpoint_messages(self, setpoint: Setpoint, wanted: Container[str] = STEP_TOPICS) -> Payloads:
        """Setpoint k's topics among ``wanted`` ahead of state k, stamped with its own time, k·dt as state k's
        (docs/protocol.md: t = k · dt)."""
        return setpoint_messages(setpoint.t, setpoint.pose, setpoint.twist, setpoint.accel, wanted)

    def sensor_messages(self, sensors: Sensors) -> Payloads:
        """Each sensor kind's topics (:func:`cdpr.ros2.topics.sensor_messages`): the IMU (platform frame), the
        winches' encoders (position) and load cells (effort), a laser tracker's point, …"""
        return sensor_messages(sensors.t, self.names, sensors.readings, self.delays)

    def command(self, topic: str, payload: bytes) -> Command:
        """A ROS 2 command as the session's Command for the state it answers (module docstring); RosCommandError.
        The payload is checked whole first (a bad one is bad whenever it comes), then matched to a state."""
        what = "JointState" if topic == "joint_commands" else "Float64MultiArray"
        try:
            if topic == "joint_commands":
                msg = ros.read_joint_state(payload)
                field = "position" if self.output == "lengths" else "effort"
                values = self._ordered(msg.name, msg.position if self.output == "lengths" else msg.effort, field)
            else:
                values, field = ros.read_float64_array(payload), "data"
                if len(values) != self.m:
                    raise RosCommandError(f"Float64MultiArray.data: {len(values)} values, expected {self.m} "
                                          f"({self.output}, cable_1 … cable_{self.m})")
            finite(values, field, what)
        except CdrError as exc:
            raise RosCommandError(str(exc)) from None
        if self.output == "lengths" and min(values) <= 0:
            raise RosCommandError(f"{what}.{field}: unstretched lengths must be > 0, got {min(values)}")
        if topic == "joint_commands":
            state = self.pending.get(msg.stamp)
            if state is None:
                raise RosCommandError(
                    f"JointState.header.stamp {msg.stamp[0]}.{msg.stamp[1]:09d}: no state awaiting a command has "
                    "this stamp (it must be the stamp of the state it answers)", "unmatched_ros2_commands")
        elif self.free:
            state = self.newest  # it acts from the sim's next step, whatever it answered
        else:
            state = self._unstamped(tuple(values))
        if state is None:
            raise RosCommandError("Float64MultiArray: no state awaits a command", "unmatched_ros2_commands")
        for key in [k for k, s in self.pending.items() if s.step <= state.step]:
            del self.pending[key]  # answered, and the ones before it are no longer awaited
        values = tuple(float(v) for v in values)
        if self.output == "lengths":
            return Command(state.step, state.t, (), True, "ok", values)
        return Command(state.step, state.t, values)

    def _unstamped(self, values: tuple[float, ...]) -> State | None:
        """The state an unstamped lock-step command answers: the oldest awaiting one, unless the command is a
        repeated answer to the state taken last (module docstring): then RosCommandError."""
        if self.repeats > 0 and self.taken is not None and values == self.taken[1]:
            self.repeats -= 1
            raise RosCommandError(f"Float64MultiArray: a repeated answer to state {self.taken[0]} (published "
                                  "again, answered already)", "repeated_ros2_commands")
        state = next(iter(self.pending.values()), None)
        if state is not None:
            self.taken, self.repeats = (state.step, values), self.copies.get(state.step, 1) - 1
            for step in [k for k in self.copies if k < state.step]:
                del self.copies[step]
        return state

    def _ordered(self, names: tuple[str, ...], values: tuple[float, ...], field: str) -> tuple[float, ...]:
        """``values`` in cable order: by ``names`` when given (any order), else as they come."""
        if len(values) != self.m:
            raise RosCommandError(f"JointState.{field}: {len(values)} values, expected {self.m} "
                                  f"({self.output}, cable_1 … cable_{self.m})")
        if not names:
            return values
        if sorted(names) != sorted(self.names):
            raise RosCommandError(f"JointState.name: {list(names)} are not the cables {list(self.names)}")
        out = [0.0] * self.m
        for name, v in zip(names, values, strict=True):
            out[self._order[name]] = v
        return tuple(out)
