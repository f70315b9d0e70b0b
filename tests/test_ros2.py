"""ROS 2 controllers in the loop (docs/ros2.md): the wire checked with rosbags (an independent CDR and RIHS01
implementation), the node's step, and whole sessions whose controller is a separate process written with
zenoh-ros2-sdk (a third party's implementation of rmw_zenoh's conventions), with no cdpr import."""

from __future__ import annotations

import contextlib
import itertools
import math
import queue
import re
import signal
import struct
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path

import numpy as np
import pytest
import zenoh
from hypothesis import given, settings
from hypothesis import strategies as st
from rosbags.typesys import Stores, get_typestore

from cdpr.config.scenario import load_scenario
from cdpr.protocol import Command, Keys, Setpoint, Setpoints, State, Status
from cdpr.ros2 import graph
from cdpr.ros2 import messages as ros
from cdpr.ros2.cdr import CdrError, stamp
from cdpr.ros2.topics import COMMANDS, PUBLISHED, default_namespace
from cdpr.runtime.transport import Event
from cdpr.tools.bench import ros2_controller
from cdpr_ros2.core import Bridge, RosCommandError
from conftest import CDPR, COMPOSE, free_port, last_json_line, realtime
from test_compose import Processes

HERE = Path(__file__).resolve().parent
CONTROLLER = Path(ros2_controller.__file__)  # run as a script (it imports nothing of cdpr)
SENSORS_CONTROLLER = Path(ros2_controller.__file__).with_name("ros2_sensors_controller.py")  # with the estimator
STORE = get_typestore(Stores.ROS2_JAZZY)
WAIT = 30.0  # seconds any single expected event may take (a bound, never a measurement)


def serialize(ros_type: str, **fields: object) -> bytes:
    return bytes(STORE.serialize_cdr(STORE.types[ros_type](**fields), ros_type))


def header(sec: int, nanosec: int, frame: str = "") -> object:
    time_ = STORE.types["builtin_interfaces/msg/Time"](sec=sec, nanosec=nanosec)
    return STORE.types["std_msgs/msg/Header"](stamp=time_, frame_id=frame)


# --------------------------------------------------------------------------------------------------
# The wire, against rosbags


def test_type_hashes_are_the_rihs01_of_rosbags() -> None:
    for ros_type, h in graph.TYPE_HASHES.items():
        assert STORE.hash_rihs01(ros_type) == h, ros_type
    for topic in (*PUBLISHED.values(), *COMMANDS.values()):
        assert topic.ros_type in graph.TYPE_HASHES


def _payloads() -> list[tuple[str, bytes, dict]]:
    t = (12, 345_678_901)
    pose, twist = (0.1, -0.2, 0.3, 0.0, 0.6, 0.0, 0.8), (1.0, 2.0, 3.0, 4.0, 5.0, 6.0)
    return [
        ("rosgraph_msgs/msg/Clock", ros.clock(t), {"clock.sec": 12, "clock.nanosec": 345_678_901}),
        ("sensor_msgs/msg/JointState",
         ros.joint_state(t, ["cable_1", "cable_2"], [1.5, 2.5], [0.1, -0.1], [30.0, 40.0]),
         {"name": ["cable_1", "cable_2"], "position": [1.5, 2.5], "velocity": [0.1, -0.1], "effort": [30.0, 40.0]}),
        ("sensor_msgs/msg/JointState", ros.joint_state(t, ["a"], [1.0], [], [2.0]), {"velocity": []}),
        ("geometry_msgs/msg/PoseStamped", ros.pose_stamped(t, "world", pose),
         {"header.frame_id": "world", "pose.position.y": -0.2, "pose.orientation.y": 0.6, "pose.orientation.w": 0.8}),
        ("geometry_msgs/msg/TwistStamped", ros.twist_stamped(t, "world", twist),
         {"twist.linear.z": 3.0, "twist.angular.x": 4.0}),
        ("geometry_msgs/msg/AccelStamped", ros.accel_stamped(t, "world", twist),
         {"accel.linear.x": 1.0, "accel.angular.z": 6.0}),
        ("tf2_msgs/msg/TFMessage", ros.tf_message(t, "world", "platform", pose), {}),
        ("sensor_msgs/msg/Imu", ros.imu(t, "platform", (0.1, 0.2, 0.3), (0.0, 0.0, 9.81)),
         {"angular_velocity.y": 0.2, "linear_acceleration.z": 9.81, "orientation.w": 1.0}),
        ("std_msgs/msg/String", ros.string('{"robot": "é"}'), {"data": '{"robot": "é"}'}),
        ("std_msgs/msg/Float64MultiArray", ros.float64_array([1.0, 2.0, 3.0]), {"data": [1.0, 2.0, 3.0]}),
    ]


def _get(msg: object, path: str) -> object:
    for part in path.split("."):
        msg = getattr(msg, part)
    return msg.tolist() if isinstance(msg, np.ndarray) else msg


@pytest.mark.parametrize(("ros_type", "payload", "expected"), _payloads(),
                         ids=lambda v: v if isinstance(v, str) else "")
def test_every_message_is_the_cdr_rosbags_reads_and_writes(ros_type: str, payload: bytes, expected: dict) -> None:
    assert payload[:4] == b"\x00\x01\x00\x00"  # CDR little-endian, no options
    msg = STORE.deserialize_cdr(payload, ros_type)
    for path, value in expected.items():
        assert _get(msg, path) == value, path
    if hasattr(msg, "header"):
        assert (msg.header.stamp.sec, msg.header.stamp.nanosec) == (12, 345_678_901)
    assert bytes(STORE.serialize_cdr(msg, ros_type)) == payload  # byte for byte what rosbags writes


def test_tf_carries_world_to_platform() -> None:
    msg = STORE.deserialize_cdr(ros.tf_message((1, 2), "world", "platform", (1, 2, 3, 0, 0, 0, 1)),
                                "tf2_msgs/msg/TFMessage")
    (tf,) = msg.transforms
    assert (tf.header.frame_id, tf.child_frame_id) == ("world", "platform")
    assert (tf.transform.translation.x, tf.transform.rotation.w) == (1.0, 1.0)


def test_command_decoders_read_what_rosbags_writes() -> None:
    js = serialize("sensor_msgs/msg/JointState", header=header(3, 4, "x"), name=["cable_2", "cable_1"],
                   position=np.array([]), velocity=np.array([]), effort=np.array([5.0, 6.0]))
    msg = ros.read_joint_state(js)
    assert (msg.stamp, msg.frame_id, msg.name, msg.position, msg.effort) == ((3, 4), "x", ("cable_2", "cable_1"),
                                                                           (), (5.0, 6.0))
    layout = STORE.types["std_msgs/msg/MultiArrayLayout"](
        dim=[STORE.types["std_msgs/msg/MultiArrayDimension"](label="cables", size=2, stride=2)], data_offset=0)
    fa = serialize("std_msgs/msg/Float64MultiArray", layout=layout, data=np.array([7.0, 8.0]))
    assert ros.read_float64_array(fa) == (7.0, 8.0)


@settings(max_examples=400, deadline=None)
@given(data=st.binary(max_size=200), cut=st.integers(0, 400))
def test_a_bad_payload_raises_a_cdr_error_and_nothing_else(data: bytes, cut: int) -> None:
    good = ros.joint_state((1, 2), ["cable_1"], [1.0], [], [2.0])
    for payload in (data, b"\x00\x01\x00\x00" + data, good[:cut], good[:cut] + data):
        for read in (ros.read_joint_state, ros.read_float64_array):
            with contextlib.suppress(CdrError):  # anything else fails the test
                read(payload)


def test_stamps_are_the_nearest_nanosecond() -> None:
    assert stamp(0.0) == (0, 0)
    assert stamp(1.001) == (1, 1_000_000)
    assert stamp(10999 * 0.001) == (10, 999_000_000)
    assert stamp(2.9999999999) == (3, 0)


def test_keys_tokens_and_attachment_are_rmw_zenohs() -> None:
    assert graph.data_key(0, "/cdpr/joint_states", "sensor_msgs/msg/JointState") == (
        "0/cdpr/joint_states/sensor_msgs::msg::dds_::JointState_/" + STORE.hash_rihs01("sensor_msgs/msg/JointState"))
    node = graph.NodeName(7, "abc", 0, "/cdpr", "cdpr")
    assert graph.node_token(node) == "@ros2_lv/7/abc/0/0/NN/%/%cdpr/cdpr"
    tok = graph.endpoint_token(node, 3, "MP", "/cdpr/platform/pose", "geometry_msgs/msg/PoseStamped", graph.Qos())
    assert tok.startswith("@ros2_lv/7/abc/0/3/MP/%/%cdpr/cdpr/%cdpr%platform%pose/"
                          "geometry_msgs::msg::dds_::PoseStamped_/")
    ep = graph.parse_token(tok)
    assert ep is not None
    assert (ep.kind, ep.namespace, ep.node, ep.topic) == ("MP", "/cdpr", "cdpr",
                                                                              "/cdpr/platform/pose")
    att = graph.attachment(5, 123, bytes(range(16)))
    assert len(att) == 33
    assert att[16] == 16
    assert struct.unpack("<qq", att[:16]) == (5, 123)
    assert graph.parse_attachment(att) == (5, 123, bytes(range(16)))


# --------------------------------------------------------------------------------------------------
# The node's step


@pytest.fixture(scope="module")
def scenario() -> object:
    return load_scenario("caroca_15kg")


def _state(k: int, m: int = 8) -> State:
    return State(k, k * 0.001, (0.9, 0.9, 0.2, 0.0, 0.0, 0.0, 1.0), (0.1, 0.0, 0.0, 0.0, 0.0, 0.01),
                 tuple(2.0 + i for i in range(m)), tuple(10.0 + i for i in range(m)))


def _setpoint(k: int) -> Setpoint:
    return Setpoint(k, k * 0.001, (0.9, 0.9, 0.2, 0.0, 0.0, 0.0, 1.0), (0.0,) * 6, (0.0,) * 6)


def _joint_command(t: tuple[int, int], effort: list[float], names: list[str] | None = None,
                   position: list[float] | None = None) -> bytes:
    return ros.joint_state(t, names if names is not None else [f"cable_{i + 1}" for i in range(8)],
                           position or [], [], effort)


def test_a_step_is_every_topic_stamped_with_the_state_time(scenario: object) -> None:
    bridge = Bridge.from_scenario(scenario)  # type: ignore[arg-type]
    out = dict(bridge.step_messages(_state(1234), _setpoint(1234)))
    assert set(out) == {"clock", "joint_states", "pose", "twist", "tf", "setpoint_pose", "setpoint_twist",
                        "setpoint_accel"}
    assert STORE.deserialize_cdr(out["clock"], "rosgraph_msgs/msg/Clock").clock.nanosec == 234_000_000
    js = STORE.deserialize_cdr(out["joint_states"], "sensor_msgs/msg/JointState")
    assert js.name == [f"cable_{i}" for i in range(1, 9)]
    assert js.position.tolist() == list(_state(0).cable_lengths)
    assert js.effort.tolist() == list(_state(0).tensions)
    # velocity: the length rates J v of the ideal cables, against a finite difference of the lengths
    from cdpr.mechanics.kinematics import inverse_kinematics
    from cdpr.mechanics.rotation import rotvec_to_matrix
    robot = bridge.robot
    p, v, w, h = np.array([0.9, 0.9, 0.2]), np.array([0.1, 0.0, 0.0]), np.array([0.0, 0.0, 0.01]), 1e-6
    ahead = inverse_kinematics(robot, p + h * v, rotvec_to_matrix(h * w)).lengths
    behind = inverse_kinematics(robot, p - h * v, rotvec_to_matrix(-h * w)).lengths
    np.testing.assert_allclose(js.velocity, (ahead - behind) / (2 * h), atol=1e-8)


class _Sent:
    """Where a ros2 node's messages go in the unit test below: (topic, stamp) in the order they are put."""

    def __init__(self, log: list[tuple[str, object]], name: str) -> None:
        self.log, self.name, self.matched = log, name, True

    def put(self, payload: bytes) -> None:
        if self.name == "command":
            self.log.append(("command", Command.decode(payload).step))
        else:
            msg = STORE.deserialize_cdr(payload, PUBLISHED[self.name].ros_type)
            self.log.append((self.name, msg.header.stamp.nanosec))


def test_the_ros2_node_sends_setpoint_k_once_state_k_minus_1_is_answered(scenario: object) -> None:
    """Setpoint k goes out before state k (docs/ros2.md, Topics): as the command for state k − 1 comes; with its
    state when it was not known then; again with a state the clock asks for again."""
    from cdpr_ros2.node import Ros2Node

    node = Ros2Node(scenario, Keys("unit"))  # type: ignore[arg-type]
    log: list[tuple[str, object]] = []
    wanted = ("joint_states", "pose", "setpoint_pose")
    node.ros = {name: _Sent(log, name) for name in wanted}  # type: ignore[misc]
    node.publishers = {"command": _Sent(log, "command")}  # type: ignore[dict-item]
    node.controllers = ("a ROS 2 process",)

    def event(topic: str, payload: bytes) -> None:
        node.handle(Event(topic, payload, "", 0.0))

    def step_of(k: int) -> None:  # state k, then the ROS 2 controller's answer
        event("state", _state(k).encode())
        event("joint_commands", _joint_command(stamp(k * 0.001), [10.0] * 8))

    event("setpoints", Setpoints(tuple(_setpoint(k) for k in range(3))).encode())
    step_of(0)
    step_of(1)
    ms = 1_000_000
    # setpoint k + 1 goes out before the command for state k goes on to the sim
    assert log == [("setpoint_pose", 0), ("joint_states", 0), ("pose", 0), ("setpoint_pose", ms), ("command", 0),
                   ("joint_states", ms), ("pose", ms), ("setpoint_pose", 2 * ms), ("command", 1)]
    log.clear()
    step_of(1)  # the clock asks for state 1 again: all of it, its answer again, and setpoint 2 ahead again
    assert log == [("setpoint_pose", ms), ("joint_states", ms), ("pose", ms), ("setpoint_pose", 2 * ms),
                   ("command", 1)]
    log.clear()
    step_of(2)
    assert log == [("joint_states", 2 * ms), ("pose", 2 * ms), ("command", 2)]  # its setpoint: ahead, above
    log.clear()
    step_of(3)  # setpoint 3 unknown when state 2 was answered: it goes with its state once it comes, first
    event("setpoints", Setpoints((_setpoint(3),)).encode())
    assert log == [("setpoint_pose", 3 * ms), ("joint_states", 3 * ms), ("pose", 3 * ms)]


class _Sink:
    """A publisher of the unit tests below: every put handed to ``put``, always matched."""

    def __init__(self, put: Callable[[bytes], None]) -> None:
        self.put, self.matched = put, True


def test_an_unstamped_repeated_answer_is_never_taken_for_the_next_state(scenario: object) -> None:
    """The orders of messages behind a thrown platform (a fresh clone's make test): the clock publishes state k
    more than once (its handshake repeats state 0; a stall asks again), an unstamped controller answers each copy
    it receives — or once for several, when its callbacks merge them — and a repeated answer arrives after state
    k + 1 went out. Whatever the order, every command the sim gets carries the values computed for its own state
    (docs/ros2.md: what an unstamped controller can rely on)."""
    from cdpr_ros2.node import Ros2Node

    def tensions(k: int) -> tuple[float, ...]:  # what the controller computes for state k (a function of it)
        return tuple(100.0 * k + i for i in range(8))

    def run(order: str, answers: dict[int, tuple[float, ...]] | None = None) -> list[tuple[int, tuple[float, ...]]]:
        """``order``: "s3" publishes state 3, "a3" is an answer computed for state 3 (``answers`` or tensions)."""
        node = Ros2Node(scenario, Keys("unit"))  # type: ignore[arg-type]
        sent: list[tuple[int, tuple[float, ...]]] = []
        node.ros = {name: _Sink(lambda _: None) for name in PUBLISHED}  # type: ignore[misc]
        node.publishers = {"command": _Sink(lambda b: sent.append(  # type: ignore[dict-item]
            (Command.decode(b).step, Command.decode(b).tensions)))}
        node.controllers = ("a ROS 2 process",)
        node.handle(Event("setpoints", Setpoints(tuple(_setpoint(k) for k in range(9))).encode(), "", 0.0))
        for what in order.split():
            k = int(what[1:])
            if what[0] == "s":
                node.handle(Event("state", _state(k).encode(), "", 0.0))
            else:
                values = (answers or {}).get(k, tensions(k))
                node.handle(Event("tension_commands", ros.float64_array(list(values)), "", 0.0))
        return sent

    def applied(*steps: int, answers: dict[int, tuple[float, ...]] | None = None) -> list:
        return [(k, (answers or {}).get(k, tensions(k))) for k in steps]

    # the handshake repeat: state 0 twice, both answered, the second answer after state 1 went out
    assert run("s0 s0 a0 s1 a0 a1 s2 a2") == applied(0, 1, 2)
    # the copies merged by the controller's callbacks: one answer for two publications
    assert run("s0 s0 a0 s1 a1 s2 a2") == applied(0, 1, 2)
    # a slow first answer: three copies, their answers anywhere up to the next state's
    assert run("s0 s0 s0 a0 s1 a0 a0 a1 s2 a2") == applied(0, 1, 2)
    assert run("s0 s0 s0 a0 a0 s1 a1 s2 a2") == applied(0, 1, 2)
    # a stall asks again for a later state: the same
    assert run("s0 a0 s1 a1 s2 s2 a2 s3 a2 a3 s4 a4") == applied(0, 1, 2, 3, 4)
    # a platform at rest: equal commands for successive states are each taken, repeats or not
    same = {k: tensions(0) for k in range(9)}
    assert run("s0 a0 s1 a1 s2 a2", same) == applied(0, 1, 2, answers=same)
    assert run("s0 s0 a0 s1 a0 a1 s2 a2", same) == applied(0, 1, 2, answers=same)
    # … but when the copies were merged, the next state's equal answer is taken for a repeat: it waits for the
    # clock to ask again (a stall of --resend-after), and so does every state while the commands stay equal —
    # slow, never a command on the wrong state
    assert run("s0 s0 a0 s1 a1 s1 a1 s2 a2 s2 a2 s3", same) == applied(0, 1, 2, answers=same)


def test_a_new_ros2_controller_answers_the_publications_from_its_joining_on(scenario: object) -> None:
    """A controller that left a repeated state unanswered: the next one in the role answers from the state
    published again when the session resumes (the old publications were not its own)."""
    bridge = Bridge.from_scenario(scenario)  # type: ignore[arg-type]
    bridge.step_messages(_state(6), _setpoint(6))
    bridge.step_messages(_state(6), _setpoint(6))
    assert bridge.command("tension_commands", ros.float64_array([6.0] * 8)).step == 6
    bridge.step_messages(_state(7), _setpoint(7))  # the controller leaves without answering state 7
    bridge.new_controller()
    bridge.step_messages(_state(7), _setpoint(7))  # the session resumes: state 7 again
    assert bridge.command("tension_commands", ros.float64_array([6.0] * 8)).step == 7  # no repeat of 6 expected


def test_a_stamped_command_answers_the_state_with_its_stamp(scenario: object) -> None:
    bridge = Bridge.from_scenario(scenario)  # type: ignore[arg-type]
    bridge.step_messages(_state(5), _setpoint(5))
    cmd = bridge.command("joint_commands", _joint_command(stamp(0.005), [float(i) for i in range(8)]))
    assert (cmd.step, cmd.tensions) == (5, tuple(float(i) for i in range(8)))
    with pytest.raises(RosCommandError, match=r"header.stamp 0.005000000: no state awaiting") as err:
        bridge.command("joint_commands", _joint_command(stamp(0.005), [1.0] * 8))  # answered already
    assert err.value.counter == "unmatched_ros2_commands"


def test_joint_names_may_come_in_any_order(scenario: object) -> None:
    bridge = Bridge.from_scenario(scenario)  # type: ignore[arg-type]
    bridge.step_messages(_state(1), _setpoint(1))
    names = [f"cable_{i}" for i in range(8, 0, -1)]
    cmd = bridge.command("joint_commands", _joint_command(stamp(0.001), [float(i) for i in range(8, 0, -1)], names))
    assert cmd.tensions == tuple(float(i) for i in range(1, 9))


def test_an_unstamped_command_answers_the_oldest_state_or_free_running_the_newest(scenario: object) -> None:
    bridge = Bridge.from_scenario(scenario)  # type: ignore[arg-type]
    for k in (1, 2, 3):
        bridge.step_messages(_state(k), _setpoint(k))
    assert bridge.command("tension_commands", ros.float64_array([1.0] * 8)).step == 1
    assert bridge.command("tension_commands", ros.float64_array([1.0] * 8)).step == 2
    bridge.free = True
    for k in (4, 5):
        bridge.step_messages(_state(k), _setpoint(k))
    assert bridge.command("tension_commands", ros.float64_array([1.0] * 8)).step == 5
    assert bridge.command("tension_commands", ros.float64_array([2.0] * 8)).step == 5  # as they arrive
    with pytest.raises(RosCommandError, match="no state awaits a command"):
        Bridge.from_scenario(scenario).command("tension_commands", ros.float64_array([1.0] * 8))  # type: ignore[arg-type]


@pytest.mark.parametrize(("topic", "payload", "message", "counter"), [
    ("joint_commands", _joint_command(stamp(0.001), [1.0] * 7),
     r"JointState.effort: 7 values, expected 8", "bad_ros2_commands"),
    ("joint_commands", _joint_command(stamp(0.001), [1.0] * 7 + [math.nan]),
     r"JointState.effort\[7\]: nan is not a finite number", "bad_ros2_commands"),
    ("joint_commands", _joint_command(stamp(0.001), [1.0] * 8, ["cable_1"] * 8),
     r"JointState.name: .* are not the cables", "bad_ros2_commands"),
    ("joint_commands", _joint_command(stamp(0.0015), [1.0] * 8), r"header.stamp 0.001500000",
     "unmatched_ros2_commands"),
    ("joint_commands", b'{"tensions": [1, 2]}', r"JointState: not little-endian CDR", "bad_ros2_commands"),
    ("joint_commands", ros.float64_array([1.0] * 8), r"JointState\.", "bad_ros2_commands"),
    ("tension_commands", ros.float64_array([1.0] * 9), r"Float64MultiArray.data: 9 values, expected 8",
     "bad_ros2_commands"),
    ("tension_commands", ros.float64_array([math.inf] * 8), r"Float64MultiArray.data\[0\]: inf", "bad_ros2_commands"),
    ("tension_commands", b"\x00\x01", r"Float64MultiArray: not CDR", "bad_ros2_commands"),
])
def test_bad_commands_are_refused_naming_the_field(scenario: object, topic: str, payload: bytes, message: str,
                                                   counter: str) -> None:
    bridge = Bridge.from_scenario(scenario)  # type: ignore[arg-type]
    bridge.step_messages(_state(1), _setpoint(1))
    with pytest.raises(RosCommandError, match=message) as err:
        bridge.command(topic, payload)
    assert err.value.counter == counter
    assert len(bridge.pending) == 1  # still awaiting its command


def test_a_winch_session_takes_unstretched_lengths_as_positions() -> None:
    bridge = Bridge.from_scenario(load_scenario("caroca_15kg_winch"))
    bridge.step_messages(_state(1), _setpoint(1))
    cmd = bridge.command("joint_commands", _joint_command(stamp(0.001), [], position=[3.0] * 8))
    assert (cmd.lengths, cmd.tensions) == ((3.0,) * 8, ())
    bridge.step_messages(_state(2), _setpoint(2))
    with pytest.raises(RosCommandError, match="must be > 0"):
        bridge.command("joint_commands", _joint_command(stamp(0.002), [], position=[0.0] * 8))


# --------------------------------------------------------------------------------------------------
# Whole sessions: the controller a separate process written with zenoh-ros2-sdk (no cdpr import)


class Session:
    """``cdpr up SCENARIO --without controller --ros2`` on a port of its own, ROS 2 controllers beside it, and a
    plain Zenoh client of the session's router watching ``clock/status``."""

    def __init__(self, tmp: Path, env: dict[str, str], session_id: str) -> None:
        self.tmp, self.env, self.sid = tmp, env, session_id
        self.ns = default_namespace(session_id)  # the session's topics: /cdpr/<session>
        self.port = free_port()
        self.procs = Processes()
        self.statuses: queue.Queue[Status] = queue.Queue()
        self.zenoh: zenoh.Session | None = None
        self.up: subprocess.Popen[bytes] | None = None
        self.realtime = False

    def start(self, scenario: str, duration: float | None = None, *extra: str) -> None:
        args = [*CDPR, "up", scenario, "--without", "controller", "--ros2", "--session", self.sid, "--quiet",
                "--listen", f"tcp/127.0.0.1:{self.port}", *extra]
        if duration is not None:
            args += ["--duration", str(duration)]
        self.stdout = (self.tmp / "up.out").open("wb")
        self.stderr = self.tmp / "up.err"
        self.realtime = "realtime" in extra  # its processes and the controllers under SCHED_FIFO (conftest.realtime)
        self.up = subprocess.Popen(realtime(args) if self.realtime else args, stdout=self.stdout,
                                   stderr=self.stderr.open("wb"), env=self.env)
        conf = zenoh.Config()
        conf.insert_json5("mode", '"client"')
        conf.insert_json5("connect/endpoints", f'["tcp/127.0.0.1:{self.port}"]')
        conf.insert_json5("connect/timeout_ms", '{"client": 20000}')
        self.zenoh = zenoh.open(conf)
        self.zenoh.declare_subscriber(Keys(self.sid).status, lambda s: self.statuses.put(Status.decode(
            s.payload.to_bytes())))

    def controller(self, name: str, *args: str) -> subprocess.Popen[bytes]:
        argv = [sys.executable, str(CONTROLLER), "--router-port", str(self.port), "--namespace", self.ns, *args]
        return self.procs.start(name, realtime(argv) if self.realtime else argv, self.tmp, self.tmp / f"{name}.log",
                                env=self.env)

    def _check_controllers(self) -> None:
        for name, p in self.procs.procs.items():
            if p.poll() not in (None, 0, -signal.SIGKILL):
                raise AssertionError(f"the ROS 2 controller {name} exited with code {p.poll()}:\n"
                                     f"{self.procs.log(name)[-3000:]}")

    def wait_status(self, ok: object, what: str, timeout: float = WAIT) -> Status:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            try:
                status = self.statuses.get(timeout=0.2)
            except queue.Empty:
                self._check_controllers()
                continue
            if ok(status):  # type: ignore[operator]
                return status
        raise AssertionError(f"no clock/status with {what} within {timeout:g} s\n{self.stderr.read_text()[-3000:]}")

    def summary(self, timeout: float = 300.0) -> dict:
        assert self.up is not None
        deadline = time.monotonic() + timeout
        while self.up.poll() is None:
            self._check_controllers()
            if time.monotonic() > deadline:
                self.up.kill()
                raise AssertionError(f"cdpr up did not end\n{self.stderr.read_text()[-3000:]}")
            time.sleep(0.1)
        self.stdout.flush()
        return last_json_line((self.tmp / "up.out").read_text())

    def close(self) -> None:
        if self.up is not None and self.up.poll() is None:
            self.up.send_signal(signal.SIGTERM)
            try:
                self.up.wait(timeout=20)
            except subprocess.TimeoutExpired:
                self.up.kill()
        self.procs.close()
        if self.zenoh is not None:
            self.zenoh.close()


@pytest.fixture
def ros2_session(tmp_path: Path, sdk_env: dict[str, str], session_id: str) -> Iterator[Session]:
    s = Session(tmp_path, sdk_env, session_id)
    try:
        yield s
    finally:
        s.close()


def test_the_ros2_controller_imports_nothing_of_cdpr() -> None:
    """The ROS 2 peer of these tests and of cdpr bench is what a ROS 2 user could write: zenoh-ros2-sdk, numpy and
    the standard library, run as a script (it lives in the package only to be found by cdpr bench)."""
    import ast

    tree = ast.parse(CONTROLLER.read_text(encoding="utf-8"))
    imported = {a.name.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    imported |= {n.module.split(".")[0] for n in ast.walk(tree) if isinstance(n, ast.ImportFrom) and n.module}
    assert imported - set(sys.stdlib_module_names) == {"numpy", "zenoh_ros2_sdk"}


@pytest.mark.slow
@pytest.mark.parametrize("unstamped", [False, True], ids=["joint_commands", "tension_commands"])
def test_a_ros2_controller_runs_caroca_15kg_to_the_end(ros2_session: Session, unstamped: bool) -> None:
    ros2_session.start("caroca_15kg")
    ctl = ros2_session.controller("controller", *(["--unstamped"] if unstamped else []))
    s = ros2_session.summary()
    assert s["exit_ok"], s
    assert s["steps"] == s["total_steps"] == 11000
    assert s["rms_position_error"] <= 1e-3  # the bar; it is ~3e-5 m (feedback linearisation, exact model)
    # nothing bad: at most a second answer to a state the clock asked for again (its handshake repeat): the sim
    # counts it stale, or, when the ros2 node has already passed the first on, the node finds no state awaiting it
    # (stamped) or knows it for a repeated state's second answer (unstamped)
    assert set(s["faults"]) <= {"sim", "ros2"}, s["faults"]
    assert set(s["faults"].get("sim", {})) <= {"stale_commands"}, s["faults"]
    assert set(s["faults"].get("ros2", {})) <= {"unmatched_ros2_commands", "repeated_ros2_commands"}, s["faults"]
    ctl.send_signal(signal.SIGTERM)
    assert ctl.wait(timeout=WAIT) == 0, ros2_session.procs.log("controller")[-2000:]
    answered = re.search(r"controller: answered (\d+) steps", ros2_session.procs.log("controller"))
    assert answered, ros2_session.procs.log("controller")[-2000:]
    assert int(answered.group(1)) >= 11000  # and again any step the clock asked for again


@pytest.mark.slow
def test_every_topic_on_the_wire_is_what_rosbags_reads(ros2_session: Session) -> None:
    """Each topic's key (DDS type name, RIHS01 hash from rosbags), encapsulation header, attachment (33 bytes:
    sequence from 1, timestamp, GID) and stamps: /clock is the state's t, and never goes back."""
    samples: list[tuple[str, bytes, bytes]] = []
    states: list[State] = []
    ros2_session.start(str(HERE / "scenarios" / "caroca_15kg_ros2_sensors.yaml"), 0.3)
    z = ros2_session.zenoh
    assert z is not None
    keep = [
        z.declare_subscriber("0/**", lambda s: samples.append(
            (str(s.key_expr), s.payload.to_bytes(), b"" if s.attachment is None else s.attachment.to_bytes()))),
        z.declare_subscriber(Keys(ros2_session.sid).state, lambda s: states.append(State.decode(s.payload.to_bytes()))),
    ]
    # the session's only controller is ours: it waits for it, so nothing is missed by subscribing first
    ros2_session.controller("controller")
    s = ros2_session.summary()
    assert s["exit_ok"], s
    time.sleep(0.5)  # deliveries still on their way to this session's callbacks (all sent: the session ended)
    del keep
    ns = ros2_session.ns
    types = {graph.qualify(ns, t.name): t.ros_type for t in PUBLISHED.values()}
    commands = {graph.qualify(ns, t.name) for t in COMMANDS.values()}
    by_topic: dict[str, list[tuple[object, tuple[int, int, bytes]]]] = {}
    for key, payload, att in samples:
        domain, *topic, dds, type_hash = key.split("/")
        name = "/" + "/".join(topic)
        if name in commands:
            continue  # the controller's own
        ros_type = types[name]
        assert (domain, dds, type_hash) == ("0", graph.dds_type(ros_type), STORE.hash_rihs01(ros_type)), key
        assert payload[:4] == b"\x00\x01\x00\x00", key
        assert len(att) == 33, key
        by_topic.setdefault(name, []).append((STORE.deserialize_cdr(payload, ros_type), graph.parse_attachment(att)))
    # session_info is latched, published once as the node starts: before or after this test subscribed
    assert set(by_topic) - {f"{ns}/session_info"} == set(types) - {f"{ns}/session_info"}
    for name, got in by_topic.items():
        seqs = [a[0] for _, a in got]
        assert seqs == list(range(seqs[0], seqs[0] + len(seqs))), name  # every one, in order
        assert len({a[2] for _, a in got}) == 1, name  # one publisher GID
        assert all(abs(a[1] - time.time_ns()) < 600e9 for _, a in got), name  # source timestamps: now (ns)
    ts = {stamp(st.t) for st in states}
    clocks = [(m.clock.sec, m.clock.nanosec) for m, _ in by_topic["/clock"]]
    assert set(clocks) == ts  # /clock is the state's t, every step
    distinct = [c for i, c in enumerate(clocks) if i == 0 or c != clocks[i - 1]]
    assert distinct == sorted(ts)  # never going back (a step the clock asked again is stamped the same)
    for name in (*(f"{ns}/{t}" for t in ("joint_states", "platform/pose", "platform/twist", "setpoint/pose", "imu",
                                          "sensors/joint_states", "sensors/laser_tracker")), "/tf"):
        stamps = [(h.stamp.sec, h.stamp.nanosec) for h in (
            (m.transforms[0].header if name == "/tf" else m.header) for m, _ in by_topic[name])]
        assert all(a < b for a, b in itertools.pairwise(stamps) if a != b), name
        assert set(stamps) <= ts | {stamp(st.t + 0.001) for st in states}, name
    state_by_stamp = {stamp(st.t): st for st in states}
    for m, _ in by_topic[f"{ns}/joint_states"]:
        st = state_by_stamp[(m.header.stamp.sec, m.header.stamp.nanosec)]
        assert m.position.tolist() == list(st.cable_lengths)
        assert m.effort.tolist() == list(st.tensions)
    for m, _ in by_topic[f"{ns}/platform/pose"]:
        st = state_by_stamp[(m.header.stamp.sec, m.header.stamp.nanosec)]
        p, q = m.pose.position, m.pose.orientation
        assert (p.x, p.y, p.z, q.x, q.y, q.z, q.w) == st.pose
        assert m.header.frame_id == "world"
    imu = by_topic[f"{ns}/imu"][0][0]
    assert imu.header.frame_id == "platform"
    assert imu.orientation_covariance[0] == -1.0  # no orientation estimate
    assert 9.0 < imu.linear_acceleration.z < 10.6  # specific force at rest, platform frame
    info = [r.ok for r in z.get(f"0{ns}/session_info/**/@adv/pub/**?_anyke", timeout=5.0) if r.ok is not None]
    if info:  # the session has ended: its node (and cache) may be gone already
        text = STORE.deserialize_cdr(info[0].payload.to_bytes(), "std_msgs/msg/String").data
        assert '"cables": ["cable_1"' in text


def _tokens(z: zenoh.Session) -> list[str]:
    return [str(r.ok.key_expr) for r in z.liveliness().get("@ros2_lv/0/**", timeout=5.0) if r.ok is not None]


@pytest.mark.slow
def test_the_graph_the_wait_the_pause_and_bad_commands(ros2_session: Session) -> None:
    """The node and its endpoints in the ROS 2 graph (names mangled as rmw_zenoh does); the session waits for a
    ROS 2 controller, pauses when its process is killed, resumes when it is restarted and finishes; bad ROS 2
    commands meanwhile are dropped and counted."""
    ros2_session.start("caroca_15kg", 3.0)
    z = ros2_session.zenoh
    assert z is not None
    ns = ros2_session.ns  # /cdpr/<session>: mangled %cdpr%<session>
    node = f"%/{graph.mangle(ns)}/cdpr"
    expected = {f"MP/{node}/{graph.mangle(graph.qualify(ns, t.name))}/{graph.dds_type(t.ros_type)}/"
                f"{graph.TYPE_HASHES[t.ros_type]}" for t in PUBLISHED.values()}
    expected |= {f"MS/{node}/{graph.mangle(graph.qualify(ns, t.name))}/{graph.dds_type(t.ros_type)}/"
                 f"{graph.TYPE_HASHES[t.ros_type]}" for t in COMMANDS.values()}
    deadline = time.monotonic() + WAIT
    while time.monotonic() < deadline:
        tokens = _tokens(z)
        ends = {"/".join(k.split("/")[5:12]) for k in tokens}
        if expected <= ends and any(k.endswith(f"/NN/{node}") for k in tokens):
            break
        time.sleep(0.1)
    else:
        raise AssertionError(f"the ros2 node's tokens are not all there: {sorted(expected - ends)}")
    assert f"{graph.mangle(ns)}%setpoint%accel" in " ".join(tokens)
    assert "/%tf/" in " ".join(tokens)
    status = ros2_session.wait_status(lambda s: s.state == "waiting" and "controller" in s.missing,
                                      "the session waiting for its controller")
    assert status.step == 0

    ros2_session.controller("first")
    ros2_session.wait_status(lambda s: s.state == "running" and s.step > 300, "the session running")
    ros2_session.procs.stop("first", signal.SIGKILL)
    paused = ros2_session.wait_status(lambda s: s.state == "paused" and "controller" in s.missing, "a pause")
    assert paused.step < 3000

    ros2_session.controller("second")
    ros2_session.wait_status(lambda s: s.state == "running" and s.step > paused.step, "the session resumed")
    bad = {
        "tension_commands": [ros.float64_array([1.0] * 9), ros.float64_array([math.nan] * 8)],
        "joint_commands": [b"not cdr at all", ros.joint_state((999, 0), [], [], [], [1.0] * 8)],
    }
    for topic, payloads in bad.items():
        ros_type = COMMANDS[topic].ros_type
        pub = z.declare_publisher(graph.data_key(0, f"{ns}/{topic}", ros_type))
        for i, payload in enumerate(payloads):
            pub.put(payload, attachment=graph.attachment(i + 1, time.time_ns(), b"\x01" * 16))
        pub.undeclare()
    s = ros2_session.summary()
    assert s["exit_ok"], s
    assert s["steps"] == 3000
    assert s["rms_position_error"] <= 1e-3
    ros2 = s["faults"].get("ros2", {})
    assert ros2.get("bad_ros2_commands") == 3, s["faults"]  # 9 values, NaN, not CDR
    # the unknown stamp (and a second answer to a state asked for again, if the clock repeated one)
    assert ros2.get("unmatched_ros2_commands", 0) >= 1, s["faults"]
    assert set(ros2) <= {"bad_ros2_commands", "unmatched_ros2_commands"}, s["faults"]
    log = ros2_session.stderr.read_text()
    assert f"[ros2] dropped a bad {ns}/tension_commands message: Float64MultiArray.data: 9 values, expected 8" in log
    assert "[ros2] the ROS 2 controller left: the session waits for it" in log


@pytest.mark.slow
def test_free_running_unstamped_commands_apply_as_they_arrive(ros2_session: Session, tmp_path: Path) -> None:
    """Free-running realtime (the sim on the wall clock): a Float64MultiArray controller, as under Gazebo — each
    command answers the newest state when it arrives and acts from the sim's next step."""
    from test_realtime import _scenario

    # 500 Hz and gains that tolerate a few steps of latency (docs/realtime.md: the paper's do not); a watchdog
    # that a loaded machine's hiccup does not trip (what is tested is the commands' path, not the machine)
    path = _scenario(tmp_path, "ros2_free", dt=0.002, duration=3.0, controller__kp=400.0, controller__kd=40.0,
                     sim__watchdog={"policy": "hold", "timeout_ms": 500})
    ros2_session.start(str(path), None, "--mode", "realtime", "--sync", "free")
    ros2_session.controller("controller", "--unstamped")
    s = ros2_session.summary()
    assert s["exit_ok"], s
    assert (s["sync"], s["steps"]) == ("free", 1500)
    assert s["rtf"] == pytest.approx(1.0, abs=0.05)
    assert s["watchdog_steps"] == 0  # a command every step or so: the watchdog never acts
    assert s["command_age_p50"] <= 2  # the newest state's answer, acting at once
    assert s["rms_position_error"] < 1e-3, s
    # nothing bad; at most the answer to a state the clock asked for again, before the session ran free
    # (a second answer to the same state: no state awaits it)
    assert "bad_ros2_commands" not in s["faults"].get("ros2", {}), s["faults"]


@pytest.mark.slow
def test_the_compose_ros2_profile_runs_a_session_with_a_ros2_controller(sdk_env: dict[str, str], session_id: str,
                                                                         tmp_path: Path) -> None:
    """docker/compose.yaml's commands with `--profile ros2 --scale controller=0`, each a local process (as
    tests/test_compose.py runs them), and a ROS 2 controller on the host reaching the router's port."""
    from test_compose import SESSION_SERVICES, load_compose, localise

    services = load_compose([COMPOSE], {"CDPR_SESSION": session_id, "CDPR_ARGS": "--duration 0.5"})
    port = free_port()
    names = ("router", *SESSION_SERVICES, "ros2")
    containers = {n: localise(n, services[n], COMPOSE.parent, tmp_path, port) for n in names}
    procs = Processes()
    try:
        for name in names:
            c = containers[name]
            procs.start(name, c.argv, c.cwd, c.log)
        procs.start("controller", [sys.executable, str(CONTROLLER), "--router-port", str(port), "--namespace",
                                   default_namespace(session_id)], tmp_path, tmp_path / "controller.log", env=sdk_env)
        codes = procs.wait(SESSION_SERVICES, timeout=180)
        assert codes == dict.fromkeys(SESSION_SERVICES, 0), procs.report()
        assert procs.wait(["ros2"], timeout=WAIT) == {"ros2": 0}, procs.report()
    finally:
        procs.close()
    assert "finished 500 steps" in procs.log("clock"), procs.report()
    counts = re.search(r"published (\d+) steps on ROS 2; applied (\d+) ROS 2 commands", procs.log("ros2"))
    assert counts, procs.report()
    # every step, and again those the clock asked for again (a handshake repeat, a resend)
    assert int(counts.group(1)) >= 501
    assert int(counts.group(2)) >= 500


def test_the_rclpy_example_s_law_gives_the_feedback_linearisation_wrench(scenario: object) -> None:
    """examples/ros2/pd_controller.py (rclpy: not installable here) — its law, on the messages of a step as a
    ROS 2 node receives them (rosbags' message classes have rclpy's field names): the cables' wrench W t is the
    wrench of cdpr's feedback linearisation (no spin: no gyroscopic term), within the tension limits."""
    import importlib.util
    import json

    from cdpr.mechanics.control import Gains, feedback_linearisation
    from cdpr.mechanics.kinematics import inverse_kinematics
    from cdpr.mechanics.rotation import matrix_to_quat, quat_to_matrix, rpy_to_matrix

    path = HERE.parent / "examples" / "ros2" / "pd_controller.py"
    spec = importlib.util.spec_from_file_location("pd_controller", path)
    assert spec is not None
    assert spec.loader is not None
    example = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(example)
    bridge = Bridge.from_scenario(scenario)  # type: ignore[arg-type]
    info = json.loads(STORE.deserialize_cdr(bridge.info_message(), "std_msgs/msg/String").data)
    q = matrix_to_quat(rpy_to_matrix(0.02, -0.01, 0.03))
    state = State(7, 0.007, (0.5, 0.4, 0.6, *q), (0.1, -0.2, 0.05, 0.0, 0.0, 0.0), (2.0,) * 8, (10.0,) * 8)
    setpoint = Setpoint(7, 0.007, (0.501, 0.3995, 0.601, *q), (0.1, -0.2, 0.051, 0.0, 0.0, 0.0),
                        (0.3, 0.1, -0.2, 0.0, 0.0, 0.0))  # 1 mm off: a wrench the cables can give
    msgs = dict(bridge.step_messages(state, setpoint))
    read = {n: STORE.deserialize_cdr(msgs[n], PUBLISHED[n].ros_type)
            for n in ("pose", "twist", "setpoint_pose", "setpoint_twist", "setpoint_accel")}
    t = example.tensions(info, read["pose"], read["twist"], read["setpoint_pose"], read["setpoint_twist"],
                         read["setpoint_accel"])
    robot = bridge.robot
    R = quat_to_matrix(np.array(state.pose[3:]))
    W = inverse_kinematics(robot, np.array(state.pose[:3]), R).wrench_matrix
    expected = feedback_linearisation(robot, state.pose[:3], R, state.twist, setpoint.pose[:3],
                                      quat_to_matrix(np.array(setpoint.pose[3:])), setpoint.twist, setpoint.accel,
                                      Gains.of(1500.0, 1500.0))
    np.testing.assert_allclose(W @ t, expected, atol=0.05 + 1e-4 * np.abs(expected).max())
    assert np.all(robot.tmin - 1e-9 <= t)
    assert np.all(t <= robot.tmax + 1e-9)


# --------------------------------------------------------------------------------------------------
# cdpr convert --to rosbag2


@pytest.mark.slow
def test_a_recording_converts_to_a_ros2_bag_with_every_step(tmp_path: Path) -> None:
    from rosbags.rosbag2 import Reader

    from cdpr import recording
    from cdpr.tools.report import read_recording, state_columns

    rrd = tmp_path / "run.rrd"
    run = subprocess.run([*CDPR, "run", str(HERE / "scenarios" / "caroca_15kg_ros2_sensors.yaml"), "--duration", "0.3",
                          "--in-process", "--quiet", "--rrd", str(rrd)], capture_output=True, text=True, timeout=300)
    assert run.returncode == 0, run.stderr[-2000:]
    conv = subprocess.run([*CDPR, "convert", str(rrd), "--to", "rosbag2"], capture_output=True, text=True,
                          timeout=300)
    assert conv.returncode == 0, conv.stderr[-2000:]
    out = last_json_line(conv.stdout)
    bag = tmp_path / "run_rosbag2"
    assert out["output"] == str(bag)
    assert (bag / "metadata.yaml").is_file()

    data = read_recording(rrd)
    k = data.get(recording.ACTUAL_POSITION).step
    cols = state_columns(data, k, 8)
    got: dict[str, list[object]] = {}
    with Reader(bag) as reader:
        assert reader.message_count == out["messages"]
        types = {c.topic: c.msgtype for c in reader.connections}
        for c in reader.connections:
            assert c.digest == STORE.hash_rihs01(c.msgtype)  # the bag's type hashes: rosbags' own
        for conn, ns, raw in reader.messages():
            msg = STORE.deserialize_cdr(raw, conn.msgtype)
            if hasattr(msg, "header"):
                assert ns == msg.header.stamp.sec * 10**9 + msg.header.stamp.nanosec  # bag time = stamp
            got.setdefault(conn.topic, []).append(msg)
    assert types["/cdpr/joint_commands"] == "sensor_msgs/msg/JointState"
    assert [(c.clock.sec, c.clock.nanosec) for c in got["/clock"]] == [stamp(step * 0.001) for step in k.tolist()]
    for i, js in enumerate(got["/cdpr/joint_states"]):
        assert js.position.tolist() == cols["cable_lengths"][i].tolist()
        assert js.effort.tolist() == cols["tensions"][i].tolist()
    for i, ps in enumerate(got["/cdpr/platform/pose"]):
        p, q = ps.pose.position, ps.pose.orientation
        assert [p.x, p.y, p.z, q.x, q.y, q.z, q.w] == cols["pose"][i].tolist()
    for i, tw in enumerate(got["/cdpr/platform/twist"]):
        assert [tw.twist.linear.x, tw.twist.angular.z] == [cols["twist"][i][0], cols["twist"][i][5]]
    commands = data.get(recording.COMMAND_TENSIONS)
    assert [c.effort.tolist() for c in got["/cdpr/joint_commands"]] == commands.values.tolist()
    assert [c.header.stamp.nanosec for c in got["/cdpr/joint_commands"]] == (commands.step * 1_000_000).tolist()
    gyro = data.get(recording.SENSOR_GYRO)
    assert len(got["/cdpr/imu"]) == len(gyro.step) == len(k)
    assert [[m.angular_velocity.x, m.angular_velocity.y, m.angular_velocity.z] for m in got["/cdpr/imu"]] \
        == gyro.values.tolist()
    loads = data.get(recording.SENSOR_LOAD_CELLS)
    assert [m.effort.tolist() for m in got["/cdpr/sensors/joint_states"]] == loads.values.tolist()
    assert len(got["/cdpr/setpoint/pose"]) == len(data.get(recording.DESIRED_POSITION).step)
    (info,) = got["/cdpr/session_info"]
    assert '"scenario": "caroca_15kg_ros2_sensors"' in info.data
    tracker = data.get("sensors/laser_tracker")  # every 4 steps (250 Hz), 2 steps late, stamped when measured
    assert len(tracker.step) >= 70
    assert (tracker.step % 4 == 2).all()
    points = got["/cdpr/sensors/laser_tracker"]
    assert [[m.point.x, m.point.y, m.point.z] for m in points] == tracker.values.tolist()
    assert [m.header.stamp.nanosec for m in points] == ((tracker.step - 2) * 1_000_000).tolist()
    assert set(got) == {"/clock", "/tf", *(f"/cdpr/{t}" for t in ("joint_states", "platform/pose", "platform/twist",
                        "setpoint/pose", "joint_commands", "imu", "sensors/joint_states", "sensors/laser_tracker",
                        "session_info"))}


@pytest.mark.slow
def test_a_ros2_controller_fed_from_the_sensors_runs_caroca_15kg_sensors_to_the_end(ros2_session: Session) -> None:
    """docs/ros2.md's controller fed from the sensors: it subscribes to sensors/joint_states (the encoders) and imu,
    never to the truth, estimates with cdpr's filter and answers with stamped joint_commands; subscribing to the
    encoders puts it in the controller's role. The session ends within #46's bound; its estimate is not recorded
    (a ROS 2 command carries none)."""
    ros2_session.start("caroca_15kg_sensors")
    argv = [sys.executable, str(SENSORS_CONTROLLER), "--router-port", str(ros2_session.port), "--namespace",
            ros2_session.ns]
    ctl = ros2_session.procs.start("controller", argv, ros2_session.tmp, ros2_session.tmp / "controller.log",
                                   env=ros2_session.env)
    s = ros2_session.summary()
    assert s["exit_ok"], s
    assert s["steps"] == s["total_steps"] == 11000
    assert s["rms_position_error"] <= 1e-3  # #46's bar (the encoders' and the IMU's noise through the filter)
    assert set(s["faults"].get("ros2", {})) <= {"unmatched_ros2_commands"}, s["faults"]
    ctl.send_signal(signal.SIGTERM)
    assert ctl.wait(timeout=WAIT) == 0, ros2_session.procs.log("controller")[-2000:]
    log = ros2_session.procs.log("controller")
    assert "fed from the sensors" in log, log[-2000:]
    answered = re.search(r"controller: answered (\d+) steps", log)
    assert answered, log[-2000:]
    assert int(answered.group(1)) >= 11000
