"""Run metrics computed from the message streams (pure; used by `cdpr run` and the recorder).

Errors compare the sim's state k with the trajectory's setpoint k (the same step); a controller fed from the
sensors sends its estimate of state k with command k, and the estimate's errors compare it with state k.
The state digest is SHA-256 over the encoded states in step order: two runs with equal digests produced
bit-identical state streams.
"""

from __future__ import annotations

import hashlib
import math
from dataclasses import dataclass, field

import numpy as np

from cdpr.mechanics.estimation import estimate_errors
from cdpr.mechanics.rotation import orientation_error, quat_to_matrix
from cdpr.protocol import Command, Setpoint, State


@dataclass
class RunMetrics:
    states: dict[int, State] = field(default_factory=dict)
    state_bytes: dict[int, bytes] = field(default_factory=dict)
    setpoints: dict[int, Setpoint] = field(default_factory=dict)
    infeasible_commands: int = 0
    commands: int = 0
    command_steps: set[int] = field(default_factory=set)
    estimates: dict[int, tuple[float, ...]] = field(default_factory=dict)  # step -> the command's estimate

    def add_state(self, state: State) -> None:
        if state.step not in self.states:  # a resent state is the same state
            self.states[state.step] = state
            self.state_bytes[state.step] = state.encode()  # as the sim put it on sim/state

    def add_setpoint(self, sp: Setpoint) -> None:
        self.setpoints.setdefault(sp.step, sp)

    def add_command(self, cmd: Command) -> None:
        if cmd.step in self.command_steps:  # one applied command per step
            return
        self.command_steps.add(cmd.step)
        self.commands += 1
        if cmd.estimate is not None:
            self.estimates[cmd.step] = cmd.estimate
        if not cmd.feasible:
            self.infeasible_commands += 1

    @property
    def last_step(self) -> int:
        return max(self.states, default=-1)

    def digest(self) -> str:
        h = hashlib.sha256()
        for k in sorted(self.state_bytes):
            h.update(self.state_bytes[k])
        return h.hexdigest()

    def errors(self) -> tuple[np.ndarray, np.ndarray]:
        """Position and orientation error norms for every step with both a state and a setpoint.

        The final state (after the last tick) has no setpoint and so no error: the "final" error is
        that of the last tick's step.
        """
        pos, rot = [], []
        for k in sorted(self.states):
            sp = self.setpoints.get(k)
            if sp is None:
                continue
            st = self.states[k]
            pos.append(math.dist(st.pose[:3], sp.pose[:3]))
            e = orientation_error(quat_to_matrix(sp.pose[3:]), quat_to_matrix(st.pose[3:]))
            rot.append(float(np.linalg.norm(e)))
        return np.asarray(pos), np.asarray(rot)

    def estimate_errors(self) -> tuple[np.ndarray, np.ndarray]:
        """Position and orientation errors (m, rad) of the estimates sent with the commands, against the states
        of their steps (every step with both)."""
        steps = [k for k in sorted(self.estimates) if k in self.states]
        if not steps:
            return np.zeros(0), np.zeros(0)
        return estimate_errors([self.estimates[k][:7] for k in steps], [self.states[k].pose for k in steps])

    def summary(self) -> dict[str, float | int | str | list[float] | None]:
        pos, rot = self.errors()
        applied = [self.states[k].tensions for k in sorted(self.states) if k > 0]
        t = np.asarray(applied) if applied else np.zeros((0, 0))
        last = self.states.get(self.last_step)

        def rms(x: np.ndarray) -> float | None:
            return float(np.sqrt(np.mean(x * x))) if x.size else None

        change = np.abs(np.diff(t, axis=0)).max() if t.shape[0] > 1 else None
        est_pos, est_rot = self.estimate_errors()
        # a controller fed from the sensors: its estimate's errors (only then: other summaries keep their keys)
        estimate = {} if not est_pos.size else {
            "rms_estimate_position_error": rms(est_pos), "max_estimate_position_error": float(est_pos.max()),
            "rms_estimate_orientation_error": rms(est_rot), "max_estimate_orientation_error": float(est_rot.max()),
        }
        return {
            "rms_position_error": rms(pos),
            "max_position_error": float(pos.max()) if pos.size else None,
            "final_position_error": float(pos[-1]) if pos.size else None,
            "rms_orientation_error": rms(rot),
            "max_orientation_error": float(rot.max()) if rot.size else None,
            "tension_min": float(t.min()) if t.size else None,
            "tension_max": float(t.max()) if t.size else None,
            "cable_tension_min": t.min(axis=0).tolist() if t.size else None,  # per cable, for per-cable limits
            "cable_tension_max": t.max(axis=0).tolist() if t.size else None,
            "max_tension_change": float(change) if change is not None else None,
            "clamped_commands": last.clamped if last is not None else 0,
            "infeasible_commands": self.infeasible_commands,
            "state_digest": self.digest(),
            **estimate,
        }
