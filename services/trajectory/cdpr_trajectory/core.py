"""The trajectory's step: tick k → setpoint k (a pure function of the sim time t_k = k·dt)."""

from __future__ import annotations

from cdpr.mechanics.trajectory import Trajectory
from cdpr.protocol import Setpoint


def setpoint_at(trajectory: Trajectory, step: int, dt: float) -> Setpoint:
    t = step * dt
    sp = trajectory.sample(t)
    return Setpoint(
        step=step,
        t=t,
        pose=(*sp.position.tolist(), *sp.quaternion.tolist()),
        twist=tuple(sp.twist.tolist()),
        accel=tuple(sp.accel.tolist()),
    )
