"""The ROS 2 messages of a cdpr session, as CDR payloads (:mod:`cdpr.ros2.cdr`). Pure, no I/O.

Encoders take plain numbers (a stamp as (sec, nanosec), poses as ``x, y, z, qx, qy, qz, qw`` — the same
order as geometry_msgs/Pose —, twists and accelerations as linear then angular); the two decoders read
what a ROS 2 controller sends (:func:`read_joint_state`, :func:`read_float64_array`) and raise
:class:`~cdpr.ros2.cdr.CdrError` naming the field for anything else. docs/ros2.md lists the topics.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

from cdpr.ros2.cdr import Reader, Writer

Stamp = tuple[int, int]  # builtin_interfaces/Time: (sec, nanosec)
_ZERO9 = (0.0,) * 9
_UNKNOWN_ORIENTATION = (-1.0, *(0.0,) * 8)  # sensor_msgs/Imu: covariance[0] = -1: no orientation estimate


def clock(t: Stamp) -> bytes:
    """rosgraph_msgs/Clock."""
    return Writer().time(*t).payload()


def joint_state(t: Stamp, names: Sequence[str], position: Sequence[float], velocity: Sequence[float],
                effort: Sequence[float], frame_id: str = "") -> bytes:
    """sensor_msgs/JointState."""
    w = Writer().header(*t, frame_id).strings(names)
    return w.f64_seq(position).f64_seq(velocity).f64_seq(effort).payload()


def pose_stamped(t: Stamp, frame_id: str, pose: Sequence[float]) -> bytes:
    """geometry_msgs/PoseStamped (position x y z, orientation x y z w)."""
    return Writer().header(*t, frame_id).f64s(pose).payload()


def point_stamped(t: Stamp, frame_id: str, point: Sequence[float]) -> bytes:
    """geometry_msgs/PointStamped (x, y, z)."""
    return Writer().header(*t, frame_id).f64s(point).payload()


def twist_stamped(t: Stamp, frame_id: str, twist: Sequence[float]) -> bytes:
    """geometry_msgs/TwistStamped (linear, angular); AccelStamped has the same layout."""
    return Writer().header(*t, frame_id).f64s(twist).payload()


accel_stamped = twist_stamped  # geometry_msgs/AccelStamped: header, linear, angular


def tf_message(t: Stamp, parent: str, child: str, pose: Sequence[float]) -> bytes:
    """tf2_msgs/TFMessage with one geometry_msgs/TransformStamped (translation, rotation)."""
    return Writer().u32(1).header(*t, parent).string(child).f64s(pose).payload()


def imu(t: Stamp, frame_id: str, gyro: Sequence[float], accel: Sequence[float]) -> bytes:
    """sensor_msgs/Imu without an orientation estimate (its covariance's first element -1, the ROS
    convention), covariances unknown (zeros)."""
    w = Writer().header(*t, frame_id).f64s((0.0, 0.0, 0.0, 1.0)).f64s(_UNKNOWN_ORIENTATION)
    return w.f64s(gyro).f64s(_ZERO9).f64s(accel).f64s(_ZERO9).payload()


def standard(ros_type: str, t: Stamp, frame_id: str, fields: Mapping[str, Sequence[float]],
             names: Sequence[str] = ()) -> bytes:
    """A sensor's message of the standard type ``ros_type`` from its ``fields`` (what :class:`cdpr.sensors.Ros2Topic`
    declares): JointState (``position``, ``velocity``, ``effort``; ``names`` its joints), Imu
    (``angular_velocity``, ``linear_acceleration``), PointStamped (``point``), PoseStamped (``pose``)."""
    if ros_type == "sensor_msgs/msg/JointState":
        return joint_state(t, names, fields.get("position", ()), fields.get("velocity", ()), fields.get("effort", ()),
                           frame_id)
    if ros_type == "sensor_msgs/msg/Imu":
        return imu(t, frame_id, fields["angular_velocity"], fields["linear_acceleration"])
    if ros_type == "geometry_msgs/msg/PointStamped":
        return point_stamped(t, frame_id, fields["point"])
    if ros_type == "geometry_msgs/msg/PoseStamped":
        return pose_stamped(t, frame_id, fields["pose"])
    raise ValueError(f"{ros_type}: not a message type cdpr.ros2 writes for a sensor")


def string(text: str) -> bytes:
    """std_msgs/String."""
    return Writer().string(text).payload()


def float64_array(data: Sequence[float], label: str = "") -> bytes:
    """std_msgs/Float64MultiArray, one dimension (what ros2_control's forward command controllers send)."""
    w = Writer().u32(1).string(label).u32(len(data)).u32(len(data)).u32(0)
    return w.f64_seq(data).payload()


@dataclass(frozen=True)
class JointStateMsg:
    stamp: Stamp
    frame_id: str
    name: tuple[str, ...]
    position: tuple[float, ...]
    velocity: tuple[float, ...]
    effort: tuple[float, ...]


def read_joint_state(payload: bytes) -> JointStateMsg:
    r = Reader(payload, "JointState")
    sec, nanosec, frame = r.header()
    msg = JointStateMsg((sec, nanosec), frame, r.strings("name"), r.f64_seq("position"), r.f64_seq("velocity"),
                        r.f64_seq("effort"))
    r.end()
    return msg


def read_float64_array(payload: bytes) -> tuple[float, ...]:
    """The data of a std_msgs/Float64MultiArray (its layout read and checked for shape, then ignored)."""
    r = Reader(payload, "Float64MultiArray")
    for i in range(r.count("layout.dim")):
        r.string(f"layout.dim[{i}].label")
        r.u32(f"layout.dim[{i}].size")
        r.u32(f"layout.dim[{i}].stride")
    r.u32("layout.data_offset")
    data = r.f64_seq("data")
    r.end()
    return data
