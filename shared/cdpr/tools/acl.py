"""The secure profile's router configuration, its access-control list derived from the topic tables.

Nothing here is written by hand per stream: each role's rules come from its row of the wiring table
(:data:`cdpr.protocol.wiring.WIRING`: the keys it puts, its liveliness token, the queryables it declares and
answers) and, for the ROS 2 side, from the ROS 2 topic table (:mod:`cdpr.ros2.topics`: what the ros2 node
publishes, the command topics a ROS 2 controller sends). A new stream or node gets its rule by being in those
tables. ``cdpr acl`` prints the router's JSON5 config (``docker/zenoh/router-secure.json5`` is its output,
checked by tests/test_acl.py), ``make certs`` makes an identity for each name of :func:`identities`.

Identities (the user names of Zenoh's ``usrpwd`` authentication):

* one per role of the wiring table (``clock``, ``sim``, ``trajectory``, ``controller``, ``recorder``, ``ros2``):
  that role's keys in every session on the router;
* ``observer``: listens to everything, publishes nothing (a dashboard, a monitor);
* ``ros2-controller``: a ROS 2 process in a session's controller role (rmw_zenoh): the command topics of any
  session, and the ROS 2 graph's tokens;
* per session S of ``sessions``: ``controller.S`` and ``ros2-controller.S``, the same rights in session S only
  (a lab router shared by several groups: one group's controller cannot move another group's platform).

Every identity may subscribe to, query and watch the liveliness of every cdpr and ROS 2 key (so it can listen)
and receives what the router forwards; what reaches the router from it (ingress) is limited to its own keys.
docs/security.md.
"""

from __future__ import annotations

import json
import re
from collections.abc import Sequence
from typing import Any

from cdpr.errors import InputError
from cdpr.protocol import SESSION_RE
from cdpr.protocol.wiring import TOPICS, WIRING, wiring_of
from cdpr.ros2.graph import ADMIN_SPACE, qualify
from cdpr.ros2.topics import COMMANDS, PUBLISHED, default_namespace

OBSERVER = "observer"
ROS2_CONTROLLER = "ros2-controller"
ROS2_NODE = "ros2"
ANY = "*"  # every session

# The messages a participant sends to the router to listen (a subscriber, a query, a liveliness watch), which the
# router forwards to the publishers and queryables, and those it forwards to a participant (data, replies, tokens,
# and the declarations of queryables and subscribers, which a publisher's matching status follows).
LISTEN = ["declare_subscriber", "declare_liveliness_subscriber", "liveliness_query", "query"]
RECEIVE = ["put", "delete", "reply", "liveliness_token", "declare_queryable", "declare_subscriber"]


def _topic_key(session: str, key: str, node: str) -> str:
    """A topic's key in ``session`` (``*``: any): ``{node}`` is the publishing node, ``{camera}`` any camera."""
    return f"cdpr/{session}/" + key.replace("{node}", node).replace("{camera}", "*")


def _ros2_key(namespace: str, topic: str) -> str:
    """Every key of a ROS 2 topic (rmw_zenoh: ``<domain>/<topic>/<type>/<hash>``), any domain."""
    return f"*/{qualify(namespace, topic).strip('/')}/**"


def _listened() -> list[str]:
    """What anyone may listen to: every session's keys, the ROS 2 topics under any namespace below ``/cdpr`` and
    the global ones, their publication caches (``…/@adv/…``), and the ROS 2 graph."""
    globals_ = sorted({_ros2_key("/", t.name) for t in PUBLISHED.values() if t.name.startswith("/")})
    return ["cdpr/**", "*/cdpr/**", *globals_, "*/cdpr/**/@adv/**", f"{ADMIN_SPACE}/**"]


def _rule(rule_id: str, messages: Sequence[str], keys: Sequence[str], flows: Sequence[str] = ("ingress",)
          ) -> dict[str, Any]:
    return {"id": rule_id, "permission": "allow", "flows": list(flows), "messages": list(messages),
            "key_exprs": sorted(set(keys))}


def role_rules(role: str, session: str = ANY, suffix: str = "") -> list[dict[str, Any]]:
    """The ingress rules of a wiring-table role in ``session``: its puts, its liveliness tokens, its queryables
    (declared and answered). The ros2 node also holds the controller's token while a ROS 2 controller is there,
    and publishes its ROS 2 topics."""
    row = wiring_of(role)
    puts, queryables = [], []
    for name in row.publishes:
        topic = TOPICS[name]
        key = _topic_key(session, topic.key, role)
        if topic.transport == "pubsub":
            puts.append(key)
        elif topic.transport == "queryable":
            queryables.append(key)
    tokens = [_topic_key(session, TOPICS["alive"].key, r) for r in (role, *row.alive_as)]
    rules = [_rule(f"{role}{suffix}-puts", ["put"], puts),
             _rule(f"{role}{suffix}-alive", ["liveliness_token"], tokens)]
    if queryables:
        rules.append(_rule(f"{role}{suffix}-answers", ["declare_queryable", "reply"], queryables))
    if role == ROS2_NODE:
        namespace = "/cdpr" if session == ANY else default_namespace(session)
        below = "/**" if session == ANY else ""
        data = [_ros2_key(namespace + below, t.name) for t in PUBLISHED.values()]
        latched = [_ros2_key(namespace + below, t.name).removesuffix("**") + "**/@adv/**"
                   for t in PUBLISHED.values() if t.qos.transient_local]
        rules += [_rule(f"ros2-topics{suffix}", ["put"], data),
                  _rule(f"ros2-latched{suffix}", ["declare_queryable", "reply", "liveliness_token"], latched),
                  _rule(f"ros2-graph{suffix}", ["liveliness_token"], [f"{ADMIN_SPACE}/**"])]
    return rules


def ros2_controller_rules(session: str = ANY, suffix: str = "") -> list[dict[str, Any]]:
    """A ROS 2 controller in ``session``: its command topics (:data:`cdpr.ros2.topics.COMMANDS`) and its tokens
    in the ROS 2 graph (rmw_zenoh declares one per node and endpoint, and for an advanced subscriber's cache)."""
    namespace = "/cdpr/**" if session == ANY else default_namespace(session)
    return [_rule(f"{ROS2_CONTROLLER}{suffix}-commands", ["put"], [_ros2_key(namespace, t.name) for t in
                                                                     COMMANDS.values()]),
            _rule(f"{ROS2_CONTROLLER}{suffix}-graph", ["liveliness_token"], [f"{ADMIN_SPACE}/**",
                                                                             "*/cdpr/**/@adv/**"])]


def check_sessions(sessions: Sequence[str]) -> list[str]:
    """The session ids, checked (InputError naming the bad one): each a cdpr session id and, for its ROS 2
    controller's identity, a ROS 2 namespace token."""
    for s in sessions:
        if not SESSION_RE.match(s) or s == ANY:
            raise InputError(f"--sessions: {s!r} is not a session id (1-64 characters of A-Z a-z 0-9 _ -)")
        try:
            default_namespace(s)  # its ROS 2 controller's topics
        except ValueError as exc:
            raise InputError(f"--sessions: {exc}: its ROS 2 topics, /cdpr/<session>, need one") from None
    if len(set(sessions)) != len(sessions):
        raise InputError(f"--sessions: {list(sessions)} names a session twice")
    return list(sessions)


def identities(sessions: Sequence[str] = ()) -> list[str]:
    """Every user name the router knows (``make certs`` makes one identity file each)."""
    names = [*WIRING, OBSERVER, ROS2_CONTROLLER]
    for s in check_sessions(sessions):
        names += [f"controller.{s}", f"{ROS2_CONTROLLER}.{s}"]
    return names


def access_control(sessions: Sequence[str] = ()) -> dict[str, Any]:
    """Zenoh's ``access_control`` section: deny by default, then each identity's rules (module docstring)."""
    # listening goes both ways: from the listener to the router, and on to the publishers and queryables
    rules = [_rule("listen", LISTEN, _listened(), ("ingress", "egress")), _rule("receive", RECEIVE, _listened(),
                                                                                ("egress",))]
    subjects = [{"id": "participants", "usernames": identities(sessions)}]
    policies: list[dict[str, Any]] = [{"rules": ["listen", "receive"], "subjects": ["participants"]}]

    def grant(user: str, own: list[dict[str, Any]]) -> None:
        rules.extend(own)
        subjects.append({"id": user, "usernames": [user]})
        policies.append({"rules": [r["id"] for r in own], "subjects": [user]})

    for role in WIRING:
        grant(role, role_rules(role))
    grant(ROS2_CONTROLLER, ros2_controller_rules())
    for s in check_sessions(sessions):
        grant(f"controller.{s}", role_rules("controller", s, f".{s}"))
        grant(f"{ROS2_CONTROLLER}.{s}", ros2_controller_rules(s, f".{s}"))
    return {"enabled": True, "default_permission": "deny", "rules": rules, "subjects": subjects,
            "policies": policies}


def router_config(sessions: Sequence[str] = ()) -> dict[str, Any]:
    """The secure profile's whole router config: TLS only, a password per identity, the access-control list.
    Paths are relative to the working directory (``/cdpr`` in the containers, ``docker/`` on a host), where
    ``make certs`` puts ``secrets/``."""
    return {
        "mode": "router",
        "listen": {"endpoints": ["tls/0.0.0.0:7447"]},
        "scouting": {"multicast": {"enabled": False}, "gossip": {"enabled": False}},
        "transport": {
            "link": {"protocols": ["tls"],
                     "tls": {"listen_private_key": "secrets/router.key", "listen_certificate": "secrets/router.pem"}},
            "auth": {"usrpwd": {"dictionary_file": "secrets/users.txt"}},
        },
        "access_control": access_control(sessions),
    }


HEADER = """\
// The secure profile's Zenoh router (docs/security.md): TLS only, a password per identity, and an access-control
// list that lets each identity publish only its own keys. GENERATED from the topic tables (cdpr.protocol.wiring,
// cdpr.ros2.topics) by:  cdpr acl{args}
// Do not edit: change the tables and run it again.
// Paths are relative to the working directory (/cdpr in the containers; docker/ on a host), where `make certs`
// put secrets/. Start it with:  cdpr router --zenoh-config {where}
"""


def render(sessions: Sequence[str] = (), where: str = "zenoh/router-secure.json5") -> str:
    """The router config as JSON5 text (JSON, one rule per line, with a header saying how it was made)."""
    config = router_config(sessions)
    text = json.dumps(config, indent=2)
    # one line per rule, subject and policy: the list reads as a table
    text = re.sub(r"\{\n\s+(\"(?:id|rules)\"[^{}]*?)\n\s+\}",
                  lambda m: "{ " + re.sub(r"\s*\n\s*", " ", m.group(1)) + " }", text)
    args = f" --sessions {','.join(sessions)}" if sessions else ""
    return HEADER.format(args=args, where=where) + text + "\n"
