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

import msgpack
import numpy as np
from zenoh_ros2_sdk import ROS2Publisher, ROS2Subscriber, get_message_class

from cdpr.protocol import Sensors
from cdpr.protocol.session import SessionInfo
from cdpr.runtime.feedback import SensorFeedback
from cdpr.tools.bench.ros2_controller import (
    SETPOINT_TOPICS,
    Law,
    StampJoin,
    session_info,
    setpoint_of,
    setpoint_subscribers,
    spin,
    vec,
)


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
    answered = [0]
    dt = info.dt

    def on_step(stamp: tuple[int, int], step: dict) -> None:
        t = stamp[0] + 1e-9 * stamp[1]
        k = round(t / dt)
        encoders, imu = step["encoders"], step.get("imu")
        channels = {"encoders": tuple(float(x) for x in encoders.position)}
        if len(encoders.effort):  # the load cells: the filter takes the cables' stretch out with them
            channels["load_cells"] = tuple(float(x) for x in encoders.effort)
        if imu is not None:
            channels["accel"] = tuple(vec(imu.linear_acceleration).tolist())
            channels["gyro"] = tuple(vec(imu.angular_velocity).tolist())
        reading = Sensors(k, t, **channels)
        with join.lock:  # the filter's own state: one step at a time, in step order
            if k < feedback.estimator.step and k not in feedback.states:
                return  # an older step handed on after a newer one (free-running): the newer one stands
            state = feedback.state(reading)  # the estimate (the same again for a step asked again)
        assert state is not None
        tensions = law.tensions(np.asarray(state.pose), np.asarray(state.twist), *setpoint_of(step))
        pub.publish(header=Header(stamp=Time(sec=stamp[0], nanosec=stamp[1]), frame_id=""),
                    name=list(law.names), position=np.zeros(0), velocity=np.zeros(0), effort=tensions)
        answered[0] += 1

    join = StampJoin(("encoders", *(["imu"] if feedback.imu else []), *SETPOINT_TOPICS), on_step)
    subs = [
        *([ROS2Subscriber(f"{ns}/imu", "sensor_msgs/msg/Imu", join.receive("imu"), **common)] if feedback.imu else []),
        *setpoint_subscribers(ns, join, common),
        # last: with it the session sees this process in the controller's role (docs/ros2.md)
        ROS2Subscriber(f"{ns}/sensors/joint_states", "sensor_msgs/msg/JointState", join.receive("encoders"),
                       **common),
    ]
    spin(stop, subs, pub, answered)


if __name__ == "__main__":
    main()
