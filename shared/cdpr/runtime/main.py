"""``python -m cdpr_<name>``: one node as its own process, without the ``cdpr`` command-line tool.

The options every node shares (scenario, session, Zenoh endpoints, realtime priority) are defined here
once; a node adds its own in :meth:`~cdpr.runtime.service.Node.add_arguments` and builds itself from
the parsed arguments in :meth:`~cdpr.runtime.service.Node.from_args`. ``cdpr <name> …`` hands its
arguments to the same function, so both spell every option the same way.

An invalid scenario or option prints one line ``cdpr: error: …`` on stderr and exits with code 2.
"""

from __future__ import annotations

import argparse
import math
import sys
from collections.abc import Callable, Sequence
from typing import TYPE_CHECKING, NoReturn

from cdpr.errors import InputError
from cdpr.runtime.options import REALTIME_OPTIONS, SESSION_OPTIONS, add_options

if TYPE_CHECKING:
    from cdpr.config.scenario import Scenario
    from cdpr.protocol import Keys
    from cdpr.runtime.service import Node


def add_zenoh_arguments(parser: argparse.ArgumentParser) -> None:
    """The Zenoh options of every node, the launcher and the remote-controller SDK."""
    z = parser.add_argument_group("Zenoh")
    z.add_argument("--zenoh-mode", choices=("peer", "client"), default="peer", help="(default: %(default)s)")
    z.add_argument("--connect", action="append", default=[], metavar="ENDPOINT",
                   help="Zenoh endpoint to connect to, e.g. tcp/192.168.1.10:7447 (repeatable)")
    z.add_argument("--listen", action="append", default=[], metavar="ENDPOINT",
                   help="Zenoh endpoint to listen on, e.g. tcp/0.0.0.0:7447 (repeatable)")
    z.add_argument("--zenoh-config", default=None, metavar="FILE", help="Zenoh JSON5 config file (or $ZENOH_CONFIG)")
    z.add_argument("--connect-timeout", type=float, default=30.0, metavar="S",
                   help="seconds a client keeps trying to reach --connect endpoints (default: %(default)s)")


def node_classes(name: str) -> list[type[Node]]:
    """The node classes of ``name``: one registered node, or several joined by ``+`` (``sim+ros2``) that
    share one process (:func:`cdpr.runtime.service.serve_group`)."""
    from cdpr.runtime.registry import node_class

    names = name.split("+")
    if len(set(names)) != len(names):
        raise InputError(f"{name!r}: a node named twice")
    return [node_class(n) for n in names]


def parser_for(name: str) -> argparse.ArgumentParser:
    classes = node_classes(name)
    docs = [(cls.__doc__ or "").strip().splitlines() for cls in classes]
    what = " ".join(d[0] for d in docs if d)
    if len(classes) > 1:
        what = f"{' and '.join(c.name for c in classes)} in one process. {what}"
    parser = argparse.ArgumentParser(prog=f"cdpr {name}", description=what or None)
    parser.add_argument("scenario", help="a shipped scenario name (caroca_15kg) or a scenario YAML file")
    add_options(parser, (*SESSION_OPTIONS, *REALTIME_OPTIONS))
    add_zenoh_arguments(parser)
    for cls in classes:
        cls.add_arguments(parser)
    return parser


def build_node(name: str, scenario: Scenario, keys: Keys, argv: Sequence[str]) -> Node:
    """Node ``name`` for ``scenario`` from its command-line options ``argv`` (the scenario argument
    first, as for ``python -m cdpr_<name>``): how the in-process composition makes its nodes."""
    from cdpr.runtime.registry import node_class

    args = parser_for(name).parse_args(list(argv))
    return node_class(name).from_args(scenario, keys, args)


def _fail(message: str) -> NoReturn:
    print(f"cdpr: error: {message}", file=sys.stderr)
    sys.exit(2)


def node_main(name: str, argv: Sequence[str] | None = None, before_serve: Callable[[], None] | None = None) -> NoReturn:
    """Parse ``argv`` (default ``sys.argv[1:]``), build node ``name`` and serve it until the session ends.
    ``name`` may join several nodes with ``+`` (``sim+ros2``): they share this process and its Zenoh session
    (ROS 2's composition; :func:`node_classes`), each built from the same options.

    ``before_serve`` runs once the node is built, before its Zenoh session opens (the launcher's forked
    services wait there for the session's router, :mod:`cdpr.tools.launch`)."""
    from cdpr.protocol import Keys
    from cdpr.runtime.service import hold_cpu_latency, serve, serve_group, set_realtime_priority
    from cdpr.runtime.transport import zenoh_config

    try:
        parser = parser_for(name)
        args = parser.parse_args(list(sys.argv[1:] if argv is None else argv))
        from cdpr.config.scenario import load_scenario  # after --help: the scenario loader is heavier

        if args.duration is not None and not (math.isfinite(args.duration) and args.duration > 0):
            raise InputError(f"--duration: must be a positive number of seconds, got {args.duration}")
        classes = node_classes(name)
        checks = tuple(dict.fromkeys(c for cls in classes for c in cls.scenario_checks))
        scenario = load_scenario(args.scenario, {"duration": args.duration}, checks=checks)
        try:
            keys = Keys(args.session_id)
        except ValueError as exc:
            raise InputError(f"--session: {exc}") from None
        conf = zenoh_config(args.zenoh_mode, args.connect, args.listen, args.zenoh_config, args.connect_timeout)
        nodes = [cls.from_args(scenario, keys, args) for cls in classes]
        for node in nodes:
            node.configure(conf)
        if args.rt_priority is not None:
            set_realtime_priority(args.rt_priority)  # before Zenoh's threads exist: they inherit it
        if args.cpu_latency is not None:
            hold_cpu_latency(args.cpu_latency)
    except InputError as exc:
        _fail(str(exc))
    if before_serve is not None:
        before_serve()
    sys.exit(serve(nodes[0], conf) if len(nodes) == 1 else serve_group(nodes, conf))
