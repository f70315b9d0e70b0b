"""Robot descriptions: YAML data files checked into a frozen :class:`Robot`.

A robot is a rigid platform hung from a fixed frame by m cables. Cable i joins the frame point a_i
(world frame) to the platform point b_i (platform frame, origin at the platform's centre of mass).
Everything is SI: m, kg, kg·m², N, s.

Three modes:

* ``spatial``: 6-DOF platform (x, y, z, and orientation).
* ``point_mass``: all cables meet at the centre of mass; 3 translational DOF are controlled.
* ``planar``: the platform moves in the vertical x–z plane (x, z, rotation about y); every point has
  y = 0. Gravity acts along −z in every mode.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, FiniteFloat, PositiveFloat, field_validator, model_validator

from cdpr.errors import InputError
from cdpr.loading import parse_model, read_yaml, resolve, shipped_names
from cdpr.rotation import Array, rpy_to_matrix

Mode = Literal["spatial", "point_mass", "planar"]
GRAVITY = np.array([0.0, 0.0, -9.81])

Vec3 = Annotated[list[FiniteFloat], Field(min_length=3, max_length=3)]


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class ShapeSpec(_Strict):
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


class PlatformSpec(_Strict):
    mass: FiniteFloat
    inertia: list[FiniteFloat] | list[list[FiniteFloat]] = Field(
        description="principal moments [Ixx, Iyy, Izz] or a full symmetric 3×3 matrix, about the centre of mass"
    )
    shape: ShapeSpec

    @field_validator("mass")
    @classmethod
    def _mass_positive(cls, v: float) -> float:
        if v <= 0.0:
            raise ValueError(f"must be > 0 (got {v})")
        return v

    @field_validator("inertia")
    @classmethod
    def _inertia_spd(cls, v: list[float] | list[list[float]]) -> list[float] | list[list[float]]:
        I = np.asarray(v, dtype=float)
        if I.shape == (3,):
            I = np.diag(I)
        if I.shape != (3, 3):
            raise ValueError(f"must be 3 principal moments or a 3×3 matrix (got shape {I.shape})")
        if not np.allclose(I, I.T, atol=1e-9):
            raise ValueError("must be symmetric")
        if np.linalg.eigvalsh(I).min() <= 0.0:
            raise ValueError("must be positive definite")
        return v


class CableLimitsSpec(_Strict):
    tmin: FiniteFloat = Field(ge=0.0, description="lowest tension a cable may be commanded, N")
    tmax: PositiveFloat = Field(description="highest tension, N")
    max_length: PositiveFloat = Field(description="longest cable length the winch holds, m")
    max_speed: PositiveFloat = Field(description="fastest cable length rate, m/s")

    @model_validator(mode="after")
    def _ordered(self) -> CableLimitsSpec:
        if self.tmin > self.tmax:
            raise ValueError(f"tmin ({self.tmin}) must not exceed tmax ({self.tmax})")
        return self


class CableSpec(_Strict):
    frame: Vec3 = Field(description="a_i, frame (world) attach point")
    platform: Vec3 = Field(description="b_i, platform attach point in the platform frame")


class DampingSpec(_Strict):
    cable: FiniteFloat = Field(0.0, ge=0.0, description="viscous damping along each cable, N·s/m")
    passive: FiniteFloat = Field(0.0, ge=0.0, description="damping of the passive U and S joints, N·m·s/rad")


class HomeSpec(_Strict):
    position: Vec3
    rpy: Vec3 = Field(default_factory=lambda: [0.0, 0.0, 0.0])


class FrameBoxSpec(_Strict):
    min: Vec3
    max: Vec3

    @model_validator(mode="after")
    def _ordered(self) -> FrameBoxSpec:
        if any(lo >= hi for lo, hi in zip(self.min, self.max, strict=True)):
            raise ValueError("min must be below max on every axis")
        return self


class RobotSpec(_Strict):
    name: str
    description: str = ""
    source: str = Field(description="where the numbers come from")
    mode: Mode = "spatial"
    platform: PlatformSpec
    limits: CableLimitsSpec
    cables: list[CableSpec] = Field(min_length=1)
    damping: DampingSpec = Field(default_factory=DampingSpec)
    home: HomeSpec
    frame_box: FrameBoxSpec


DOF = {"spatial": 6, "point_mass": 3, "planar": 3}
# Rows of the 6×m wrench matrix that the controller acts on, per mode: [fx fy fz mx my mz].
CONTROLLED_ROWS = {"spatial": (0, 1, 2, 3, 4, 5), "point_mass": (0, 1, 2), "planar": (0, 2, 4)}


def _frozen(a: Array) -> Array:
    a = np.array(a, dtype=float)
    a.flags.writeable = False
    return a


@dataclass(frozen=True)
class Shape:
    type: str
    size: tuple[float, ...]

    def box_inertia(self, mass: float) -> Array:
        """Inertia of a solid body of this shape and the given mass about its centre."""
        if self.type == "box":
            x, y, z = self.size
            return np.diag([y * y + z * z, x * x + z * z, x * x + y * y]) * mass / 12.0
        if self.type == "sphere":
            (r,) = self.size
            return np.eye(3) * 0.4 * mass * r * r
        r, h = self.size
        ixx = mass * (3 * r * r + h * h) / 12.0
        return np.diag([ixx, ixx, 0.5 * mass * r * r])


@dataclass(frozen=True)
class Robot:
    """A validated robot. Arrays are read-only; use :meth:`replace` for variants."""

    name: str
    description: str
    source: str
    mode: Mode
    frame_points: Array  # (m, 3) a_i, world frame
    platform_points: Array  # (m, 3) b_i, platform frame
    mass: float
    inertia: Array  # (3, 3) about the centre of mass, platform frame
    shape: Shape
    tmin: float
    tmax: float
    max_length: float
    max_speed: float
    cable_damping: float
    passive_damping: float
    home_position: Array  # (3,)
    home_rotation: Array  # (3, 3)
    frame_min: Array
    frame_max: Array

    @property
    def m(self) -> int:
        """Number of cables."""
        return int(self.frame_points.shape[0])

    @property
    def dof(self) -> int:
        """Number of controlled degrees of freedom."""
        return DOF[self.mode]

    @property
    def controlled_rows(self) -> tuple[int, ...]:
        return CONTROLLED_ROWS[self.mode]

    def replace(self, **changes: object) -> Robot:
        frozen = {k: _frozen(v) if isinstance(v, np.ndarray) else v for k, v in changes.items()}
        return dataclasses.replace(self, **frozen)

    def with_mass(self, mass: float) -> Robot:
        """The same robot whose whole platform has this mass, with the solid-shape inertia for it."""
        if not 0.0 < mass < np.inf:
            raise InputError(f"platform mass must be finite and > 0 (got {mass})")
        return self.replace(mass=float(mass), inertia=self.shape.box_inertia(mass))

    def with_payload(self, payload: float) -> Robot:
        """A point-mass payload rigidly attached at the centre of mass: mass grows, inertia is unchanged."""
        if not 0.0 <= payload < np.inf:
            raise InputError(f"payload must be finite and >= 0 (got {payload})")
        return self.replace(mass=self.mass + float(payload))

    def summary(self) -> dict[str, object]:
        return {
            "name": self.name,
            "description": self.description,
            "source": self.source,
            "mode": self.mode,
            "cables": self.m,
            "dof": self.dof,
            "mass": self.mass,
            "inertia": self.inertia.tolist(),
            "shape": {"type": self.shape.type, "size": list(self.shape.size)},
            "tension_limits": [self.tmin, self.tmax],
            "max_length": self.max_length,
            "max_speed": self.max_speed,
            "home": {"position": self.home_position.tolist(), "rotation": self.home_rotation.tolist()},
            "frame_points": self.frame_points.tolist(),
            "platform_points": self.platform_points.tolist(),
        }


def robot_from_spec(spec: RobotSpec, where: str) -> Robot:
    """Build and check a Robot; ``where`` names the file in errors."""
    inertia = np.asarray(spec.platform.inertia, dtype=float)
    if inertia.shape == (3,):
        inertia = np.diag(inertia)
    a = np.array([c.frame for c in spec.cables])
    b = np.array([c.platform for c in spec.cables])
    robot = Robot(
        name=spec.name,
        description=spec.description,
        source=spec.source,
        mode=spec.mode,
        frame_points=_frozen(a),
        platform_points=_frozen(b),
        mass=spec.platform.mass,
        inertia=_frozen(inertia),
        shape=Shape(spec.platform.shape.type, tuple(spec.platform.shape.size)),
        tmin=spec.limits.tmin,
        tmax=spec.limits.tmax,
        max_length=spec.limits.max_length,
        max_speed=spec.limits.max_speed,
        cable_damping=spec.damping.cable,
        passive_damping=spec.damping.passive,
        home_position=_frozen(spec.home.position),
        home_rotation=_frozen(rpy_to_matrix(*spec.home.rpy)),
        frame_min=_frozen(spec.frame_box.min),
        frame_max=_frozen(spec.frame_box.max),
    )
    check_robot(robot, where)
    return robot


def check_robot(robot: Robot, where: str) -> None:
    """Checks that need the whole robot: mode-specific geometry and the wrench matrix's rank."""
    from cdpr.kinematics import inverse_kinematics  # kinematics imports this module's types

    if robot.m < robot.dof:
        raise InputError(
            f"{where}: cables: {robot.m} cable(s) cannot control the {robot.dof} DOF of a {robot.mode} robot"
        )
    if robot.mode == "point_mass" and np.abs(robot.platform_points).max() > 1e-12:
        raise InputError(f"{where}: cables: a point_mass robot needs every platform point at [0, 0, 0]")
    if robot.mode == "planar":
        pts = np.vstack([robot.frame_points, robot.platform_points, robot.home_position[None, :]])
        if np.abs(pts[:, 1]).max() > 1e-12:
            raise InputError(f"{where}: cables: a planar robot lives in the x–z plane: every y must be 0")
    ik = inverse_kinematics(robot, robot.home_position, robot.home_rotation)
    if np.any(ik.lengths < 1e-9):
        i = int(np.argmin(ik.lengths))
        raise InputError(f"{where}: cables.{i}: zero cable length at the home pose")
    W = ik.wrench_matrix[list(robot.controlled_rows), :]
    rank = int(np.linalg.matrix_rank(W, tol=1e-9 * max(1.0, float(np.abs(W).max()))))
    if rank < robot.dof:
        raise InputError(
            f"{where}: cables: the wrench matrix has rank {rank} < {robot.dof} at the home pose "
            "(the cables cannot hold the platform there)"
        )


def load_robot(name_or_path: str | Path) -> Robot:
    """A shipped robot name (``caroca``) or a path to a robot YAML file → a validated Robot."""
    path = resolve(name_or_path, "robots", "robot")
    spec = parse_model(RobotSpec, read_yaml(path), path)
    return robot_from_spec(spec, str(path))


def shipped_robots() -> list[str]:
    return shipped_names("robots")
