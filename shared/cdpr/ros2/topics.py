"""The ROS 2 topics of a cdpr session (docs/ros2.md has the table) and their payloads from plain numbers.

Shared by the ros2 node (``cdpr_ros2``, live) and ``cdpr convert --to rosbag2`` (a recording): the same
names, types, QoS, frames and stamps either way. Pure, no I/O.
"""

from __future__ import annotations

import json
import re
from collections.abc import Container, Mapping, Sequence
from dataclasses import dataclass
from types import SimpleNamespace
from typing import Any

from cdpr.ros2 import messages as ros
from cdpr.ros2.cdr import stamp
from cdpr.ros2.graph import Qos
from cdpr.sensors import SENSOR_KINDS, Ros2Topic, latency_steps

WORLD, PLATFORM = "world", "platform"  # the tf frames (REP 105's fixed frame, the body)
RELIABLE = Qos()  # reliable, volatile, keep last 10 (ROS 2's default)
Payloads = list[tuple[str, bytes]]  # (topic name of PUBLISHED, CDR payload)


@dataclass(frozen=True)
class RosTopic:
    name: str  # below the node's namespace unless absolute
    ros_type: str
    qos: Qos = RELIABLE


def sensor_topic_key(topic: Ros2Topic) -> str:
    """A sensor topic's key in :data:`PUBLISHED`: ``sensors/joint_states`` → ``sensor_joint_states``."""
    name = topic.name.removeprefix("sensors/")
    return ("sensor_" if name != topic.name else "") + name.replace("/", "_")


# What a session publishes: every step, with the sensors, once (latched)
PUBLISHED: dict[str, RosTopic] = {
    "clock": RosTopic("/clock", "rosgraph_msgs/msg/Clock"),
    "joint_states": RosTopic("joint_states", "sensor_msgs/msg/JointState"),
    "pose": RosTopic("platform/pose", "geometry_msgs/msg/PoseStamped"),
    "twist": RosTopic("platform/twist", "geometry_msgs/msg/TwistStamped"),
    "tf": RosTopic("/tf", "tf2_msgs/msg/TFMessage"),
    "setpoint_pose": RosTopic("setpoint/pose", "geometry_msgs/msg/PoseStamped"),
    "setpoint_twist": RosTopic("setpoint/twist", "geometry_msgs/msg/TwistStamped"),
    "setpoint_accel": RosTopic("setpoint/accel", "geometry_msgs/msg/AccelStamped"),
    **{sensor_topic_key(t): RosTopic(t.name, t.type) for kind in SENSOR_KINDS for t in kind.ros2},
    "session_info": RosTopic("session_info", "std_msgs/msg/String", Qos(transient_local=True, depth=1)),
}
SENSOR_TOPIC_KIND = {sensor_topic_key(t): kind.name for kind in SENSOR_KINDS for t in kind.ros2}
# What a ROS 2 controller sends
COMMANDS: dict[str, RosTopic] = {
    "joint_commands": RosTopic("joint_commands", "sensor_msgs/msg/JointState"),
    "tension_commands": RosTopic("tension_commands", "std_msgs/msg/Float64MultiArray"),
}
STEP_TOPICS = ("clock", "joint_states", "pose", "twist", "tf", "setpoint_pose", "setpoint_twist", "setpoint_accel")


NAMESPACE = "/cdpr"  # the topics' namespace of the session "default"
_TOKEN = re.compile(r"[A-Za-z][A-Za-z0-9_]*")


def default_namespace(session: str) -> str:
    """The topics' namespace of ``session``: ``/cdpr`` for ``default``, ``/cdpr/<session>`` for any other, so that
    the sessions of one router (and their controllers' identities: docs/security.md) never share a command topic.
    ValueError when the session id is not a ROS 2 name (letters, digits, ``_``, a letter first)."""
    if session == "default":
        return NAMESPACE
    if not _TOKEN.fullmatch(session) or "__" in session:
        raise ValueError(f"session {session!r} is not a ROS 2 name (letters, digits and single _, a letter first)")
    return f"{NAMESPACE}/{session}"


def cable_names(m: int) -> tuple[str, ...]:
    """The joints of sensor_msgs/JointState: one per cable, ``cable_1`` … ``cable_m``."""
    return tuple(f"cable_{i + 1}" for i in range(m))


def info_message(info: Mapping[str, Any], m: int) -> bytes:
    """``session_info``: the session/info map as JSON (robot geometry, mass, inertia, limits, gains), with the
    joint names and the frames."""
    return ros.string(json.dumps({**info, "cables": list(cable_names(m)), "world_frame": WORLD,
                                  "platform_frame": PLATFORM}))


def state_messages(t: float, names: Sequence[str], pose: Sequence[float], twist: Sequence[float],
                   lengths: Sequence[float], rates: Sequence[float] | None, tensions: Sequence[float],
                   wanted: Container[str] = STEP_TOPICS) -> Payloads:
    """A state's topics among ``wanted``: /clock, joint_states (``rates``: the length rates, needed for it),
    the platform's pose and twist, /tf — all stamped ``t``."""
    s = stamp(t)
    out: Payloads = []
    if "clock" in wanted:
        out.append(("clock", ros.clock(s)))
    if "joint_states" in wanted:
        assert rates is not None
        out.append(("joint_states", ros.joint_state(s, names, lengths, rates, tensions)))
    if "pose" in wanted:
        out.append(("pose", ros.pose_stamped(s, WORLD, pose)))
    if "twist" in wanted:
        out.append(("twist", ros.twist_stamped(s, WORLD, twist)))
    if "tf" in wanted:
        out.append(("tf", ros.tf_message(s, WORLD, PLATFORM, pose)))
    return out


def setpoint_messages(t: float, pose: Sequence[float], twist: Sequence[float] | None,
                      accel: Sequence[float] | None, wanted: Container[str] = STEP_TOPICS) -> Payloads:
    """A setpoint's topics among ``wanted`` (a missing twist or acceleration: no message for it)."""
    s = stamp(t)
    out: Payloads = []
    if "setpoint_pose" in wanted:
        out.append(("setpoint_pose", ros.pose_stamped(s, WORLD, pose)))
    if "setpoint_twist" in wanted and twist is not None:
        out.append(("setpoint_twist", ros.twist_stamped(s, WORLD, twist)))
    if "setpoint_accel" in wanted and accel is not None:
        out.append(("setpoint_accel", ros.accel_stamped(s, WORLD, accel)))
    return out


def sensor_delays(info: Mapping[str, Any]) -> dict[str, float]:
    """Each sensor kind's latency, s (a whole number of steps), from the session/info map's ``sim.sensors``."""
    dt = float(info.get("dt", 0.0) or 0.0)
    sensors = (info.get("sim") or {}).get("sensors") or {}
    return {name: latency_steps(SimpleNamespace(latency=float(entry.get("latency", 0.0))), dt) * dt
            for name, entry in sensors.items() if isinstance(entry, dict) and dt > 0.0}


def sensor_messages(t: float, names: Sequence[str], readings: Mapping[str, Sequence[float]],
                    delays: Mapping[str, float] | None = None) -> Payloads:
    """The ROS 2 messages of one step's sensor readings (channel name → values; absent channels: no message):
    each kind's topics (:data:`cdpr.sensors.SENSOR_KINDS`, e.g. ``imu``, ``sensors/joint_states``,
    ``sensors/laser_tracker``) whose channels are all there, stamped with the measurement's time: ``t`` less the
    kind's latency (``delays``: kind name → s)."""
    out: Payloads = []
    for kind in SENSOR_KINDS:
        if not kind.ros2 or any(c.name not in readings for c in kind.channels):
            continue
        s = stamp(max(0.0, t - (delays or {}).get(kind.name, 0.0)))
        for topic in kind.ros2:
            out.append((sensor_topic_key(topic), ros.standard(topic.type, s, topic.frame, topic.fields(readings),
                                                              names)))
    return out
