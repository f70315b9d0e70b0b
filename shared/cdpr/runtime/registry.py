"""The node registry: a node's name → its class, through the ``cdpr.nodes`` entry points.

Every service registers its :class:`~cdpr.runtime.service.Node` subclass in ``pyproject.toml``::

    [project.entry-points."cdpr.nodes"]
    sim = "cdpr_sim.node:SimNode"

so the launcher, the bench, the in-process composition and the tests find nodes by name without
importing service packages by hand, and a third-party package can add a node of its own the same way
(as ROS 2 components are found through their package's plugin description).
"""

from __future__ import annotations

from functools import cache
from importlib.metadata import entry_points
from typing import TYPE_CHECKING

from cdpr.errors import InputError

if TYPE_CHECKING:
    from cdpr.runtime.service import Node

GROUP = "cdpr.nodes"


@cache
def _entries() -> dict[str, str]:
    return {ep.name: ep.value for ep in entry_points(group=GROUP)}


def node_names() -> tuple[str, ...]:
    """The names of every registered node, sorted."""
    return tuple(sorted(_entries()))


def node_class(name: str) -> type[Node]:
    """The registered node class called ``name`` (imported on first use)."""
    for ep in entry_points(group=GROUP, name=name):
        node: type[Node] = ep.load()
        return node
    known = ", ".join(node_names()) or "none: is the cdpr package installed?"
    raise InputError(f"no node called {name!r} is registered (known: {known})")
