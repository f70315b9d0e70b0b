"""A ROS 2 controller of a cdpr session, written with zenoh-ros2-sdk only: no cdpr import.

What a ROS 2 user would write against the topics of docs/ros2.md: it reads the robot from the latched
``session_info``, subscribes to ``joint_states``, ``platform/pose``, ``platform/twist`` and
``setpoint/{pose,twist,accel}``, and for each step computes the seed paper's feedback linearisation (eq. 6–7)
with a minimum-2-norm tension distribution in the limits (eq. 8, by the closed-form method that clamps the
worst cable and solves again), then publishes the tensions: ``joint_commands`` (JointState, stamped with the
state's stamp) or, with ``--unstamped``, ``tension_commands`` (Float64MultiArray, as ros2_control's forward
command controllers do). Runs until SIGTERM/SIGINT.
"""

from __future__ import annotations

import argparse
import json
import math
import signal
import threading
import time

import numpy as np
from zenoh_ros2_sdk import ROS2Publisher, ROS2Subscriber, ZenohSession, get_message_class
from zenoh_ros2_sdk.qos import QosDurability, QosProfile

GRAVITY = np.array([0.0, 0.0, -9.81])


def quat_matrix(x: float, y: float, z: float, w: float) -> np.ndarray:
    return np.array([
        [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
        [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
        [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
    ])


def rotation_error(qd: np.ndarray, q: np.ndarray) -> np.ndarray:
    """log(q_d q⁻¹) as a rotation vector (world frame)."""
    xd, yd, zd, wd = (qd / np.linalg.norm(qd)).tolist()
    x, y, z, w = (q / np.linalg.norm(q)).tolist()
    # q_d ⊗ conj(q)
    ew = wd * w + xd * x + yd * y + zd * z
    ex = -wd * x + xd * w - yd * z + zd * y
    ey = -wd * y + yd * w - zd * x + xd * z
    ez = -wd * z + zd * w - xd * y + yd * x
    if ew < 0:
        ew, ex, ey, ez = -ew, -ex, -ey, -ez
    s = math.sqrt(ex * ex + ey * ey + ez * ez)
    k = 2.0 if s < 1e-12 else 2.0 * math.atan2(s, ew) / s
    return np.array([ex, ey, ez]) * k


def cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise a × b (numpy's own cross product costs more than the rest of the law on 3-vectors)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def distribute(W: np.ndarray, w: np.ndarray, tmin: float, tmax: float) -> np.ndarray:
    """min ‖t‖₂ subject to W t = w, tmin ≤ t ≤ tmax: the minimum-norm solution of the free cables, the worst
    violation clamped to its limit, again, until every cable is inside (or too few are left)."""
    t = W.T @ np.linalg.solve(W @ W.T, w)  # the minimum-norm solution: most steps, every cable inside
    if t.min() >= tmin - 1e-9 and t.max() <= tmax + 1e-9:
        return np.clip(t, tmin, tmax)
    free = np.ones(W.shape[1], dtype=bool)
    while True:
        low, high = tmin - t, t - tmax
        worst = np.where(free, np.maximum(low, high), -np.inf)
        i = int(np.argmax(worst))
        if worst[i] <= 1e-9 or free.sum() <= W.shape[0]:
            return np.clip(t, tmin, tmax)
        t[i] = tmin if low[i] > 0 else tmax
        free[i] = False
        Wf = W[:, free]  # the minimum-norm solution of the free cables (W_F has full row rank)
        t[free] = Wf.T @ np.linalg.solve(Wf @ Wf.T, w - W[:, ~free] @ t[~free])


class Law:
    def __init__(self, info: dict) -> None:
        robot = info["robot"]
        self.frame = np.array(robot["frame_points"])
        self.platform = np.array(robot["platform_points"])
        self.mass = float(robot["mass"])
        self.inertia = np.array(robot["inertia"])
        self.tmin, self.tmax = robot["tension_limits"]
        self.kp = np.array(info["controller"]["kp"], dtype=float)
        self.kd = np.array(info["controller"]["kd"], dtype=float)
        self.names = info["cables"]

    def tensions(self, pose, twist, pose_d, twist_d, accel_d) -> np.ndarray:
        p, q = pose[:3], pose[3:]
        R = quat_matrix(*q.tolist())  # Python floats: numpy's scalars cost more than the arithmetic
        e = np.concatenate([pose_d[:3] - p, rotation_error(pose_d[3:], q)])
        acc = accel_d + self.kp * e + self.kd * (twist_d - twist)
        inertia = R @ self.inertia @ R.T
        omega = twist[3:]
        wrench = np.concatenate([self.mass * (acc[:3] - GRAVITY),
                                 inertia @ acc[3:] + cross(omega, inertia @ omega)])
        b = self.platform @ R.T
        d = self.frame - p - b
        d /= np.linalg.norm(d, axis=1, keepdims=True)
        W = np.vstack([d.T, cross(b, d).T])
        return distribute(W, wrench, self.tmin, self.tmax)


def vec(v) -> np.ndarray:
    return np.array([v.x, v.y, v.z])


def session_info(ns: str, common: dict, stop: threading.Event) -> dict | None:
    """The latched ``session_info`` (JSON), once it comes; None if stopped first."""
    got: dict[str, dict] = {}

    def on_info(msg) -> None:
        got.setdefault("info", json.loads(msg.data))

    latched = QosProfile(durability=QosDurability.TRANSIENT_LOCAL, history_depth=1)
    sub = ROS2Subscriber(f"{ns}/session_info", "std_msgs/msg/String", on_info, qos=latched, **common)
    session = ZenohSession.get_instance().session
    while "info" not in got and not stop.wait(0.2):  # the session's node may start after this one
        # zenoh-ros2-sdk 0.1.8 looks for a transient-local publisher with its topic's inner '/' left unmangled
        # (subscriber._discover_publishers): it never finds one of a nested topic. Ask the publication cache
        # as rmw_zenoh's subscribers do, on the SDK's own session and with its own decoding.
        for reply in session.get(f"{sub.keyexpr}/@adv/pub/**?_anyke;_max=1", timeout=2.0):
            if reply.ok is not None:
                sub._process_sample(reply.ok)
    sub.close()
    return None if stop.is_set() else got["info"]


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--namespace", default="/cdpr")
    ap.add_argument("--router-port", type=int, default=7447)
    ap.add_argument("--unstamped", action="store_true", help="tension_commands (Float64MultiArray)")
    ap.add_argument("--node-name", default="pd_controller")
    ap.add_argument("--slow-start", type=float, default=0.0, metavar="SECONDS",
                    help="wait this long before the first answer (a slow start: the session repeats state 0 meanwhile)")
    args = ap.parse_args()
    ns, port, node = args.namespace.rstrip("/"), args.router_port, args.node_name
    common = {"node_name": node, "router_port": port}
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())

    info = session_info(ns, common, stop)
    if info is None:
        return
    law = Law(info)
    print(f"controller: robot {info['robot']['name']} with {len(law.names)} cables", flush=True)

    Header = get_message_class("std_msgs/msg/Header")
    Time = get_message_class("builtin_interfaces/msg/Time")
    if args.unstamped:
        pub = ROS2Publisher(f"{ns}/tension_commands", "std_msgs/msg/Float64MultiArray", **common)
        Layout = get_message_class("std_msgs/msg/MultiArrayLayout")
        Dim = get_message_class("std_msgs/msg/MultiArrayDimension")
    else:
        pub = ROS2Publisher(f"{ns}/joint_commands", "sensor_msgs/msg/JointState", **common)

    answered = [0]
    slow_start = [args.slow_start] if args.slow_start > 0 else []

    def on_step(stamp: tuple[int, int], step: dict) -> None:
        pose, twist = step["pose"].pose, step["twist"].twist
        t = law.tensions(pose_of(pose), np.concatenate([vec(twist.linear), vec(twist.angular)]), *setpoint_of(step))
        if args.unstamped:
            pub.publish(layout=Layout(dim=[Dim(label="cables", size=len(t), stride=len(t))], data_offset=0), data=t)
        else:
            pub.publish(header=Header(stamp=Time(sec=stamp[0], nanosec=stamp[1]), frame_id=""),
                        name=list(law.names), position=np.zeros(0), velocity=np.zeros(0), effort=t)
        answered[0] += 1

    def first() -> None:
        if slow_start:  # once, holding the lock: every other callback waits too
            time.sleep(slow_start.pop())

    join = StampJoin(("joint_states", "pose", "twist", *SETPOINT_TOPICS), on_step, first)
    subs = [
        ROS2Subscriber(f"{ns}/platform/pose", "geometry_msgs/msg/PoseStamped", join.receive("pose"), **common),
        ROS2Subscriber(f"{ns}/platform/twist", "geometry_msgs/msg/TwistStamped", join.receive("twist"), **common),
        *setpoint_subscribers(ns, join, common),
        # last: with it the session sees this process in the controller's role (docs/ros2.md)
        ROS2Subscriber(f"{ns}/joint_states", "sensor_msgs/msg/JointState", join.receive("joint_states"), **common),
    ]
    spin(stop, subs, pub, answered)


# setpoint k's topics, stamped as state k: the name a StampJoin knows each by, the topic, its type
SETPOINT_TOPICS = {"sp_pose": ("setpoint/pose", "geometry_msgs/msg/PoseStamped"),
                   "sp_twist": ("setpoint/twist", "geometry_msgs/msg/TwistStamped"),
                   "sp_accel": ("setpoint/accel", "geometry_msgs/msg/AccelStamped")}


def pose_of(pose) -> np.ndarray:
    """A geometry_msgs/Pose as [x, y, z, qx, qy, qz, qw]."""
    q = pose.orientation
    return np.concatenate([vec(pose.position), [q.x, q.y, q.z, q.w]])


def setpoint_of(step: dict) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The desired pose, twist and acceleration among a step's joined messages."""
    twist, accel = step["sp_twist"].twist, step["sp_accel"].accel
    return (pose_of(step["sp_pose"].pose), np.concatenate([vec(twist.linear), vec(twist.angular)]),
            np.concatenate([vec(accel.linear), vec(accel.angular)]))


def setpoint_subscribers(ns: str, join: StampJoin, common: dict) -> list:
    return [ROS2Subscriber(f"{ns}/{topic}", ros_type, join.receive(name), **common)
            for name, (topic, ros_type) in SETPOINT_TOPICS.items()]


class StampJoin:
    """Each step's messages joined by their stamp: ``on_step(stamp, messages)`` once every one of ``needed`` is in
    (the older incomplete steps dropped then); ``first`` runs, holding the lock, before each step is handed on."""

    def __init__(self, needed, on_step, first=None) -> None:
        self.needed, self.on_step, self.first = tuple(needed), on_step, first
        self.parts: dict[tuple[int, int], dict] = {}
        self.lock = threading.Lock()

    def receive(self, name: str):
        def callback(msg) -> None:
            stamp = (msg.header.stamp.sec, msg.header.stamp.nanosec)
            with self.lock:
                step = self.parts.setdefault(stamp, {})
                step[name] = msg
                if len(step) < len(self.needed):
                    return
                del self.parts[stamp]
                for old in [s for s in self.parts if s < stamp]:
                    del self.parts[old]
                if self.first is not None:
                    self.first()
            self.on_step(stamp, step)
        return callback


def spin(stop: threading.Event, subs: list, pub, answered: list[int]) -> None:
    """Run until stopped (SIGTERM/SIGINT), then close everything and say how many steps were answered."""
    print("controller: ready", flush=True)
    started = time.monotonic()
    while not stop.wait(0.5):
        pass
    for s in subs:
        s.close()
    pub.close()
    ZenohSession.get_instance().close()
    print(f"controller: answered {answered[0]} steps in {time.monotonic() - started:.1f} s", flush=True)


if __name__ == "__main__":
    main()
