"""``cdpr convert``: a recording made already, in another format (``--to mcap``: Foxglove's MCAP).

The ``.rrd`` is read back (:func:`cdpr.tools.report.read_recording`: every time series by step, the session
description) and its rows go into the very sink the recorder writes with ``--mcap``
(:class:`cdpr.recording.mcap.FoxgloveSink`), so a converted file has the channels, schemas and values of
one written live. What the recording does not keep is rebuilt by the recorder's rules: the 3D rows are
every ``scene_every``-th state (and the final one), the travelled path a point every ``path_every`` steps;
a state's and a setpoint's ``t`` is ``step · dt`` (as the sim and the trajectory compute it). A command
whose status is ``ok`` has no status text in the recording (the recorder logs the others) and gets ``ok``.
"""

from __future__ import annotations

from collections import defaultdict
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import click
import numpy as np

from cdpr.errors import InputError
from cdpr.tools.cli.group import cli, emit


@cli.command()
@click.argument("file", type=click.Path())
@click.option("--to", "fmt", type=click.Choice(["mcap", "rosbag2"]), required=True,
              help="mcap: Foxglove's MCAP file; rosbag2: a ROS 2 bag directory (MCAP storage, CDR: ros2 bag play)")
@click.option("-o", "--output", type=click.Path(), default=None,
              help="where to write (default: FILE.mcap, or the directory FILE_rosbag2, beside it)")
@click.option("--ros-namespace", default="/cdpr", show_default=True, help="rosbag2: the namespace of the topics")
def convert(file: str, fmt: str, output: str | None, ros_namespace: str) -> None:
    """Convert the recording FILE.rrd (from cdpr run --rrd) to MCAP for Foxglove (and Rerun's MCAP reader), or to
    a ROS 2 bag with the ros2 node's topics (docs/ros2.md)."""
    if fmt == "rosbag2":
        from cdpr.tools.rosbag2 import rrd_to_rosbag2

        emit(rrd_to_rosbag2(file, Path(output) if output is not None else Path(file).with_name(
            Path(file).stem + "_rosbag2"), ros_namespace))
        return
    out = Path(output) if output is not None else Path(file).with_suffix(f".{fmt}")
    emit(rrd_to_mcap(file, out))


@dataclass
class _Extras:
    """What :func:`cdpr.tools.report.read_recording` leaves out: text logs, the clock's rows, the frame box."""

    texts: dict[str, list[tuple[int, int, str]]] = field(default_factory=lambda: defaultdict(list))  # (step, ns, text)
    clock: dict[str, list[tuple[int, int, float]]] = field(default_factory=lambda: defaultdict(list))  # (step, ns, v)
    frame_box: tuple[np.ndarray, np.ndarray] | None = None
    planned_path: np.ndarray | None = None
    # per camera entity (world/cameras/NAME, world/platform/cameras/NAME): its frames' (step, ns, pixels) and
    # its images' (step, ns, JPEG)
    camera_points: dict[str, list[tuple[int, int, list[float]]]] = field(default_factory=lambda: defaultdict(list))
    camera_images: dict[str, list[tuple[int, int, bytes]]] = field(default_factory=lambda: defaultdict(list))


def _read_extras(path: Path, text_entities: tuple[str, ...], clock_prefix: str) -> _Extras:
    import pyarrow as pa
    from rerun.chunk import RrdReader

    from cdpr import recording

    out = _Extras()
    for chunk in RrdReader(str(path)).stream().to_chunks():
        entity = chunk.entity_path.lstrip("/")
        batch = chunk.to_record_batch()
        names = batch.schema.names
        if entity == recording.FRAME and "Boxes3D:centers" in names and "Boxes3D:half_sizes" in names:
            c = np.asarray(batch.column("Boxes3D:centers")[0].as_py()[0], dtype=float)
            h = np.asarray(batch.column("Boxes3D:half_sizes")[0].as_py()[0], dtype=float)
            out.frame_box = (np.round(c - h, 6), np.round(c + h, 6))  # stored as float32
            continue
        if entity == recording.PLANNED_PATH and "LineStrips3D:strips" in names:
            out.planned_path = np.asarray(batch.column("LineStrips3D:strips")[0].as_py()[0], dtype=float)
            continue
        if recording.STEP not in names or chunk.num_rows == 0:
            continue
        steps = batch.column(recording.STEP).to_numpy().tolist()
        ns = (batch.column(recording.SIM_TIME).cast(pa.int64()).to_numpy().tolist() if recording.SIM_TIME in names
              else [0] * len(steps))
        if entity.startswith((recording.CAMERAS + "/", recording.PLATFORM_CAMERAS + "/")):
            if entity.endswith("/" + recording.CAMERA_MARKERS) and "Points2D:positions" in names:
                camera = entity.rsplit("/", 2)[1]
                for k, t, xy in zip(steps, ns, batch.column("Points2D:positions").to_pylist(), strict=True):
                    out.camera_points[camera].append((k, t, [c for p in xy or () for c in p]))
            elif "EncodedImage:blob" in names:
                camera = entity.rsplit("/", 1)[1]
                for k, t, blob in zip(steps, ns, batch.column("EncodedImage:blob").to_pylist(), strict=True):
                    out.camera_images[camera].append((k, t, bytes(blob[0])))
            continue
        if entity in text_entities and "TextLog:text" in names:
            for k, t, texts in zip(steps, ns, batch.column("TextLog:text").to_pylist(), strict=True):
                out.texts[entity] += [(k, t, s) for s in texts or ()]
        elif entity.startswith(clock_prefix) and recording.SCALARS_COLUMN in names:
            for k, t, v in zip(steps, ns, batch.column(recording.SCALARS_COLUMN).to_pylist(), strict=True):
                if v:
                    out.clock[entity[len(clock_prefix):]].append((k, t, float(v[0])))
    return out


@dataclass(frozen=True)
class _StatusRow:
    step: int
    t: float
    state: str
    reason: str
    stats: dict[str, float]
    changed: bool


def _status_rows(extras: _Extras, state_entity: str) -> list[_StatusRow]:
    """The clock's status rows: the j-th row of step k of every ``clock/<stat>`` series is one status; its
    state is the latest ``clock/state`` text logged at a step ≤ k (texts are logged when the state changes)."""
    grouped: dict[tuple[int, int], dict[str, float]] = defaultdict(dict)
    times: dict[tuple[int, int], int] = {}
    for stat, rows in extras.clock.items():
        seen: dict[int, int] = defaultdict(int)
        for k, ns, v in rows:
            key = (k, seen[k])
            seen[k] += 1
            grouped[key][stat] = v
            times.setdefault(key, ns)
    changes = sorted(extras.texts.get(state_entity, []), key=lambda r: r[0])
    out: list[_StatusRow] = []
    state, reason, applied = "", "", 0
    for key in sorted(grouped):
        changed = False
        while applied < len(changes) and changes[applied][0] <= key[0]:
            state, _, reason = changes[applied][2].partition(": ")
            applied, changed = applied + 1, True
        out.append(_StatusRow(key[0], times[key] * 1e-9, state, reason, grouped[key], changed))
    return out


def rrd_to_mcap(rrd: str | Path, out: str | Path) -> dict[str, Any]:
    """Write the cdpr recording ``rrd`` as the MCAP file ``out``; what was written, as a JSON-ready map."""
    from cdpr import recording
    from cdpr.recording.mcap import FoxgloveSink
    from cdpr.tools.report import read_recording, session_of

    src, dst = Path(rrd), Path(out)
    if dst.resolve() == src.resolve():
        raise InputError(f"-o: {dst} is the input file")
    data = read_recording(src)
    session = data.session
    info, robot, dt, m = session_of(data, "MCAP")
    try:
        scene_every, path_every = int(session.get("scene_every", 10)), int(session.get("path_every", 50))
    except (TypeError, ValueError) as exc:
        raise InputError(f"{src}: the session description lacks what MCAP needs ({exc})") from None
    extras = _read_extras(src, (recording.COMMAND_STATUS, recording.CLOCK_STATE), recording.CLOCK + "/")
    if extras.frame_box is not None:
        robot = robot.replace(frame_min=extras.frame_box[0], frame_max=extras.frame_box[1])
    from cdpr.config.camera import CameraSpec

    cameras = tuple(CameraSpec.model_validate(c).build(dt, robot.com_offset)
                    for c in info.get("sim", {}).get("cameras", []))
    sink = FoxgloveSink(robot, session, mcap=dst, planned_path=extras.planned_path, cameras=cameras)
    try:
        counts = _feed(sink, data, extras, dt, m, scene_every, path_every)
    finally:
        sink.close()
    return {"input": str(src), "output": str(dst), "format": "mcap", "recording_id": data.recording_id,
            "scenario": session.get("scenario"), **counts, "messages": sink.messages, "bytes": dst.stat().st_size}


def _feed(
    sink: Any, data: Any, extras: _Extras, dt: float, m: int, scene_every: int, path_every: int
) -> dict[str, int]:
    from cdpr import recording
    from cdpr.recording.mcap import ESTIMATE_STREAM
    from cdpr.tools.report import sensor_columns, state_columns

    get = data.get
    k = get(recording.ACTUAL_POSITION).step  # the steps with a state
    try:
        columns = state_columns(data, k, m)
    except KeyError as exc:
        raise InputError(f"{data.path}: incomplete recording: no state data for step {exc.args[0]}") from None
    final = int(k[-1]) if len(k) else -1
    scene = (k % scene_every == 0) | (k == final)
    sink.states(k, k * dt, columns, scene)
    pose = columns["pose"]

    desired = get(recording.DESIRED_POSITION)
    d = desired.step
    if len(d):
        try:
            dq = get(recording.DESIRED_QUATERNION).at(d)
        except KeyError as exc:
            raise InputError(f"{data.path}: incomplete recording: no setpoint data for step {exc.args[0]}") from None
        sink.setpoints(d, d * dt, np.column_stack([desired.values, dq]), d % scene_every == 0)

    feasible = get(recording.COMMAND_FEASIBLE)
    c = feasible.step
    if len(c):
        kind = "lengths" if len(get(recording.COMMAND_LENGTHS).step) else "tensions"
        values = get(recording.COMMAND_LENGTHS if kind == "lengths" else recording.COMMAND_TENSIONS)
        solve = get(recording.COMMAND_SOLVE_TIME)
        timed = np.isin(c, solve.step)
        solve_time = np.full(len(c), np.nan)
        lag = np.full(len(c), np.nan)
        try:
            vals = values.at(c)
            solve_time[timed] = solve.at(c[timed])[:, 0]
            lagged = get(recording.LOOP_LAG)
            has_lag = np.isin(c, lagged.step)
            lag[has_lag] = lagged.at(c[has_lag])[:, 0]
        except KeyError as exc:
            raise InputError(f"{data.path}: incomplete recording: no command data for step {exc.args[0]}") from None
        status = {step: text.partition(": ")[2] for step, _, text in extras.texts.get(recording.COMMAND_STATUS, [])}
        sink.commands(c, c * dt, kind, vals, feasible.values[:, 0] >= 0.5,
                      [status.get(int(s), "ok") for s in c.tolist()], solve_time, lag)

    ep, eo = get(recording.POSITION_ERROR_AXES), get(recording.ORIENTATION_ERROR_AXES)
    if len(ep.step):
        try:
            sink.errors(ep.step, ep.step * dt, ep.values, eo.at(ep.step))
        except KeyError as exc:
            raise InputError(f"{data.path}: incomplete recording: no error data for step {exc.args[0]}") from None

    try:
        r, readings = sensor_columns(data, m)
    except KeyError as exc:
        raise InputError(f"{data.path}: incomplete recording: no sensor data for step {exc.args[0]}") from None
    if len(r):
        sink.sensors(r, r * dt, readings)
    try:  # a controller fed from the sensors: its estimates (and their errors) with its commands
        e, estimates = sensor_columns(data, m, ESTIMATE_STREAM)
    except KeyError as exc:
        raise InputError(f"{data.path}: incomplete recording: no estimate data for step {exc.args[0]}") from None
    if len(e):
        sink.estimates(e, e * dt, estimates)

    statuses = _status_rows(extras, recording.CLOCK_STATE)
    sink.statuses(statuses)

    for name, rows in sorted(extras.camera_points.items()):
        rows.sort()
        sink.camera_frames(name, [t * 1e-9 for _, t, _ in rows], [px for _, _, px in rows])
    for name, shots in sorted(extras.camera_images.items()):
        shots.sort(key=lambda r: r[0])
        sink.camera_images(name, [t * 1e-9 for _, t, _ in shots], [data for _, _, data in shots])

    on_path = (k % path_every == 0) | (k == final)
    points = pose[on_path, :3]
    sink.path(k[on_path].tolist(), (k[on_path] * dt).tolist(), [points[: j + 1] for j in range(len(points))])
    sink.end_batch()
    return {"states": len(k), "setpoints": len(d), "commands": len(c), "statuses": len(statuses)}
