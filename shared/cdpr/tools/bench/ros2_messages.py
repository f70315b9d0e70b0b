"""An offline message cache for zenoh-ros2-sdk, the ROS 2 peer of tests/test_ros2.py and ``cdpr bench``
(``ZENOH_ROS2_SDK_CACHE``): the git repositories it would clone from GitHub at first use
(ros2/common_interfaces, ros2/rcl_interfaces, ros2/geometry2, branch ``jazzy``), holding the ``.msg`` files it
needs, written from the ``rosbags`` library's ROS 2 Jazzy type store. The SDK then computes its type hashes
from these files itself (an independent check of ours): a cache of the SDK's own format, made without a
network."""

from __future__ import annotations

import subprocess
from pathlib import Path
from typing import Any

from rosbags.typesys import Stores, get_typestore
from rosbags.typesys.base import Nodetype

REPOSITORIES = {  # the SDK's repository of each package (zenoh_ros2_sdk._repositories)
    "common_interfaces": ("std_msgs", "geometry_msgs", "sensor_msgs"),
    "rcl_interfaces": ("builtin_interfaces", "rosgraph_msgs"),
    "geometry2": ("tf2_msgs",),
}


def _type_name(kind: Nodetype, spec: Any) -> str:
    if kind == Nodetype.BASE:
        base, bound = spec
        return f"{base}<={bound}" if bound else str(base)
    if kind == Nodetype.NAME:
        pkg, _, msg = str(spec).split("/")
        return f"{pkg}/{msg}"
    sub_kind, sub_spec = spec[0]
    inner = _type_name(sub_kind, sub_spec)
    n = spec[1]
    if kind == Nodetype.ARRAY:
        return f"{inner}[{n}]"
    return f"{inner}[<={n}]" if n else f"{inner}[]"


def msg_text(store: Any, ros_type: str) -> str:
    """The ``.msg`` definition of ``ros_type`` (constants, then fields)."""
    consts, fields = store.fielddefs[ros_type]
    lines = [f"{ctype} {name}={value}" for name, ctype, value in consts]
    lines += [f"{_type_name(kind, spec)} {name}" for name, (kind, spec) in fields]
    return "\n".join(lines) + "\n"


def make_cache(root: Path) -> Path:
    store = get_typestore(Stores.ROS2_JAZZY)
    for repo, packages in REPOSITORIES.items():
        path = root / repo
        for ros_type in store.fielddefs:
            pkg, kind, name = ros_type.split("/")
            if pkg in packages and kind == "msg":
                f = path / pkg / "msg" / f"{name}.msg"
                f.parent.mkdir(parents=True, exist_ok=True)
                f.write_text(msg_text(store, ros_type))
        git = ["git", "-C", str(path), "-c", "user.name=test", "-c", "user.email=test@localhost"]
        subprocess.run(["git", "init", "-q", "-b", "jazzy", str(path)], check=True)
        subprocess.run([*git, "add", "."], check=True)
        subprocess.run([*git, "commit", "-q", "-m", "messages from rosbags' ROS 2 Jazzy store"], check=True)
    return root
