"""Robot files: YAML data checked by pydantic into a frozen :class:`~cdpr.mechanics.robot.Robot`.

Errors name the file and the field (``file: dotted.field: message``); the command line turns them into
exit code 2. The file format is documented in the shipped robots (``shared/cdpr/robots/*.yaml``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    Field,
    FiniteFloat,
    PositiveFloat,
    field_validator,
    model_validator,
)

from cdpr.config.loading import Strict, parse_model, read_yaml, resolve, shipped_names, shown
from cdpr.errors import InputError
from cdpr.mechanics.kinematics import check_robot
from cdpr.mechanics.pulley import Pulleys
from cdpr.mechanics.robot import Mode, Plane, Robot, Shape, frozen_array
from cdpr.mechanics.rotation import rpy_to_matrix
from cdpr.mechanics.workspace import why_not_held, wrench_feasible

Vec3 = Annotated[list[FiniteFloat], Field(min_length=3, max_length=3)]


class ShapeSpec(Strict):
    type: Literal["box", "sphere", "cylinder"]
    size: list[PositiveFloat] = Field(
        description="box: [x, y, z] edge lengths; sphere: [radius]; cylinder: [radius, length along z]"
    )

    @model_validator(mode="after")
    def _size_matches_type(self) -> ShapeSpec:
        want = {"box": 3, "sphere": 1, "cylinder": 2}[self.type]
        if len(self.size) != want:
            raise ValueError(f"a {self.type} needs {want} size value(s), got {len(self.size)}")
        return self


class PlatformSpec(Strict):
    mass: FiniteFloat
    inertia: list[FiniteFloat] | list[list[FiniteFloat]] | FiniteFloat = Field(
        description="principal moments [Ixx, Iyy, Izz] or a full symmetric 3×3 matrix, about the centre of mass; "
                    "a planar robot may give one number, its moment about the plane's normal"
    )
    shape: ShapeSpec
    com: Vec3 = Field(default_factory=lambda: [0.0, 0.0, 0.0],
                      description="the centre of mass in the platform frame, m: that frame's origin need not be the "
                                  "COM; the cables' platform points and the home pose are in that frame, the inertia "
                                  "about the COM (axes of that frame)")

    @field_validator("mass")
    @classmethod
    def _mass_positive(cls, v: float) -> float:
        if v <= 0.0:
            raise ValueError(f"must be > 0 (got {shown(v)})")
        return v

    @field_validator("inertia")
    @classmethod
    def _inertia_spd(cls, v: float | list[float] | list[list[float]]) -> float | list[float] | list[list[float]]:
        J = np.asarray(v, dtype=float)
        if J.shape == ():
            if J <= 0.0:
                raise ValueError(f"must be > 0 (got {shown(v)})")
            return v
        if J.shape == (3,):
            J = np.diag(J)
        if J.shape != (3, 3):
            raise ValueError(f"must be 3 principal moments or a 3×3 matrix (got shape {J.shape})")
        if not np.allclose(J, J.T, atol=1e-9):
            raise ValueError("must be symmetric")
        if np.linalg.eigvalsh(J).min() <= 0.0:
            raise ValueError("must be positive definite")
        return v


class CableLimitsSpec(Strict):
    tmin: FiniteFloat = Field(ge=0.0, description="lowest tension a cable may be commanded, N")
    tmax: PositiveFloat = Field(description="highest tension, N")
    max_length: PositiveFloat = Field(description="longest cable length the winch holds, m")
    max_speed: PositiveFloat = Field(description="fastest cable length rate, m/s")

    @model_validator(mode="after")
    def _ordered(self) -> CableLimitsSpec:
        if self.tmin > self.tmax:
            raise ValueError(f"tmin ({self.tmin}) must not exceed tmax ({self.tmax})")
        return self


class PulleySpec(Strict):
    radius: FiniteFloat = Field(ge=0.0, description="the pulley wheel's radius, m (0: a fixed exit point)")
    axis: Vec3 = Field(description="the swivel axis through the cable's frame point, pointing the way the cable runs "
                                   "into the pulley (from its winch)")

    @field_validator("axis")
    @classmethod
    def _axis_not_zero(cls, v: list[float]) -> list[float]:
        if float(np.linalg.norm(v)) < 1e-9:
            raise ValueError("must not be zero (a direction)")
        return v


class CableSpec(Strict):
    frame: Vec3 = Field(description="a_i, frame (world) attach point (with a pulley: where the cable meets its axis)")
    platform: Vec3 = Field(description="b_i, platform attach point in the platform frame")
    tmin: FiniteFloat | None = Field(None, ge=0.0, description="this cable's least tension, N (default limits.tmin)")
    tmax: PositiveFloat | None = Field(None, description="this cable's greatest tension, N (default limits.tmax)")
    max_length: PositiveFloat | None = Field(None, description="this cable's longest length, m (default "
                                                                "limits.max_length)")
    pulley: PulleySpec | None = Field(None, description="a swivelling exit pulley (docs/robots.md)")
    encoder_offset: FiniteFloat = Field(0.0, description="what this cable's winch encoder reads beyond the cable's "
                                        "length, m (its zero error after homing; `cdpr calibrate` identifies it)")


class DampingSpec(Strict):
    cable: FiniteFloat = Field(0.0, ge=0.0, description="viscous damping along each cable, N·s/m")
    passive: FiniteFloat = Field(0.0, ge=0.0, description="damping of the passive U and S joints, N·m·s/rad")


class HomeSpec(Strict):
    position: Vec3
    rpy: Vec3 = Field(default_factory=lambda: [0.0, 0.0, 0.0])


class FrameBoxSpec(Strict):
    min: Vec3
    max: Vec3

    @model_validator(mode="after")
    def _ordered(self) -> FrameBoxSpec:
        if any(lo >= hi for lo, hi in zip(self.min, self.max, strict=True)):
            raise ValueError("min must be below max on every axis")
        return self


class RobotSpec(Strict):
    name: str
    description: str = ""
    source: str = Field(description="where the numbers come from")
    mode: Mode = "spatial"
    plane: Plane | None = Field(None, description="a planar robot's plane: xz (vertical, the default) or xy "
                                                  "(horizontal, gravity out of the plane)")
    platform: PlatformSpec
    limits: CableLimitsSpec
    cables: list[CableSpec] = Field(min_length=1, description="the robot's cables (its default cable set)")
    cable_set: str = Field("default", min_length=1, description="the name of the set ``cables`` is")
    cable_sets: dict[str, Annotated[list[CableSpec], Field(min_length=1)]] = Field(
        default_factory=dict, description="other sets of cables on the same frame and platform, by name "
                                          "(``--cable-set NAME``, a scenario's ``cable_set``)")
    damping: DampingSpec = Field(default_factory=lambda: DampingSpec())
    home: HomeSpec
    frame_box: FrameBoxSpec

    @model_validator(mode="after")
    def _set_names_differ(self) -> RobotSpec:
        if self.cable_set in self.cable_sets:
            raise ValueError(f"cable_sets.{self.cable_set}: the name of the default set (cable_set); "
                             "give the other sets other names")
        return self

    def set_names(self) -> list[str]:
        return [self.cable_set, *self.cable_sets]

    def with_cable_set(self, name: str | None) -> RobotSpec:
        """The spec whose ``cables`` are the set ``name`` (None: the default one)."""
        if name is None or name == self.cable_set:
            return self
        if name not in self.cable_sets:
            raise InputError(f"cable_set: no cable set {name!r} (this robot has: {', '.join(self.set_names())})")
        return self.model_copy(update={"cables": self.cable_sets[name], "cable_set": name})

    @model_validator(mode="after")
    def _plane_and_inertia_of_a_planar_robot(self) -> RobotSpec:
        if self.plane is not None and self.mode != "planar":
            raise ValueError(f"plane: only a planar robot has a plane (mode is {self.mode})")
        if np.ndim(self.platform.inertia) == 0 and self.mode != "planar":
            raise ValueError("platform.inertia: one number is a planar robot's moment about its plane's normal; "
                             "give [Ixx, Iyy, Izz] or a 3×3 matrix")
        return self

    def cable_limits(self, name: Literal["tmin", "tmax", "max_length"]) -> list[float]:
        """One limit per cable: the cable's own, else the robot's ``limits``."""
        default = getattr(self.limits, name)
        return [default if (v := getattr(c, name)) is None else v for c in self.cables]


def robot_from_spec(spec: RobotSpec, where: str, check_home: bool = True) -> Robot:
    """Build and check a Robot; ``where`` names the file in errors. ``check_home``: also that tensions within the
    limits hold the platform at its home pose (a session's robot; the tools that analyse a robot take one whose
    home is not held, and say so: :func:`home_problem`)."""
    inertia = np.asarray(spec.platform.inertia, dtype=float)
    if inertia.shape == ():  # a planar robot's one moment: the other axes cannot turn, any positive moment serves
        inertia = np.eye(3) * inertia
    elif inertia.shape == (3,):
        inertia = np.diag(inertia)
    lo, hi = spec.cable_limits("tmin"), spec.cable_limits("tmax")
    for i, (low, high) in enumerate(zip(lo, hi, strict=True)):
        if low > high:
            raise InputError(f"{where}: cables.{i}: tmin ({low}) must not exceed tmax ({high}) (limits.tmin/tmax "
                             "where the cable gives none)")
    a = np.array([c.frame for c in spec.cables])
    com = np.array(spec.platform.com, dtype=float)
    b = np.array([c.platform for c in spec.cables]) - com  # from the COM, the origin of the robot's model
    home_rotation = rpy_to_matrix(*spec.home.rpy)
    robot = Robot(
        name=spec.name,
        description=spec.description,
        source=spec.source,
        mode=spec.mode,
        frame_points=frozen_array(a),
        platform_points=frozen_array(b),
        mass=spec.platform.mass,
        inertia=frozen_array(inertia),
        shape=Shape(spec.platform.shape.type, tuple(spec.platform.shape.size)),
        tmin=np.array(spec.cable_limits("tmin")),
        tmax=np.array(spec.cable_limits("tmax")),
        max_length=np.array(spec.cable_limits("max_length")),
        max_speed=spec.limits.max_speed,
        cable_damping=spec.damping.cable,
        passive_damping=spec.damping.passive,
        home_position=frozen_array(np.asarray(spec.home.position) + home_rotation @ com),
        home_rotation=frozen_array(home_rotation),
        frame_min=frozen_array(spec.frame_box.min),
        frame_max=frozen_array(spec.frame_box.max),
        plane=spec.plane or "xz",
        cable_set=spec.cable_set,
        com_offset=frozen_array(com),
        pulleys=_pulleys(spec.cables),
        encoder_offsets=frozen_array(np.array([c.encoder_offset for c in spec.cables], dtype=float)),
    )
    check_robot(robot, where)
    if check_home and (problem := home_problem(robot, where, spec.home.position, spec.home.rpy)) is not None:
        raise InputError(problem)
    return robot


def _pulleys(cables: list[CableSpec]) -> Pulleys | None:
    """The cables' pulleys (None when no cable has one of radius > 0)."""
    if all(c.pulley is None or c.pulley.radius == 0.0 for c in cables):
        return None
    radius = [0.0 if c.pulley is None else c.pulley.radius for c in cables]
    axis = np.array([[0.0, 0.0, 1.0] if c.pulley is None else c.pulley.axis for c in cables], dtype=float)
    return Pulleys(frozen_array(radius), frozen_array(axis / np.linalg.norm(axis, axis=1, keepdims=True)))


def home_problem(robot: Robot, where: str, position: list[float], rpy: list[float]) -> str | None:
    """None when tensions within the robot's limits hold its platform at rest at its home pose (the robot's
    reference pose: ``cdpr show``'s, a session's check that its robot can be held); else why not, which cables,
    and the way forward, in one line."""
    if wrench_feasible(robot, robot.home_position[None, :], robot.home_rotation)[0]:
        return None
    pos = ", ".join(f"{x:g}" for x in position)  # as the file gives it (the platform frame's)
    angles = ", ".join(f"{x:g}" for x in rpy)
    which = "limits.tmin, limits.tmax" if robot.uniform_limits else "per cable: cables.i.tmin/tmax, else limits"
    why = why_not_held(robot, robot.home_position, robot.home_rotation)
    return (f"{where}: home: no tensions in {robot.tension_limits_text()} ({which}) hold the {robot.mass:g} kg "
            f"platform at rest at the home pose (position [{pos}] m, rpy [{angles}] rad): {why}; "
            f"`cdpr robots {where} --find-home` finds a pose they hold (cdpr ik, tda and workspace take this file)")


def load_robot(name_or_path: str | Path, cable_set: str | None = None, check_home: bool = True) -> Robot:
    """A shipped robot name (``caroca``) or a path to a robot YAML file → a validated Robot, with its cable set
    ``cable_set`` (None: the file's ``cables``). Every set of the file is checked (``check_home``: their home
    poses held too)."""
    path = resolve(name_or_path, "robots", "robot")
    return robot_from_data(read_yaml(path), path, cable_set, check_home)


def robot_from_data(data: dict[str, Any], where: str | Path, cable_set: str | None = None,
                    check_home: bool = True) -> Robot:
    """A robot file's content → the Robot of its cable set ``cable_set`` (None: its ``cables``), every set of
    it checked; errors start with ``where``."""
    spec = parse_model(RobotSpec, data, where)
    try:
        chosen = spec.with_cable_set(cable_set)
    except InputError as exc:
        raise InputError(f"{where}: {exc}") from None
    for name in spec.set_names():
        if name != chosen.cable_set:
            robot_from_spec(spec.with_cable_set(name), f"{where}: cable_sets.{name}", check_home)
    place = str(where) if chosen.cable_set == spec.cable_set else f"{where}: cable_sets.{chosen.cable_set}"
    return robot_from_spec(chosen, place, check_home)


def home_held_problem(robot: Robot, where: str | Path) -> str | None:
    """:func:`home_problem` of a loaded robot (its home as the file gives it: the platform frame's pose)."""
    from cdpr.mechanics.rotation import matrix_to_rpy

    R = robot.home_rotation
    position = (robot.home_position - R @ robot.com_offset).tolist()
    return home_problem(robot, str(where), position, list(matrix_to_rpy(R)))


def shipped_robots() -> list[str]:
    return shipped_names("robots")
