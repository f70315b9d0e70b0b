"""Desired-pose trajectories: 5th-order polynomial waypoints and the pick-and-place S-curve.

Pure numpy, no I/O. A :class:`Trajectory` maps a time ``t`` (s) to a :class:`Setpoint`: the desired
pose of the platform's centre of mass, its twist ``[v; ω]`` and its acceleration ``[a; α]``, all in the
world frame (the controller's x_d, ẋ_d, ẍ_d of the seed paper, section 4.1). Before the first waypoint
the first pose is held, after the last one the final pose is held, both with zero twist and acceleration.

Interpolation (:class:`QuinticWaypoints`)
-----------------------------------------
Between waypoints a (at t_a) and b (at t_b), with h = t_b − t_a and τ = (t − t_a)/h ∈ [0, 1]::

    s(τ) = 10τ³ − 15τ⁴ + 6τ⁵        ṡ = 30τ²(1 − τ)²/h        s̈ = 60τ(1 − τ)(1 − 2τ)/h²
    x(t) = x_a + (x_b − x_a)·s       R(t) = R_a · exp(s·[r]×),  r = log(R_aᵀ R_b)

so velocity and acceleration are zero at every waypoint, and position, velocity and acceleration are
continuous everywhere. The orientation follows the shortest geodesic on SO(3) (rotation angle ≤ π).
Because ``exp(s[r]×) r = r``, the world-frame angular velocity and acceleration are simply
``ω = R_a r ṡ`` and ``α = R_a r s̈`` (a fixed axis per segment).

Scenario YAML schema (:func:`trajectory_from_spec`, :class:`TrajectorySpec`)
---------------------------------------------------------------------------
Units are SI, angles are radians, roll-pitch-yaw as in :mod:`cdpr.mechanics.rotation`. Two forms, chosen by ``type``::

    type: quintic
    waypoints:                      # at least 2, times strictly increasing
      - {t: 0.0,  position: [0, 0, 0.2], rpy: [0, 0, 0]}
      - {t: 10.0, position: [0, 0, 1.2]}          # rpy omitted: keep the previous waypoint's
      - {t: 20.0, position: [0.9, 0.9, 1.2], rpy: [0, 0, 0.3]}

    type: scurve                    # lift vertically, travel, lower vertically
    start: [0.9, 0.9, 0.2]
    goal: [-0.9, -0.9, 1.0]
    pass_height: 1.3                # absolute travel height, or [0.6, 1.3]: height above start, above goal
    # lift_height: 0.5              # instead of pass_height: travel at start z + lift_height
    t_start: 0.0                    # optional, default 0: the motion starts here
    times: [5.0, 25.0, 30.0]        # absolute end times of the lift, travel and lower phases
    start_rpy: [0, 0, 0]            # optional, default [0, 0, 0]
    goal_rpy: [0, 0, 0]             # optional, default start_rpy; the rotation happens during travel

Unknown keys, missing keys, non-finite numbers and inconsistent values raise ``ValueError`` naming the
field, e.g. ``trajectory: quintic.waypoints.1.position.2: Input should be a finite number (got nan)`` or
``trajectory: quintic: waypoints.2.t: times must be strictly increasing (got 5.0 after 5.0)``.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from bisect import bisect_right
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import ArrayLike

from cdpr.mechanics.rotation import (
    Array,
    matrices_to_quats,
    matrix_to_quat,
    matrix_to_rotvec,
    readonly,
    rpy_to_matrix,
    skew,
)

__all__ = [
    "Block",
    "QuinticWaypoints",
    "SCurve",
    "Setpoint",
    "Trajectory",
]


@dataclass(frozen=True, eq=False)
class Setpoint:
    """The desired state at one instant. Arrays are read-only (a setpoint may be shared between calls)."""

    position: Array  # (3,) world, centre of mass
    rotation: Array  # (3, 3) platform → world
    twist: Array  # (6,) [v; ω] world frame
    accel: Array  # (6,) [a; α] world frame

    @property
    def quaternion(self) -> Array:
        """The rotation as a unit quaternion [qx, qy, qz, qw] (qw ≥ 0)."""
        return matrix_to_quat(self.rotation)


@dataclass(frozen=True, eq=False)
class Block:
    """The setpoints at n instants, row by row (:meth:`Trajectory.sample_block`): what n :meth:`~Trajectory.sample`
    calls give, bit for bit, as arrays."""

    position: Array  # (n, 3)
    rotation: Array  # (n, 3, 3)
    twist: Array  # (n, 6)
    accel: Array  # (n, 6)

    @property
    def quaternion(self) -> Array:
        """(n, 4) the rotations as unit quaternions [qx, qy, qz, qw] (qw ≥ 0), each as :attr:`Setpoint.quaternion`."""
        return matrices_to_quats(self.rotation)


def _hold(position: Array, rotation: Array) -> Setpoint:
    """A resting setpoint: the pose with zero twist and acceleration."""
    return Setpoint(
        readonly(np.array(position, dtype=float)),
        readonly(np.array(rotation, dtype=float)),
        readonly(np.zeros(6)),
        readonly(np.zeros(6)),
    )


class Trajectory(ABC):
    """A desired-pose source: ``sample(t)`` for any finite t, holding the end poses outside the motion."""

    duration: float  # time of the last waypoint (absolute, s)

    @abstractmethod
    def sample(self, t: float) -> Setpoint:
        """The setpoint at time ``t`` (s)."""

    @abstractmethod
    def waypoints(self) -> list[tuple[float, Array]]:
        """(time, position) of each waypoint, in time order, for drawing and checks."""

    def sample_block(self, times: ArrayLike) -> Block:
        """The setpoints at ``times`` (s, (n,)): :meth:`sample` at each, bit for bit, as a :class:`Block`
        (a trajectory that can samples them all at once: a block of 100 costs about what 5 samples do)."""
        samples = [self.sample(float(t)) for t in np.asarray(times, dtype=float).reshape(-1)]
        return Block(*(np.array([getattr(x, f) for x in samples]).reshape(len(samples), *shape)
                       for f, shape in (("position", (3,)), ("rotation", (3, 3)), ("twist", (6,)), ("accel", (6,)))))


class PlatformPoint(Trajectory):
    """The motion of the point ``offset`` (platform frame) of a platform whose frame follows ``frame``: where a
    robot's centre of mass goes when its trajectory is given for a platform frame whose origin is not the COM.

    p = p_f + R c, v = v_f + ω × R c, a = a_f + α × R c + ω × (ω × R c); the rotation, ω and α are the frame's.
    """

    def __init__(self, frame: Trajectory, offset: ArrayLike) -> None:
        self.frame = frame
        self.offset = readonly(_as_vec3(offset, "offset"))
        self.duration = frame.duration

    def sample(self, t: float) -> Setpoint:
        s = self.frame.sample(t)
        r = s.rotation @ self.offset  # R c, world frame
        w, alpha = s.twist[3:], s.accel[3:]
        w_r = np.cross(w, r)
        twist = np.r_[s.twist[:3] + w_r, w]
        accel = np.r_[s.accel[:3] + np.cross(alpha, r) + np.cross(w, w_r), alpha]
        return Setpoint(readonly(s.position + r), s.rotation, readonly(twist), readonly(accel))

    def sample_block(self, times: ArrayLike) -> Block:
        b = self.frame.sample_block(times)
        r = np.array([R @ self.offset for R in b.rotation]).reshape(-1, 3)  # as sample() multiplies, row by row
        w, alpha = b.twist[:, 3:], b.accel[:, 3:]
        w_r = np.cross(w, r)
        twist = np.hstack((b.twist[:, :3] + w_r, w))
        accel = np.hstack((b.accel[:, :3] + np.cross(alpha, r) + np.cross(w, w_r), alpha))
        return Block(b.position + r, b.rotation, twist, accel)

    def waypoints(self) -> list[tuple[float, Array]]:
        return [(t, self.sample(t).position.copy()) for t, _ in self.frame.waypoints()]


def _as_points(values: ArrayLike, n: int | None, name: str) -> Array:
    """``values`` as an (n, 3) finite float array, or ValueError naming ``name``."""
    try:
        a = np.array(values, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be a list of [x, y, z] triples of numbers") from None
    if a.ndim != 2 or a.shape[1] != 3:
        raise ValueError(f"{name} must be a list of [x, y, z] triples (got shape {a.shape})")
    if n is not None and a.shape[0] != n:
        raise ValueError(f"{name} must have one entry per waypoint ({n}), got {a.shape[0]}")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite")
    return a


def _as_vec3(values: ArrayLike, name: str) -> Array:
    try:
        a = np.array(values, dtype=float)
    except (TypeError, ValueError):
        raise ValueError(f"{name} must be 3 numbers") from None
    if a.shape != (3,):
        raise ValueError(f"{name} must be 3 numbers (got shape {a.shape})")
    if not np.all(np.isfinite(a)):
        raise ValueError(f"{name} must be finite (got {a.tolist()})")
    return a


class QuinticWaypoints(Trajectory):
    """Rest-to-rest quintic segments through waypoints (zero velocity and acceleration at each).

    ``times`` (s, strictly increasing, at least 2), ``positions`` (n × 3, world, centre of mass) and
    optionally ``rpys`` (n × 3, radians; identity orientation if omitted). See the module docstring for
    the formulas.
    """

    def __init__(
        self,
        times: Sequence[float],
        positions: Sequence[Sequence[float]],
        rpys: Sequence[Sequence[float]] | None = None,
    ) -> None:
        try:
            t = np.array(times, dtype=float)
        except (TypeError, ValueError):
            raise ValueError("times must be a list of numbers") from None
        if t.ndim != 1:
            raise ValueError(f"times must be a flat list of numbers (got shape {t.shape})")
        if t.size < 2:
            raise ValueError(f"a trajectory needs at least 2 waypoints (got {t.size})")
        if not np.all(np.isfinite(t)):
            raise ValueError("times must be finite")
        bad = np.flatnonzero(np.diff(t) <= 0.0)
        if bad.size:
            i = int(bad[0]) + 1
            raise ValueError(f"times must be strictly increasing (times[{i}] = {t[i]} after {t[i - 1]})")
        n = t.size
        x = _as_points(positions, n, "positions")
        R = np.repeat(np.eye(3)[None], n, axis=0) if rpys is None else _rotations(_as_points(rpys, n, "rpys"))

        self.duration = float(t[-1])
        self._times: list[float] = t.tolist()
        self._points = x
        self._x0 = x[:-1].copy()
        self._dx = np.diff(x, axis=0)
        self._inv_h = 1.0 / np.diff(t)
        # Orientation per segment: R(s) = R_a + sin(sθ)·R_a K + (1 − cos(sθ))·R_a K², K = [r/θ]× (Rodrigues).
        m = n - 1
        self._R0 = R[:-1].copy()
        self._RK = np.zeros((m, 3, 3))
        self._RK2 = np.zeros((m, 3, 3))
        self._theta = np.zeros(m)
        self._axis_world = np.zeros((m, 3))  # R_a r: ω = (R_a r) ṡ
        for i in range(m):
            r = matrix_to_rotvec(R[i].T @ R[i + 1])
            theta = float(np.linalg.norm(r))
            self._axis_world[i] = R[i] @ r
            if theta > 0.0:
                K = skew(r / theta)
                self._theta[i] = theta
                self._RK[i] = R[i] @ K
                self._RK2[i] = R[i] @ K @ K
        self._first = _hold(x[0], R[0])
        self._last = _hold(x[-1], R[-1])

    @property
    def times(self) -> list[float]:
        """Waypoint times (s)."""
        return list(self._times)

    def waypoints(self) -> list[tuple[float, Array]]:
        return [(t, p.copy()) for t, p in zip(self._times, self._points, strict=True)]

    def sample(self, t: float) -> Setpoint:
        t = float(t)
        if not math.isfinite(t):
            raise ValueError(f"sample time must be finite (got {t})")
        if t <= self._times[0]:
            return self._first
        if t >= self.duration:
            return self._last
        i = bisect_right(self._times, t) - 1
        inv_h = float(self._inv_h[i])
        tau = (t - self._times[i]) * inv_h
        u = 1.0 - tau
        s = tau * tau * tau * (10.0 - 15.0 * tau + 6.0 * tau * tau)
        ds = 30.0 * tau * tau * u * u * inv_h
        dds = 60.0 * tau * u * (1.0 - 2.0 * tau) * inv_h * inv_h

        dx = self._dx[i]
        position = self._x0[i] + s * dx
        a = s * self._theta[i]
        rotation = self._R0[i] + math.sin(a) * self._RK[i] + (1.0 - math.cos(a)) * self._RK2[i]
        twist = np.empty(6)
        twist[:3] = ds * dx
        twist[3:] = ds * self._axis_world[i]
        accel = np.empty(6)
        accel[:3] = dds * dx
        accel[3:] = dds * self._axis_world[i]
        return Setpoint(readonly(position), readonly(rotation), readonly(twist), readonly(accel))

    def sample_block(self, times: ArrayLike) -> Block:
        """:meth:`sample` at every time at once: the same operations in the same order on arrays (numpy's
        elementwise arithmetic rounds as Python's; the angles' sines with :mod:`math`, as there): bit for bit."""
        t = np.asarray(times, dtype=float).reshape(-1)
        if not np.isfinite(t).all():
            raise ValueError(f"sample time must be finite (got {t[~np.isfinite(t)][0]})")
        n = t.size
        position, rotation = np.empty((n, 3)), np.empty((n, 3, 3))
        twist, accel = np.zeros((n, 6)), np.zeros((n, 6))
        before, after = t <= self._times[0], t >= self.duration
        for mask, hold in ((before, self._first), (after & ~before, self._last)):
            position[mask], rotation[mask] = hold.position, hold.rotation
        moving = ~(before | after)
        if moving.any():
            tm = t[moving]
            i = np.searchsorted(self._times, tm, side="right") - 1  # bisect_right − 1
            inv_h = self._inv_h[i]
            tau = (tm - np.asarray(self._times)[i]) * inv_h
            u = 1.0 - tau
            s = tau * tau * tau * (10.0 - 15.0 * tau + 6.0 * tau * tau)
            ds = (30.0 * tau * tau * u * u * inv_h)[:, None]
            dds = (60.0 * tau * u * (1.0 - 2.0 * tau) * inv_h * inv_h)[:, None]
            dx, axis = self._dx[i], self._axis_world[i]
            position[moving] = self._x0[i] + s[:, None] * dx
            a = (s * self._theta[i]).tolist()
            sin_a = np.array([math.sin(x) for x in a])[:, None, None]
            one_minus_cos = np.array([1.0 - math.cos(x) for x in a])[:, None, None]
            rotation[moving] = self._R0[i] + sin_a * self._RK[i] + one_minus_cos * self._RK2[i]
            twist[moving] = np.hstack((ds * dx, ds * axis))
            accel[moving] = np.hstack((dds * dx, dds * axis))
        return Block(position, rotation, twist, accel)


def _rotations(rpys: Array) -> Array:
    return np.array([rpy_to_matrix(*rpy) for rpy in rpys])


class SCurve(Trajectory):
    """Pick-and-place: lift vertically from ``start``, travel to above ``goal``, lower onto ``goal``.

    Parameters (SI, radians):

    * ``start``, ``goal``: (3,) centre-of-mass positions to pick from and place at.
    * ``lift_height``: travel height relative to the start, z = start_z + lift_height (≥ 0). Give either
      it or the keyword ``pass_height``, not both (pass ``None`` for the one not used).
    * ``pass_height``: absolute travel height z, or a pair (z above start, z above goal): the travel
      phase then climbs or descends in a straight line between the two. Each must be ≥ the z of its end
      point, so the lift goes up and the lowering goes down.
    * ``t_lift``, ``t_travel``, ``t_lower``: phase durations (s, > 0); the motion starts at ``t_start``.
    * ``start_rpy``, ``goal_rpy``: orientations (default zero, and ``goal_rpy`` defaults to
      ``start_rpy``); the rotation happens during travel only, lift and lowering keep the orientation.

    Each phase is a rest-to-rest quintic (zero velocity and acceleration at the phase ends; the corners
    are not blended), i.e. a :class:`QuinticWaypoints` through the four corner points.
    """

    def __init__(
        self,
        start: ArrayLike,
        goal: ArrayLike,
        lift_height: float | None,
        t_lift: float,
        t_travel: float,
        t_lower: float,
        start_rpy: ArrayLike | None = None,
        goal_rpy: ArrayLike | None = None,
        t_start: float = 0.0,
        *,
        pass_height: float | Sequence[float] | None = None,
    ) -> None:
        a = _as_vec3(start, "start")
        b = _as_vec3(goal, "goal")
        if (lift_height is None) == (pass_height is None):
            raise ValueError(
                "give exactly one of lift_height (relative to start) and pass_height (absolute z)"
            )
        if lift_height is not None:
            lift = float(lift_height)
            if not (math.isfinite(lift) and lift >= 0.0):
                raise ValueError(f"lift_height must be finite and >= 0 (got {lift_height})")
            z_up = z_down = a[2] + lift
        else:
            try:
                heights = np.atleast_1d(np.asarray(pass_height, dtype=float))
            except (TypeError, ValueError):
                raise ValueError(
                    f"pass_height must be a number or a pair of numbers (got {pass_height!r})"
                ) from None
            if heights.shape not in ((1,), (2,)) or not np.all(np.isfinite(heights)):
                raise ValueError(
                    f"pass_height must be one finite height or a pair of them (got {pass_height})"
                )
            z_up, z_down = float(heights[0]), float(heights[-1])
        if z_up < a[2]:
            raise ValueError(f"pass_height {z_up} is below the start height {a[2]}: the lift must go up")
        if z_down < b[2]:
            raise ValueError(
                f"pass_height {z_down} is below the goal height {b[2]}: the lowering must go down"
            )
        durations = {"t_lift": t_lift, "t_travel": t_travel, "t_lower": t_lower}
        for name, value in durations.items():
            if not (math.isfinite(float(value)) and float(value) > 0.0):
                raise ValueError(f"{name} must be a finite duration > 0 (got {value})")
        t0 = float(t_start)
        if not math.isfinite(t0):
            raise ValueError(f"t_start must be finite (got {t_start})")

        rpy_a = np.zeros(3) if start_rpy is None else _as_vec3(start_rpy, "start_rpy")
        rpy_b = rpy_a if goal_rpy is None else _as_vec3(goal_rpy, "goal_rpy")
        t1 = t0 + float(t_lift)
        t2 = t1 + float(t_travel)
        t3 = t2 + float(t_lower)
        self._path = QuinticWaypoints(
            [t0, t1, t2, t3],
            np.array([a, [a[0], a[1], z_up], [b[0], b[1], z_down], b]).tolist(),
            np.array([rpy_a, rpy_a, rpy_b, rpy_b]).tolist(),
        )
        self.duration = t3
        self.phase_times: tuple[float, float, float, float] = (t0, t1, t2, t3)
        """Start of the lift, end of the lift, end of the travel, end of the lowering (s)."""

    def sample(self, t: float) -> Setpoint:
        return self._path.sample(t)

    def sample_block(self, times: ArrayLike) -> Block:
        return self._path.sample_block(times)

    def waypoints(self) -> list[tuple[float, Array]]:
        return self._path.waypoints()
