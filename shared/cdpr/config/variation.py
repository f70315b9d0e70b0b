"""A study's points: the grid's product times the random draws, each as scenario (and robot) YAML text.

Draws are reproducible: parameter ``j`` of sample ``s`` draws from ``numpy.random.default_rng([seed, s,
j])``, so adding a parameter or a grid value changes no other draw, and every grid point of a sample sees
the same random numbers (common random numbers: grid values are compared on equal terms).

``set`` draws one value per point and puts it at every place the path matches; ``add`` and ``scale``
draw one number per number they change (independent errors, e.g. each coordinate of each attachment
point). The table records a parameter as its value, or, when it drew several numbers, as the RMS of
their deviations (the offsets for ``add``, ``factor - 1`` for ``scale``).
"""

from __future__ import annotations

import copy
import hashlib
import itertools
import json
import math
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import yaml

from cdpr.config.loading import parse_model, read_yaml, resolve
from cdpr.config.robot import RobotSpec
from cdpr.config.scenario import ScenarioSpec
from cdpr.config.study import ParameterSpec, StudySpec
from cdpr.errors import InputError


@dataclass
class Base:
    """The base scenario and robot documents (plain YAML data) a study varies."""

    scenario: dict[str, Any]
    robot: dict[str, Any]
    robot_ref: str  # the scenario's robot: a shipped name, or "robot.yaml" (its file copied beside the point)
    robot_is_file: bool


@dataclass
class Point:
    index: int
    sample: int | None
    values: dict[str, Any]  # column -> what the table records
    files: dict[str, str]  # file name -> YAML text: scenario.yaml, maybe robot.yaml, controller.yaml, ...
    split: bool  # the controller runs its own scenario (controller.yaml): plant_only parameters
    digest: str = field(default="")

    @property
    def id(self) -> str:
        return f"p{self.index:05d}-{self.digest[:10]}"


def load_base(spec: StudySpec, study_path: Path) -> Base:
    ref = spec.scenario
    if ref.endswith((".yaml", ".yml")) and not Path(ref).is_absolute():
        ref = str(study_path.parent / ref)
    path = resolve(ref, "scenarios", "scenario")
    scenario = read_yaml(path)
    parse_model(ScenarioSpec, scenario, path)  # the base itself is a valid scenario
    robot_ref = str(scenario.get("robot", ""))
    is_file = robot_ref.endswith((".yaml", ".yml"))
    if is_file and not Path(robot_ref).is_absolute():
        robot_ref = str(path.parent / robot_ref)
    robot_path = resolve(robot_ref, "robots", "robot")
    robot = read_yaml(robot_path)
    parse_model(RobotSpec, robot, robot_path)
    return Base(scenario, robot, "robot.yaml" if is_file else robot_ref, is_file)


# ------------------------------------------------------------------------------------------------
# Dotted paths


def _split(path: str) -> list[str]:
    return path.split(".")


def matches(doc: Any, path: str, create: bool, where: str) -> list[tuple[Any, str | int]]:
    """(container, key) of every place ``path`` names in ``doc``; ``create`` adds missing mappings."""
    places: list[tuple[Any, str | int]] = []

    def walk(node: Any, parts: list[str], done: list[str]) -> None:
        part, rest = parts[0], parts[1:]
        if isinstance(node, list):
            if part == "*":
                keys: list[Any] = list(range(len(node)))
            elif part.isdigit() and int(part) < len(node):
                keys = [int(part)]
            else:
                raise InputError(f"{where}: {'.'.join(done) or '(top)'} is a list of {len(node)}: no element "
                                 f"{part!r}")
        elif isinstance(node, dict):
            if part == "*":
                keys = list(node)
            elif part in node:
                keys = [part]
            elif create:
                node[part] = {} if rest else None
                keys = [part]
            else:
                raise InputError(f"{where}: {'.'.join([*done, part])} is not in the base file")
        else:
            raise InputError(f"{where}: {'.'.join(done)} is a value, not a mapping or a list")
        for key in keys:
            if rest:
                if node[key] is None and create and isinstance(node, dict):
                    node[key] = {}
                walk(node[key], rest, [*done, str(key)])
            else:
                places.append((node, key))

    walk(doc, _split(path), [])
    return places


def _numbers(value: Any, where: str) -> np.ndarray:
    try:
        arr = np.asarray(value, dtype=float)
    except (TypeError, ValueError):
        raise InputError(f"{where}: add and scale need numbers there, found {value!r}") from None
    if arr.size == 0:
        raise InputError(f"{where}: add and scale need numbers there, found {value!r}")
    return arr


def _plain(x: Any) -> Any:
    """numpy → plain Python (YAML-safe)."""
    if isinstance(x, np.ndarray):
        return [_plain(v) for v in x.tolist()]
    if isinstance(x, np.generic):
        return x.item()
    if isinstance(x, list | tuple):
        return [_plain(v) for v in x]
    return x


# ------------------------------------------------------------------------------------------------
# Draws


def draw(p: ParameterSpec, rng: np.random.Generator, size: int) -> np.ndarray | list[Any]:
    if p.uniform is not None:
        out = rng.uniform(p.uniform[0], p.uniform[1], size)
    elif p.normal is not None:
        out = rng.normal(p.normal[0], p.normal[1], size)
    elif p.loguniform is not None:
        out = np.exp(rng.uniform(math.log(p.loguniform[0]), math.log(p.loguniform[1]), size))
    elif p.choice is not None:
        picks = rng.integers(0, len(p.choice), size)
        return [p.choice[int(i)] for i in picks]
    else:
        raise ValueError(f"{p.path}: a grid has no draws")
    return np.round(out) if p.integer else out


def apply(doc: dict[str, Any], p: ParameterSpec, value: Any, rng: np.random.Generator | None,
          where: str) -> Any:
    """Apply one parameter to ``doc`` (in place); ``value`` for a grid, ``rng`` for a random law.

    Returns what the table records.
    """
    path = p.path.removeprefix("robot.") if p.on_robot else p.path
    places = matches(doc, path, create=p.op == "set", where=where)
    if p.op == "set":
        if rng is not None:
            drawn = draw(p, rng, 1)
            value = _plain(drawn[0])
            if p.integer:
                value = int(value)
        for container, key in places:
            container[key] = copy.deepcopy(_plain(value))
        return value if not isinstance(value, list | dict) else json.dumps(value)
    deviations: list[np.ndarray] = []
    for container, key in places:
        base = _numbers(container[key], f"{where}: {p.path}")
        if rng is not None:
            factor = np.asarray(draw(p, rng, base.size), dtype=float).reshape(base.shape)
        else:
            factor = np.full(base.shape, float(value))
        new = base + factor if p.op == "add" else base * factor
        deviations.append((factor if p.op == "add" else factor - 1.0).ravel())
        plain = _plain(new)
        container[key] = plain
    if rng is None:
        return value
    dev = np.concatenate(deviations)
    if dev.size == 1:
        return float(dev[0]) if p.op == "add" else float(dev[0]) + 1.0
    return float(np.sqrt(np.mean(dev * dev)))


def _dump(doc: dict[str, Any], comment: str) -> str:
    return f"# {comment}\n" + yaml.safe_dump(doc, sort_keys=False, default_flow_style=None, width=120)


def build_point(spec: StudySpec, base: Base, index: int, grid_values: dict[int, Any], sample: int | None,
                where: str, duration_fraction: float = 1.0, name: str | None = None) -> Point:
    """One point's files. ``grid_values``: parameter index → value (grid laws, or tune's chosen values)."""
    plant = copy.deepcopy(base.scenario)
    robot = copy.deepcopy(base.robot)
    for path, value in spec.set.items():
        target = robot if path.startswith("robot.") else plant
        for container, key in matches(target, path.removeprefix("robot."), create=True, where=f"{where}: set"):
            container[key] = copy.deepcopy(value)
    nominal_scenario, nominal_robot = copy.deepcopy(plant), copy.deepcopy(robot)
    values: dict[str, Any] = {}
    split = False
    for j, p in enumerate(spec.parameters):
        rng = None if j in grid_values else np.random.default_rng([spec.seed, sample or 0, j])
        targets = [robot if p.on_robot else plant]
        if not p.plant_only:
            targets.append(nominal_robot if p.on_robot else nominal_scenario)
        else:
            split = True
        for k, doc in enumerate(targets):
            # the same draw for the plant and the controller: a fresh generator of the same seed each
            again = None if rng is None else np.random.default_rng([spec.seed, sample or 0, j])
            recorded = apply(doc, p, grid_values.get(j), again, f"{where}: parameters.{j}")
            if k == 0:
                values[p.column] = recorded
    robot_changed = robot != base.robot or nominal_robot != base.robot
    files: dict[str, str] = {}
    label = name or f"{spec.name}_{index:05d}"
    for doc, rob, scen_file, robot_file in ((plant, robot, "scenario.yaml", "robot.yaml"),
                                            (nominal_scenario, nominal_robot, "controller.yaml",
                                             "controller_robot.yaml")):
        if scen_file == "controller.yaml" and not split:
            break
        doc = copy.deepcopy(doc)
        doc["name"] = label
        settings = ", ".join(f"{k} = {v}" for k, v in values.items())
        doc["description"] = (f"Point {index} of study {spec.name} ({settings}) of the scenario "
                              f"{base.scenario.get('name')}: {doc.get('description', '')}").strip()
        if duration_fraction != 1.0:
            doc["duration"] = _duration(doc, where) * duration_fraction
        if base.robot_is_file or robot_changed:
            doc["robot"] = robot_file
            files[robot_file] = _dump(rob, f"robot of point {index} of study {spec.name}")
        else:
            doc["robot"] = base.robot_ref
        files[scen_file] = _dump(doc, f"point {index} of study {spec.name}: {json.dumps(values)}")
    digest = hashlib.sha256(json.dumps(files, sort_keys=True).encode()).hexdigest()
    return Point(index, sample, values, files, split, digest)


def _duration(doc: dict[str, Any], where: str) -> float:
    if doc.get("duration") is not None:
        return float(doc["duration"])
    scenario = parse_model(ScenarioSpec, doc, where)
    return float(scenario.trajectory.build().duration + 1.0)


def study_points(spec: StudySpec, base: Base, where: str) -> list[Point]:
    """Every point of a study: the product of the grids (in parameter order), each with ``samples`` draws."""
    grids = [(j, p.values) for j, p in enumerate(spec.parameters) if p.values is not None]  # the grid laws
    samples: list[int | None] = list(range(spec.samples)) if spec.samples else [None]
    points = []
    combos = itertools.product(*[vals for _, vals in grids]) if grids else [()]
    index = 0
    for combo in combos:
        chosen = {j: v for (j, _), v in zip(grids, combo, strict=True)}
        for s in samples:
            points.append(build_point(spec, base, index, chosen, s, where))
            index += 1
    return points


def write_point_files(point: Point, folder: Path) -> None:
    folder.mkdir(parents=True, exist_ok=True)
    for name, text in point.files.items():
        (folder / name).write_text(text, encoding="utf-8")


def check_point(point: Point, folder: Path) -> tuple[list[float], list[float]]:
    """Load the point's scenario files as ``cdpr run`` will (InputError if invalid); its (tmin, tmax) per cable."""
    from cdpr.config.scenario import load_scenario

    scenario = load_scenario(folder / "scenario.yaml")
    if point.split:
        load_scenario(folder / "controller.yaml")
    return scenario.robot.tmin.tolist(), scenario.robot.tmax.tolist()
