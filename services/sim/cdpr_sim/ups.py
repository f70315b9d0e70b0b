"""The seed paper's own cable model as a cross-check of :class:`cdpr_sim.core.PlatformSim`. No I/O.

Model (seed paper §3.1: "a parallel robot with universal-prismatic-spherical (U-P-S) architecture with
the prismatic joint actuated", "virtual links … defined with negligible masses")
------------------------------------------------------------------------------------------------------
* The platform is the same free rigid body as in ``PlatformSim`` (a ``FreeJoint``; a ``PlanarJoint``
  in the robot's plane for planar robots), its own skeleton.
* Cable i is a leg, its own skeleton hung from the world: a ``UniversalJoint`` centred at the frame
  point a_i → link ``upper`` (centre of mass at a_i) → a ``PrismaticJoint`` along the cable → link
  ``lower`` (centre of mass at the far end). The prismatic coordinate is the cable length l_i: the
  lower link's origin is at ``a_i + l_i u_i``, ``u_i`` the unit vector from a_i towards the platform.
* The spherical joint at the platform point b_i closes each loop: a
  ``dartpy.constraint.BallJointConstraint`` between the lower link and the platform, added to the
  world's constraint solver (DART solves the 8 × 3 bilateral impulses as one boxed LCP, Dantzig).
  DART's defaults are kept: error reduction 0.01 per step, constraint force mixing 1e-9.
* The universal joint's frame is aligned at every :meth:`UpsSim.reset` so that its z axis is the cable
  direction at the initial pose (its two angles start at 0, 90° away from the joint's singularity);
  the prismatic coordinate starts at the inverse-kinematics length and every joint velocity at the
  value that makes each leg's end move with its platform point (the leg's 3×3 Jacobian, solved).
* Tension: the prismatic joint's generalized force is ``−(f_i + c·l̇_i)``, with f_i clamped to
  ``[0, tmax]`` by :func:`cdpr_sim.core.clamp_tensions` (DART does not clamp FORCE joints) — the axis
  points away from a_i, so a positive tension pulls the platform towards a_i, as in ``PlatformSim``.

Exit pulleys
------------
A cable over a swivelling exit pulley (:mod:`cdpr.mechanics.pulley`) is the chain the pulley makes: a
``RevoluteJoint`` about the swivel axis u_i at a_i → link ``fork`` → a ``RevoluteJoint`` about the wheel's axle
(normal to the wheel's plane, through its centre a_i + r e_i) → link ``arm`` → the ``PrismaticJoint`` at the
tangent point, along the free span → link ``lower``, ball-joined to the platform as above. The prismatic
coordinate is the free span; the axle's angle q moves the tangent point round the wheel, so the cable's length
is the span plus r (β0 − q). The wrapped cable holds the arm: the axle gets the torque r (f_i + c·l̇_i) that
balances the span's pull at the tangent point (the prismatic axis stays tangent by construction). The swivel
gets the passive damping of a universal joint's axis. At every reset the frames are set from the pulley's
closed form at the initial pose (every angle 0).

Damping, and why it is applied explicitly
-----------------------------------------
``robot.cable_damping`` c acts on the prismatic joint (force ``−c·l̇_i``), ``robot.passive_damping`` c_p
on the universal joints (torques ``−c_p·q̇_U``) and on the spherical joints (torque
``−c_p (ω_platform − ω_lower)`` on the platform, the opposite on the lower link). All are evaluated with
the velocities at the start of the step and added to the commands, like the cable damping of
``PlatformSim``. DART's own joint damping (``setDampingCoefficient``) is *not* used: DART integrates it
implicitly, ``−c·q̇_{k+1}``, inside each skeleton's *unconstrained* step, before the loop-closure
impulses. For a near-massless leg that velocity is dominated by ``f·dt/m_link`` (the tension
accelerating the light link alone), so the built-in damping absorbs the fraction
``c·dt/(m_link + c·dt)`` of every tension (half of it at m_link = 1e-3 kg, c = 1 N·s/m, dt = 1 ms; 91 %
at 1e-4 kg). Measured on CAROCA at 15 kg: the one-step acceleration was then off by 3.3 m/s² (1e-3 kg
links) and 6.0 m/s² (1e-4 kg) instead of ≤ 1e-5 m/s² (ratio 1.82, as the two fractions predict); it
approaches the explicit result only for links of 1 kg and more.

Link masses
-----------
Each link is a solid sphere of mass ``LINK_MASS`` = 1e-4 kg and radius 5 mm (the Gazebo cable's visual
radius), inertia 1e-9 kg·m². Their effect, to first order: the lower link's centre of mass moves with b_i,
so the platform behaves as if it carried m point masses m_link at its platform points; the upper link
sits on the fixed point a_i and only adds its tiny inertia about it. The one-step accelerations match
Newton–Euler of that augmented body to 5e-9 relative at rest, and within the velocity-level closure
bias (``m_link × centripetal accelerations``, see below) when moving; the bare body's to
``‖M⁻¹ΔM‖·‖ẍ − g‖``, ‖M⁻¹ΔM‖ = 1.6e-4 for CAROCA at 15 kg (tests/test_ups.py). In closed loop the
controller, unaware of the links, sees an extra weight of m·m_link·g: a steady offset of about
m·m_link·g/(M·Kp). Measured over the 11 s of ``caroca_15kg``, max ‖t_UPS − t_ideal‖:

    m_link (kg)   1e-6     1e-5     1e-4     1e-3     1e-2
    15 kg         9.3e-8   1.1e-7   3.9e-7   3.5e-6   3.5e-5 m
    1 kg                            5.8e-6   5.3e-5        m

Linear in m_link down to 1e-4 kg; below, other effects (the closure gaps) dominate, and at 1e-6 kg the
gaps start to grow (6e-6 m, against 3e-6 m) as the LCP's mass ratio reaches 1.5e7. 1e-4 kg keeps the
1 kg platform within 6 µm of the ideal model, with the gaps unchanged.

Accuracy of the loop closure
----------------------------
DART enforces the closures at the velocity level with the Jacobians at the start of the step,
``J(q_k) v_{k+1} = 0`` instead of ``J q̈ + J̇ q̇ = 0``. The missed velocity-product terms (the platform
point's and the leg end's centripetal and Coriolis accelerations) are corrected by an impulse carried
by the light side, so they perturb the platform by at most m_link times those accelerations per leg,
and each step leaves an O(dt²) position gap at each spherical joint, which the error reduction
(1 %/step) keeps bounded. The gap ‖a_i + l_i u_i − (t + R b_i)‖ is reported by
:meth:`UpsSim.closure_errors`; on the 15 kg scenario it stays below 3.2e-6 m, and the prismatic lengths
equal the inverse-kinematics lengths to 2.6e-6 m. Cost: ~85 µs a step against ~15 µs for
``PlatformSim`` (one 24-unknown LCP a step).

State: pose and twist are read from the platform body (world frame, at its centre of mass), cable
lengths and rates are the prismatic joints' positions and velocities, tensions are as applied. Same
inputs, bit-identical outputs.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import dartpy as dart
import numpy as np
from numpy.typing import ArrayLike

from cdpr.config.scenario import Scenario
from cdpr.mechanics.pulley import Pulleys, pulley_geometry
from cdpr.mechanics.robot import Robot
from cdpr.mechanics.rotation import Array, readonly
from cdpr.protocol import State
from cdpr_sim.core import (
    PlatformBody,
    PlatformState,
    StepReport,
    check_dt,
    clamp_tensions,
    restore_world,
    start_pose,
    state_message,
    tension_ceiling,
    world_snapshot,
)

LINK_MASS = 1e-4  # kg, each of the two virtual links of a leg (module docstring: why)
LINK_RADIUS = 0.005  # m, the links' inertia is a solid sphere's of this radius (the cable's visual radius)


@dataclass(frozen=True)
class _Leg:
    """One cable: U joint at a_i → upper link → prismatic joint → lower link (ball-joined to the platform).

    Over an exit pulley (module docstring, "Exit pulleys"): swivel joint at a_i → fork → axle joint at the
    wheel's centre → arm → prismatic joint at the tangent point → lower link; ``universal`` is then the swivel
    and ``axle`` the axle joint."""

    skeleton: dart.dynamics.Skeleton
    universal: dart.dynamics.Joint
    lower: dart.dynamics.BodyNode
    axle: dart.dynamics.RevoluteJoint | None = None
    prismatic: dart.dynamics.PrismaticJoint | None = None


@dataclass(frozen=True)
class _Snapshot:
    position: Array  # (3,)
    rotation: Array  # (3, 3)
    twist: Array  # (6,)
    lengths: Array  # (m,) prismatic positions
    rates: Array  # (m,) prismatic velocities
    leg_velocities: Array  # (m, 3) [q̇_U1, q̇_U2, l̇] per leg


class UpsSim:
    """The platform of ``robot`` hung from m U-P-S legs in one DART world, stepped by cable tensions.

    Same interface as :class:`cdpr_sim.core.PlatformSim` (``dt`` in s, initial pose defaults to home,
    twist to rest, ``t = step_count·dt``). ``link_mass`` (kg) is the mass of each virtual link.
    """

    fallbacks = 0  # the U-P-S legs have no domain to leave (SimModel)
    fallback_reason: str | None = None

    def __init__(
        self,
        robot: Robot,
        dt: float = 1e-3,
        position: ArrayLike | None = None,
        rotation: ArrayLike | None = None,
        twist: ArrayLike | None = None,
        *,
        link_mass: float = LINK_MASS,
    ) -> None:
        self.dt = check_dt(dt)
        if not (np.isfinite(link_mass) and link_mass > 0.0):
            raise ValueError(f"link_mass must be a positive finite number of kg (got {link_mass})")
        self.robot = robot
        self.step_count = 0
        self.link_mass = float(link_mass)
        self._a = np.array(robot.frame_points, dtype=float)
        self._b = np.array(robot.platform_points, dtype=float)
        self._platform = PlatformBody(robot, self.dt)
        self._world, self._joint, self._body = self._platform.world, self._platform.joint, self._platform.body
        body = self._body
        link_inertia = dart.dynamics.Inertia(
            self.link_mass, np.zeros(3), np.eye(3) * 0.4 * self.link_mass * LINK_RADIUS**2
        )
        pulleys = robot.pulleys
        self._radius = np.zeros(robot.m) if pulleys is None else np.array(pulleys.radius, dtype=float)
        self._wrap0 = np.zeros(robot.m)  # each pulley leg's wrapped angle at the axle's zero (set by reset)
        self._legs = tuple(self._make_pulley_leg(i, link_inertia) if self._radius[i] > 0.0
                           else self._make_leg(i, link_inertia) for i in range(robot.m))
        self._tensions = readonly(np.zeros(robot.m))
        self._snap: _Snapshot | None = None
        self.reset(position, rotation, twist)
        # The closures are made once, with every leg's end on its platform point: the constraint keeps
        # the offsets (0 on the lower link, b_i on the platform), which every reset preserves.
        solver = self._world.getConstraintSolver()
        ends = self._platform_points_world()
        for leg, point in zip(self._legs, ends, strict=True):
            solver.addConstraint(dart.constraint.BallJointConstraint(leg.lower, body, point))

    def _make_leg(self, i: int, inertia: dart.dynamics.Inertia) -> _Leg:
        skeleton = dart.dynamics.Skeleton(f"cable_{i}")
        universal, upper = skeleton.createUniversalJointAndBodyNodePair()
        universal.setAxis1(np.array([1.0, 0.0, 0.0]))
        universal.setAxis2(np.array([0.0, 1.0, 0.0]))
        upper.setName(f"cable_{i}_upper")
        upper.setInertia(inertia)
        prismatic, lower = skeleton.createPrismaticJointAndBodyNodePair(upper)
        prismatic.setActuatorType(dart.dynamics.ActuatorType.FORCE)  # DART's default, stated
        prismatic.setAxis(np.array([0.0, 0.0, 1.0]))
        lower.setName(f"cable_{i}_lower")
        lower.setInertia(inertia)
        self._world.addSkeleton(skeleton)
        return _Leg(skeleton, universal, lower)

    def _make_pulley_leg(self, i: int, inertia: dart.dynamics.Inertia) -> _Leg:
        skeleton = dart.dynamics.Skeleton(f"cable_{i}")
        swivel, fork = skeleton.createRevoluteJointAndBodyNodePair()
        swivel.setAxis(np.array([0.0, 0.0, 1.0]))  # the swivel axis u (the joint frame's z, set by reset)
        fork.setName(f"cable_{i}_fork")
        fork.setInertia(inertia)
        axle, arm = skeleton.createRevoluteJointAndBodyNodePair(fork)
        axle.setAxis(np.array([0.0, -1.0, 0.0]))  # normal to the wheel's plane (x = e, z = u): φ grows with it
        arm.setName(f"cable_{i}_arm")
        arm.setInertia(inertia)
        prismatic, lower = skeleton.createPrismaticJointAndBodyNodePair(arm)
        prismatic.setActuatorType(dart.dynamics.ActuatorType.FORCE)
        prismatic.setAxis(np.array([0.0, 0.0, 1.0]))  # along the free span (its frame, set by reset)
        lower.setName(f"cable_{i}_lower")
        lower.setInertia(inertia)
        self._world.addSkeleton(skeleton)
        return _Leg(skeleton, swivel, lower, axle, prismatic)

    @classmethod
    def from_scenario(cls, scenario: Scenario) -> UpsSim:
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
        """Back to step 0 at the given pose and twist (defaults: home pose, at rest), legs by IK."""
        self._platform.place(*start_pose(self.robot, position, rotation, twist))
        # Read the pose back from DART, so that the legs meet the platform exactly where DART has it.
        ends = self._platform_points_world()
        vt, w = self._body.getLinearVelocity(), self._body.getAngularVelocity()
        R_dart = self._body.getTransform().rotation()
        for i, (leg, a, b, end) in enumerate(zip(self._legs, self._a, self._b, ends, strict=True)):
            if leg.axle is not None:
                self._place_pulley_leg(i, leg, a, end)
            else:
                vec = end - a
                length = float(np.linalg.norm(vec))
                if length < 1e-9:
                    raise ValueError("a cable has zero length at this pose")
                frame = dart.math.Isometry3()
                frame.set_rotation(_frame_with_z(vec / length))
                frame.set_translation(a)
                leg.universal.setTransformFromParentBodyNode(frame)
                leg.skeleton.setPositions(np.array([0.0, 0.0, length]))
            # Inverse velocity kinematics: the leg's end moves with its platform point t + R b.
            point_velocity = vt + np.cross(w, R_dart @ b)
            leg.skeleton.setVelocities(np.linalg.solve(leg.lower.getLinearJacobian(), point_velocity))
            leg.skeleton.clearExternalForces()
            leg.skeleton.clearInternalForces()
        self._world.reset()
        self._snap = None
        self.step_count = 0
        self._tensions = readonly(np.zeros(self.robot.m))

    def _place_pulley_leg(self, i: int, leg: _Leg, a: Array, end: Array) -> None:
        """A pulley leg's joint frames for the platform point ``end``: the swivel's z along u with x the wheel's
        direction e (angle 0), the axle at the wheel's centre (angle 0), the prismatic joint at the tangent
        point along the free span, its length the span's."""
        pulleys, axle, prismatic = self.robot.pulleys, leg.axle, leg.prismatic
        assert pulleys is not None
        assert axle is not None
        assert prismatic is not None
        one = Pulleys(pulleys.radius[i:i + 1], pulleys.axis[i:i + 1])
        g = pulley_geometry(a[None], one, end[None])
        r, u, e = float(self._radius[i]), one.axis[0], g.swivel[0]
        if g.free_lengths[0] < 1e-9:
            raise ValueError("a cable has zero length at this pose")
        swivel = dart.math.Isometry3()
        swivel.set_rotation(np.column_stack((e, np.cross(u, e), u)))
        swivel.set_translation(a)
        leg.universal.setTransformFromParentBodyNode(swivel)
        centre = dart.math.Isometry3()
        centre.set_translation(np.array([r, 0.0, 0.0]))
        axle.setTransformFromParentBodyNode(centre)
        phi = float(np.pi - g.wrap[0])  # the tangent point's angle, from e towards u
        radial = np.array([np.cos(phi), 0.0, np.sin(phi)])  # in the fork's frame (x = e, y = u × e, z = u)
        span = np.array([np.sin(phi), 0.0, -np.cos(phi)])  # towards B: the wheel's tangent, clockwise from a
        tangent = dart.math.Isometry3()
        tangent.set_rotation(_frame_with_z(span))
        tangent.set_translation(r * radial)
        prismatic.setTransformFromParentBodyNode(tangent)
        self._wrap0[i] = g.wrap[0]
        leg.skeleton.setPositions(np.array([0.0, 0.0, float(g.free_lengths[0])]))

    def _platform_points_world(self) -> Array:
        tf = self._body.getTransform()
        return tf.translation() + self._b @ tf.rotation().T

    def _snapshot(self) -> _Snapshot:
        if self._snap is not None:
            return self._snap
        tf = self._body.getTransform()
        legs = np.array([leg.skeleton.getPositions() for leg in self._legs])
        leg_v = np.array([leg.skeleton.getVelocities() for leg in self._legs])
        twist = np.concatenate((self._body.getLinearVelocity(), self._body.getAngularVelocity()))
        # a cable's length: its leg's prismatic span, and over a pulley the wrap r β, β = β0 − q_axle
        lengths = legs[:, 2] + self._radius * (self._wrap0 - legs[:, 1])
        rates = leg_v[:, 2] - self._radius * leg_v[:, 1]
        snap = _Snapshot(
            *(readonly(x) for x in (tf.translation(), tf.rotation(), twist, lengths, rates, leg_v))
        )
        self._snap = snap
        return snap

    def state(self) -> PlatformState:
        """The current state. Its arrays are read-only and never change afterwards: safe to keep."""
        s = self._snapshot()
        return PlatformState.of(self.step_count, self.t, s.position, s.rotation, s.twist, s.lengths, s.rates,
                                self._tensions)

    def message(self, clamped: int) -> State:
        """The current state as a ``sim/state`` message."""
        return state_message(self.state(), clamped)

    def snapshot(self) -> dict[str, Any]:
        return world_snapshot(self._world, self.step_count, self._tensions)

    def restore(self, snapshot: dict[str, Any]) -> None:
        """The legs' frames come from the scenario's initial pose (:meth:`reset`), the same in every sim of
        the scenario; the rest is in the world."""
        self.step_count, self._tensions = restore_world(self._world, snapshot, self.robot.m)
        self._snap = None

    def encoder_lengths(self) -> Array:
        """(m,) the legs' lengths."""
        return self._snapshot().lengths  # (not state(): no quaternion to derive)

    def load_cell_tensions(self) -> Array:
        """(m,) the tensions applied over the last step."""
        return self._tensions

    def closure_errors(self) -> Array:
        """(m,) distance, m, between each leg's end and its platform point (the spherical joints' gaps)."""
        ends = np.array([leg.lower.getTransform().translation() for leg in self._legs])
        return np.linalg.norm(ends - self._platform_points_world(), axis=1)

    # -- dynamics ---------------------------------------------------------------------------------
    def step(self, tensions: np.ndarray) -> StepReport:
        """Clamp ``tensions`` (m,) to [0, tmax], command them and the damping on the legs, step ``dt``."""
        commanded = np.asarray(tensions, dtype=float)
        if commanded.shape != (self.robot.m,):
            raise ValueError(f"expected {self.robot.m} tensions, got shape {commanded.shape}")
        applied, low, high = clamp_tensions(commanded, tension_ceiling(self.robot))
        s = self._snapshot()
        damping = self.robot.cable_damping * s.rates
        c_p = self.robot.passive_damping
        forces = np.empty((self.robot.m, 3))
        forces[:, :2] = -c_p * s.leg_velocities[:, :2]  # universal joints (a pulley leg's swivel)
        forces[:, 2] = -(applied + damping)  # the prismatic axis points away from a_i
        # over a pulley the cable on the wheel holds the arm: the torque r f about the axle (module docstring)
        forces[:, 1] = np.where(self._radius > 0.0, self._radius * (applied + damping), forces[:, 1])
        for leg, f in zip(self._legs, forces, strict=True):
            leg.skeleton.setForces(f)
        # Spherical joints: −c_p (ω_platform − ω_lower) on the platform, the opposite on the lower link.
        if c_p > 0.0:
            w = self._body.getAngularVelocity()
            total = np.zeros(3)
            for leg in self._legs:
                torque = c_p * (leg.lower.getAngularVelocity() - w)
                leg.lower.setExtTorque(-torque, False)
                total += torque
            self._body.setExtTorque(total, False)
        self._world.step()  # semi-implicit Euler + closure impulses; clears forces and commands afterwards
        self._snap = None
        self.step_count += 1
        self._tensions = readonly(applied)
        return StepReport(self._tensions, low, high, readonly(damping))


def _frame_with_z(z: Array) -> Array:
    """A rotation matrix whose third column is the unit vector ``z`` (x from the world axis least along z)."""
    helper = np.eye(3)[int(np.argmin(np.abs(z)))]
    x = np.cross(helper, z)
    x /= np.linalg.norm(x)
    return np.column_stack((x, np.cross(z, x), z))
