"""The ros2 node's step, without Zenoh: a session's messages as ROS 2 messages, and ROS 2 commands back.

:class:`Bridge` turns state k with setpoint k into the payloads of every ROS 2 topic of that step
(:meth:`Bridge.step_messages`), the sensors into theirs, and a ROS 2 controller's command into the
session's :class:`~cdpr.protocol.Command` (:meth:`Bridge.command`): a ``joint_commands`` JointState is bound
to the state whose stamp it carries, a ``tension_commands`` Float64MultiArray to the oldest state not yet
answered (free-running: the newest published, answered or not, so that it acts at once, as a command does
under Gazebo). Anything else
raises :class:`RosCommandError` with a one-line reason naming the field. docs/ros2.md.
"""

from __future__ import annotations

import json
from collections import OrderedDict
from collections.abc import Container, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from cdpr.config.scenario import Scenario
from cdpr.mechanics.kinematics import cable_length_rates, inverse_kinematics
from cdpr.mechanics.outputs import CommandKind
from cdpr.mechanics.robot import Robot
from cdpr.mechanics.rotation import quat_to_matrix
from cdpr.protocol import Command, Sensors, Setpoint, State
from cdpr.protocol.session import session_info
from cdpr.ros2 import messages as ros
from cdpr.ros2.cdr import CdrError, finite, stamp
from cdpr.ros2.graph import Qos

WORLD, PLATFORM = "world", "platform"  # the tf frames (REP 105's fixed frame, the body)
RELIABLE = Qos()  # reliable, volatile, keep last 10 (ROS 2's default)
MAX_PENDING = 1000  # states kept for a late stamped command (free-running: older ones are dropped)


@dataclass(frozen=True)
class RosTopic:
    name: str  # below the node's namespace unless absolute
    ros_type: str
    qos: Qos = RELIABLE


# What the node publishes (docs/ros2.md has the table): every step, with the sensors, once (latched)
PUBLISHED: dict[str, RosTopic] = {
    "clock": RosTopic("/clock", "rosgraph_msgs/msg/Clock"),
    "joint_states": RosTopic("joint_states", "sensor_msgs/msg/JointState"),
    "pose": RosTopic("platform/pose", "geometry_msgs/msg/PoseStamped"),
    "twist": RosTopic("platform/twist", "geometry_msgs/msg/TwistStamped"),
    "tf": RosTopic("/tf", "tf2_msgs/msg/TFMessage"),
    "setpoint_pose": RosTopic("setpoint/pose", "geometry_msgs/msg/PoseStamped"),
    "setpoint_twist": RosTopic("setpoint/twist", "geometry_msgs/msg/TwistStamped"),
    "setpoint_accel": RosTopic("setpoint/accel", "geometry_msgs/msg/AccelStamped"),
    "imu": RosTopic("imu", "sensor_msgs/msg/Imu"),
    "sensor_joint_states": RosTopic("sensors/joint_states", "sensor_msgs/msg/JointState"),
    "session_info": RosTopic("session_info", "std_msgs/msg/String", Qos(transient_local=True, depth=1)),
}
# What a ROS 2 controller sends
COMMANDS: dict[str, RosTopic] = {
    "joint_commands": RosTopic("joint_commands", "sensor_msgs/msg/JointState"),
    "tension_commands": RosTopic("tension_commands", "std_msgs/msg/Float64MultiArray"),
}
STEP_TOPICS = ("clock", "joint_states", "pose", "twist", "tf", "setpoint_pose", "setpoint_twist", "setpoint_accel")


def cable_names(m: int) -> tuple[str, ...]:
    """The joints of sensor_msgs/JointState: one per cable, ``cable_1`` … ``cable_m``."""
    return tuple(f"cable_{i + 1}" for i in range(m))


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
        self.info = {"v": 2, **info, "cables": list(self.names), "world_frame": WORLD, "platform_frame": PLATFORM}
        self.free = False
        self.newest: State | None = None  # the last state published with its setpoint
        self.pending: OrderedDict[tuple[int, int], State] = OrderedDict()  # published, not answered: by stamp

    @classmethod
    def from_scenario(cls, scenario: Scenario) -> Bridge:
        return cls(scenario.robot, scenario.output, session_info(scenario))

    def info_message(self) -> bytes:
        """``session_info``: the session/info map as JSON (robot geometry, mass, inertia, limits, gains)."""
        return ros.string(json.dumps(self.info))

    def length_rates(self, state: State) -> list[float]:
        """The cables' length rates at ``state`` (the length Jacobian of the ideal geometry times the twist)."""
        kin = inverse_kinematics(self.robot, np.asarray(state.pose[:3]), quat_to_matrix(np.asarray(state.pose[3:])))
        return cable_length_rates(kin, state.twist).tolist()

    def state_messages(self, state: State, wanted: Container[str] = STEP_TOPICS) -> list[tuple[str, bytes]]:
        """State k's own topics among ``wanted``: /clock, joint_states, the platform's pose and twist, /tf."""
        t = stamp(state.t)
        out = []
        if "clock" in wanted:
            out.append(("clock", ros.clock(t)))
        if "joint_states" in wanted:
            out.append(("joint_states", ros.joint_state(t, self.names, state.cable_lengths, self.length_rates(state),
                                                        state.tensions)))
        if "pose" in wanted:
            out.append(("pose", ros.pose_stamped(t, WORLD, state.pose)))
        if "twist" in wanted:
            out.append(("twist", ros.twist_stamped(t, WORLD, state.twist)))
        if "tf" in wanted:
            out.append(("tf", ros.tf_message(t, WORLD, PLATFORM, state.pose)))
        return out

    def step_messages(self, state: State, setpoint: Setpoint, wanted: Container[str] = STEP_TOPICS
                      ) -> list[tuple[str, bytes]]:
        """State k and setpoint k as (topic, payload) for the topics of :data:`STEP_TOPICS` among ``wanted``;
        state k now awaits its command (whatever is wanted)."""
        t = stamp(state.t)
        self.newest = state
        self.pending[t] = state
        self.pending.move_to_end(t)
        while len(self.pending) > MAX_PENDING:
            self.pending.popitem(last=False)
        out = self.state_messages(state, wanted)
        if "setpoint_pose" in wanted:
            out.append(("setpoint_pose", ros.pose_stamped(t, WORLD, setpoint.pose)))
        if "setpoint_twist" in wanted:
            out.append(("setpoint_twist", ros.twist_stamped(t, WORLD, setpoint.twist)))
        if "setpoint_accel" in wanted:
            out.append(("setpoint_accel", ros.accel_stamped(t, WORLD, setpoint.accel)))
        return out

    def sensor_messages(self, sensors: Sensors) -> list[tuple[str, bytes]]:
        """The IMU (platform frame) and the winches' encoders (position) and load cells (effort)."""
        return self.sensor_messages_of(sensors.t, sensors.encoders, sensors.load_cells, sensors.accel, sensors.gyro)

    def sensor_messages_of(self, t: float, encoders: Sequence[float], load_cells: Sequence[float],
                           accel: Sequence[float], gyro: Sequence[float]) -> list[tuple[str, bytes]]:
        stamp_ = stamp(t)
        return [
            ("imu", ros.imu(stamp_, PLATFORM, gyro, accel)),
            ("sensor_joint_states", ros.joint_state(stamp_, self.names, encoders, (), load_cells)),
        ]

    def command(self, topic: str, payload: bytes) -> Command:
        """A ROS 2 command as the session's Command for the state it answers (module docstring); RosCommandError."""
        try:
            if topic == "joint_commands":
                msg = ros.read_joint_state(payload)
                values = msg.position if self.output == "lengths" else msg.effort
                field = "position" if self.output == "lengths" else "effort"
                values = self._ordered(msg.name, values, field)
                state = self.pending.get(msg.stamp)
                if state is None:
                    raise RosCommandError(
                        f"JointState.header.stamp {msg.stamp[0]}.{msg.stamp[1]:09d}: no state awaiting a command has "
                        "this stamp (it must be the stamp of the state it answers)", "unmatched_ros2_commands")
            else:
                values = ros.read_float64_array(payload)
                field = "data"
                if len(values) != self.m:
                    raise RosCommandError(f"Float64MultiArray.data: {len(values)} values, expected {self.m} "
                                     f"({self.output}, cable_1 … cable_{self.m})")
                if self.free:
                    state = self.newest  # it acts from the sim's next step, whatever it answered
                elif self.pending:
                    state = next(iter(self.pending.values()))
                else:
                    state = None
                if state is None:
                    raise RosCommandError("Float64MultiArray: no state awaits a command", "unmatched_ros2_commands")
            finite(values, field, "JointState" if topic == "joint_commands" else "Float64MultiArray")
        except CdrError as exc:
            raise RosCommandError(str(exc)) from None
        if self.output == "lengths" and min(values) <= 0:
            raise RosCommandError(f"{field}: unstretched lengths must be > 0")
        for key in [k for k, s in self.pending.items() if s.step <= state.step]:
            del self.pending[key]  # answered, and the ones before it are no longer awaited
        values = tuple(float(v) for v in values)
        if self.output == "lengths":
            return Command(state.step, state.t, (), True, "ok", values)
        return Command(state.step, state.t, values)

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
