"""Interference at one pose: how close each cable's free span comes to the other cables, to the platform and to the
scene's obstacles, and the floor. Pure numpy, no I/O; the distances are :mod:`cdpr.mechanics.distance`'s.

* A cable's free span is the segment from where it leaves the frame (a_i, over a pulley its tangent point T_i) to
  its platform point B_i (world frame).
* Cable–cable: every pair's segment distance, but for two cables that share an end (CAROCA's pairs leave the
  frame at one point): they meet there by design, and are not compared (a distance from a shared point says
  nothing about a margin).
* Cable–platform: a cable leaves its platform point on the platform's box (centred on the robot file's platform
  frame, its axes); the box being convex, the cable runs through it exactly when it leaves into the box, i.e. when
  its direction u has u·n < 0 for the outward normal n of every face its point lies on. The clearance is the angle
  ``asin(max_n u·n)`` (rad): how far the cable turns before it enters (a distance from a point on the box would
  be 0 always). A point off the box's surface is not checked.
* Cable–obstacle: the segment against each obstacle (box, cylinder, sphere, mesh); the floor: the lowest point of
  any span above ``floor``.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cdpr.mechanics import distance as dist
from cdpr.mechanics.pulley import pulley_geometry
from cdpr.mechanics.robot import Robot
from cdpr.mechanics.rotation import Array

SHARED = 1e-6  # m: two cables whose ends are this close share that end
_ON_FACE = 1e-9  # m: a platform point this close to a face's plane lies on it


@dataclass(frozen=True)
class Obstacle:
    """A solid obstacle, world frame: ``kind`` box (``size`` = full sizes), cylinder (``radius``, ``length``, axis
    along its z), sphere (``radius``) or mesh (``triangles`` (n, 3, 3), its surface)."""

    name: str
    kind: str
    position: Array
    rotation: Array
    size: Array = field(default_factory=lambda: np.zeros(3))
    radius: float = 0.0
    length: float = 0.0
    triangles: Array | None = None

    def distance(self, p0: Array, p1: Array) -> dist.Closest:
        if self.kind == "box":
            return dist.segment_box(p0, p1, self.position, self.rotation, 0.5 * self.size)
        if self.kind == "cylinder":
            return dist.segment_cylinder(p0, p1, self.position, self.rotation, self.radius, 0.5 * self.length)
        if self.kind == "sphere":
            return dist.segment_sphere(p0, p1, self.position, self.radius)
        assert self.triangles is not None
        return dist.segment_mesh(p0, p1, self.triangles)


@dataclass(frozen=True)
class Nearest:
    """The least distance of one kind at a pose, and between what: cables ``i`` (and ``j``), obstacle ``other``."""

    distance: float
    i: int = -1
    j: int = -1
    other: str = ""


@dataclass(frozen=True)
class Clearances:
    cable_cable: Nearest
    cable_platform: Nearest  # an angle, rad (module docstring)
    cable_obstacle: Nearest
    floor: Nearest  # the lowest span's height above the floor (inf without a floor)


def spans(robot: Robot, position: ArrayLike, R: ArrayLike) -> tuple[Array, Array]:
    """(exits, platform points): each cable's free span, frame end first (m, 3) each, world frame."""
    Rm = np.asarray(R, dtype=float)
    B = np.asarray(position, dtype=float) + np.asarray(robot.platform_points) @ Rm.T
    if robot.pulleys is None:
        return np.array(robot.frame_points, dtype=float), B
    return pulley_geometry(robot.frame_points, robot.pulleys, B).tangent_points, B


def pair_sides(exits: Array, points: Array) -> tuple[Array, Array, Array, Array, Array]:
    """For every pair of cables that share no end: (i, j, side, interior). ``side`` is the sign of
    ``(d_i × d_j) · (e_j − e_i)`` (d: the spans, e: their frame ends) — which side of each other the two lines
    pass; it flips when they cross. ``interior``: the lines' closest points lie within both spans. Between two
    poses, a pair whose side flipped with its closest points within the spans has crossed: two cables passed
    through each other, which a distance at each pose alone can miss — unless the side flipped because the spans
    turned through parallel (their normal ``d_i × d_j`` reversed, also returned: compare it across the poses)."""
    m = len(exits)
    i, j = np.triu_indices(m, 1)
    apart = ((np.linalg.norm(exits[i] - exits[j], axis=1) > SHARED)
             & (np.linalg.norm(points[i] - points[j], axis=1) > SHARED))
    i, j = i[apart], j[apart]
    d1, d2, r = points[i] - exits[i], points[j] - exits[j], exits[i] - exits[j]
    normal = np.cross(d1, d2)
    side = np.sign(np.einsum("ni,ni->n", normal, -r))
    a, e, b = (np.einsum("ni,ni->n", x, y) for x, y in ((d1, d1), (d2, d2), (d1, d2)))
    c, f = np.einsum("ni,ni->n", d1, r), np.einsum("ni,ni->n", d2, r)
    denom = a * e - b * b
    with np.errstate(divide="ignore", invalid="ignore"):
        s, t = (b * f - c * e) / denom, (a * f - b * c) / denom
    interior = (denom > 0.0) & (s >= 0.0) & (s <= 1.0) & (t >= 0.0) & (t <= 1.0)
    return i, j, side, interior, normal


def cable_pairs(robot: Robot, exits: Array, points: Array) -> Nearest:
    """The nearest pair of cables that share no end (module docstring)."""
    m = len(exits)
    i, j = np.triu_indices(m, 1)
    apart = ((np.linalg.norm(exits[i] - exits[j], axis=1) > SHARED)
             & (np.linalg.norm(points[i] - points[j], axis=1) > SHARED))
    i, j = i[apart], j[apart]
    if not len(i):
        return Nearest(np.inf)
    d = dist.segment_distances(exits[i], points[i], exits[j], points[j])[0]
    k = int(np.argmin(d))
    return Nearest(float(d[k]), int(i[k]), int(j[k]))


def cable_platform(robot: Robot, exits: Array, points: Array, position: ArrayLike, R: ArrayLike) -> Nearest:
    """The cable nearest to running into the platform's box (module docstring), as an angle (rad): positive while
    every cable leaves its platform point outwards; inf for a platform that is no box."""
    if robot.shape.type != "box":
        return Nearest(np.inf)
    Rm = np.asarray(R, dtype=float)
    half = 0.5 * np.asarray(robot.shape.size, dtype=float)
    local_b = np.asarray(robot.platform_points) + np.asarray(robot.com_offset)  # the robot file's (box's) frame
    u = (exits - points) @ Rm  # each cable's direction, platform → frame, box frame
    u /= np.linalg.norm(u, axis=1)[:, None]
    # outward normals of the faces each point lies on: ±e_k where |b_k| = h_k
    on = np.abs(np.abs(local_b) - half) < _ON_FACE
    outward = np.where(on, np.sign(local_b) * u, -np.inf)  # u · n for each face it lies on
    inside = np.all(np.abs(local_b) < half + _ON_FACE, axis=1) & on.any(axis=1)
    angle = np.where(inside, np.arcsin(np.clip(outward.max(axis=1), -1.0, 1.0)), np.inf)
    k = int(np.argmin(angle))
    return Nearest(float(angle[k]), k) if np.isfinite(angle[k]) else Nearest(np.inf)


def clearances(robot: Robot, position: ArrayLike, R: ArrayLike, obstacles: tuple[Obstacle, ...] = (),
               floor: float | None = None, free_spans: tuple[Array, Array] | None = None) -> Clearances:
    """Every kind's nearest at the pose (the centre of mass at ``position``, orientation ``R``; ``free_spans``:
    :func:`spans` of that pose, when the caller has them)."""
    exits, points = spans(robot, position, R) if free_spans is None else free_spans
    obstacle = Nearest(np.inf)
    for ob in obstacles:
        for i in range(len(exits)):
            d = ob.distance(exits[i], points[i]).distance
            if d < obstacle.distance:
                obstacle = Nearest(d, i, other=ob.name)
    low = Nearest(np.inf)
    if floor is not None:
        z = np.minimum(exits[:, 2], points[:, 2]) - floor
        k = int(np.argmin(z))
        low = Nearest(float(z[k]), k, other="floor")
    return Clearances(cable_pairs(robot, exits, points), cable_platform(robot, exits, points, position, R),
                      obstacle, low)


def interference_free(robot: Robot, positions: ArrayLike, R: ArrayLike, margin: float = 0.0
                      ) -> tuple[NDArray[np.bool_], Array]:
    """At each position (n, 3) with the orientation R: whether no two cables (that share no end) come within
    ``margin`` and no cable runs into the platform (:func:`cable_pairs`, :func:`cable_platform`, vectorised), and
    the least cable–cable distance there. Returns (free (n,) bool, distance (n,))."""
    P = np.asarray(positions, dtype=float).reshape(-1, 3)
    Rm = np.asarray(R, dtype=float)
    if len(P) == 0:
        return np.zeros(0, dtype=bool), np.zeros(0)
    B = P[:, None, :] + (np.asarray(robot.platform_points) @ Rm.T)[None]  # (n, m, 3)
    if robot.pulleys is None:
        E = np.broadcast_to(np.asarray(robot.frame_points, dtype=float), B.shape)
    else:
        E = pulley_geometry(robot.frame_points, robot.pulleys, B).tangent_points
    m = robot.m
    i, j = np.triu_indices(m, 1)
    a, b = np.asarray(robot.frame_points), np.asarray(robot.platform_points)  # ends shared by design: the robot's
    apart = (np.linalg.norm(a[i] - a[j], axis=1) > SHARED) & (np.linalg.norm(b[i] - b[j], axis=1) > SHARED)
    i, j = i[apart], j[apart]
    nearest = np.full(len(P), np.inf)
    if len(i):
        nearest = dist.segment_distances(E[:, i], B[:, i], E[:, j], B[:, j])[0].min(axis=1)
    free = nearest > margin
    if robot.shape.type == "box":
        half = 0.5 * np.asarray(robot.shape.size, dtype=float)
        local_b = np.asarray(robot.platform_points) + np.asarray(robot.com_offset)
        on = np.abs(np.abs(local_b) - half) < _ON_FACE  # (m, 3): the faces each point lies on
        checked = np.all(np.abs(local_b) < half + _ON_FACE, axis=1) & on.any(axis=1)
        u = (E - B) @ Rm  # (n, m, 3) box frame
        outward = np.where(on[None], np.sign(local_b)[None] * u, -np.inf).max(axis=2)  # (n, m)
        free &= ~np.any(checked[None] & (outward <= 0.0), axis=1)
    return np.asarray(free, dtype=bool), np.asarray(nearest, dtype=float)
