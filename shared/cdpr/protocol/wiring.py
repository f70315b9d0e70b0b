"""The wiring table: which node publishes and which subscribes to each topic, in one place.

Like a dora-rs dataflow or a Drake diagram, each node lists its inputs (``subscribes``) and outputs
(``publishes``) by topic name; :func:`cdpr.runtime.service.serve` declares exactly these on Zenoh for
the node (a node cannot publish a topic it did not list), the in-process composition wires the same
names, and tests check that docs/protocol.md and docker/compose.yaml say the same. Everything else is derived
from these two tables: a node's ``subscribes``/``publishes`` (its row, set on the class from its name), the
session's key expressions (:class:`cdpr.protocol.Keys`: ``keys.tick`` is ``cdpr/{session}/`` + the topic's key)
and the service names that may hold a liveliness token. Every node also
subscribes to ``status`` and publishes ``stats``, a liveliness token ``alive/{node}`` and answers ``ping/{node}``
(an echo: ``cdpr ping`` measures the round trip to it): the serve loop
does that for all of them, so they are listed here once (:data:`EVERY_NODE`) rather than per node.
"""

from __future__ import annotations

from dataclasses import dataclass


@dataclass(frozen=True)
class Topic:
    """One topic: its key below ``cdpr/{session}/``, its message, and how it is served."""

    key: str
    message: str  # the class in cdpr.protocol that encodes and decodes it
    bad: str = ""  # the fault counter of a receiver that drops a bad one (docs/protocol.md, "Bad input")
    transport: str = "pubsub"  # "pubsub", "queryable" (answered to a `get`) or "liveliness" (a token)


TOPICS: dict[str, Topic] = {
    "tick": Topic("clock/tick", "Tick", "bad_ticks"),
    "status": Topic("clock/status", "Status", "bad_status"),
    "state": Topic("sim/state", "State", "bad_states"),
    "setpoints": Topic("trajectory/setpoints", "Setpoints", "bad_setpoints"),
    "command": Topic("controller/command", "Command", "bad_commands"),
    "telemetry": Topic("sim/telemetry", "Telemetry", "bad_telemetry"),
    "sensors": Topic("sim/sensors", "Sensors", "bad_sensors"),
    # one key per camera of the scenario (sim.cameras): the node declares them itself (cdpr_sim.node)
    "camera": Topic("sim/camera/{camera}", "CameraFrame", "bad_camera"),
    "camera_image": Topic("sim/camera/{camera}/image", "CameraImage", "bad_camera_image"),
    "info": Topic("session/info", "SessionInfo", transport="queryable"),
    "resume": Topic("session/resume", "Resume", "bad_resume"),
    "end": Topic("session/end", "End", "bad_end"),
    "stats": Topic("stats/{node}", "ServiceStats", "bad_stats"),
    "alive": Topic("alive/{node}", "", transport="liveliness"),
    "ping": Topic("ping/{node}", "", transport="queryable"),  # answers a get with its payload (cdpr ping)
}


@dataclass(frozen=True)
class NodeWiring:
    subscribes: tuple[str, ...]
    publishes: tuple[str, ...]
    optional: tuple[str, ...] = ()  # of subscribes: left out by a node that does not use them (nothing sent to it)
    alive_as: tuple[str, ...] = ()  # other roles whose liveliness token it may hold (it acts as them)


# What the serve loop wires for every node, whatever the table says below.
EVERY_NODE = NodeWiring(subscribes=("status",), publishes=("stats", "alive", "ping"))

WIRING: dict[str, NodeWiring] = {
    "clock": NodeWiring(subscribes=("telemetry", "stats", "end"), publishes=("tick", "status", "info", "resume")),
    "sim": NodeWiring(subscribes=("tick", "command", "resume"),
                      publishes=("state", "telemetry", "sensors", "camera", "camera_image")),
    "trajectory": NodeWiring(subscribes=("tick",), publishes=("setpoints",)),
    # camera: the frames of an image-based visual servo (controller.law: ibvs)
    # end: a controller may end the session early (a learning environment's episode: cdpr.gym)
    # sensors instead of state: a controller fed an estimate from the sensors (controller.feedback: sensors)
    "controller": NodeWiring(subscribes=("state", "setpoints", "camera", "sensors"), publishes=("command", "end"),
                             optional=("state", "camera", "sensors")),
    "recorder": NodeWiring(subscribes=("telemetry", "setpoints", "camera", "camera_image"), publishes=()),
    # the session on ROS 2's wire (rmw_zenoh); "command", and the controller's token, only while a ROS 2
    # controller is there (docs/ros2.md)
    "ros2": NodeWiring(subscribes=("tick", "state", "setpoints", "sensors"), publishes=("command",),
                       alive_as=("controller",)),
}


def wiring_of(node: str) -> NodeWiring:
    """The table's row for ``node``, the wiring every node has added."""
    row = WIRING.get(node, NodeWiring((), ()))
    return NodeWiring(row.subscribes + EVERY_NODE.subscribes, row.publishes + EVERY_NODE.publishes,
                      alive_as=row.alive_as)


def publishers(topic: str) -> tuple[str, ...]:
    return tuple(n for n in WIRING if topic in wiring_of(n).publishes)


def subscribers(topic: str) -> tuple[str, ...]:
    return tuple(n for n in WIRING if topic in wiring_of(n).subscribes)


def check_node(node: str, subscribes: tuple[str, ...], publishes: tuple[str, ...]) -> None:
    """Raise ValueError if a node declares a topic its row of :data:`WIRING` does not list (or misses one that is
    not optional)."""
    if node not in WIRING:
        raise ValueError(f"node {node!r} is not in the wiring table (cdpr.protocol.wiring.WIRING)")
    row = WIRING[node]
    for what, declared, listed, optional in (("subscribes", subscribes, row.subscribes, row.optional),
                                             ("publishes", publishes, row.publishes, ())):
        if not set(declared) <= set(listed) or not set(listed) - set(declared) <= set(optional):
            raise ValueError(f"node {node!r} {what} {sorted(declared)}, the wiring table lists {sorted(listed)}"
                             + (f" ({', '.join(optional)} optional)" if optional else ""))
