"""``cdpr workspace`` in Rerun: the grid of a :class:`~cdpr.mechanics.workspace.Workspace` as points in
the robot's static scene."""

from __future__ import annotations

import uuid
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
from numpy.typing import ArrayLike

from cdpr import recording as rec_mod
from cdpr.mechanics.robot import Robot
from cdpr.mechanics.rotation import matrix_to_quat
from cdpr.mechanics.workspace import Workspace


def record_workspace(
    robot: Robot,
    ws: Workspace,
    R: ArrayLike | None = None,
    rrd: str | Path | None = None,
    spawn: bool = False,
    info: dict[str, Any] | None = None,
) -> list[str]:
    """Log the frame, anchors, the platform at home (orientation R) and the grid: feasible points green at
    :data:`cdpr.recording.WORKSPACE_FEASIBLE`, the others faint red at ``WORKSPACE_INFEASIBLE``.

    ``info`` is logged as the session description. Returns the sinks' problems (see ``Recording.close``).
    """
    rec = rec_mod.Recording(
        f"workspace-{robot.name}-{uuid.uuid4().hex[:8]}",
        rrd=rrd,
        spawn=spawn,
        blueprint=rec_mod.scene_blueprint(),
    )
    rec.send_recording_name(f"{robot.name} wrench-feasible workspace")
    rec_mod.log_scene(rec, robot, ghost=False)
    rotation = np.eye(3) if R is None else np.asarray(R, dtype=float)
    rec.log(
        rec_mod.PLATFORM,
        rr.Transform3D(translation=robot.home_position, quaternion=rr.Quaternion(xyzw=matrix_to_quat(rotation))),
        static=True,
    )
    step = float(ws.spacing[ws.spacing > 0].min()) if np.any(ws.spacing > 0) else 0.1
    rec.log(
        rec_mod.WORKSPACE_FEASIBLE,
        rr.Points3D(ws.points[ws.feasible], radii=0.25 * step, colors=[(40, 170, 60, 255)]),
        static=True,
    )
    rec.log(
        rec_mod.WORKSPACE_INFEASIBLE,
        rr.Points3D(ws.points[~ws.feasible], radii=0.1 * step, colors=[(200, 60, 60, 40)]),
        static=True,
    )
    rec_mod.log_session(rec, info or {"robot": robot.summary()})
    return rec.close()
