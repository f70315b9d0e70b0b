"""The layout: folders are import names, the layers import only downwards, and a node starts without the CLI."""

from __future__ import annotations

import ast
import subprocess
import sys
import tomllib
from pathlib import Path

import pytest

ROOT = Path(__file__).resolve().parents[1]
COMMON = ROOT / "shared" / "cdpr"
SERVICES = ("sim", "controller", "trajectory", "clock", "recorder", "ros2")

# The outside libraries each layer of the common package may import (at the top of a module or inside a
# function); numpy everywhere. The tools import anything.
ALLOWED = {
    "mechanics": {"numpy", "scipy", "qpsolvers"},  # qpsolvers: the QP tension distribution (eq. 8), pure math
    "config": {"numpy", "pydantic", "yaml"},
    "protocol": {"numpy", "msgpack", "msgspec"},  # msgspec: the per-step messages' C-speed coding
    "runtime": {"numpy", "zenoh"},
    "ros2": set(),  # ROS 2's wire format: the standard library only
    "recording": {"numpy", "rerun", "rerun_cli", "pyarrow",  # all three come with rerun-sdk
                  "foxglove", "orjson"},  # MCAP files and the live Foxglove server (cdpr.recording.mcap, .live)
    "gym": {"numpy", "gymnasium", "zenoh",  # Gymnasium environments; session mode is a Zenoh participant
            "stable_baselines3"},  # cdpr.gym.policy loads a saved model when the `train` extra is there
}
STDLIB = set(sys.stdlib_module_names) | {"__future__"}


def _imports(path: Path) -> set[str]:
    names: set[str] = set()
    for node in ast.walk(ast.parse(path.read_text(encoding="utf-8"))):
        if isinstance(node, ast.Import):
            names.update(a.name for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module and node.level == 0:
            names.add(node.module)
    return names


def test_folders_are_import_names() -> None:
    files = subprocess.run(["git", "ls-files"], cwd=ROOT, capture_output=True, text=True, check=True).stdout.split()
    py = [f for f in files if f.endswith(".py") and f.startswith(("shared/", "services/"))]
    assert py
    for f in py:
        parts = Path(f).parts
        if parts[0] == "shared":
            assert parts[1] == "cdpr", f
        else:
            assert parts[2] == f"cdpr_{parts[1]}", f
    config = tomllib.loads((ROOT / "pyproject.toml").read_text(encoding="utf-8"))
    assert "package-dir" not in config["tool"]["setuptools"]


@pytest.mark.parametrize("layer", sorted(ALLOWED))
def test_each_layer_imports_one_outside_library(layer: str) -> None:
    for path in sorted((COMMON / layer).rglob("*.py")):
        outside = {name.split(".")[0] for name in _imports(path)} - STDLIB - {"cdpr"}
        assert outside <= ALLOWED[layer], (path.relative_to(ROOT), outside - ALLOWED[layer])


def test_the_common_package_imports_no_service_and_no_tool_below_tools() -> None:
    """Services are reached through the registry only; nothing but the tools imports the tools (cdpr.gym,
    just below them, draws its domain randomisation from cdpr.config.variation, as ``cdpr study`` does)."""
    for path in sorted(COMMON.rglob("*.py")):
        names = _imports(path)
        assert not {n for n in names if n.startswith("cdpr_")}, path.relative_to(ROOT)
        if "tools" not in path.relative_to(COMMON).parts and path != COMMON / "__main__.py":  # python -m cdpr
            assert not {n for n in names if n.startswith("cdpr.tools")}, path.relative_to(ROOT)


@pytest.mark.parametrize("service", SERVICES)
def test_a_node_starts_without_the_command_line_tool(service: str) -> None:
    """``python -m cdpr_<name> --help`` imports neither the CLI nor click."""
    probe = (
        "import runpy, sys\n"
        f"sys.argv = ['cdpr_{service}', '--help']\n"
        "try:\n"
        f"    runpy.run_module('cdpr_{service}', run_name='__main__')\n"
        "except SystemExit as exc:\n"
        "    assert exc.code == 0, exc.code\n"
        "loaded = sorted(m for m in sys.modules if m.startswith('cdpr.tools') or m == 'click')\n"
        "print('LOADED', loaded)\n"
    )
    proc = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=60, check=True)
    assert f"usage: cdpr {service}" in proc.stdout
    assert "LOADED []" in proc.stdout, proc.stdout[-500:]


def test_the_registry_knows_every_service() -> None:
    from cdpr.runtime.registry import node_class, node_names

    assert set(node_names()) == set(SERVICES)
    for name in SERVICES:
        cls = node_class(name)
        assert cls.__module__ == f"cdpr_{name}.node"
        assert cls.name == name
