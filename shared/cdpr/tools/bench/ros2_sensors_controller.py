"""A ROS 2 controller fed from the sensors, written with zenoh-ros2-sdk and cdpr's estimator (docs/ros2.md).

What a ROS 2 user whose robot has winch encoders and an IMU would write: it never subscribes to the truth
(``joint_states``, ``platform/pose``, ``platform/twist``); it reads the encoders' lengths on
``sensors/joint_states`` and the IMU on ``imu``, estimates the pose and twist with cdpr's Kalman filter
(:class:`cdpr.runtime.feedback.SensorFeedback`, built from the latched ``session_info``: the robot and the sensors'
noise — the one thing it takes from cdpr), and answers each step with the seed paper's law
(:class:`cdpr.tools.bench.ros2_controller.Law`) on ``joint_commands``, stamped with the encoders' stamp (the step
it answers). Runs until SIGTERM/SIGINT.
"""

from __future__ import annotations

import argparse
import signal
import threading
import time

import msgpack
import numpy as np
from zenoh_ros2_sdk import ROS2Publisher, ROS2Subscriber, ZenohSession, get_message_class

from cdpr.protocol import Sensors
from cdpr.protocol.session import SessionInfo
from cdpr.runtime.feedback import SensorFeedback
from cdpr.tools.bench.ros2_controller import Law, session_info, vec


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--namespace", default="/cdpr")
    ap.add_argument("--router-port", type=int, default=7447)
    ap.add_argument("--node-name", default="sensors_controller")
    args = ap.parse_args()
    ns, common = args.namespace.rstrip("/"), {"node_name": args.node_name, "router_port": args.router_port}
    stop = threading.Event()
    signal.signal(signal.SIGTERM, lambda *_: stop.set())
    signal.signal(signal.SIGINT, lambda *_: stop.set())
    raw = session_info(ns, common, stop)
    if raw is None:
        return
    info = SessionInfo.from_payload(msgpack.packb(raw))
    feedback = SensorFeedback.from_info(info)  # the robot, dt and the sensors' noise of the session
    law = Law(raw)
    print(f"controller: robot {info.robot.name} with {len(law.names)} cables, fed from the sensors", flush=True)

    Header = get_message_class("std_msgs/msg/Header")
    Time = get_message_class("builtin_interfaces/msg/Time")
    pub = ROS2Publisher(f"{ns}/joint_commands", "sensor_msgs/msg/JointState", **common)
    parts: dict[tuple[int, int], dict] = {}
    lock = threading.Lock()
    answered = [0]
    needed = ("encoders", "imu", "sp_pose", "sp_twist", "sp_accel")

    def receive(name: str):
        def callback(msg) -> None:
            stamp = (msg.header.stamp.sec, msg.header.stamp.nanosec)
            with lock:
                step = parts.setdefault(stamp, {})
                step[name] = msg
                if len(step) < len(needed):
                    return
                del parts[stamp]
                for old in [s for s in parts if s < stamp]:
                    del parts[old]
                t = stamp[0] + 1e-9 * stamp[1]
                k = round(t / info.dt)
                imu = step["imu"]
                reading = Sensors(k, t, encoders=tuple(float(x) for x in step["encoders"].position),
                                  accel=tuple(vec(imu.linear_acceleration).tolist()),
                                  gyro=tuple(vec(imu.angular_velocity).tolist()))
                state = feedback.state(reading)  # the estimate (the same again for a step asked again)
            assert state is not None
            sp = step["sp_pose"].pose
            tensions = law.tensions(
                np.asarray(state.pose), np.asarray(state.twist),
                np.concatenate([vec(sp.position), [sp.orientation.x, sp.orientation.y, sp.orientation.z,
                                                   sp.orientation.w]]),
                np.concatenate([vec(step["sp_twist"].twist.linear), vec(step["sp_twist"].twist.angular)]),
                np.concatenate([vec(step["sp_accel"].accel.linear), vec(step["sp_accel"].accel.angular)]))
            pub.publish(header=Header(stamp=Time(sec=stamp[0], nanosec=stamp[1]), frame_id=""),
                        name=list(law.names), position=np.zeros(0), velocity=np.zeros(0), effort=tensions)
            answered[0] += 1
        return callback

    subs = [
        ROS2Subscriber(f"{ns}/imu", "sensor_msgs/msg/Imu", receive("imu"), **common),
        ROS2Subscriber(f"{ns}/setpoint/pose", "geometry_msgs/msg/PoseStamped", receive("sp_pose"), **common),
        ROS2Subscriber(f"{ns}/setpoint/twist", "geometry_msgs/msg/TwistStamped", receive("sp_twist"), **common),
        ROS2Subscriber(f"{ns}/setpoint/accel", "geometry_msgs/msg/AccelStamped", receive("sp_accel"), **common),
        # last: with it the session sees this process in the controller's role (docs/ros2.md)
        ROS2Subscriber(f"{ns}/sensors/joint_states", "sensor_msgs/msg/JointState", receive("encoders"), **common),
    ]
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
