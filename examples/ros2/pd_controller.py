"""A ROS 2 node controlling a cdpr session (docs/ros2.md): PD + gravity, stamped tension commands.

    cdpr up caroca_15kg --without controller --ros2                    # the session waits for its controller
    RMW_IMPLEMENTATION=rmw_zenoh_cpp python3 examples/ros2/pd_controller.py   # ROS 2 Jazzy or later, sourced

Its topics are relative to its namespace, /cdpr (the session "default"'s); a session labA's are below /cdpr/labA:
``python3 examples/ros2/pd_controller.py --ros-args -r __ns:=/cdpr/labA``.

The cables leave the frame at its frame points: for a robot with exit pulleys (session_info's "pulleys"), take
each cable's direction from where it leaves its pulley instead (docs/robots.md, "Exit pulleys").
"""
import json

import numpy as np
from scipy.optimize import lsq_linear
from scipy.spatial.transform import Rotation

GRAVITY = np.array([0.0, 0.0, -9.81])
TOPICS = ["joint_states", "platform/pose", "platform/twist", "setpoint/pose", "setpoint/twist", "setpoint/accel"]


def xyz(v):
    return np.array([v.x, v.y, v.z])


def tensions(info, pose, twist, pose_d, twist_d, accel_d):
    """PD + gravity through the platform's inertia; the tensions of least norm within the limits."""
    r, c = info["robot"], {k: np.array(info["controller"][k]) for k in ("kp", "kd")}
    q, qd = (Rotation.from_quat([o.x, o.y, o.z, o.w]) for o in (pose.pose.orientation, pose_d.pose.orientation))
    p = xyz(pose.pose.position)
    e = np.r_[xyz(pose_d.pose.position) - p, (qd * q.inv()).as_rotvec()]
    v, v_d = (np.r_[xyz(m.twist.linear), xyz(m.twist.angular)] for m in (twist, twist_d))
    acc = np.r_[xyz(accel_d.accel.linear), xyz(accel_d.accel.angular)] + c["kp"] * e + c["kd"] * (v_d - v)
    inertia = q.as_matrix() @ np.array(r["inertia"]) @ q.as_matrix().T
    wrench = np.r_[r["mass"] * (acc[:3] - GRAVITY), inertia @ acc[3:]]
    b = q.apply(r["platform_points"])  # the cables' platform ends (world frame, from the centre of mass)
    d = np.array(r["frame_points"]) - p - b
    d /= np.linalg.norm(d, axis=1, keepdims=True)  # unit cable directions, platform -> frame
    w = np.vstack([d.T, np.cross(b, d).T])  # the wrench matrix: W t is the cables' wrench on the platform
    n, limits = w.shape[1], r["cable_limits"]  # each cable's own [tmin, tmax]
    return lsq_linear(np.vstack([w, 1e-3 * np.eye(n)]), np.r_[wrench, np.zeros(n)],
                      bounds=(limits["tmin"], limits["tmax"])).x


def main():
    import rclpy
    from geometry_msgs.msg import AccelStamped, PoseStamped, TwistStamped
    from message_filters import Subscriber, TimeSynchronizer
    from rclpy.qos import DurabilityPolicy, QoSProfile
    from sensor_msgs.msg import JointState
    from std_msgs.msg import String

    rclpy.init()
    node = rclpy.create_node("pd_controller", namespace="/cdpr")  # --ros-args -r __ns:=… for another session
    info = {}
    latched = QoSProfile(depth=1, durability=DurabilityPolicy.TRANSIENT_LOCAL)
    node.create_subscription(String, "session_info", lambda m: info.update(json.loads(m.data)), latched)
    pub = node.create_publisher(JointState, "joint_commands", 10)
    types = [JointState, PoseStamped, TwistStamped, PoseStamped, TwistStamped, AccelStamped]

    def step(joints, *state_and_setpoint):  # the six messages of one step: all with the state's stamp
        if info:
            t = tensions(info, *state_and_setpoint)
            pub.publish(JointState(header=joints.header, name=joints.name, effort=t.tolist()))

    sync = TimeSynchronizer([Subscriber(node, k, n) for k, n in zip(types, TOPICS, strict=True)], 10)
    sync.registerCallback(step)
    rclpy.spin(node)


if __name__ == "__main__":
    main()
