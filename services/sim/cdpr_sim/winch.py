"""Winch-driven cables: the drive model and the sub-stepped platform sim shared by the elastic and sag models.

No I/O. :class:`WinchSim` is the part of :class:`cdpr_sim.elastic.ElasticSim` and
:class:`cdpr_sim.sag.SagSim` that does not depend on the cable's force law: the platform (a DART rigid
body, as in :class:`cdpr_sim.core.PlatformSim`), one winch per cable, and the two command modes.

Command modes
-------------
``tensions`` (the seed paper's, and :class:`~cdpr_sim.core.PlatformSim`'s)
    Each winch is torque-controlled with an ideal tension loop: the drive winds or pays out cable so
    that the tension where the cable meets the platform is the commanded one, clamped to [0, tmax] by
    :func:`~cdpr_sim.core.clamp_tensions`. The drum's inertia and friction are inside that loop and do
    not show; the unstretched length ``l0`` follows from the force law (elastic: ``l0 = l·EA/(EA + f)``,
    sag: the catenary whose platform-end tension is f). One integration step of ``dt``, forces evaluated
    at the start of the step, like ``PlatformSim``. With straight elastic cables this *is* the ideal
    model (the same forces); with sagging cables the force leaves the platform along the catenary's
    tangent, not along the chord the controller assumes.
``lengths``
    The controller commands each cable's unstretched length ``l0`` (m). Each winch is a position-
    controlled drum of radius r, inertia J (rotor and drum, about the drum axis), viscous friction b,
    torque limit τ_max, whose angle θ sets ``l0 = r θ`` (θ grows when cable is paid out). Its drive
    runs a PID on the angle at the sub-step rate, with the reference ramped through the step at the
    commands' own rate (θ_ref = l0_k/r + (l0_k − l0_{k−1})/(r·dt)·τ, τ the time into the step) and a
    velocity error ``θ̇_ref − θ̇`` in the D term:

        τ_m = clamp(kp (θ_ref − θ) + ki ∫(θ_ref − θ) + kd (θ̇_ref − θ̇), ±τ_max)
        J θ̈ = τ_m + r f_frame − b θ̇      (the cable's tension at the drum pays cable out)

    The integral stops while the torque is saturated and would grow further (anti-windup). Tensions
    come from the cable's force law (:meth:`WinchSim._law`). The commanded length is clamped to
    ``(0, robot.max_length]`` (counted as ``clamped_high``).

Length limits and the model's domain (lengths mode)
---------------------------------------------------
The drum holds ``robot.max_length`` of cable: it has end stops at ``l0 = 0`` (all cable wound in) and
``l0 = max_length`` (all paid out). A drum driven or dragged into a stop stays there, its speed towards
the stop set to 0 (an inelastic stop); drive-steps spent at a stop are counted in :attr:`WinchSim.stopped`.
A cable's axial stiffness ``EA/l0`` grows without bound as l0 → 0, faster than the sub-steps can follow:
below :attr:`WinchSim.min_length`, the length at which the drum–cable mode reaches ω h = 1 (or the
platform's, ``EA/l0`` through its mass), the force law is outside its domain and is evaluated at
``min_length`` instead — a fallback. A step in which any force law falls back (here, or a sag cable
whose catenary has no solution) is counted in :attr:`WinchSim.fallbacks`, and its reason kept in
:attr:`WinchSim.fallback_reason`; the sim node turns these into its ``cable_fallbacks`` fault counter.

Integration (lengths mode)
--------------------------
The platform and the drums are integrated together by semi-implicit (symplectic) Euler over
``substeps`` equal sub-steps ``h = dt/substeps`` of each ``dt``: at the start of each sub-step the
cable forces are evaluated from the current pose, twist, drum angles and speeds, the drive torques from
the PID, then every velocity is updated and every position moves with the new velocity (DART's
``World.step`` for the platform, the same update for the drums). A stiff cable makes this a stiff
system: its fastest mode must satisfy ω h < 2 to be stable, and ω h ≲ 0.3 to be accurate.
:func:`substeps_for` estimates ω at the initial pose from the platform's stiffness ``W diag(k) Wᵀ``
through its mass matrix and the drum–cable mode ``k r²/J + kp/J`` (k = EA/l0), and picks the smallest
number of sub-steps with ``ω h ≤ 0.3`` and ``(c r² + kd + b) h / J ≤ 0.5`` (explicit damping), unless the
scenario sets ``sim.substeps``. The state's tensions are the mean over the sub-steps.

Initial state: the winches start holding the platform at rest, at the least-norm tensions within
[tmin, tmax] that balance its weight (the ``qp`` distribution): ``l0`` from the force law, the drums at
rest, each PID's integral preloaded with the torque that holds that tension (no start-up transient).

``robot.cable_damping`` (the seed paper's damping of the actuated prismatic joint) is not applied by
these models: the cables have their own damping (the law's ``damping``, N·s/m on the stretch rate) and
the winches their own friction.
"""

from __future__ import annotations

import math
from abc import ABC, abstractmethod
from dataclasses import dataclass
from typing import Any, ClassVar

import numpy as np
from numpy.typing import ArrayLike

from cdpr.config.scenario import Scenario, StretchSpec, WinchSpec
from cdpr.mechanics.dynamics import gravity_wrench, mass_matrix
from cdpr.mechanics.kinematics import cable_geometry, inverse_kinematics
from cdpr.mechanics.outputs import COMMAND_KINDS, CommandKind
from cdpr.mechanics.robot import Robot
from cdpr.mechanics.rotation import Array, cross_rows, readonly
from cdpr.mechanics.tda import make_tda
from cdpr.protocol import State
from cdpr_sim.core import (
    PlatformBody,
    PlatformState,
    StepReport,
    arrays,
    check_dt,
    clamp_tensions,
    restore_world,
    start_pose,
    state_message,
    tension_ceiling,
    world_snapshot,
)

ACCURACY = 0.3  # ω h of the fastest mode that :func:`substeps_for` allows
DAMPING_LIMIT = 0.5  # (c r² + kd + b) h / J that :func:`substeps_for` allows


@dataclass(frozen=True)
class WinchState:
    """The drums, (m,) each: angle θ (rad, l0 = r θ), speed θ̇ (rad/s), PID integral ∫e dt (rad·s)."""

    angle: Array
    speed: Array
    integral: Array


def drive_torque(
    p: WinchSpec, s: WinchState, angle_ref: Array, speed_ref: Array, h: float
) -> tuple[Array, Array, Array]:
    """The PID's torque (m,), its new integral, and which drives saturated (bool (m,)). Pure."""
    error = angle_ref - s.angle
    raw = p.kp * error + p.ki * s.integral + p.kd * (speed_ref - s.speed)
    torque = np.clip(raw, -p.torque_max, p.torque_max)
    saturated = torque != raw
    # Anti-windup: integrate unless saturated and the error would push the torque further out.
    hold = saturated & (np.sign(error) == np.sign(raw))
    integral = np.where(hold, s.integral, s.integral + h * error)
    return torque, integral, saturated


def drum_step(p: WinchSpec, s: WinchState, torque: Array, tension: Array, integral: Array,
              h: float) -> WinchState:
    """One semi-implicit Euler step of J θ̈ = τ + r f − b θ̇ (f: the tension at the drum). Pure."""
    speed = s.speed + h * (torque + p.radius * tension - p.friction * s.speed) / p.inertia
    return WinchState(s.angle + h * speed, speed, integral)


def end_stops(s: WinchState, low: float | Array, high: float | Array) -> tuple[WinchState, int]:
    """Drums past an end stop (angle outside [low, high]) put back on it, their speed towards it set to 0
    (an inelastic stop); the other drums are returned unchanged. Pure: (state, drums at a stop)."""
    below, above = s.angle <= low, s.angle >= high
    if not (below.any() or above.any()):
        return s, 0
    speed = np.where((below & (s.speed < 0.0)) | (above & (s.speed > 0.0)), 0.0, s.speed)
    return WinchState(np.clip(s.angle, low, high), speed, s.integral), int(np.count_nonzero(below | above))


def min_length_for(EA: float, mass: float, winch: WinchSpec, h: float) -> float:
    """The shortest unstretched length (m) whose cable the explicit sub-steps of ``h`` still follow.

    A cable of stiffness k = EA/l0 on a drum makes the mode ω² = k r²/J + kp/J, and on the platform at
    least ω² = k/mass; this is the l0 at which the faster of the two reaches ω h = 1 (stable up to 2).
    0 when the drive alone is faster than that (sub-steps too long for the drive: no length helps).
    """
    drum = (winch.inertia / winch.radius**2) * (1.0 / h**2 - winch.kp / winch.inertia)
    k_max = min(drum, mass / h**2)
    return EA / k_max if k_max > 0.0 else 0.0


@dataclass(frozen=True)
class Geometry:
    """The platform and its cables at one instant (world frame). Read-only arrays."""

    position: Array  # (3,)
    rotation: Array  # (3, 3)
    twist: Array  # (6,) [v; ω]
    points: Array  # (m, 3) t + R b_i, the platform's attach points
    arms: Array  # (m, 3) R b_i
    lengths: Array  # (m,) chord lengths ‖a_i − t − R b_i‖ (over an exit pulley: the wrapped arc plus the span)
    directions: Array  # (m, 3) unit chords d_i, platform → frame (over a pulley: the free span's)
    rates: Array  # (m,) l̇ = −(d_i · v + ((R b_i) × d_i) · ω)
    anchors: Array  # (m, 3) where each cable's free span starts at the frame: a_i, or its pulley's tangent point
    wrapped: Array  # (m,) the length of cable on each exit pulley's wheel (0 without one), m


@dataclass(frozen=True)
class CableForces:
    """What the cables do at one instant: forces on the platform and tensions at both ends."""

    forces: Array  # (m, 3) on the platform, world frame
    platform: Array  # (m,) tension magnitude at the platform end (reported in the state)
    frame: Array  # (m,) tension magnitude at the frame end (what the winch and its load cell feel)


def substeps_for(robot: Robot, dt: float, stiffness: Array, winch: WinchSpec, damping: float,
                 position: Array, rotation: Array) -> int:
    """Sub-steps per ``dt`` so that the fastest mode has ω h ≤ ACCURACY (module docstring)."""
    kin = inverse_kinematics(robot, position, rotation)
    M = mass_matrix(robot, rotation)
    W = kin.wrench_matrix[: M.shape[0]]
    K = W @ (stiffness[:, None] * W.T)
    L = np.linalg.cholesky(M)
    Linv = np.linalg.inv(L)
    platform = float(np.linalg.eigvalsh(Linv @ K @ Linv.T).max())
    r2_J = winch.radius**2 / winch.inertia
    drum = float(stiffness.max()) * r2_J + winch.kp / winch.inertia
    omega = math.sqrt(max(platform, 0.0) + drum)
    rate = damping * r2_J + (winch.kd + winch.friction) / winch.inertia
    return max(1, math.ceil(dt * omega / ACCURACY), math.ceil(dt * rate / DAMPING_LIMIT))


class WinchSim(ABC):
    """The platform of ``robot`` on DART, pulled by m winch-driven cables whose force law subclasses give.

    ``command`` is ``"tensions"`` or ``"lengths"`` (module docstring); ``substeps`` (lengths mode) defaults
    to :func:`substeps_for`. Same interface as :class:`~cdpr_sim.core.PlatformSim`: ``state()``,
    ``step(command)``, ``reset(...)``, ``t``, ``step_count``, ``dt``, ``robot``; plus :meth:`encoder_lengths`
    and :meth:`load_cell_tensions` (what the sensors see) and ``winch``/``substeps``/``saturated``.
    ``params`` are the cable law's parameters (a :attr:`params_type`, its defaults when None).
    """

    params_type: ClassVar[type[StretchSpec]]  # the cable law's parameters (a scenario section), set by each subclass

    def __init__(
        self,
        robot: Robot,
        dt: float = 1e-3,
        position: ArrayLike | None = None,
        rotation: ArrayLike | None = None,
        twist: ArrayLike | None = None,
        *,
        params: StretchSpec | None = None,
        command: CommandKind = "tensions",
        winch: WinchSpec | None = None,
        substeps: int | None = None,
    ) -> None:
        self.dt = check_dt(dt)
        self.params = params if params is not None else self.params_type()  # the cable law's parameters
        if command not in COMMAND_KINDS:
            raise ValueError(f"command must be one of {', '.join(COMMAND_KINDS)} (got {command!r})")
        if substeps is not None and not (isinstance(substeps, int) and substeps >= 1):
            raise ValueError(f"substeps must be an integer >= 1 (got {substeps!r})")
        self.robot = robot
        self.command: CommandKind = command
        self.winch = winch if winch is not None else WinchSpec()
        self.step_count = 0
        self.saturated = 0  # drive-steps (cable × sub-step) spent at the torque limit since reset
        self.stopped = 0  # drive-steps (cable × sub-step) spent at a drum end stop since reset
        self.fallbacks = 0  # steps in which a force law fell back (outside its domain) since reset
        self.fallback_reason: str | None = None  # why, the last time
        self._fell_back = False
        self._a = np.array(robot.frame_points, dtype=float)
        self._b = np.array(robot.platform_points, dtype=float)
        self._no_wrap = readonly(np.zeros(robot.m))
        p0, R0, v0 = start_pose(robot, position, rotation, twist)
        if command == "tensions":
            self.substeps = 1
        elif substeps is not None:
            self.substeps = substeps
        else:
            kin = inverse_kinematics(robot, p0, R0)
            self.substeps = substeps_for(robot, self.dt, self._stiffness(kin.lengths), self.winch,
                                         self._damping(), p0, R0)
        self.h = self.dt / self.substeps
        self.min_length = min_length_for(self.params_stiffness(), robot.mass, self.winch, self.h)
        self._platform = PlatformBody(robot, self.h)
        self._world, self._joint, self._body = self._platform.world, self._platform.joint, self._platform.body
        self._hold = make_tda("qp")
        self.reset(p0, R0, v0)

    @classmethod
    def from_scenario(cls, scenario: Scenario) -> WinchSim:
        """The sim of a scenario whose ``sim.cable_model`` is this class's :attr:`model`."""
        spec = scenario.spec.sim
        return cls(
            scenario.robot,
            scenario.dt,
            scenario.initial_position,
            scenario.initial_rotation,
            params=spec.cable_params,
            command=scenario.output,
            winch=spec.winch,
            substeps=spec.substeps,
        )

    # -- the force law, given by subclasses -------------------------------------------------------
    @abstractmethod
    def _law(self, g: Geometry, l0: Array, l0_rate: Array) -> CableForces:
        """Cable forces for unstretched lengths ``l0`` (m,) paid out at ``l0_rate`` (m/s) (lengths mode)."""

    @abstractmethod
    def _law_for_tension(self, g: Geometry, tensions: Array) -> tuple[CableForces, Array]:
        """Forces and the unstretched lengths for platform-end ``tensions`` (m,) (tensions mode)."""

    @abstractmethod
    def _stiffness(self, lengths: Array) -> Array:
        """(m,) axial stiffness EA/l0, N/m, for sub-step selection."""

    def params_stiffness(self) -> float:
        """The cables' EA (N): the stiffness of a cable of unit length (:attr:`min_length`)."""
        return float(self._stiffness(np.ones(1))[0])

    def _fallback(self, reason: str) -> None:
        """A force law could not be evaluated in its domain this step and used a fallback: ``reason``."""
        self._fell_back = True
        self.fallback_reason = reason

    @abstractmethod
    def _damping(self) -> float:
        """The cables' damping coefficient, N·s/m, for sub-step selection."""

    # -- state ------------------------------------------------------------------------------------
    @property
    def t(self) -> float:
        return self.step_count * self.dt

    def reset(
        self,
        position: ArrayLike | None = None,
        rotation: ArrayLike | None = None,
        twist: ArrayLike | None = None,
    ) -> None:
        """Back to step 0 at the pose and twist (defaults: home, at rest), the winches holding the weight."""
        self._platform.place(*start_pose(self.robot, position, rotation, twist))
        self._world.reset()
        self.step_count = 0
        self.saturated = 0
        self.stopped = 0
        self.fallbacks = 0
        self.fallback_reason = None
        self._geometry: Geometry | None = None
        g = self._read()
        forces, l0 = self._holding(g)
        r = self.winch.radius
        ki = self.winch.ki
        self._winch = WinchState(
            angle=l0 / r,
            speed=g.rates / r,  # the drums start paying out as fast as the cables lengthen
            integral=(-r * forces.frame / ki) if ki > 0.0 else np.zeros(self.robot.m),
        )
        self._l0_rate = g.rates.copy()
        self._ref: Array | None = None  # the last commanded angle (lengths mode)
        self._tensions = readonly(np.zeros(self.robot.m))
        self._frame_tensions = readonly(np.array(forces.frame))

    def _holding(self, g: Geometry) -> tuple[CableForces, Array]:
        """Forces and unstretched lengths that hold the platform's weight at rest at ``g``'s pose.

        The ``qp`` distribution of the weight, within [:meth:`_holding_floor`, tmax], over the cables' lines
        of action at the platform — the
        chords at first, then (for sagging cables, whose force leaves along the catenary's tangent) the
        directions of the forces found, until the tensions change by less than 1 nN (at most 50 rounds).
        """
        rows = list(self.robot.controlled_rows)
        weight = np.zeros(6)
        weight[:3] = -gravity_wrench(self.robot)[:3]  # the cables hold the weight (no moment about the COM)
        directions = g.directions
        self._hold.reset()
        tensions = None
        for _ in range(50):
            W = np.vstack((directions.T, cross_rows(g.arms, directions).T))
            floor = self._holding_floor(g)
            new = np.maximum(self._hold.solve(W[rows], weight[rows], floor, self.robot.tmax).tensions, 1e-3)
            if tensions is not None and float(np.abs(new - tensions).max()) < 1e-9:
                break
            tensions = new
            forces, l0 = self._law_for_tension(g, tensions)
            size = np.sqrt(np.einsum("ij,ij->i", forces.forces, forces.forces))
            unit = forces.forces / np.maximum(size, 1e-300)[:, None]
            directions = np.where(size[:, None] > 0.0, unit, g.directions)
        return forces, l0

    def _holding_floor(self, g: Geometry) -> Array | float:
        """The least tension a cable holds the platform with at the start: ``robot.tmin``."""
        return self.robot.tmin

    def _read(self) -> Geometry:
        """The current geometry, read from DART once per (sub-)step."""
        if self._geometry is not None:
            return self._geometry
        tf = self._body.getTransform()
        p, R = tf.translation(), tf.rotation()
        v, w = self._body.getLinearVelocity(), self._body.getAngularVelocity()
        arms, lengths, d, _, rates, spans = cable_geometry(self._a, self._b, p, R, v, w, self.robot.pulleys)
        points = p + arms
        if self.robot.pulleys is None:
            anchors, wrapped = self._a, self._no_wrap
        else:  # the free spans start where the cables leave their pulleys; the rest of each length is on the wheel
            anchors = points + spans
            wrapped = lengths - np.sqrt(np.einsum("ij,ij->i", spans, spans))
        g = Geometry(*(readonly(x) for x in (p, R, np.concatenate((v, w)), points, arms, lengths, d, rates,
                                             anchors, wrapped)))
        self._geometry = g
        return g

    def state(self) -> PlatformState:
        """The current state (chord lengths; tensions at the platform end, mean over the last step)."""
        g = self._read()
        return PlatformState.of(self.step_count, self.t, g.position, g.rotation, g.twist, g.lengths, g.rates,
                                self._tensions)

    def message(self, clamped: int) -> State:
        """The current state as a ``sim/state`` message."""
        return state_message(self.state(), clamped)

    def snapshot(self) -> dict[str, Any]:
        w = self._winch
        return {**world_snapshot(self._world, self.step_count, self._tensions),
                "saturated": self.saturated, "stopped": self.stopped, "fallbacks": self.fallbacks,
                "angle": w.angle.tolist(), "speed": w.speed.tolist(), "integral": w.integral.tolist(),
                "l0_rate": self._l0_rate.tolist(), "ref": None if self._ref is None else self._ref.tolist(),
                "frame_tensions": self._frame_tensions.tolist()}

    def restore(self, snapshot: dict[str, Any]) -> None:
        self.step_count, self._tensions = restore_world(self._world, snapshot, self.robot.m)
        angle, speed, integral, l0_rate, ref, frame = arrays(snapshot, "angle", "speed", "integral", "l0_rate",
                                                             "ref", "frame_tensions")
        if angle is None or speed is None or integral is None or l0_rate is None or frame is None:
            raise ValueError("not a snapshot of a winch model (no drum state)")
        self._winch = WinchState(angle, speed, integral)
        self._l0_rate, self._ref, self._frame_tensions = l0_rate, ref, readonly(frame)
        self.saturated, self.stopped = int(snapshot["saturated"]), int(snapshot["stopped"])
        self.fallbacks = int(snapshot["fallbacks"])
        self._geometry = None

    def encoder_lengths(self) -> Array:
        """(m,) the unstretched lengths the winches have paid out, r θ (what drum encoders measure)."""
        return readonly(self.winch.radius * self._winch.angle)

    def load_cell_tensions(self) -> Array:
        """(m,) the tensions at the frame end over the last step (what a load cell at the winch reads)."""
        return self._frame_tensions

    # -- dynamics ---------------------------------------------------------------------------------
    def _apply(self, g: Geometry, forces: Array) -> None:
        """Apply the cables' forces (m, 3) at their platform points as one force at the COM and a moment."""
        self._body.setExtForce(forces.sum(axis=0), np.zeros(3), False, True)
        self._body.setExtTorque(cross_rows(g.arms, forces).sum(axis=0), False)
        self._world.step()  # semi-implicit Euler; clears the external force and torque afterwards
        self._geometry = None

    def step(self, command: np.ndarray) -> StepReport:
        """One ``dt`` under ``command``: m tensions (N) or m unstretched lengths (m), per :attr:`command`."""
        cmd = np.asarray(command, dtype=float)
        if cmd.shape != (self.robot.m,):
            raise ValueError(f"expected {self.robot.m} {self.command}, got shape {cmd.shape}")
        self._fell_back = False
        report = self._step_tensions(cmd) if self.command == "tensions" else self._step_lengths(cmd)
        if self._fell_back:
            self.fallbacks += 1
        self.step_count += 1
        return report

    def _step_tensions(self, commanded: Array) -> StepReport:
        applied, low, high = clamp_tensions(commanded, tension_ceiling(self.robot))
        g = self._read()
        forces, l0 = self._law_for_tension(g, applied)
        self._apply(g, forces.forces)
        r = self.winch.radius
        self._winch = WinchState(l0 / r, (l0 - r * self._winch.angle) / (self.dt * r), self._winch.integral)
        self._tensions = readonly(np.array(forces.platform))
        self._frame_tensions = readonly(np.array(forces.frame))
        return StepReport(self._tensions, low, high, readonly(np.zeros(self.robot.m)))

    def _step_lengths(self, commanded: Array) -> StepReport:
        if not np.all(np.isfinite(commanded)) or np.any(commanded <= 0.0):
            raise ValueError("commanded lengths must be finite and > 0")
        high = int(np.count_nonzero(commanded > self.robot.max_length))
        lengths = np.minimum(commanded, self.robot.max_length)
        p, h = self.winch, self.h
        ref = lengths / p.radius
        speed_ref = (ref - self._ref) / self.dt if self._ref is not None else np.zeros_like(ref)
        self._ref = ref
        platform_sum = np.zeros(self.robot.m)
        frame_sum = np.zeros(self.robot.m)
        s = self._winch
        top = self.robot.max_length / p.radius
        for j in range(self.substeps):
            g = self._read()
            l0 = p.radius * s.angle
            if np.any(l0 < self.min_length):
                short = np.flatnonzero(l0 < self.min_length)
                self._fallback(f"cable(s) {short.tolist()} wound in to {float(l0.min()):.3g} m, below the "
                               f"{self.min_length:.3g} m the sub-steps can follow: taken as {self.min_length:.3g} m")
                l0 = np.maximum(l0, self.min_length)
            law = self._law(g, l0, p.radius * s.speed)
            torque, integral, saturated = drive_torque(p, s, ref + speed_ref * (j * h), speed_ref, h)
            self.saturated += int(np.count_nonzero(saturated))
            s = drum_step(p, s, torque, law.frame, integral, h)
            s, stopped = end_stops(s, 0.0, top)
            self.stopped += stopped
            self._apply(g, law.forces)
            platform_sum += law.platform
            frame_sum += law.frame
        self._winch = s
        self._tensions = readonly(platform_sum / self.substeps)
        self._frame_tensions = readonly(frame_sum / self.substeps)
        return StepReport(self._tensions, 0, high, readonly(np.zeros(self.robot.m)))
