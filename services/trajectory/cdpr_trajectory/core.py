"""The trajectory's step: tick k → setpoint k (a pure function of the sim time t_k = k·dt)."""

from __future__ import annotations

import numpy as np

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


def setpoints_between(trajectory: Trajectory, first: int, last: int, dt: float) -> tuple[Setpoint, ...]:
    """Setpoints ``first`` … ``last``: :func:`setpoint_at` of each, bit for bit, from one
    :meth:`~cdpr.mechanics.trajectory.Trajectory.sample_block` (a block of 100 in ~50 µs instead of ~1 ms)."""
    if last < first:
        return ()
    steps = np.arange(first, last + 1)
    times = steps * dt
    b = trajectory.sample_block(times)
    poses = np.hstack((b.position, b.quaternion)).tolist()
    return tuple(Setpoint(step=k, t=t, pose=tuple(p), twist=tuple(v), accel=tuple(a))
                 for k, t, p, v, a in zip(steps.tolist(), times.tolist(), poses, b.twist.tolist(), b.accel.tolist(),
                                          strict=True))
