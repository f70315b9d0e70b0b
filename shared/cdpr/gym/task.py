"""The tracking task of :mod:`cdpr.gym`: observation layout and bounds, actions, reward, termination. No I/O.

Everything here is a pure function of the scenario (its robot and trajectory), the options and the
messages of the loop (:class:`~cdpr.protocol.State`, :class:`~cdpr.protocol.Setpoint`,
:class:`~cdpr.protocol.Sensors`): the local and the session mode of the environment share it, so for the
same states they give the same observations and rewards, bit for bit.

Observation (a flat ``float32`` vector, in this order; docs/learning.md):

=====================  ====  ================================================================
``position_error``      3    setpoint position − platform position, m (world frame)
``orientation_error``   3    log(R_d Rᵀ) as a rotation vector, rad (world frame)
``twist``               6    platform [v; ω], m/s and rad/s (world frame, at the centre of mass)
``setpoint_twist``      6    the trajectory's twist at the same step
``setpoint_accel``      6    the trajectory's acceleration at the same step
``cable_lengths``       m    m (the encoders' noisy readings when the scenario has sensors)
``tensions``            m    N, as applied over the last step (the load cells' when it has sensors)
=====================  ====  ================================================================

Every entry is clipped to the observation space's finite bounds (:meth:`Task.bounds`).
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import numpy as np

from cdpr.config.scenario import Scenario
from cdpr.mechanics.robot import GRAVITY
from cdpr.mechanics.rotation import Array, orientation_error, quat_to_matrix
from cdpr.protocol import Sensors, Setpoint, State

ActionKind = Literal["tensions", "wrench", "residual"]
ACTIONS: tuple[ActionKind, ...] = ("tensions", "wrench", "residual")
OBSERVATION_PARTS = ("position_error", "orientation_error", "twist", "setpoint_twist", "setpoint_accel",
                     "cable_lengths", "tensions")


@dataclass(frozen=True)
class RewardWeights:
    """cost = position·‖e_p‖ + orientation·‖e_R‖ + effort·mean((f/f_ref)²) + rate·mean((Δf/f_ref)²), with
    f_ref the platform's weight m·g and Δf the change of the mean applied tensions from one env step to
    the next; reward = −cost / (1 + cost), in (−1, 0]."""

    position: float = 100.0  # per m: 1 cm of error costs 1
    orientation: float = 10.0  # per rad
    effort: float = 1e-3
    rate: float = 1e-2

    @classmethod
    def of(cls, weights: dict[str, float] | RewardWeights | None) -> RewardWeights:
        if weights is None or isinstance(weights, RewardWeights):
            return weights or cls()
        known = {"position", "orientation", "effort", "rate"}
        if unknown := set(weights) - known:
            raise ValueError(f"reward_weights: unknown weight(s) {', '.join(sorted(unknown))} "
                             f"(known: {', '.join(sorted(known))})")
        for name, value in weights.items():
            if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
                raise ValueError(f"reward_weights.{name}: expected a finite number >= 0, got {value!r}")
        return cls(**{k: float(v) for k, v in weights.items()})


@dataclass(frozen=True)
class Limits:
    """When an episode terminates, and the observation's bounds for the unbounded quantities."""

    max_position_error: float = 0.25  # m
    max_orientation_error: float = 0.5  # rad
    slack_fraction: float = 0.5  # a cable below this fraction of tmin (after step 0) is slack
    max_speed: float = 5.0  # m/s: the twist's bound (observation)
    max_angular_speed: float = 10.0  # rad/s


@dataclass
class Task:
    """The task for one scenario: sizes, bounds, action mapping, reward and termination."""

    scenario: Scenario
    action: ActionKind = "residual"
    control_every: int = 10
    weights: RewardWeights = field(default_factory=RewardWeights)
    limits: Limits = field(default_factory=Limits)

    def __post_init__(self) -> None:
        if self.action not in ACTIONS:
            raise ValueError(f"action: expected one of {', '.join(ACTIONS)}, got {self.action!r}")
        if not (isinstance(self.control_every, int) and self.control_every >= 1):
            raise ValueError(f"control_every: expected an integer >= 1, got {self.control_every!r}")
        robot = self.scenario.robot
        self.m = robot.m
        self.rows = list(self.scenario_rows())
        self.tmin, self.tmax = robot.tmin, robot.tmax  # (m,) each cable's limits
        self.weight = float(robot.mass) * float(-GRAVITY[2])  # m g, N
        radius = float(np.max(np.linalg.norm(np.asarray(robot.platform_points, dtype=float), axis=1)))
        self.radius = max(radius, 0.1)  # m: the moment arm of the wrench scales (a point mass has none)
        frame = np.asarray(robot.frame_points, dtype=float)
        # the workspace box: the anchors' extent, down to the floor z = 0 (a suspended robot's anchors are all high)
        self.box_low, self.box_high = frame.min(axis=0), frame.max(axis=0)
        if robot.mode != "planar":
            self.box_low[2] = min(self.box_low[2], 0.0)
        diagonal = float(np.linalg.norm(self.box_high - self.box_low))
        self.max_length = diagonal + self.radius  # no cable is longer inside the frame's box
        self.total_steps = self.scenario.total_steps
        self.env_steps = -(-self.total_steps // self.control_every)  # the last env step may be shorter
        self._peak = self._trajectory_peaks()

    def scenario_rows(self) -> Sequence[int]:
        from cdpr.mechanics.control import controlled_rows

        return controlled_rows(self.scenario.robot, self.scenario.variant)

    def _trajectory_peaks(self) -> tuple[float, float]:
        """The largest speed and acceleration component of the trajectory (sampled every 10 ms)."""
        traj, dt = self.scenario.trajectory, 0.01
        speed = accel = 0.0
        for t in np.arange(0.0, self.scenario.duration + dt, dt):
            s = traj.sample(float(t))
            speed = max(speed, float(np.abs(s.twist).max()))
            accel = max(accel, float(np.abs(s.accel).max()))
        return speed, accel

    # -- spaces ------------------------------------------------------------------------------------
    @property
    def observation_size(self) -> int:
        return 24 + 2 * self.m

    @property
    def action_size(self) -> int:
        return self.m if self.action == "tensions" else len(self.rows)

    def bounds(self) -> tuple[Array, Array]:
        """The observation space's (low, high), finite."""
        lim = self.limits
        lin, ang = lim.max_speed, lim.max_angular_speed
        sp_speed = max(1.0, 2.0 * self._peak[0])
        sp_accel = max(10.0, 2.0 * self._peak[1])
        high = np.concatenate([
            np.full(3, max(lim.max_position_error, 1e-3) * 2.0),  # twice: the step that crosses the limit
            np.full(3, math.pi),
            [lin] * 3 + [ang] * 3,
            np.full(6, sp_speed),
            np.full(6, sp_accel),
            np.full(self.m, self.max_length),
            1.5 * self.tmax,  # load cells: noise and bias around [0, tmax]
        ])
        low = -high
        low[24:] = 0.0
        return low.astype(np.float32), high.astype(np.float32)

    def names(self) -> list[str]:
        """One name per observation entry (docs, logs)."""
        out = [f"position_error_{a}" for a in "xyz"] + [f"orientation_error_{a}" for a in "xyz"]
        out += [f"twist_{a}" for a in ("vx", "vy", "vz", "wx", "wy", "wz")]
        out += [f"setpoint_twist_{a}" for a in ("vx", "vy", "vz", "wx", "wy", "wz")]
        out += [f"setpoint_accel_{a}" for a in ("ax", "ay", "az", "alphax", "alphay", "alphaz")]
        out += [f"cable_length_{i + 1}" for i in range(self.m)] + [f"tension_{i + 1}" for i in range(self.m)]
        return out

    # -- actions -----------------------------------------------------------------------------------
    def wrench_scale(self) -> Array:
        """Per controlled row: the wrench an action of 1 adds (N, N·m): residual 0.2·m·g (·r), wrench 2·m·g (·r)."""
        factor = 0.2 if self.action == "residual" else 2.0
        scale = np.array([self.weight] * 3 + [self.weight * self.radius] * 3) * factor
        return scale[self.rows]

    def hover_wrench(self) -> Array:
        """The wrench that holds the platform's weight (controlled rows): what an action of 0 asks in wrench mode."""
        w = np.zeros(6)
        w[2] = self.weight
        return w[self.rows]

    def tensions_of(self, action: Array) -> Array:
        """Tensions action: [-1, 1]^m → [tmin, tmax]^m."""
        a = np.clip(np.asarray(action, dtype=float), -1.0, 1.0)
        return self.tmin + 0.5 * (a + 1.0) * (self.tmax - self.tmin)

    def wrench_of(self, action: Array) -> Array:
        """Wrench (or residual) action → the wrench on the controlled rows."""
        a = np.clip(np.asarray(action, dtype=float), -1.0, 1.0)
        w = a * self.wrench_scale()
        return w + self.hover_wrench() if self.action == "wrench" else w

    # -- observations and reward -------------------------------------------------------------------
    def errors(self, state: State, setpoint: Setpoint) -> tuple[Array, Array]:
        """(position error, orientation error) of state k against setpoint k."""
        e_p = np.asarray(setpoint.pose[:3], dtype=float) - np.asarray(state.pose[:3], dtype=float)
        e_r = orientation_error(quat_to_matrix(setpoint.pose[3:]), quat_to_matrix(state.pose[3:]))
        return e_p, e_r

    def observe(self, state: State, setpoint: Setpoint, sensors: Sensors | None) -> Array:
        e_p, e_r = self.errors(state, setpoint)
        lengths = (None if sensors is None else sensors.get("encoders")) or state.cable_lengths
        tensions = (None if sensors is None else sensors.get("load_cells")) or state.tensions
        obs = np.concatenate([e_p, e_r, state.twist, setpoint.twist, setpoint.accel, lengths, tensions])
        low, high = self.bounds_cache
        return np.clip(obs.astype(np.float32), low, high)

    @property
    def bounds_cache(self) -> tuple[Array, Array]:
        cached: tuple[Array, Array] | None = getattr(self, "_bounds", None)
        if cached is None:
            cached = self._bounds = self.bounds()
        return cached

    def cost(self, e_p: Array, e_r: Array, tensions: Array, previous: Array | None) -> float:
        w = self.weights
        f = np.asarray(tensions, dtype=float) / self.weight
        cost = w.position * float(np.linalg.norm(e_p)) + w.orientation * float(np.linalg.norm(e_r))
        cost += w.effort * float(np.mean(f * f))
        if previous is not None:
            d = f - np.asarray(previous, dtype=float) / self.weight
            cost += w.rate * float(np.mean(d * d))
        return cost

    @staticmethod
    def reward(cost: float) -> float:
        return -cost / (1.0 + cost)

    def termination(self, state: State, e_p: Array, e_r: Array) -> str | None:
        """Why the episode must end at this state (None: it goes on)."""
        lim = self.limits
        p = np.asarray(state.pose[:3], dtype=float)
        if not np.all(np.isfinite(p)) or np.any(p < self.box_low) or np.any(p > self.box_high):
            return "the platform left the frame's box"
        if float(np.linalg.norm(e_p)) > lim.max_position_error:
            return f"position error above {lim.max_position_error:g} m"
        if float(np.linalg.norm(e_r)) > lim.max_orientation_error:
            return f"orientation error above {lim.max_orientation_error:g} rad"
        if state.step > 0 and bool(np.any(slack := np.asarray(state.tensions) < lim.slack_fraction * self.tmin)):
            i = int(np.argmax(slack))
            return f"a cable went slack (cable {i}: tension below {lim.slack_fraction * self.tmin[i]:g} N)"
        return None
