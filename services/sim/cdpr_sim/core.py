"""Physics core of the sim service: the platform as a DART rigid body pulled by m cables. No I/O.

Model (seed paper §2.3 and §3.1)
--------------------------------
* The platform is one rigid body with the robot's mass and full 3×3 inertia about its centre of mass
  (the body origin). Gravity is (0, 0, −9.81) in every mode.
* Joint to the world, per robot mode:

  - ``spatial`` and ``point_mass``: a DART ``FreeJoint`` (6 DOF). A point-mass robot is the same free
    body with every cable attached at the centre of mass, so the cables exert no moment on it.
  - ``planar``: a DART ``PlanarJoint`` in the robot's plane: ZX for ``xz`` (translations along z and x,
    rotation about +y), XY for ``xy`` (along x and y, rotation about +z; the joint holds the weight, as a
    table would). The constraint is exact, in joint coordinates: the body has 3 DOF, so the coordinate along
    the plane's normal, and the rotations about the in-plane axes, cannot change (no penalty, no drift).

* Cables are massless, inextensible, pull-only force elements. Each step applies the tension
  ``f_i ∈ [0, tmax]`` (see :func:`clamp_tensions`) along the unit vector ``d_i`` from ``t + R b_i`` to
  ``a_i``. The cable's length is not a constraint: a tension-controlled winch pays cable in or out as
  needed, so only the force's line of action matters. The wrench on the platform is ``W f`` exactly as
  in :mod:`cdpr.mechanics.kinematics` (force ``Σ f_i d_i`` and moment ``Σ (R b_i) × f_i d_i`` about the COM).
  It is computed from the cables' Plücker coordinates and handed to DART as the joint's generalized
  forces (both below).
* Cable damping (``robot.cable_damping`` = c, N·s/m): the paper's cable is an actuated prismatic joint
  with viscous damping, whose force opposes the cable's length rate. On the platform this is the extra,
  bilateral, force ``c·l̇_i`` along ``d_i``: a lengthening cable (l̇_i > 0) pulls the platform back, a
  shortening one pushes it, and its power ``−Σ c·l̇_i²`` is never positive. It is evaluated with the
  twist at the start of the step and reported in :attr:`StepReport.damping`, apart from the tensions.
  The passive U/S joint damping of the Gazebo model (``robot.passive_damping``) has no counterpart in a
  single-body model and is not simulated.
* Integration: DART's ``World.step``, semi-implicit (symplectic) Euler, forces evaluated at
  ``(q_k, v_k)``: ``v_{k+1} = v_k + dt·M⁻¹(W f + w_g − C v_k)``, then the pose moves with the *new*
  twist: ``t_{k+1} = t_k + dt·ṫ_{k+1}`` and ``R_{k+1} = exp(dt [ω_{k+1}]×) R_k`` (DART evaluates exp by
  its Taylor series for small angles, error < θ³/6). With dartpy 6.20's ``FreeJoint`` this holds for the
  world-frame twist at the COM, so ``(v_{k+1} − v_k)/dt`` equals :func:`cdpr.mechanics.dynamics.forward_dynamics`
  to rounding (tested). Local error O(dt²), global O(dt): a free fall from rest is ``g·t·dt/2`` below
  ``g t²/2``. DART's body deactivation ("sleeping", on by default in dartpy 6.20's World: thresholds
  1 cm/s and 0.05 rad/s held for 0.5 s) is switched off, so a slow platform is never frozen.

Reading and writing DART
------------------------
The body is read once per step, as its joint's generalized coordinates, which in dartpy 6.20 are all in
the world frame (tested): a ``FreeJoint``'s positions are ``[r; t]`` (r the rotation vector of R, t the
COM) and its velocities ``[ω; ṫ]`` (the twist at the COM, angular first: what ``getAngularVelocity`` and
``getLinearVelocity`` return, to the last bit); a ZX ``PlanarJoint``'s are ``[z, x, θ_y]`` and
``[ż, ẋ, θ̇_y]``, an XY one's ``[x, y, θ_z]`` and ``[ẋ, ẏ, θ̇_z]``. R is the matrix of r's quaternion (DART's
own R to rounding, tested). A free body's pose and twist are written through the ``FreeJoint``'s world-frame
setters, a planar body's as its coordinates.
Dually, the joint's generalized forces are the wrench about the COM, world frame: ``[M; F]`` for a
``FreeJoint`` (the same step, to the last bit or so, as ``setExtForce`` at the COM plus ``setExtTorque``, tested),
``[F_z, F_x, M_y]`` for the ZX planar joint, ``[F_x, F_y, M_z]`` for the XY one; ``World.step`` zeroes them after
each step.

The cables in Plücker coordinates
---------------------------------
Cable i's line of action, through ``a_i`` along ``d_i``, has the Plücker coordinates ``G_i = [a_i × d_i; d_i]``
(moment about the world origin first, DART's order). Unnormalised, ``[a_i × l_i; l_i]`` is *linear* in R
and t: ``l_i = a_i − t − R b_i`` and ``a_i × l_i = −a_i × t − a_i × (R b_i)``; R's entries are linear in the
products of the quaternion's components (``1 − 2(q_y² + q_z²)``, ...). So, once per step, the m of them are
one product of a constant (6m × 13) matrix (:func:`cable_line_map`) with those 9 products, t and 1, and
the lengths ``‖l_i‖`` follow: the numpy calls of a step do not grow with m, and no cross product is
taken. With the twist referred to the world origin, ``[ω; ṫ + t × ω]`` (the velocity of the body point
passing through the origin), the length rates are ``l̇ = −G [ω; ṫ + t × ω]`` (= ``J v``: ``−d_i`` dotted
with the attach point's velocity) and the cables' wrench ``Gᵀ(f + c l̇) = [M_O; F]`` about the origin is
``[M_O − t × F; F]`` about the COM: ``W (f + c l̇)``, to rounding (the moment about the COM is a
difference of moments about the origin, ~|a_i|/|b_i| times larger). A point-mass robot's moment is 0,
exactly, so it never turns.

The same inputs give bit-identical outputs; nothing is random and no module state is mutable.
"""

from __future__ import annotations

import math
import operator
from dataclasses import dataclass, field
from typing import Any, Protocol

import dartpy as dart
import numpy as np
from numpy.typing import ArrayLike

from cdpr.config.scenario import Scenario
from cdpr.mechanics.pulley import pulley_geometry
from cdpr.mechanics.robot import GRAVITY, Robot
from cdpr.mechanics.rotation import Array, matrix_to_quat, quat_matrix, readonly, rotvec_quat, skew
from cdpr.protocol import State
from cdpr.protocol.streams import STATE_COLUMNS

_ORTHONORMAL_TOL = 1e-6  # a rotation given to the sim must satisfy ‖RᵀR − I‖∞ ≤ this, and det R > 0
_PLANAR_TOL = 1e-9  # out-of-plane pose/twist components a planar robot tolerates (then set to 0)
_FORCE_HALF = np.array([0.0, 0.0, 0.0, 1.0, 1.0, 1.0])  # np.square(rows [a_i × l_i; l_i]) @ this: ‖l_i‖²
_FORCE_HALF.flags.writeable = False


def clamp_tensions(commanded: np.ndarray, tmax: float | np.ndarray) -> tuple[np.ndarray, int, int]:
    """What the cables can apply: negatives → 0 (a cable only pulls), above ``tmax`` → ``tmax`` (a number for
    every cable, or one per cable: :func:`tension_ceiling` gives the cheaper form for a robot).

    Returns ``(applied, n_clamped_low, n_clamped_high)``. Pure: ``commanded`` is not modified. ``tmin``
    is not enforced here (that is the controller's business). A NaN raises ``ValueError``.
    """
    f = np.asarray(commanded, dtype=float)
    if f.ndim == 1 and f.size:  # the usual case, a few numbers: reductions on a list beat numpy's
        values = f.tolist()
        within = (max(values) <= tmax if not isinstance(tmax, np.ndarray)
                  else all(map(operator.le, values, tmax.tolist())))
        if not math.isnan(sum(values)) and min(values) >= 0.0 and within:
            return f.copy(), 0, 0  # no NaN (it would make the sum NaN) and nothing to clamp
    if np.isnan(f).any():
        raise ValueError("tensions contain NaN")
    low = int(np.count_nonzero(f < 0.0))
    high = int(np.count_nonzero(f > tmax))
    return np.minimum(np.maximum(f, 0.0), tmax), low, high


def tension_ceiling(robot: Robot) -> float | np.ndarray:
    """``robot.tmax`` as :func:`clamp_tensions` takes it fastest: one number when every cable has the same."""
    return float(robot.tmax[0]) if robot.uniform_limits else robot.tmax


@dataclass(frozen=True)
class PlatformState:
    """The platform after ``step`` steps, world frame, twist at the centre of mass. Arrays are read-only."""

    step: int
    t: float
    position: np.ndarray  # (3,) t, the COM
    quaternion: np.ndarray  # (4,) [qx, qy, qz, qw], qw ≥ 0
    rotation: np.ndarray  # (3, 3) R, platform → world
    twist: np.ndarray  # (6,) [v; ω]
    cable_lengths: np.ndarray  # (m,) ‖a_i − t − R b_i‖
    cable_rates: np.ndarray  # (m,) l̇ = J v
    tensions: np.ndarray  # (m,) as applied (clamped) during the step that led here; zeros at step 0

    @classmethod
    def of(cls, step: int, t: float, position: np.ndarray, rotation: np.ndarray, twist: np.ndarray,
           lengths: np.ndarray, rates: np.ndarray, tensions: np.ndarray) -> PlatformState:
        """A state from read-only arrays (the quaternion is derived from the rotation)."""
        return cls(step, t, position, readonly(matrix_to_quat(rotation)), rotation, twist, lengths, rates, tensions)


@dataclass(frozen=True)
class StepReport:
    """What one step did with the commanded tensions."""

    applied: np.ndarray  # (m,) tensions applied after clamping to [0, tmax]
    clamped_low: int  # how many commanded tensions were below 0
    clamped_high: int  # how many were above tmax
    # (m,) cable damping force c·l̇_i applied along d_i on top of the tensions (> 0 pulls, < 0 pushes)
    damping: np.ndarray = field(default_factory=lambda: np.zeros(0))


class SimModel(Protocol):
    """What the sim service needs of a cable model: :class:`PlatformSim` (ideal cables) and the models of
    :mod:`cdpr_sim.ups`, :mod:`cdpr_sim.elastic` and :mod:`cdpr_sim.sag`, chosen in :mod:`cdpr_sim.models`."""

    robot: Robot
    dt: float
    step_count: int
    fallbacks: int  # steps in which the cable law fell back outside its domain (0 where it cannot)
    fallback_reason: str | None  # why, the last time

    @property
    def t(self) -> float: ...

    def state(self) -> PlatformState:
        """The current state (read-only arrays, safe to keep)."""
        ...

    def message(self, clamped: int) -> State:
        """The current state as a ``sim/state`` message, made by :func:`build` (every column the model's)."""
        ...

    def step(self, command: np.ndarray) -> StepReport:
        """Integrate one step under the command (tensions, or lengths for a winch model)."""
        ...

    def encoder_lengths(self) -> Array:
        """(m,) what length encoders measure: the cable lengths, or what the winches paid out."""
        ...

    def load_cell_tensions(self) -> Array:
        """(m,) what load cells at the frame read: the applied tensions, or the frame-end tensions."""
        ...

    def snapshot(self) -> dict[str, Any]:
        """Everything the model needs to go on from this step, bit for bit: :func:`world_snapshot` plus its
        own state (msgpack-ready: numbers, strings, lists, maps)."""
        ...

    def restore(self, snapshot: dict[str, Any]) -> None:
        """Go on from a :meth:`snapshot` of a model of the same scenario (ValueError if it does not fit)."""
        ...


# One read of the body and its cables (:meth:`PlatformSim._read`): ``(pose, twist, lines, lengths)``. The pose as
# a message has it (x, y, z, qx, qy, qz, qw: the COM t and the unit quaternion of R) and the twist [ω; ṫ] at the
# COM (world frame, angular first as DART has it), Python floats; the cables' unnormalised Plücker coordinates
# [a_i × l_i; l_i] (m, 6) and their lengths ‖l_i‖ (m,).
_Reading = tuple[tuple[float, ...], list[float], Array, Array]


class PlatformBody:
    """The platform of ``robot`` alone in a DART world: a free body (a planar joint in the robot's plane for
    planar robots) with the robot's mass and inertia, gravity on, never put to sleep. The part every
    sim model shares; what pulls on the body is the model's business."""

    def __init__(self, robot: Robot, time_step: float) -> None:
        self.planar = robot.mode == "planar"
        self.plane = robot.plane
        self.world = dart.simulation.World()
        self.world.setGravity(GRAVITY)
        self.world.setTimeStep(time_step)
        sleep = self.world.getDeactivationOptions()
        sleep.mEnabled = False  # a slow platform must never be frozen
        self.world.setDeactivationOptions(sleep)
        skeleton = dart.dynamics.Skeleton("platform")
        if self.planar:
            joint, body = skeleton.createPlanarJointAndBodyNodePair()
            if self.plane == "xy":
                joint.setXYPlane()  # generalized coordinates [x, y, θ about +z]
            else:
                joint.setZXPlane()  # generalized coordinates [z, x, θ about +y]
        else:
            joint, body = skeleton.createFreeJointAndBodyNodePair()
        body.setName("platform")
        body.setInertia(dart.dynamics.Inertia(robot.mass, np.zeros(3), np.array(robot.inertia, dtype=float)))
        self.world.addSkeleton(skeleton)
        self.joint, self.body = joint, body

    def place(self, p: Array, R: Array, v: Array) -> None:
        """Put the body at position ``p``, rotation ``R`` with twist ``v`` = [ṫ; ω] (world frame), with no
        external force on it."""
        if self.planar:
            positions, velocities = planar_coordinates(p, R, v, self.plane)
            self.joint.setPositions(positions)
            self.joint.setVelocities(velocities)
        else:
            tf = dart.math.Isometry3()
            tf.set_rotation(R)
            tf.set_translation(p)
            world = dart.dynamics.Frame.World()
            self.joint.setTransform(tf, world)
            self.joint.setLinearVelocity(v[:3], world, world)
            self.joint.setAngularVelocity(v[3:], world, world)
        self.body.clearExternalForces()


def start_pose(robot: Robot, position: ArrayLike | None, rotation: ArrayLike | None,
               twist: ArrayLike | None) -> tuple[Array, Array, Array]:
    """(p, R, v) of a sim's (re)start, checked: defaults are the robot's home pose, at rest."""
    p = _vector(robot.home_position if position is None else position, 3, "position")
    R = _rotation(robot.home_rotation if rotation is None else rotation)
    return p, R, _vector(np.zeros(6) if twist is None else twist, 6, "twist")


def check_dt(dt: float) -> float:
    """``dt`` as a float; ValueError unless it is a positive finite number of seconds."""
    if not (np.isfinite(dt) and dt > 0.0):
        raise ValueError(f"dt must be a positive finite number of seconds (got {dt})")
    return float(dt)


class PlatformSim:
    """A DART world holding the platform of ``robot``, stepped by cable tensions.

    ``dt`` is the step, s. The initial pose defaults to the robot's home pose and the twist to rest.
    ``t`` is ``step_count * dt`` (computed, not accumulated).
    """

    fallbacks = 0  # the ideal cable's law has no domain to leave (SimModel)
    fallback_reason: str | None = None

    def __init__(
        self,
        robot: Robot,
        dt: float = 1e-3,
        position: ArrayLike | None = None,
        rotation: ArrayLike | None = None,
        twist: ArrayLike | None = None,
    ) -> None:
        self.robot = robot
        self.dt = check_dt(dt)
        self.step_count = 0
        self._line_map = cable_line_map(robot.frame_points, robot.platform_points)
        self._minus_c = -float(robot.cable_damping)
        self._platform = PlatformBody(robot, self.dt)
        self._world, self._joint = self._platform.world, self._platform.joint
        self._planar = self._platform.planar and robot.plane == "xz"  # a ZX joint's coordinates
        self._horizontal = self._platform.planar and robot.plane == "xy"  # an XY joint's
        self._tmax = tension_ceiling(self.robot)
        self._pulleys = robot.pulleys
        self._point_mass = robot.mode == "point_mass"
        self._shape = (robot.m,)  # of a command
        self._tensions = readonly(np.zeros(robot.m))
        self._now: _Reading | None = None  # the current step's reading, from its first use to the next step
        self.reset(position, rotation, twist)

    @classmethod
    def from_scenario(cls, scenario: Scenario) -> PlatformSim:
        """The sim of ``scenario``: its robot and dt, at its initial pose."""
        return cls(scenario.robot, scenario.dt, scenario.initial_position, scenario.initial_rotation)

    @property
    def t(self) -> float:
        return self.step_count * self.dt

    # -- state ------------------------------------------------------------------------------------
    def reset(
        self,
        position: ArrayLike | None = None,
        rotation: ArrayLike | None = None,
        twist: ArrayLike | None = None,
    ) -> None:
        """Back to step 0 at the given pose and twist (defaults: home pose, at rest)."""
        self._platform.place(*start_pose(self.robot, position, rotation, twist))
        self._world.reset()
        self._now = None
        self.step_count = 0
        self._tensions = readonly(np.zeros(self.robot.m))

    def _read(self) -> _Reading:
        """The body now and its cables (:data:`_Reading`), from the joint's coordinates (module docstring),
        at most once per step: what :meth:`message` needs, and the rest of the step's geometry."""
        if self._now is None:
            positions, velocities = self._joint.getPositions().tolist(), self._joint.getVelocities().tolist()
            if self._planar:  # [z, x, θ_y] and [ż, ẋ, θ̇_y]
                (z, x, ry), (dz, dx, wy) = positions, velocities
                rx = rz = y = 0.0
                twist = [0.0, wy, 0.0, dx, 0.0, dz]
            elif self._horizontal:  # [x, y, θ_z] and [ẋ, ẏ, θ̇_z]
                (x, y, rz), (dx, dy, wz) = positions, velocities
                rx = ry = z = 0.0
                twist = [0.0, 0.0, wz, dx, dy, 0.0]
            else:  # [r; t] and [ω; ṫ]
                rx, ry, rz, x, y, z = positions
                twist = velocities
            qx, qy, qz, qw = rotvec_quat(rx, ry, rz)
            if self._pulleys is None:
                features = (qx * qx, qy * qy, qz * qz, qx * qy, qx * qz, qy * qz, qx * qw, qy * qw, qz * qw, x, y, z,
                            1.0)
                unnormalised = (self._line_map @ np.array(features)).reshape(-1, 6)  # rows [a_i × l_i; l_i]
                lengths = np.sqrt(np.square(unnormalised) @ _FORCE_HALF)
            else:  # each cable's line leaves its pulley at T_i: rows [T_i × d_i; d_i]·l_i
                unnormalised, lengths = self._over_pulleys((x, y, z), quat_matrix(qx, qy, qz, qw))
            self._now = ((x, y, z, qx, qy, qz, qw), twist, unnormalised, lengths)
        return self._now

    def _over_pulleys(self, t: tuple[float, float, float], R: Array) -> tuple[Array, Array]:
        """The cables' unnormalised Plücker rows and lengths over their exit pulleys (:mod:`cdpr.mechanics.pulley`):
        the line of cable i passes through T_i, where it leaves the wheel, along the free span d_i; its length
        is the wrapped arc plus the span."""
        assert self._pulleys is not None
        g = pulley_geometry(self.robot.frame_points, self._pulleys, np.array(t) + self.robot.platform_points @ R.T)
        d = g.free_spans / g.free_lengths[:, None]
        return np.hstack((np.cross(g.tangent_points, d), d)) * g.lengths[:, None], g.lengths

    def state(self) -> PlatformState:
        """The current state. Its arrays are read-only and never change afterwards: safe to keep."""
        pose, twist, unnormalised, lengths = self._read()
        rates = (unnormalised @ origin_twist(pose, twist, -1.0)) / lengths  # l̇ = −G [ω; ṫ + t × ω] = J v
        return PlatformState(self.step_count, self.t, readonly(np.array(pose[:3])), readonly(np.array(pose[3:])),
                             readonly(quat_matrix(*pose[3:])), readonly(np.array(twist[3:] + twist[:3])),
                             readonly(lengths), readonly(rates), self._tensions)

    def encoder_lengths(self) -> Array:
        """(m,) the cable lengths (an ideal cable's encoder measures them exactly)."""
        return readonly(self._read()[3])

    def load_cell_tensions(self) -> Array:
        """(m,) the tensions applied over the last step."""
        return self._tensions

    def message(self, clamped: int) -> State:
        """The current state as a ``sim/state`` message: ``state_message(self.state(), clamped)``, the same
        numbers, from the least work (pose, twist and cable lengths). The rest of the cables' geometry,
        which the next step needs, waits for :meth:`step` (or :meth:`state`): the sim service sends the
        message first."""
        pose, twist, _, lengths = self._read()
        return build(self.step_count, self.step_count * self.dt, pose, (*twist[3:], *twist[:3]),
                     tuple(lengths.tolist()), tuple(self._tensions.tolist()), clamped)

    def snapshot(self) -> dict[str, Any]:
        return world_snapshot(self._world, self.step_count, self._tensions)

    def restore(self, snapshot: dict[str, Any]) -> None:
        self.step_count, self._tensions = restore_world(self._world, snapshot, self.robot.m)
        self._now = None

    # -- dynamics ---------------------------------------------------------------------------------
    def step(self, tensions: np.ndarray) -> StepReport:
        """Clamp ``tensions`` (m,) to [0, tmax], apply them and the cable damping, integrate one ``dt``.

        The cables' forces ``(f_i + c·l̇_i) d_i`` at the points ``t + R b_i`` are applied as their sum and
        their moment about the COM, world frame (``W (f + c l̇)``, from the cables' Plücker coordinates), as
        the joint's generalized forces: the wrench of one ``addExtForce(force_i, b_i, isForceLocal=False,
        isOffsetLocal=True)`` per cable, in one call.
        """
        commanded = np.asarray(tensions, dtype=float)
        if commanded.shape != self._shape:
            raise ValueError(f"expected {self.robot.m} tensions, got shape {commanded.shape}")
        applied, low, high = clamp_tensions(commanded, self._tmax)
        pose, twist, unnormalised, lengths = self._read()
        lines = unnormalised / lengths[:, None]  # G: rows [a_i × d_i; d_i]
        damping = lines @ origin_twist(pose, twist, self._minus_c)  # c·l̇ = −c·G [ω; ṫ + t × ω]
        mx, my, mz, fx, fy, fz = ((applied + damping) @ lines).tolist()  # [M_O; F], about the world origin
        x, y, z = pose[:3]
        mx, my, mz = mx - (y * fz - z * fy), my - (z * fx - x * fz), mz - (x * fy - y * fx)  # about the COM
        if self._point_mass:  # cables at the COM: no moment, exactly (not the rounding error of M_O − t × F)
            mx = my = mz = 0.0
        self._joint.setForces((fz, fx, my) if self._planar else (fx, fy, mz) if self._horizontal
                              else (mx, my, mz, fx, fy, fz))
        self._world.step()  # semi-implicit Euler; zeroes the joint's forces afterwards
        self._now = None
        self.step_count += 1
        self._tensions = readonly(applied)
        return StepReport(self._tensions, low, high, readonly(damping))


def origin_twist(pose: tuple[float, ...], twist: list[float], scale: float) -> Array:
    """``scale`` times the twist ``[ω; ṫ]`` at the COM ``t = pose[:3]`` referred to the world origin:
    ``[ω; ṫ + t × ω]``, the velocity of the body point passing through the origin (Python floats in)."""
    x, y, z = pose[:3]
    wx, wy, wz, vx, vy, vz = twist
    return np.array((scale * wx, scale * wy, scale * wz, scale * (vx + (y * wz - z * wy)),
                     scale * (vy + (z * wx - x * wz)), scale * (vz + (x * wy - y * wx))))


def cable_line_map(frame_points: ArrayLike, platform_points: ArrayLike) -> Array:
    """The constant (6m, 13) matrix K of the cables' unnormalised Plücker coordinates (module docstring).

    For the platform at ``(t, R)``, R the rotation of the unit quaternion q,
    ``(K @ [q_x², q_y², q_z², q_x q_y, q_x q_z, q_y q_z, q_x q_w, q_y q_w, q_z q_w, t_x, t_y, t_z, 1]).reshape(m, 6)``
    has the rows ``[a_i × l_i; l_i]``, ``l_i = a_i − t − R b_i``. Both halves are linear in R and t
    (``a_i × l_i = −a_i × t − a_i × (R b_i)``, as ``a_i × a_i = 0``), and R's entries are linear in these
    products of q's components and 1 (:func:`~cdpr.mechanics.rotation.quat_matrix`).
    """
    a, b = np.array(frame_points, dtype=float), np.array(platform_points, dtype=float)
    # [R row by row; t; 1] from the 13 features: R = [[1 − 2(yy + zz), 2(xy − zw), 2(xz + yw)], …]
    xx, yy, zz, xy, xz, yz, xw, yw, zw, one = 0, 1, 2, 3, 4, 5, 6, 7, 8, 12
    terms = (((one, 1), (yy, -2), (zz, -2)), ((xy, 2), (zw, -2)), ((xz, 2), (yw, 2)),
             ((xy, 2), (zw, 2)), ((one, 1), (xx, -2), (zz, -2)), ((yz, 2), (xw, -2)),
             ((xz, 2), (yw, -2)), ((yz, 2), (xw, 2)), ((one, 1), (xx, -2), (yy, -2)))
    pose = np.zeros((13, 13))
    for entry, combination in enumerate(terms):
        for feature, coefficient in combination:
            pose[entry, feature] = coefficient
    pose[9:, 9:] = np.eye(4)  # t and 1
    # [a_i × l_i; l_i] from [R row by row; t; 1]
    out = np.zeros((len(a), 6, 13))
    for i, (a_i, b_i) in enumerate(zip(a, b, strict=True)):
        chord = np.zeros((3, 13))  # l_i = −(R b_i) − t + a_i, with (R b_i)_j = Σ_k R_jk b_ik
        for j in range(3):
            chord[j, 3 * j:3 * j + 3] = -b_i
        chord[:, 9:12] = -np.eye(3)
        chord[:, 12] = a_i
        out[i, :3] = skew(a_i) @ chord  # a_i × l_i
        out[i, :3, 12] = 0.0  # a_i × a_i, exactly (a fused multiply-add could leave a rounding error)
        out[i, 3:] = chord
    out = out.reshape(6 * len(a), 13) @ pose
    out.flags.writeable = False
    return out


def planar_coordinates(p: Array, R: Array, v: Array, plane: str = "xz") -> tuple[Array, Array]:
    """A ``PlanarJoint``'s positions and velocities for a pose and twist: ``[z, x, θ_y]`` and ``[ż, ẋ, θ̇_y]``
    in the ZX plane (``xz``), ``[x, y, θ_z]`` and ``[ẋ, ẏ, θ̇_z]`` in the XY plane (``xy``).

    Raises ``ValueError`` if the pose or the twist leaves the plane by more than ``_PLANAR_TOL``.
    """
    if plane == "xy":
        theta = float(np.arctan2(R[1, 0], R[0, 0]))  # R = Rz(θ) = [[c, −s, 0], [s, c, 0], [0, 0, 1]]
        c, s = np.cos(theta), np.sin(theta)
        about = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])
        normal, in_plane, turn = 2, (0, 1), 5
    else:
        theta = float(np.arctan2(R[0, 2], R[0, 0]))  # R = Ry(θ) = [[c, 0, s], [0, 1, 0], [−s, 0, c]]
        c, s = np.cos(theta), np.sin(theta)
        about = np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])
        normal, in_plane, turn = 1, (2, 0), 4
    axis = "xyz"[normal]
    others = [f"ω_{'xyz'[j]}" for j in range(3) if j != normal]
    off_plane = {
        f"position {axis}": abs(p[normal]),
        f"rotation (not about {axis})": float(np.abs(R - about).max()),
        f"twist v_{axis}": abs(v[normal]),
        f"twist {', '.join(others)}": max(abs(v[3 + j]) for j in range(3) if j != normal),
    }
    for what, err in off_plane.items():
        if err > _PLANAR_TOL:
            raise ValueError(f"a planar robot moves in the {plane[0]}–{plane[1]} plane: {what} must be 0 "
                             f"(got {err:.3g})")
    a, b = in_plane
    return np.array([p[a], p[b], theta]), np.array([v[a], v[b], v[turn]])


def _vector(x: ArrayLike, n: int, what: str) -> Array:
    a = np.array(x, dtype=float).reshape(-1)
    if a.shape != (n,) or not np.isfinite(a).all():
        raise ValueError(f"{what} must be {n} finite numbers (got {np.asarray(x).tolist()})")
    return a


def _rotation(x: ArrayLike) -> Array:
    R = np.array(x, dtype=float)
    if R.shape != (3, 3) or not np.isfinite(R).all():
        raise ValueError("rotation must be a finite 3×3 matrix")
    err = float(np.abs(R.T @ R - np.eye(3)).max())
    if err > _ORTHONORMAL_TOL or np.linalg.det(R) <= 0.0:
        det = float(np.linalg.det(R))
        raise ValueError(
            f"rotation must be a proper rotation matrix (‖RᵀR − I‖ = {err:.3g}, det = {det:.3g})"
        )
    if err > 1e-14:  # hand DART the nearest rotation (polar decomposition), not an almost-rotation
        U, _, Vt = np.linalg.svd(R)
        R = U @ Vt
    return R


# --------------------------------------------------------------------------------------------------
# Snapshots: a sim that restarts goes on from the last step it reported (docs/faults.md)


def world_snapshot(world: Any, step: int, tensions: Array) -> dict[str, Any]:
    """The generalized positions and velocities of every skeleton of a DART ``world`` (exact floats), the step
    and the tensions applied over the step before: what every model's snapshot holds."""
    skeletons = [world.getSkeleton(i) for i in range(world.getNumSkeletons())]
    return {"step": int(step), "tensions": tensions.tolist(),
            "skeletons": [[sk.getPositions().tolist(), sk.getVelocities().tolist()] for sk in skeletons]}


def restore_world(world: Any, snapshot: dict[str, Any], m: int) -> tuple[int, Array]:
    """Put a :func:`world_snapshot` back into ``world``; returns its step and tensions. ValueError naming
    what does not fit (another robot, another model)."""
    try:
        step, skeletons = int(snapshot["step"]), snapshot["skeletons"]
        tensions = np.array(snapshot["tensions"], dtype=float)
        if step < 0 or tensions.shape != (m,) or len(skeletons) != world.getNumSkeletons():
            raise ValueError("another robot or cable model")
        for i, (q, dq) in enumerate(skeletons):
            sk = world.getSkeleton(i)
            q, dq = np.array(q, dtype=float), np.array(dq, dtype=float)
            if q.shape != (sk.getNumDofs(),) or dq.shape != (sk.getNumDofs(),):
                raise ValueError(f"skeleton {i} has {sk.getNumDofs()} degrees of freedom")
            sk.setPositions(q)
            sk.setVelocities(dq)
            sk.clearExternalForces()
    except (KeyError, TypeError) as exc:
        raise ValueError(f"not a snapshot of this model ({exc})") from None
    return step, readonly(tensions)


def arrays(snapshot: dict[str, Any], *names: str) -> list[Array | None]:
    """The snapshot's ``names`` as float arrays (None where it holds None)."""
    out: list[Array | None] = []
    for name in names:
        if name not in snapshot:
            raise ValueError(f"not a snapshot of this model (no {name!r})")
        value = snapshot[name]
        out.append(None if value is None else np.array(value, dtype=float))
    return out


# --------------------------------------------------------------------------------------------------
# The state as a message: one builder for every cable model
#
# ``State`` gives its later columns defaults (an older sender stays valid on the wire), so a model that built
# it by hand could leave a new column at its default unnoticed. Every model's ``message`` goes through
# :func:`build` instead, which takes each of the model's columns explicitly or raises (tests/test_state_builder.py
# runs every model).

# The columns of STATE_COLUMNS the sim node stamps on a model's message (cdpr_sim.node, ``publish_state``: how
# old the command that acted over the step before was, and whether the watchdog acted instead); a model's
# message has them 0. Every other column is the model's to give.
STAMPED_COLUMNS = ("command_age", "watchdog")
_NAMES = tuple(c.name for c in STATE_COLUMNS)
if not set(STAMPED_COLUMNS) <= set(_NAMES):
    raise RuntimeError(f"cdpr_sim.core.STAMPED_COLUMNS: {STAMPED_COLUMNS} are not all state columns")
MODEL_COLUMNS = tuple(name for name in _NAMES if name not in STAMPED_COLUMNS)
_ARGUMENTS = ("pose", "twist", "cable_lengths", "tensions", "clamped")  # build's, in their order
_PLAIN = (*_ARGUMENTS, *STAMPED_COLUMNS) == _NAMES  # build's arguments are the model's columns, then the stamped


def build(step: int, t: float, pose: tuple[float, ...], twist: tuple[float, ...], cable_lengths: tuple[float, ...],
          tensions: tuple[float, ...], clamped: int, **more: Any) -> State:
    """The ``sim/state`` message of step ``step`` at time ``t``: the one builder of every cable model's.

    It takes every column of :data:`cdpr.protocol.streams.STATE_COLUMNS` but the :data:`STAMPED_COLUMNS`
    (which are 0 here), i.e. every one of :data:`MODEL_COLUMNS`: the five above, each required, and any column
    added to the table since by name in ``more``. A column left out, or one that is not the model's to give,
    is a ``TypeError`` naming it, never a default.
    """
    if not more and _PLAIN:  # each step's case: no dict (command_age and watchdog 0)
        return State(step, t, pose, twist, cable_lengths, tensions, clamped, 0, 0)
    values: dict[str, Any] = {"pose": pose, "twist": twist, "cable_lengths": cable_lengths, "tensions": tensions,
                              "clamped": clamped, **more}
    if unknown := [name for name in values if name not in MODEL_COLUMNS]:
        raise TypeError(f"not a state column a model gives: {', '.join(unknown)} (those: {', '.join(MODEL_COLUMNS)})")
    if missing := [name for name in MODEL_COLUMNS if name not in values]:
        raise TypeError(f"no value for the state column(s) {', '.join(missing)}: every cable model's message gives "
                        "every column of cdpr.protocol.streams.STATE_COLUMNS (cdpr_sim.core.build)")
    values.update(dict.fromkeys(STAMPED_COLUMNS, 0))
    return State(step, t, **values)


def state_message(s: PlatformState, clamped: int) -> State:
    """The ``sim/state`` message of a :class:`PlatformState` (the models of :mod:`cdpr_sim.ups` and
    :mod:`cdpr_sim.winch`; :meth:`PlatformSim.message` gives the same numbers from less work), by :func:`build`."""
    return build(s.step, s.t, (*s.position.tolist(), *s.quaternion.tolist()), tuple(s.twist.tolist()),
                 tuple(s.cable_lengths.tolist()), tuple(s.tensions.tolist()), clamped)
