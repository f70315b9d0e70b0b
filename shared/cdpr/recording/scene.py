"""Everything Rerun, in one place: ids, timelines, entity paths, the static scene, the blueprint, sinks.

The recorder service, ``cdpr show`` and ``cdpr report`` all go through this module, so an entity path
is spelled exactly once (documented in ``docs/recording.md``). Two timelines: ``step`` (sequence, the
clock's step k) and ``sim_time`` (duration, the message's own ``t`` — never wall time).

Pure helpers (:func:`cable_strips`, :func:`tension_colors`, :func:`anchor_labels`) compute geometry and
colours; the ``log_*``/``send_*`` functions write to a :class:`Recording` passed in (no global
recording is ever used).
"""

from __future__ import annotations

import json
import os
import uuid
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
import rerun as rr
import rerun.blueprint as rrb
from numpy.typing import ArrayLike, NDArray

from cdpr.errors import InputError
from cdpr.mechanics.camera import Camera
from cdpr.mechanics.pulley import pulley_geometry
from cdpr.mechanics.robot import Robot
from cdpr.mechanics.rotation import matrix_to_quat, quat_matrix
from cdpr.protocol.streams import (
    ACTUAL_POSITION,
    ACTUAL_QUATERNION,
    ACTUAL_TWIST,
    CABLE_LENGTHS,
    TENSION_SERIES,
    Column,
)
from cdpr.sensors import encoders, imu, load_cells

APP_ID = "cdpr"
RECORDING_ID_ENV = "CDPR_RECORDING_ID"  # forces the recording id (e.g. to merge several recorders)

# Timelines
STEP = "step"
SIM_TIME = "sim_time"

# Static description of the session (a JSON TextDocument: scenario, dt, robot, limits, ids)
SESSION = "session"

# 3D scene (world frame, z up)
WORLD = "world"
FRAME = "world/frame"  # static wireframe box robot.frame_min..frame_max
FRAME_ANCHORS = "world/frame/anchors"  # static a_i, labelled with the cable indices
PLATFORM = "world/platform"  # Transform3D: the platform's pose (3D rate)
PLATFORM_SHAPE = "world/platform/shape"  # static shape in the platform frame
PLATFORM_ANCHORS = "world/platform/anchors"  # static b_i in the platform frame
CABLES = "world/cables"  # m line strips b_i(world) → a_i, coloured by tension (3D rate)
DESIRED = "world/desired"  # Transform3D: the desired pose (3D rate)
DESIRED_SHAPE = "world/desired/shape"  # static translucent ghost of the platform
PATH = "world/path"  # line strip of the travelled path (path rate)
PLANNED_PATH = "world/planned_path"  # static line strip of the trajectory, sampled
WORKSPACE_FEASIBLE = "world/workspace/feasible"  # static points: wrench-feasible grid points (cdpr workspace)
WORKSPACE_INFEASIBLE = "world/workspace/infeasible"  # static faint points: the other grid points
CAMERAS = "world/cameras"  # a frame-mounted camera: world/cameras/<name> (static Transform3D + Pinhole)
PLATFORM_CAMERAS = "world/platform/cameras"  # a platform-mounted one: moves with the platform
CAMERA_MARKERS = "markers"  # <camera>/markers: the 2D points it saw, labelled with the markers' ids (per frame)

# Time series (every step)
DESIRED_POSITION = "desired/position"  # [x, y, z] of the setpoint, m
DESIRED_QUATERNION = "desired/quaternion"  # [qx, qy, qz, qw]
# the state's series (actual/position, actual/quaternion, actual/twist, actual/cable_lengths, actual/clamped,
# tension/cable_<i>): declared with the state's columns, cdpr.protocol.streams
POSITION_ERROR = "error/position"  # view origin of the two below
POSITION_ERROR_AXES = "error/position/axes"  # desired − actual, [x, y, z], m
POSITION_ERROR_NORM = "error/position/norm"  # ‖desired − actual‖, m
ORIENTATION_ERROR = "error/orientation"
ORIENTATION_ERROR_AXES = "error/orientation/axes"  # rotation vector e, exp([e]×) R = R_desired, rad
ORIENTATION_ERROR_NORM = "error/orientation/norm"  # ‖e‖, rad
TENSION = "tension"  # view origin: one entity per cable plus the limits
TENSION_MIN = "tension/tmin"
TENSION_MAX = "tension/tmax"
COMMAND_FEASIBLE = "command/feasible"  # 1 feasible, 0 not (controller's tension distribution)
COMMAND_STATUS = "command/status"  # TextLog of every command whose status is not "ok"
COMMAND_TENSIONS = "command/tensions"  # m values: the tensions the controller commanded, N (tension output)
COMMAND_LENGTHS = "command/lengths"  # m values: the unstretched lengths commanded, m (length output)
COMMAND_SOLVE_TIME = "command/solve_time"  # s the controller spent on the step (feedback law + TDA)
LOOP_LAG = "loop/lag"  # s from the sim's state going out to the step's integration (controller + wait)
# the sensors' series are declared with their kinds (cdpr.sensors: each channel's ``series``), e.g.
SENSOR_ENCODERS, SENSOR_LOAD_CELLS = encoders.SERIES, load_cells.SERIES
SENSOR_ACCEL, SENSOR_GYRO = imu.ACCEL, imu.GYRO
CLOCK = "clock"  # clock/<stat> for each number in clock/status stats (nested maps joined with "/")
CLOCK_STATE = "clock/state"  # TextLog of the clock's state changes

AXES = ("x", "y", "z")
AXIS_COLORS = ((228, 26, 28), (77, 175, 74), (55, 126, 184))

# Archetype component columns, as stored (for reading recordings back)
SCALARS_COLUMN = "Scalars:scalars"
TEXT_DOCUMENT_COLUMN = "TextDocument:text"

# A perceptual colour scale (viridis, 5 stops) from tmin (dark) to tmax (yellow)
_SCALE = np.array([[68, 1, 84], [59, 82, 139], [33, 145, 140], [94, 201, 98], [253, 231, 37]], dtype=float)
_FRAME_COLOR = (140, 140, 140, 255)
_PLATFORM_COLOR = (70, 130, 180, 255)
_GHOST_COLOR = (255, 165, 0, 70)
_PATH_COLOR = (220, 50, 47, 255)
_PLANNED_COLOR = (255, 165, 0, 160)
_ANCHOR_COLOR = (30, 30, 30, 255)
_CABLE_RADIUS = 0.01
DEFAULT_VIEWER_URL = "rerun+http://127.0.0.1:9876/proxy"  # where `rerun` (and a spawned viewer) listens


def tension_series(i: int) -> str:
    """Entity of cable ``i``'s tension (0-based, as in the robot file and on the wire)."""
    return TENSION_SERIES.format(i=i)


def clock_series(stat: str) -> str:
    return f"{CLOCK}/{stat}"


def recording_id(session: str, env: Mapping[str, str] | None = None) -> str:
    """``$CDPR_RECORDING_ID`` if set, else the session id plus a random suffix (one recording per run)."""
    forced = (os.environ if env is None else env).get(RECORDING_ID_ENV, "").strip()
    return forced or f"{session}-{uuid.uuid4().hex[:12]}"


# --------------------------------------------------------------------------------------------------
# Pure geometry and colours


def cable_strips(robot: Robot, positions: ArrayLike, quaternions: ArrayLike) -> NDArray[np.float64]:
    """Cable segments for n poses: (n, m, 2, 3), each [b_i in the world, a_i] (over an exit pulley, its free span:
    [b_i, T_i], T_i where the cable leaves the wheel). Quaternions [qx,qy,qz,qw]."""
    p = np.asarray(positions, dtype=float).reshape(-1, 3)
    q = np.asarray(quaternions, dtype=float).reshape(-1, 4)
    q = q / np.linalg.norm(q, axis=1, keepdims=True)
    R = np.moveaxis(quat_matrix(*q.T), -1, 0)  # (n, 3, 3)
    b_world = p[:, None, :] + np.einsum("nij,mj->nmi", R, robot.platform_points)
    if robot.pulleys is None:
        a = np.broadcast_to(robot.frame_points, b_world.shape)
    else:
        a = pulley_geometry(robot.frame_points, robot.pulleys, b_world).tangent_points
    return np.stack([b_world, a], axis=2)


def tension_colors(tensions: ArrayLike, tmin: ArrayLike, tmax: ArrayLike) -> NDArray[np.uint8]:
    """RGBA colours (…, 4) of tensions on the scale tmin → tmax (values outside are clipped); the limits are
    numbers, or one per cable (the last axis of ``tensions``)."""
    f = np.asarray(tensions, dtype=float)
    tmin, tmax = np.asarray(tmin, dtype=float), np.asarray(tmax, dtype=float)
    span = np.where(tmax > tmin, tmax - tmin, 1.0)
    u = np.clip((f - tmin) / span, 0.0, 1.0) * (len(_SCALE) - 1)
    lo = np.minimum(np.floor(u).astype(int), len(_SCALE) - 2)
    frac = (u - lo)[..., None]
    rgb = _SCALE[lo] * (1.0 - frac) + _SCALE[lo + 1] * frac
    alpha = np.full((*f.shape, 1), 255.0)
    return np.concatenate([np.rint(rgb), alpha], axis=-1).astype(np.uint8)


def anchor_labels(points: ArrayLike) -> tuple[NDArray[np.float64], list[str]]:
    """Distinct anchor points and their labels: the indices of the cables that share each point."""
    pts = np.asarray(points, dtype=float)
    unique: list[NDArray[np.float64]] = []
    labels: list[list[int]] = []
    for i, p in enumerate(pts):
        for j, u in enumerate(unique):
            if np.allclose(p, u, atol=1e-9):
                labels[j].append(i)
                break
        else:
            unique.append(p)
            labels.append([i])
    return np.array(unique).reshape(-1, 3), [",".join(str(i) for i in group) for group in labels]


# --------------------------------------------------------------------------------------------------
# Sinks, blueprint, static scene


class Recording:
    """One recording (app id ``cdpr``, one recording id) written to an .rrd file and/or streamed to viewers.

    The file and the viewers get separate :class:`rerun.RecordingStream` objects of the same recording,
    so a viewer that is slow or unreachable can never hold up, or cost, the file: :meth:`close` finishes
    the file first. Columns are built once and sent to every stream.
    ``spawn`` starts a native viewer (default port) and streams to it; ``viewer`` is a gRPC URL such as
    ``rerun+http://127.0.0.1:9876/proxy``. At least one sink is required.
    """

    def __init__(
        self,
        rec_id: str,
        rrd: str | Path | None = None,
        spawn: bool = False,
        viewer: str | None = None,
        blueprint: rrb.Blueprint | None = None,
    ) -> None:
        self.recording_id = rec_id
        self.streams: list[rr.RecordingStream] = []  # the file's first
        self._file: rr.RecordingStream | None = None
        if rrd is not None:
            path = Path(rrd)
            try:
                path.parent.mkdir(parents=True, exist_ok=True)
                path.touch()
            except OSError as exc:
                raise InputError(f"--rrd: cannot write {path}: {exc.strerror or exc}") from None
            stream = rr.RecordingStream(APP_ID, recording_id=rec_id)
            stream.set_sinks(rr.FileSink(str(path)), default_blueprint=blueprint)
            self.streams.append(stream)
            self._file = stream
        urls: list[str] = []
        live = rr.RecordingStream(APP_ID, recording_id=rec_id) if spawn or viewer else None
        if spawn:
            rr.spawn(connect=False, recording=live, executable_path=rerun_binary())
            urls.append(DEFAULT_VIEWER_URL)
        if viewer and viewer not in urls:
            urls.append(viewer)
        if live is not None:
            try:
                live.set_sinks(*(rr.GrpcSink(url) for url in urls), default_blueprint=blueprint)
            except Exception as exc:  # the SDK raises on a malformed URL
                raise InputError(f"--connect-viewer: {viewer!r}: {str(exc).splitlines()[0]}") from None
            self.streams.append(live)
        if not self.streams:
            raise ValueError("a recording needs at least one sink: an .rrd path, spawn or a viewer URL")

    def log(self, path: str, *entity: Any, static: bool = False) -> None:
        for stream in self.streams:
            stream.log(path, *entity, static=static)

    def send_columns(self, path: str, indexes: Sequence[rr.TimeColumn], columns: Any) -> None:
        for stream in self.streams:
            stream.send_columns(path, indexes=indexes, columns=columns)

    def send_blueprint(self, bp: rrb.Blueprint) -> None:
        """Replace the layout (e.g. once the tension range of the run is known)."""
        for stream in self.streams:
            stream.send_blueprint(bp, make_active=True, make_default=True)

    def send_recording_name(self, name: str) -> None:
        for stream in self.streams:
            stream.send_recording_name(name)

    def close(self, viewer_timeout: float = 1.0) -> list[str]:
        """Flush and close every sink, the file first; returns the problems met (e.g. a lost viewer)."""
        problems = []
        for stream in self.streams:
            live = stream is not self._file
            try:
                if live:
                    stream.flush(timeout_sec=viewer_timeout)
                else:
                    stream.flush()
            except Exception as exc:  # the SDK raises RuntimeError when a gRPC sink cannot be reached
                problems.append(str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
            stream.disconnect()
        self.streams = []
        return problems


def camera_entity(camera: Camera) -> str:
    """Where a camera lives in the scene: under the platform's transform when it rides on it."""
    return f"{PLATFORM_CAMERAS if camera.on_platform else CAMERAS}/{camera.name}"


def log_cameras(rec: Recording, cameras: Sequence[Camera]) -> None:
    """Each camera as its mount transform and a pinhole (the frustum in the 3D view, its own 2D view)."""
    for cam in cameras:
        path, k = camera_entity(cam), cam.intrinsics
        rec.log(path, rr.Transform3D(translation=cam.mount_position, mat3x3=cam.mount_rotation), static=True)
        rec.log(path, rr.Pinhole(image_from_camera=k.matrix, resolution=[k.width, k.height],
                                 camera_xyz=rr.ViewCoordinates.RDF, image_plane_distance=0.3), static=True)


def send_camera_frames(rec: Recording, camera: Camera, steps: ArrayLike, times: ArrayLike,
                       pixels: Sequence[ArrayLike], ids: Sequence[Sequence[str]]) -> None:
    """A camera's frames: at each frame's step, the markers it saw as labelled 2D points (one call for all)."""
    if not len(np.asarray(steps)):
        return
    counts = [len(i) for i in ids]
    flat = np.concatenate([np.asarray(p, dtype=float).reshape(-1, 2) for p in pixels]) if sum(counts) else \
        np.zeros((0, 2))
    labels = [label for frame in ids for label in frame]
    rec.send_columns(f"{camera_entity(camera)}/{CAMERA_MARKERS}", time_columns(steps, times),
                     rr.Points2D.columns(positions=flat, labels=labels).partition(counts))


def send_camera_images(rec: Recording, camera: Camera, steps: ArrayLike, times: ArrayLike,
                       images: Sequence[bytes]) -> None:
    """A camera's images (JPEG) at their steps, on the camera's entity: shown in its 2D view and in the
    frustum of the 3D view."""
    if not len(np.asarray(steps)):
        return
    rec.send_columns(camera_entity(camera), time_columns(steps, times),
                     rr.EncodedImage.columns(blob=list(images), media_type=["image/jpeg"] * len(images)))


def blueprint(tension_range: tuple[float, float] | None = None, cameras: Sequence[Camera] = ()) -> rrb.Blueprint:
    """The default layout: the 3D scene beside the paper's Fig. 2/3 four panels (desired position,
    actual position, position error, cable tensions), with more plots in tabs under the scene, and what
    each camera sees (a 2D view per camera) beside the scene.

    ``tension_range`` fixes the tension plot's y axis (the recorder sends the layout again at the end
    with the range the tensions used, so that a tmax far above them does not squash the curves)."""
    figure = rrb.Grid(
        rrb.TimeSeriesView(origin=DESIRED_POSITION, name="Desired position (m)"),
        rrb.TimeSeriesView(origin=ACTUAL_POSITION, name="Actual position (m)"),
        rrb.TimeSeriesView(origin=POSITION_ERROR, name="Position error (m)"),
        rrb.TimeSeriesView(
            origin=TENSION,
            name="Cable tensions (N)",
            axis_y=rrb.ScalarAxis(range=tension_range) if tension_range is not None else None,
        ),
        grid_columns=2,
        name="Fig. 2/3",
    )
    more = rrb.Tabs(
        rrb.TimeSeriesView(origin=ORIENTATION_ERROR, name="Orientation error (rad)"),
        rrb.TimeSeriesView(origin=ACTUAL_TWIST, name="Twist"),
        # a controller fed from the sensors (controller.feedback: sensors): its estimate's errors (empty otherwise)
        rrb.TimeSeriesView(origin="estimate/error", name="Estimation error (m, rad)"),
        rrb.TimeSeriesView(origin=CABLE_LENGTHS, name="Cable lengths (m)"),
        rrb.TimeSeriesView(origin="command", name="Controller"),
        rrb.TimeSeriesView(origin="latency", name="Command age (steps), watchdog"),
        rrb.TimeSeriesView(origin=CLOCK, name="Clock"),
        rrb.TextLogView(origin="/", name="Events"),
    )
    scene: rrb.Container | rrb.View = rrb.Spatial3DView(origin=WORLD, name="Scene")
    if cameras:
        scene = rrb.Horizontal(scene, rrb.Vertical(*(rrb.Spatial2DView(origin=camera_entity(c), name=f"Camera {c.name}")
                                                     for c in cameras)), column_shares=[2, 1])
    return rrb.Blueprint(
        rrb.Horizontal(
            rrb.Vertical(scene, more, row_shares=[3, 2]),
            figure,
            column_shares=[2, 3],
        ),
        rrb.TimePanel(timeline=SIM_TIME),
        collapse_panels=False,
    )


def scene_blueprint() -> rrb.Blueprint:
    """Only the 3D scene (for ``cdpr show``)."""
    return rrb.Blueprint(rrb.Spatial3DView(origin=WORLD, name="Scene"), collapse_panels=True)


def _shape(robot: Robot, color: tuple[int, int, int, int]) -> Any:
    size = robot.shape.size
    solid = rr.components.FillMode.Solid
    if robot.shape.type == "box":
        return rr.Boxes3D(half_sizes=[[s / 2.0 for s in size]], colors=[color], fill_mode=solid)
    if robot.shape.type == "sphere":
        r = size[0]
        return rr.Ellipsoids3D(half_sizes=[[r, r, r]], colors=[color], fill_mode=solid)
    r, h = size
    return rr.Cylinders3D(lengths=[h], radii=[r], colors=[color], fill_mode=solid)


def log_scene(rec: Recording, robot: Robot, ghost: bool = True) -> None:
    """Static parts of the 3D scene: frame box, frame anchors, platform shape and anchors, ghost."""
    rec.log(WORLD, rr.ViewCoordinates.RIGHT_HAND_Z_UP, static=True)
    lo, hi = np.asarray(robot.frame_min), np.asarray(robot.frame_max)
    rec.log(
        FRAME,
        rr.Boxes3D(
            mins=[lo], sizes=[hi - lo], colors=[_FRAME_COLOR], fill_mode=rr.components.FillMode.MajorWireframe
        ),
        static=True,
    )
    a, a_labels = anchor_labels(robot.frame_points)
    rec.log(FRAME_ANCHORS, rr.Points3D(a, radii=0.04, colors=[_ANCHOR_COLOR], labels=a_labels), static=True)
    rec.log(PLATFORM_SHAPE, _shape(robot, _PLATFORM_COLOR), static=True)
    b, b_labels = anchor_labels(robot.platform_points)
    rec.log(
        PLATFORM_ANCHORS, rr.Points3D(b, radii=0.025, colors=[_ANCHOR_COLOR], labels=b_labels), static=True
    )
    rec.log(CABLES, rr.LineStrips3D.from_fields(radii=[_CABLE_RADIUS]), static=True)
    if ghost:
        rec.log(DESIRED_SHAPE, _shape(robot, _GHOST_COLOR), static=True)
        rec.log(PATH, rr.LineStrips3D.from_fields(radii=[0.008], colors=[_PATH_COLOR]), static=True)


def log_planned_path(rec: Recording, points: ArrayLike) -> None:
    rec.log(
        PLANNED_PATH,
        rr.LineStrips3D([np.asarray(points, dtype=float)], radii=0.006, colors=[_PLANNED_COLOR]),
        static=True,
    )


def log_session(rec: Recording, info: Mapping[str, Any]) -> None:
    """Static JSON description of the session (what ``cdpr report`` needs: dt, cables, limits...)."""
    rec.log(
        SESSION, rr.TextDocument(json.dumps(dict(info), indent=2), media_type=rr.MediaType.TEXT), static=True
    )


def log_series_styles(rec: Recording, m: int, per_cable_limits: bool = False) -> None:
    """Static names and colours of the time series (``per_cable_limits``: a tmin and a tmax line per cable)."""
    xyz = rr.SeriesLines(names=list(AXES), colors=list(AXIS_COLORS))
    for path in (DESIRED_POSITION, ACTUAL_POSITION, POSITION_ERROR_AXES, ORIENTATION_ERROR_AXES):
        rec.log(path, xyz, static=True)
    rec.log(POSITION_ERROR_NORM, rr.SeriesLines(names=["norm"], colors=[(0, 0, 0)]), static=True)
    rec.log(ORIENTATION_ERROR_NORM, rr.SeriesLines(names=["norm"], colors=[(0, 0, 0)]), static=True)
    rec.log(DESIRED_QUATERNION, rr.SeriesLines(names=["qx", "qy", "qz", "qw"]), static=True)
    rec.log(ACTUAL_QUATERNION, rr.SeriesLines(names=["qx", "qy", "qz", "qw"]), static=True)
    rec.log(ACTUAL_TWIST, rr.SeriesLines(names=["vx", "vy", "vz", "wx", "wy", "wz"]), static=True)
    rec.log(CABLE_LENGTHS, rr.SeriesLines(names=[f"cable {i}" for i in range(m)]), static=True)
    palette = tension_palette(m)
    for i in range(m):
        rec.log(tension_series(i), rr.SeriesLines(names=[f"cable {i}"], colors=[palette[i]]), static=True)
    if per_cable_limits:
        for path, name in ((TENSION_MIN, "tmin"), (TENSION_MAX, "tmax")):
            rec.log(path, rr.SeriesLines(names=[f"{name} cable {i}" for i in range(m)], colors=palette,
                                         widths=[1.0] * m), static=True)
    else:
        rec.log(TENSION_MIN, rr.SeriesLines(names=["tmin"], colors=[(120, 120, 120)], widths=[2.0]), static=True)
        rec.log(TENSION_MAX, rr.SeriesLines(names=["tmax"], colors=[(200, 0, 0)], widths=[2.0]), static=True)


def tension_palette(m: int) -> list[tuple[int, int, int]]:
    """Distinct colours for m cable series (Tableau 10, repeated)."""
    base = [
        (31, 119, 180),
        (255, 127, 14),
        (44, 160, 44),
        (214, 39, 40),
        (148, 103, 189),
        (140, 86, 75),
        (227, 119, 194),
        (127, 127, 127),
        (188, 189, 34),
        (23, 190, 207),
    ]
    return [base[i % len(base)] for i in range(m)]


# --------------------------------------------------------------------------------------------------
# Columnar logging (one call per entity and batch)


def time_columns(steps: ArrayLike, times: ArrayLike) -> list[rr.TimeColumn]:
    return [
        rr.TimeColumn(STEP, sequence=np.asarray(steps, dtype=np.int64)),
        rr.TimeColumn(SIM_TIME, duration=np.asarray(times, dtype=float)),
    ]


def send_scalars(rec: Recording, path: str, steps: ArrayLike, times: ArrayLike, values: ArrayLike) -> None:
    """Rows of scalars: ``values`` (n,) gives one series, (n, k) gives k series on one entity."""
    v = np.asarray(values, dtype=float)
    n = v.shape[0]
    if n == 0:
        return
    cols = rr.Scalars.columns(scalars=v.reshape(-1))
    if v.ndim == 2:
        cols = cols.partition(np.full(n, v.shape[1]))
    rec.send_columns(path, indexes=time_columns(steps, times), columns=cols)


def send_columns_series(rec: Recording, columns: Sequence[Column], steps: ArrayLike, times: ArrayLike,
                        values: Mapping[str, NDArray[Any]]) -> None:
    """Each column's Rerun time series (:class:`cdpr.protocol.streams.Series`) for rows ``values[name]``
    (n, width) — (n,) for a one-number column — at ``steps``/``times``, from each column's ``since`` step."""
    k, t = np.asarray(steps), np.asarray(times, dtype=float)
    for c in columns:
        rows = k >= c.since
        if not rows.any():
            continue
        v = np.asarray(values[c.name], dtype=float)[rows]
        v = v.reshape(len(v), -1)
        for series in c.series:
            part = v[:, series.first:series.end]
            if series.split:
                for i in range(part.shape[1]):
                    send_scalars(rec, series.path.format(i=series.first + i), k[rows], t[rows], part[:, i])
            else:
                send_scalars(rec, series.path, k[rows], t[rows], part[:, 0] if part.shape[1] == 1 else part)


def send_text(
    rec: Recording,
    path: str,
    steps: Sequence[int],
    times: Sequence[float],
    texts: Sequence[str],
    level: str | rr.TextLogLevel = "INFO",
) -> None:
    if not texts:
        return
    rec.send_columns(
        path,
        indexes=time_columns(steps, times),
        columns=rr.TextLog.columns(text=list(texts), level=[level] * len(texts)),
    )


def send_poses(rec: Recording, path: str, steps: ArrayLike, times: ArrayLike, poses: ArrayLike) -> None:
    """Transform3D rows from poses (n, 7) [x, y, z, qx, qy, qz, qw]."""
    p = np.asarray(poses, dtype=float).reshape(-1, 7)
    if p.shape[0] == 0:
        return
    rec.send_columns(
        path,
        indexes=time_columns(steps, times),
        columns=rr.Transform3D.columns(translation=p[:, :3], quaternion=p[:, 3:]),
    )


def send_cables(
    rec: Recording, robot: Robot, steps: ArrayLike, times: ArrayLike, poses: ArrayLike, tensions: ArrayLike
) -> None:
    """Cable line strips for n poses (n, 7), coloured by the tensions (n, m) on the tmin..tmax scale."""
    p = np.asarray(poses, dtype=float).reshape(-1, 7)
    n, m = p.shape[0], robot.m
    if n == 0:
        return
    strips = cable_strips(robot, p[:, :3], p[:, 3:]).reshape(n * m, 2, 3)
    colors = tension_colors(np.asarray(tensions, dtype=float).reshape(n, m), robot.tmin, robot.tmax).reshape(
        n * m, 4
    )
    # (rerun takes the (n·m, 2, 3) array as n·m strips; its type hints do not list 3-d arrays)
    cols = rr.LineStrips3D.columns(strips=strips, colors=colors).partition(np.full(n, m))  # type: ignore[arg-type]
    rec.send_columns(CABLES, indexes=time_columns(steps, times), columns=cols)


def send_path(
    rec: Recording, steps: Sequence[int], times: Sequence[float], paths: Sequence[NDArray[np.float64]]
) -> None:
    """The travelled path: row j is the whole path so far, a (k_j, 3) line strip."""
    if not paths:
        return
    cols = rr.LineStrips3D.columns(strips=[np.asarray(p, dtype=float) for p in paths]).partition(
        np.ones(len(paths), int)
    )
    rec.send_columns(PATH, indexes=time_columns(steps, times), columns=cols)


def show_robot(robot: Robot, rrd: str | Path | None = None, viewer: str | None = None) -> dict[str, Any]:
    """Draw ``robot`` at its home pose: frame, numbered anchors, platform and cables (static data).

    Writes ``rrd`` if given, streams to ``viewer`` if given, else spawns a viewer.
    """
    rec_id = f"show-{robot.name}-{uuid.uuid4().hex[:8]}"
    rec = Recording(
        rec_id, rrd=rrd, spawn=rrd is None and viewer is None, viewer=viewer, blueprint=scene_blueprint()
    )
    rec.send_recording_name(f"{robot.name} at home")
    log_scene(rec, robot, ghost=False)
    home = np.concatenate([robot.home_position, matrix_to_quat(robot.home_rotation)])
    rec.log(PLATFORM, rr.Transform3D(translation=home[:3], quaternion=rr.Quaternion(xyzw=home[3:])), static=True)
    strips = cable_strips(robot, home[None, :3], home[None, 3:])[0]
    rec.log(
        CABLES,
        rr.LineStrips3D(
            strips, colors=[(90, 90, 90, 255)] * robot.m, labels=[f"cable {i}" for i in range(robot.m)]
        ),
        static=True,
    )
    log_session(rec, {"robot": robot.summary(), "recording_id": rec_id})
    problems = rec.close()
    return {
        "robot": robot.name,
        "cables": robot.m,
        "rrd": None if rrd is None else str(rrd),
        "recording_id": rec_id,
        "problems": problems,
    }


def rerun_binary() -> str | None:
    """The viewer binary shipped with rerun-sdk (so a viewer starts even when the venv is not on PATH)."""
    try:
        import rerun_cli
    except ImportError:
        return None
    exe = Path(rerun_cli.__file__).parent / "rerun"
    return str(exe) if exe.is_file() else None


def viewer_command(
    path: str | Path, web: bool = False, web_port: int = 9090, grpc_port: int = 9876, bind: str = "127.0.0.1"
) -> list[str]:
    """The ``rerun`` command line (the viewer shipped with rerun-sdk) that opens ``path``.

    The binary is called directly when found (``python -m rerun`` would not pass signals on to it).
    """
    import sys

    exe = rerun_binary()
    cmd = [exe] if exe else [sys.executable, "-m", "rerun"]
    cmd.append(str(path))
    if web:
        cmd += [
            "--web-viewer",
            "--web-viewer-port",
            str(web_port),
            "--port",
            str(grpc_port),
            "--renderer",
            "webgl",
            "--bind",
            bind,
        ]
    return cmd


def web_viewer_url(web_port: int, grpc_port: int) -> str:
    return (
        f"http://127.0.0.1:{web_port}/?url=rerun%2Bhttp%3A%2F%2F127.0.0.1%3A{grpc_port}%2Fproxy"
        "&renderer=webgl"
    )
