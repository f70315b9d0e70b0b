"""The robot as the mechanics sees it: a frozen :class:`Robot` (geometry, mass, limits), no I/O.

A robot is a rigid platform hung from a fixed frame by m cables. Cable i joins the frame point a_i
(world frame) to the platform point b_i (platform frame, origin at the platform's centre of mass).
Everything is SI: m, kg, kg·m², N, s. Robot files are read into it by :mod:`cdpr.config.robot`.
Limits are per cable: ``tmin``, ``tmax`` and ``max_length`` are (m,) arrays (a scalar given to the constructor
or to :meth:`Robot.replace` applies to every cable).

Three modes:

* ``spatial``: 6-DOF platform (x, y, z, and orientation).
* ``point_mass``: all cables meet at the centre of mass; 3 translational DOF are controlled.
* ``planar``: the platform moves in a plane through the origin, every point in it: ``plane`` ``xz``, the
  vertical x–z plane (x, z, rotation about y; gravity in the plane), or ``xy``, the horizontal x–y plane (x,
  y, rotation about z; gravity out of the plane, held by whatever supports the platform, as on a table).
  Gravity acts along −z in every mode.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Any, Literal

import numpy as np
from numpy.typing import ArrayLike

from cdpr.errors import InputError
from cdpr.mechanics.pulley import Pulleys
from cdpr.mechanics.rotation import Array

Mode = Literal["spatial", "point_mass", "planar"]
Plane = Literal["xz", "xy"]
GRAVITY = np.array([0.0, 0.0, -9.81])


DOF = {"spatial": 6, "point_mass": 3, "planar": 3}
# Rows of the 6×m wrench matrix that the controller acts on, per mode: [fx fy fz mx my mz].
CONTROLLED_ROWS = {"spatial": (0, 1, 2, 3, 4, 5), "point_mass": (0, 1, 2), "planar": (0, 2, 4)}
# A planar robot's plane: its rows of W, and the axis normal to it (the rotation axis; every point's coordinate
# along it is 0).
PLANE_ROWS: dict[str, tuple[int, ...]] = {"xz": (0, 2, 4), "xy": (0, 1, 5)}
PLANE_NORMAL = {"xz": 1, "xy": 2}


def frozen_array(a: ArrayLike) -> Array:
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
    tmin: Array  # (m,) least tension of each cable, N
    tmax: Array  # (m,) greatest tension of each cable, N
    max_length: Array  # (m,) the longest each cable may be, m
    max_speed: float
    cable_damping: float
    passive_damping: float
    home_position: Array  # (3,)
    home_rotation: Array  # (3, 3)
    frame_min: Array
    frame_max: Array
    plane: Plane = "xz"  # a planar robot's plane (ignored in the other modes)
    cable_set: str = "default"  # the name of the robot file's set these cables are
    # The COM in the platform frame of the robot file (whose origin need not be the COM): every point, pose and
    # motion here is of the COM; a pose given for that frame is the COM's after :meth:`com_pose`.
    com_offset: Array = dataclasses.field(default_factory=lambda: frozen_array(np.zeros(3)))
    # Swivelling exit pulleys (:mod:`cdpr.mechanics.pulley`): None, or per cable a radius (0: none) and an axis;
    # a cable with a pulley runs into it at its frame point a_i.
    pulleys: Pulleys | None = None
    # What each winch encoder reads beyond its cable's length, m (zero errors after homing; cdpr calibrate): the
    # sim's encoders add it, a controller fed from the sensors takes it off. One number or one per cable.
    encoder_offsets: Array = dataclasses.field(default_factory=lambda: frozen_array(np.zeros(1)))

    def __post_init__(self) -> None:
        object.__setattr__(self, "com_offset", frozen_array(np.broadcast_to(self.com_offset, (3,))))
        m = self.m
        for name in ("tmin", "tmax", "max_length", "encoder_offsets"):
            value = np.asarray(getattr(self, name), dtype=float)
            if name == "encoder_offsets" and value.shape == (1,):
                value = value[0]
            if value.shape not in ((), (m,)):
                raise InputError(f"{name}: expected one number or {m} (one per cable), got shape {value.shape}")
            object.__setattr__(self, name, frozen_array(np.broadcast_to(value, (m,))))

    def com_pose(self, position: ArrayLike, R: ArrayLike) -> Array:
        """The COM's position when the platform frame of the robot file is at (position, R): position + R c."""
        return np.asarray(position, dtype=float) + np.asarray(R, dtype=float) @ self.com_offset

    @property
    def uniform_limits(self) -> bool:
        """Every cable has the same tension limits."""
        return bool(np.all(self.tmin == self.tmin[0]) and np.all(self.tmax == self.tmax[0]))

    @property
    def common_tension_range(self) -> tuple[float, float]:
        """``(max tmin, min tmax)``: the tensions admissible for every cable (what a client that takes one range
        for all cables must keep to; ``session/info``'s ``tension_limits``)."""
        return float(self.tmin.max()), float(self.tmax.min())

    def tension_limits_text(self) -> str:
        """The tension limits for a message: ``[1, 6500] N``, or per cable ``[0, 1000]/[0, 5000]/… N``."""
        if self.uniform_limits:
            return f"[{self.tmin[0]:g}, {self.tmax[0]:g}] N"
        pairs = zip(self.tmin.tolist(), self.tmax.tolist(), strict=True)
        return "/".join(f"[{lo:g}, {hi:g}]" for lo, hi in pairs) + " N"

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
        return PLANE_ROWS[self.plane] if self.mode == "planar" else CONTROLLED_ROWS[self.mode]

    @property
    def normal_axis(self) -> int:
        """A planar robot's axis normal to its plane: 1 (y) for x–z, 2 (z) for x–y."""
        return PLANE_NORMAL[self.plane]

    def replace(self, **changes: Any) -> Robot:
        """A copy with ``changes``; with another number of cables, limits the same for every cable carry over
        (per-cable ones must be given anew)."""
        if "frame_points" in changes and np.shape(changes["frame_points"])[0] != self.m:
            if self.pulleys is not None and "pulleys" not in changes:
                raise InputError("pulleys: the robot has pulleys: give them for the new cables")
            for name in ("tmin", "tmax", "max_length", "encoder_offsets"):
                value = getattr(self, name)
                if name not in changes:
                    if np.any(value != value[0]):
                        raise InputError(f"{name}: the robot has per-cable values: give them for the new cables")
                    changes[name] = float(value[0])
        frozen: dict[str, Any] = {k: frozen_array(v) if isinstance(v, np.ndarray) else v for k, v in changes.items()}
        return dataclasses.replace(self, **frozen)

    def with_mass(self, mass: float) -> Robot:
        """The same robot whose whole platform has this mass, with the solid-shape inertia for it."""
        if not 0.0 < mass < np.inf:
            raise InputError(f"mass: must be > 0 (got {mass:.12g})")
        return self.replace(mass=float(mass), inertia=self.shape.box_inertia(mass))

    def with_payload(self, payload: float) -> Robot:
        """A point-mass payload rigidly attached at the centre of mass: mass grows, inertia is unchanged."""
        if not 0.0 <= payload < np.inf:
            raise InputError(f"payload: must be >= 0 (got {payload:.12g})")
        return self.replace(mass=self.mass + float(payload))

    def summary(self) -> dict[str, object]:
        return {
            "name": self.name,
            "description": self.description,
            "source": self.source,
            "mode": self.mode,
            **({"plane": self.plane} if self.mode == "planar" else {}),
            "cable_set": self.cable_set,
            "com_offset": self.com_offset.tolist(),
            **({} if self.pulleys is None else {"pulleys": {"radius": self.pulleys.radius.tolist(),
                                                            "axis": self.pulleys.axis.tolist()}}),
            "cables": self.m,
            "dof": self.dof,
            "mass": self.mass,
            "inertia": self.inertia.tolist(),
            "shape": {"type": self.shape.type, "size": list(self.shape.size)},
            "tension_limits": list(self.common_tension_range),
            "max_length": float(self.max_length.min()),
            "cable_limits": {"tmin": self.tmin.tolist(), "tmax": self.tmax.tolist(),
                             "max_length": self.max_length.tolist()},
            "max_speed": self.max_speed,
            "home": {"position": self.home_position.tolist(), "rotation": self.home_rotation.tolist()},
            "frame_points": self.frame_points.tolist(),
            "platform_points": self.platform_points.tolist(),
            **({"encoder_offsets": self.encoder_offsets.tolist()} if self.encoder_offsets.any() else {}),
        }
