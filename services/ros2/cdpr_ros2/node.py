"""The ros2 node: a session on ROS 2's own Zenoh wire format (rmw_zenoh), so that ROS 2 nodes join it as
they are — no bridge binary, no ROS installation on the session's side. docs/ros2.md.

It publishes each step's state and setpoint (and the sensors) on ROS 2 topics (:mod:`cdpr_ros2.core`),
holds the liveliness tokens that make it a node of the ROS 2 graph, and watches that graph: while a ROS 2
process publishes on a command topic and subscribes to ``joint_states`` (or, a controller fed from the
sensors, to the encoders' ``sensors/joint_states``), this node holds the session's
``alive/controller`` token and turns that process's commands into ``controller/command`` — the session
waits for it, pauses when it leaves and resumes when it comes back, exactly as for a cdpr controller.
``--observe``: the topics only, never the controller's role (rviz2, PlotJuggler, ``ros2 topic echo`` on
any session).
"""

from __future__ import annotations

import argparse
import os
import time
from typing import Any

import zenoh
import zenoh.ext

from cdpr.config.scenario import Scenario
from cdpr.errors import InputError
from cdpr.protocol import Keys
from cdpr.protocol.pairing import Pairing
from cdpr.ros2.graph import NodeName, data_key, endpoint_token, node_token, parse_token, qualify
from cdpr.ros2.graph import attachment as make_attachment
from cdpr.ros2.topics import COMMANDS, PUBLISHED, default_namespace
from cdpr.runtime.service import Node, pair
from cdpr.runtime.transport import PUBLISH_OPTS, Event, Inbox, log
from cdpr_ros2.core import Bridge, RosCommandError


class _RosPublisher:
    """One ROS 2 publisher: its Zenoh publisher, GID and sequence numbers (every message carries rmw_zenoh's
    attachment), and whether any subscriber matches it now (``matched``: Zenoh's matching status; a
    transient-local one always counts as matched, for the late joiners)."""

    def __init__(self, pub: Any, transient_local: bool = False) -> None:
        self.pub, self.gid, self.seq = pub, os.urandom(16), 0
        self.matched = True
        self.listener: Any = None
        if not transient_local:
            self.matched = pub.matching_status.matching
            self.listener = pub.declare_matching_listener(self._on_matching)

    def _on_matching(self, status: Any) -> None:
        self.matched = status.matching

    def put(self, payload: bytes) -> None:
        self.seq += 1
        self.pub.put(payload, attachment=make_attachment(self.seq, time.time_ns(), self.gid))


def _domain() -> int:
    raw = os.environ.get("ROS_DOMAIN_ID", "").strip() or "0"
    if not raw.isdigit() or int(raw) > 232:
        raise InputError(f"ROS_DOMAIN_ID: expected a number from 0 to 232, got {raw!r}")
    return int(raw)


class Ros2Node(Node):
    name = "ros2"
    direct = True  # handled on Zenoh's receive thread: a state's topics and a command's answer go out at once

    def __init__(self, scenario: Scenario, keys: Keys, namespace: str = "/cdpr", domain: int = 0,
                 observe: bool = False, node_name: str = "cdpr") -> None:
        super().__init__(keys)
        self.bridge = Bridge.from_scenario(scenario)
        self.m = scenario.robot.m
        self.total_steps = scenario.total_steps
        self.namespace, self.domain, self.observe, self.node_name = namespace, domain, observe, node_name
        self.pairing = Pairing()
        self.ros: dict[str, _RosPublisher] = {}
        self.session: zenoh.Session | None = None
        self.zid = ""
        self.graph: dict[str, set[tuple[str, str]]] = {}  # zid -> its (MP|MS, topic) endpoints
        self.controller_token: Any = None
        self.controllers: tuple[str, ...] = ()  # the zids of the ROS 2 processes in the controller's role
        self.published_steps = 0
        self.commands = 0
        self.newest_step = -1  # the newest state published
        self.ahead = -1  # the newest step whose setpoint went out ahead of its state (preview)

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        g = parser.add_argument_group("ros2")
        g.add_argument("--ros-namespace", default=None, metavar="NS",
                       help="the namespace of the session's topics (default: /cdpr for the session default, "
                            "/cdpr/<session> for another: the sessions of one router never share a topic)")
        g.add_argument("--ros-node-name", default="cdpr", metavar="NAME",
                       help="this node's name in the ROS 2 graph (default: %(default)s)")
        g.add_argument("--observe", action="store_true",
                       help="publish the topics only: never take the controller's role")

    @classmethod
    def from_args(cls, scenario: Scenario, keys: Keys, args: argparse.Namespace) -> Ros2Node:
        ns = args.ros_namespace
        if ns is None:
            try:
                ns = default_namespace(keys.session)
            except ValueError as exc:
                raise InputError(f"--session: {exc}: give its ROS 2 topics a namespace (--ros-namespace)") from None
        if not ns.startswith("/") or "//" in ns or (len(ns) > 1 and ns.endswith("/")) \
                or not all(c.isalnum() or c in "_/" for c in ns):
            raise InputError(f"--ros-namespace: {ns!r} is not a ROS 2 namespace (/name/name…: letters, digits, _)")
        if not args.ros_node_name or not all(c.isalnum() or c == "_" for c in args.ros_node_name):
            raise InputError(f"--ros-node-name: {args.ros_node_name!r} is not a ROS 2 node name (letters, digits, _)")
        return cls(scenario, keys, namespace=ns, domain=_domain(), observe=args.observe,
                   node_name=args.ros_node_name)

    def configure(self, conf: zenoh.Config) -> None:
        conf.insert_json5("timestamping/enabled", "true")  # a transient-local topic's cache orders by timestamps

    def topic(self, name: str) -> str:
        return qualify(self.namespace, name)

    @property
    def fed(self) -> set[str]:
        """The topics a controller subscribes to for what it answers: the state's ``joint_states``, or the encoders'
        ``sensors/joint_states`` (a controller fed from the sensors: it answers with their stamp)."""
        return {self.topic(PUBLISHED[name].name) for name in ("joint_states", "sensor_joint_states")}

    def declare(self, session: zenoh.Session, inbox: Inbox) -> list[Any]:
        self.session = session
        self.zid = str(session.info.zid())
        me = NodeName(self.domain, self.zid, 0, self.namespace, self.node_name)
        keep: list[Any] = []
        liveliness = session.liveliness()
        keep.append(liveliness.declare_token(node_token(me)))
        for i, (name, topic) in enumerate(PUBLISHED.items(), start=1):
            key = data_key(self.domain, self.topic(topic.name), topic.ros_type)
            if topic.qos.transient_local:  # late joiners get the last message (rmw_zenoh: an advanced publisher)
                pub: Any = zenoh.ext.declare_advanced_publisher(
                    session, key, cache=zenoh.ext.CacheConfig(max_samples=topic.qos.depth), publisher_detection=True)
            else:
                # not express: a step's messages leave in one batch (one write, one wake-up of a subscriber)
                pub = session.declare_publisher(key, **{**PUBLISH_OPTS, "express": False})
            self.ros[name] = _RosPublisher(pub, topic.qos.transient_local)
            keep.append(pub)
            if self.ros[name].listener is not None:
                keep.append(self.ros[name].listener)
            keep.append(liveliness.declare_token(
                endpoint_token(me, i, "MP", self.topic(topic.name), topic.ros_type, topic.qos)))
        self.ros["session_info"].put(self.bridge.info_message())
        if not self.observe:
            for i, (name, topic) in enumerate(COMMANDS.items(), start=len(PUBLISHED) + 1):
                fq = self.topic(topic.name)
                # any type hash: a ROS 2 distribution without them (Humble: "TypeHashNotSupported") is served too
                keep.append(inbox.subscribe(session, data_key(self.domain, fq, topic.ros_type).rsplit("/", 1)[0]
                                            + "/*", name))
                keep.append(liveliness.declare_token(endpoint_token(me, i, "MS", fq, topic.ros_type, topic.qos)))
            keep.append(inbox.watch_liveliness(session, f"@ros2_lv/{self.domain}/**"))
        log(self.name, f"ROS 2 domain {self.domain}, node {self.namespace.rstrip('/')}/{self.node_name}"
            + (" (observer)" if self.observe else ": waiting for a ROS 2 controller (publishing "
               f"{self.topic('joint_commands')} or {self.topic('tension_commands')}, subscribed to "
               f"{' or '.join(sorted(self.fed))})"))
        return keep

    # -- the session's messages -> ROS 2 ------------------------------------------------------------
    def handle(self, event: Event) -> None:
        topic = event.topic
        if topic == "state" and self.final(event):
            return
        if topic in ("state", "setpoints"):
            if (due := pair(self, self.pairing, event, self.m)) is not None:
                state, setpoint = due
                # its setpoint went out ahead (preview), unless the clock asks for this step again: then all of
                # it again, and the answer to it sends the next setpoint ahead again
                first = state.step > self.newest_step
                if not first:
                    self.ahead = min(self.ahead, state.step)
                for name, payload in self.bridge.step_messages(
                        state, None if first and self.ahead == state.step else setpoint, self._wanted()):
                    self.ros[name].put(payload)
                self.newest_step = max(self.newest_step, state.step)
                self.pairing.done(state.step)
                self.published_steps += 1
        elif topic == "sensors":
            if (sensors := self.decode(event, self.m)) is not None:
                for name, payload in self.bridge.sensor_messages(sensors):
                    if self.ros[name].matched:
                        self.ros[name].put(payload)
        elif topic == "tick":
            if (tick := self.decode(event)) is not None and tick.free:
                self.bridge.free = True
        elif topic in COMMANDS:
            self.on_command(topic, event.payload)
        elif topic in ("alive", "gone"):
            self.on_graph(topic == "alive", event.key)

    def _wanted(self) -> set[str]:
        """The topics somebody subscribes to now: a message nobody takes is neither encoded nor sent."""
        return {name for name, pub in self.ros.items() if pub.matched}

    def preview(self, step: int) -> None:
        """Setpoint ``step`` out now, ahead of its state, as the state before it is answered (docs/ros2.md): a
        ROS 2 controller that keeps the newest setpoint has the right one when the state comes, and takes it in
        while the sim steps (called before the command goes on to the sim, whose step runs within that put when
        both share a process). Not when that state is out already or the setpoint is not known yet (then it
        goes out with its state, first)."""
        setpoint = self.pairing.setpoints.get(step)
        if setpoint is None or step <= self.newest_step or step <= self.ahead or step >= self.total_steps:
            return
        for name, payload in self.bridge.setpoint_messages(setpoint, self._wanted()):
            self.ros[name].put(payload)
        self.ahead = step

    def final(self, event: Event) -> bool:
        """The session's last state (it has no setpoint and awaits no command): its topics without the setpoint's."""
        state = self.decode(event, self.m)
        if state is None or state.step < self.total_steps:
            return state is None
        for name, payload in self.bridge.state_messages(state, self._wanted()):
            self.ros[name].put(payload)
        self.published_steps += 1
        return True

    def on_command(self, topic: str, payload: bytes) -> None:
        if not self.controllers:
            self.count("ros2_commands_without_controller")
            self.warn("no_controller", f"dropped a {self.topic(topic)} message: its publisher is not in the "
                      f"controller's role (it must also subscribe to {' or '.join(sorted(self.fed))})")
            return
        try:
            cmd = self.bridge.command(topic, payload)
        except RosCommandError as exc:
            self.count(exc.counter)
            self.warn(exc.counter, f"dropped a bad {self.topic(topic)} message: {exc}")
            return
        self.preview(cmd.step + 1)
        self.publishers["command"].put(cmd.encode())
        self.commands += 1

    # -- the ROS 2 graph: who is in the controller's role --------------------------------------------
    def on_graph(self, alive: bool, key: str) -> None:
        ep = parse_token(key)
        if ep is None or ep.zid == self.zid or ep.kind not in ("MP", "MS"):
            return
        entry = (ep.kind, ep.topic)
        ends = self.graph.setdefault(ep.zid, set())
        if alive:
            ends.add(entry)
        else:
            ends.discard(entry)
        commands = {self.topic(t.name) for t in COMMANDS.values()}
        controllers = tuple(sorted(
            zid for zid, e in self.graph.items()
            if any(k == "MP" and t in commands for k, t in e) and any(k == "MS" and t in self.fed for k, t in e)))
        if controllers == self.controllers:
            return
        was, self.controllers = self.controllers, controllers
        assert self.session is not None
        if controllers and not was:
            log(self.name, f"a ROS 2 controller joined (Zenoh session {controllers[0]}): in the controller's role")
            self.bridge.new_controller()
            self.controller_token = self.session.liveliness().declare_token(self.keys.alive("controller"))
        elif was and not controllers:
            log(self.name, "the ROS 2 controller left: the session waits for it")
            if self.controller_token is not None:
                self.controller_token.undeclare()
                self.controller_token = None

    def close(self) -> None:
        if self.controller_token is not None:
            self.controller_token.undeclare()
            self.controller_token = None
        log(self.name, f"published {self.published_steps} steps on ROS 2; applied {self.commands} ROS 2 commands")
