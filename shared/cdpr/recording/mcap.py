"""Sessions as MCAP and live over Foxglove's WebSocket protocol: one sink, fed the recorder's column batches.

Everything a session shows in Rerun, for the tools of the ROS/Foxglove world: the same rows (one per step
and stream, the 3D rows decimated alike), written with ``foxglove-sdk`` on channels whose schemas those
tools understand:

* Foxglove well-known schemas (protobuf) for the 3D view: ``FrameTransform`` for the platform's pose and
  the desired pose, ``SceneUpdate`` for the frame, the platform, the cables coloured by tension, the
  travelled and the planned path;
* JSON-schema channels (JSON messages) for the time series: platform state, cable tensions, cable
  lengths, setpoints, tracking errors, commands with the tension distribution's status, sensors, clock;
* every message's ``log_time`` is the **simulation time** in nanoseconds (``t · 10⁹``), never the wall
  clock; static messages (the session, the scene's fixed parts) are at time 0;
* the session's static description (scenario, robot, protocol version, ids) is the MCAP metadata record
  ``cdpr.session``.

:class:`FoxgloveSink` takes rows as numpy columns (the recorder's ``Batch``, or a recording read back by
``cdpr convert``) and logs each message once per output: an MCAP file, a live
:class:`cdpr.recording.live.LiveServer`, or both (each output has its own Foxglove context, so a viewer
that connects late can be sent the static messages again without writing them twice into the file).

JSON rows are encoded with ``orjson`` (shortest round-trip text of each float64, about ten times faster
than ``json``), so the numbers read back are exactly the values recorded; NaN is written as ``null``.
"""

from __future__ import annotations

import json
from collections.abc import Iterable, Mapping, Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cdpr.errors import InputError
from cdpr.mechanics.camera import Camera
from cdpr.mechanics.robot import Robot
from cdpr.mechanics.rotation import matrix_to_quat
from cdpr.protocol.streams import (
    COMMAND_TIMING,
    ESTIMATE_COLUMNS,
    ESTIMATE_ERROR_COLUMNS,
    LENGTHS,
    PLATFORM_ESTIMATE,
    PLATFORM_STATE,
    STATE_COLUMNS,
    TENSIONS,
    ChannelField,
    Column,
)
from cdpr.recording.scene import anchor_labels, cable_strips, tension_colors
from cdpr.sensors import SENSOR_COLUMNS, encoders

if TYPE_CHECKING:
    import foxglove

    from cdpr.recording.live import LiveServer

METADATA_NAME = "cdpr.session"  # the MCAP metadata record with the session's static description
PROFILE = ""  # no ROS profile: Foxglove schemas and JSON

# Topics
SESSION = "/session"  # JSON, once at t = 0: the session description (as the metadata record)
PLATFORM_POSE = "/platform/pose"  # foxglove.FrameTransform world → platform (3D rate)
DESIRED_POSE = "/desired/pose"  # foxglove.FrameTransform world → desired (3D rate)
SCENE_STATIC = "/scene/static"  # foxglove.SceneUpdate, once at t = 0: frame, anchors, platform, ghost, plan
SCENE_CABLES = "/scene/cables"  # foxglove.SceneUpdate: the m cables coloured by tension (3D rate)
SCENE_PATH = "/scene/path"  # foxglove.SceneUpdate: the path travelled so far (path rate)
# PLATFORM_STATE (/platform/state), TENSIONS (/cables/tensions, every state but 0, with tmin and tmax) and
# LENGTHS (/cables/lengths): the state's channels, whose fields are declared with the state's columns
# (cdpr.protocol.streams.STATE_COLUMNS)
SETPOINT = "/setpoint"  # JSON every setpoint: desired position and quaternion
ERROR = "/error"  # JSON every step with a state and a setpoint: position and orientation errors
COMMAND = "/command"  # JSON every command: commanded values, feasibility, TDA status, solve time, loop lag
SENSORS = encoders.CHANNEL  # "/sensors": JSON every reading (scenarios with sensors): encoders, load cells, IMU
# ... and each sensor channel's own: their fields are declared with the sensors' columns (cdpr.sensors), e.g.
# /sensors/laser_tracker
# PLATFORM_ESTIMATE (/platform/estimate): JSON every command with an estimate (controller.feedback: sensors), the
# controller's estimate of state k and its errors; fields declared with ESTIMATE_COLUMNS and ESTIMATE_ERROR_COLUMNS
CLOCK = "/clock/status"  # JSON about once a second: the clock's state and stats
# Cameras (scenario sim.cameras), per camera NAME: /camera/NAME/image (foxglove.CompressedImage, JPEG, with
# image: true), /camera/NAME/calibration (foxglove.CameraCalibration, with each frame),
# /camera/NAME/markers (foxglove.ImageAnnotations: the markers seen, every frame); the camera's frame
# camera_NAME is a static transform from world (frame-mounted) or platform (platform-mounted)

CAMERA_FRAMES = "/camera/frames"  # foxglove.FrameTransform, once at t = 0: each camera's optical frame
WORLD_FRAME, PLATFORM_FRAME, DESIRED_FRAME = "world", "platform", "desired"
BACKLOG = 1 << 15  # messages buffered per live client (a fast-mode batch is ~1 500 messages)

_NUM = {"type": "number"}
_INT = {"type": "integer"}


def _vec(n: int | None, description: str) -> dict[str, Any]:
    out: dict[str, Any] = {"type": "array", "items": _NUM, "description": description}
    if n is not None:
        out["minItems"] = out["maxItems"] = n
    return out


def _schema(title: str, description: str, properties: Mapping[str, Any]) -> dict[str, Any]:
    return {
        "title": title,
        "description": description,
        "type": "object",
        "properties": {"step": {**_INT, "description": "the clock's step k"},
                       "t": {**_NUM, "description": "simulation time k·dt, s"}, **properties},
        "required": ["step", "t", *(k for k in properties if k not in _OPTIONAL)],
    }


_OPTIONAL = frozenset({"cable_tmin", "cable_tmax"})  # fields some messages of a channel leave out


# The state's channels: schema title and description, and the fields every message of the channel repeats.
_STATE_CHANNELS = {
    PLATFORM_STATE: ("cdpr.PlatformState", "the sim's state of the platform", {}),
    TENSIONS: ("cdpr.CableTensions", "tensions the sim applied over [t − dt, t]", {
        "tmin": {**_NUM, "description": "lower tension limit, N (with per-cable limits: the highest cable's)"},
        "tmax": {**_NUM, "description": "upper tension limit, N (with per-cable limits: the lowest cable's)"},
        "cable_tmin": {"type": "array", "items": _NUM, "description": "each cable's lower limit, N (only with "
                       "per-cable limits)"},
        "cable_tmax": {"type": "array", "items": _NUM, "description": "each cable's upper limit, N (only with "
                       "per-cable limits)"},
    }),
    LENGTHS: ("cdpr.CableLengths", "geometric cable lengths ‖a_i − t − R b_i‖ (over an exit pulley: the wrapped arc "
                                   "plus the free span)", {}),
    COMMAND_TIMING: ("cdpr.CommandTiming", "how old the command that acted over [t − dt, t] was, and the watchdog", {}),
}


_SENSOR_CHANNELS: dict[str, tuple[str, str, dict[str, Any]]] = {
    SENSORS: ("cdpr.Sensors", "noisy sensor readings taken with state k", {})}
ESTIMATE_STREAM = ESTIMATE_COLUMNS + ESTIMATE_ERROR_COLUMNS  # the columns of the /platform/estimate channel
_ESTIMATE_CHANNELS: dict[str, tuple[str, str, dict[str, Any]]] = {
    PLATFORM_ESTIMATE: ("cdpr.PlatformEstimate", "the pose and twist of state k a controller fed from the sensors "
                        "estimated (its command k), and their errors against state k", {})}


def state_channels(columns: Sequence[Column] = STATE_COLUMNS) -> dict[str, list[tuple[Column, ChannelField]]]:
    """Each JSON channel of a stream and the column parts it carries (the columns' ``fields``), in order: the
    state's (STATE_COLUMNS) or the sensors' (SENSOR_COLUMNS)."""
    out: dict[str, list[tuple[Column, ChannelField]]] = {}
    for c in columns:
        for f in c.fields:
            out.setdefault(f.channel, []).append((c, f))
    return out


def _state_schemas(m: int, columns: Sequence[Column] = STATE_COLUMNS,
                   channels: Mapping[str, tuple[str, str, dict[str, Any]]] = _STATE_CHANNELS
                   ) -> dict[str, dict[str, Any]]:
    schemas = {}
    for channel, parts in state_channels(columns).items():
        title, description, constants = channels.get(
            channel, (f"cdpr.{channel.strip('/').replace('/', '.').title().replace('_', '')}",
                      f"{parts[0][0].doc}", {}))
        properties: dict[str, Any] = {}
        for c, f in parts:
            width = (c.size(m) if f.end is None else f.end) - f.first
            text = f"{c.doc}{f', {c.unit}' if c.unit else ''}"
            properties[f.name] = ({**_INT, "description": text} if c.integer
                                  else {**_NUM, "description": text} if c.width == 1 else _vec(width, text))
        schemas[channel] = _schema(title, description, {**properties, **constants})
    return schemas


def json_schemas(m: int) -> dict[str, dict[str, Any]]:
    """The JSON schema of every JSON channel, for a robot of ``m`` cables."""
    cables = f"{m} values, cable 0 first"
    return {
        **_state_schemas(m),
        SETPOINT: _schema("cdpr.Setpoint", "the trajectory's desired pose", {
            "position": _vec(3, "[x, y, z], m"),
            "quaternion": _vec(4, "[qx, qy, qz, qw]"),
        }),
        ERROR: _schema("cdpr.TrackingError", "setpoint k against state k", {
            "position": _vec(3, "desired − actual, [x, y, z], m"),
            "position_norm": {**_NUM, "description": "‖desired − actual‖, m"},
            "orientation": _vec(3, "rotation vector e with exp([e]×) R = R_desired, rad"),
            "orientation_norm": {**_NUM, "description": "‖e‖, rad"},
        }),
        COMMAND: _schema("cdpr.Command", "the command the sim applied at step k and the controller's report", {
            "kind": {"type": "string", "enum": ["tensions", "lengths"], "description": "what values holds"},
            "values": _vec(m, f"commanded tensions (N) or unstretched lengths (m), {cables}"),
            "feasible": {"type": "boolean", "description": "the tension distribution was feasible"},
            "status": {"type": "string", "description": "the tension distribution's status"},
            "solve_time": {"type": ["number", "null"], "description": "s the controller spent (null: not sent)"},
            "lag": {**_NUM, "description": "s from the state going out to the step's integration"},
        }),
        **_state_schemas(m, SENSOR_COLUMNS, _SENSOR_CHANNELS),
        **_state_schemas(m, ESTIMATE_STREAM, _ESTIMATE_CHANNELS),
        CLOCK: _schema("cdpr.ClockStatus", "the clock's status (about once a second)", {
            "state": {"type": "string", "description": "waiting, running, paused, finished or aborted"},
            "reason": {"type": "string"},
            "changed": {"type": "boolean", "description": "state or reason differ from the previous status"},
            "stats": {"type": "object", "additionalProperties": _NUM,
                      "description": "every number of the clock's stats, nested maps joined with /"},
        }),
    }


SESSION_SCHEMA = {"title": "cdpr.Session", "type": "object",
                  "description": "the session's static description (also the MCAP metadata record cdpr.session)"}


# --------------------------------------------------------------------------------------------------
# Pure formatting


def nanoseconds(t: ArrayLike) -> NDArray[np.int64]:
    """Simulation times (s) as MCAP log times (ns, rounded)."""
    return np.rint(np.asarray(t, dtype=float) * 1e9).astype(np.int64)


def _cells(column: Any, n: int) -> list[bytes]:
    """The JSON text of each row of one column: (n,) numbers, booleans or strings, or (n, k) numbers."""
    import orjson

    if isinstance(column, np.ndarray) and column.dtype.kind in "fiu":
        if column.ndim == 1:  # one orjson call for the whole column, split at the commas
            return orjson.dumps(column.tolist())[1:-1].split(b",")
        rows = orjson.dumps(column.reshape(n, -1).tolist())[2:-2].split(b"],[")
        return [b"[" + r + b"]" for r in rows]
    values = column.tolist() if isinstance(column, np.ndarray) else list(column)
    seen: dict[Any, bytes] = {}  # booleans and strings: few distinct values
    out = []
    for v in values:
        text = seen.get(v)
        if text is None:
            text = seen[v] = orjson.dumps(v)
        out.append(text)
    return out


def json_rows(fields: Mapping[str, Any], constants: Mapping[str, Any] | None = None) -> list[bytes]:
    """One JSON object per row: ``fields`` maps a name to a column — (n,) values give a number (or bool,
    string) per row, (n, k) arrays give a k-number array — and ``constants`` adds the same fields to every
    row. Floats are written as the shortest text that reads back as the same float64 (``orjson``); NaN as
    null. Each column is encoded in one call and the rows are assembled from the pieces."""
    import orjson

    columns = list(fields.values())
    n = len(columns[0])
    if n == 0:
        return []
    keys = [orjson.dumps(name) for name in fields]
    template = b"{" + b",".join(k + b":%b" for k in keys)
    if constants:
        template += b"," + orjson.dumps(dict(constants))[1:-1]
    template += b"}"
    cells = [_cells(c, n) for c in columns]
    for name, c in zip(fields, cells, strict=True):
        if len(c) != n:
            raise ValueError(f"{name}: expected {n} rows, got {len(c)}")
    return [template % row for row in zip(*cells, strict=True)]


def metadata(session: Mapping[str, Any], protocol_version: int) -> dict[str, str]:
    """The ``cdpr.session`` metadata record: every field of the session description, as text (JSON for
    anything but a string), plus the protocol version and the robot's name."""
    out = {k: v if isinstance(v, str) else json.dumps(v) for k, v in session.items()}
    out["protocol_version"] = str(protocol_version)
    robot = session.get("info", {}).get("robot", {}) if isinstance(session.get("info"), Mapping) else {}
    if "name" in robot:
        out["robot"] = str(robot["name"])
    return out


# --------------------------------------------------------------------------------------------------
# The sink


class _Output:
    """One Foxglove context (an MCAP file's or a live server's) with a channel per topic."""

    def __init__(self, context: foxglove.Context, schemas: Mapping[str, tuple[str, foxglove.Schema]]) -> None:
        import foxglove

        self.context = context
        self.channels = {
            topic: foxglove.Channel(topic, schema=schema, message_encoding=encoding, context=context)
            for topic, (encoding, schema) in schemas.items()
        }

    def wants(self, topic: str) -> bool:
        return self.channels[topic].has_sinks()

    def log(self, topic: str, messages: Sequence[bytes], times: Sequence[int]) -> None:
        log = self.channels[topic].base.log
        for msg, ns in zip(messages, times, strict=True):
            log(msg, ns)

    def close(self) -> None:
        for channel in self.channels.values():
            channel.close()


class FoxgloveSink:
    """The session's Foxglove channels, written to an MCAP file (``mcap``) and/or a live server.

    ``session`` is the session description (the same map as the Rerun recording's ``session`` document);
    ``planned_path`` the trajectory sampled (drawn once). Rows go in through :meth:`states`,
    :meth:`setpoints`, :meth:`commands`, :meth:`errors`, :meth:`sensors`, :meth:`statuses` and
    :meth:`path`; :meth:`end_batch` after each batch, :meth:`close` at the end.
    """

    def __init__(
        self,
        robot: Robot,
        session: Mapping[str, Any],
        mcap: str | Path | None = None,
        live: LiveServer | None = None,
        planned_path: ArrayLike | None = None,
        protocol_version: int | None = None,
        compression: str = "zstd",
        cameras: Sequence[Camera] = (),
    ) -> None:
        import foxglove
        from foxglove import messages as fm
        from foxglove.mcap import MCAPCompression, MCAPWriteOptions

        from cdpr.protocol import PROTOCOL_VERSION

        if mcap is None and live is None:
            raise ValueError("a Foxglove sink needs an MCAP path or a live server")
        self.robot = robot
        self.m = robot.m
        self.session = dict(session)
        self.mcap_path = None if mcap is None else Path(mcap)
        self.live = live
        self.messages = 0  # logged to the file (or to the live server without a file)
        self._fm = fm
        schemas: dict[str, tuple[str, foxglove.Schema]] = {
            topic: ("json", foxglove.Schema(name=s["title"], encoding="jsonschema", data=json.dumps(s).encode()))
            for topic, s in json_schemas(self.m).items()
        }
        schemas[SESSION] = ("json", foxglove.Schema(name=SESSION_SCHEMA["title"], encoding="jsonschema",
                                                    data=json.dumps(SESSION_SCHEMA).encode()))
        for topic in (PLATFORM_POSE, DESIRED_POSE):
            schemas[topic] = ("protobuf", fm.FrameTransform.get_schema())
        for topic in (SCENE_STATIC, SCENE_CABLES, SCENE_PATH):
            schemas[topic] = ("protobuf", fm.SceneUpdate.get_schema())
        self.cameras = {c.name: c for c in cameras}
        for name in self.cameras:
            schemas[f"/camera/{name}/image"] = ("protobuf", fm.CompressedImage.get_schema())
            schemas[f"/camera/{name}/calibration"] = ("protobuf", fm.CameraCalibration.get_schema())
            schemas[f"/camera/{name}/markers"] = ("protobuf", fm.ImageAnnotations.get_schema())
        if self.cameras:
            schemas[CAMERA_FRAMES] = ("protobuf", fm.FrameTransform.get_schema())
        self.outputs: list[_Output] = []
        self.writer: Any = None
        if self.mcap_path is not None:
            try:
                self.mcap_path.parent.mkdir(parents=True, exist_ok=True)
                self.mcap_path.touch()
            except OSError as exc:
                raise InputError(f"--mcap: cannot write {self.mcap_path}: {exc.strerror or exc}") from None
            codec = {"zstd": MCAPCompression.Zstd, "lz4": MCAPCompression.Lz4, "none": None}[compression]
            context = foxglove.Context()
            # The recorder shares the machine with the loop: zstd level 1 (half the CPU of the default level 3,
            # a file as small), on the writer's thread (no helper threads), and no CRC over every chunk and
            # the data section (as costly as the compression; the summary keeps its CRC)
            options = MCAPWriteOptions(compression=codec, compression_level=1 if codec is not None else 0,
                                       profile=PROFILE, compression_threads=0, calculate_chunk_crcs=False,
                                       calculate_data_section_crc=False)
            self.writer = foxglove.open_mcap(self.mcap_path, allow_overwrite=True, context=context,
                                             writer_options=options)
            self.outputs.append(_Output(context, schemas))
        if live is not None:
            self.outputs.append(_Output(live.context, schemas))
        self._live = self.outputs[-1] if live is not None else None
        version = PROTOCOL_VERSION if protocol_version is None else protocol_version
        if self.writer is not None:
            self.writer.write_metadata(METADATA_NAME, metadata(self.session, version))
        tmin, tmax = robot.common_tension_range
        self._limits: dict[str, Any] = {"tmin": tmin, "tmax": tmax}
        if not robot.uniform_limits:
            self._limits.update(cable_tmin=robot.tmin.tolist(), cable_tmax=robot.tmax.tolist())
        self.last_ns = 0  # log time of the latest message
        self._static = self._static_messages(planned_path, version)
        for topic, msg in self._static:
            self._log(topic, [msg], [0])

    # -- static data ------------------------------------------------------------------------------
    def _static_messages(self, planned_path: ArrayLike | None, version: int) -> list[tuple[str, bytes]]:
        fm, robot = self._fm, self.robot
        session = json.dumps({**self.session, "protocol_version": version}).encode()
        grey, dark = _color(140, 140, 140, 255), _color(30, 30, 30, 255)
        lo, hi = np.asarray(robot.frame_min, float), np.asarray(robot.frame_max, float)
        corners = np.array([[x, y, z] for x in (lo[0], hi[0]) for y in (lo[1], hi[1]) for z in (lo[2], hi[2])])
        edges = [(0, 1), (0, 2), (0, 4), (1, 3), (1, 5), (2, 3), (2, 6), (3, 7), (4, 5), (4, 6), (5, 7), (6, 7)]
        frame_lines = fm.LinePrimitive(
            type=fm.LinePrimitiveLineType.LineList, thickness=0.01, color=grey,
            points=[_point(corners[i]) for pair in edges for i in pair],
        )
        a, a_labels = anchor_labels(robot.frame_points)
        b, b_labels = anchor_labels(robot.platform_points)
        entities = [
            fm.SceneEntity(frame_id=WORLD_FRAME, id="frame", lines=[frame_lines],
                           spheres=[_sphere(p, 0.08, dark) for p in a],
                           texts=[_text(p, label) for p, label in zip(a, a_labels, strict=True)]),
            fm.SceneEntity(frame_id=PLATFORM_FRAME, id="platform", frame_locked=True,
                           **self._shape(_color(70, 130, 180, 255)),
                           **({"spheres": [_sphere(p, 0.05, dark) for p in b]} if robot.mode != "point_mass" else {}),
                           texts=[_text(p, label) for p, label in zip(b, b_labels, strict=True)]),
            fm.SceneEntity(frame_id=DESIRED_FRAME, id="desired", frame_locked=True,
                           **self._shape(_color(255, 165, 0, 70))),
        ]
        if planned_path is not None:
            pts = np.asarray(planned_path, dtype=float).reshape(-1, 3)
            entities.append(fm.SceneEntity(frame_id=WORLD_FRAME, id="planned_path", lines=[fm.LinePrimitive(
                type=fm.LinePrimitiveLineType.LineStrip, thickness=0.012, color=_color(255, 165, 0, 160),
                points=[_point(p) for p in pts])]))
        scene = fm.SceneUpdate(entities=entities).encode()
        mounts = []
        for cam in self.cameras.values():  # each camera's optical frame, fixed to the frame or the platform
            x, y, z, w = matrix_to_quat(cam.mount_rotation).tolist()
            px, py, pz = cam.mount_position.tolist()
            mounts.append((CAMERA_FRAMES, fm.FrameTransform(
                timestamp=_stamp(0), parent_frame_id=PLATFORM_FRAME if cam.on_platform else WORLD_FRAME,
                child_frame_id=f"camera_{cam.name}", translation=fm.Vector3(x=px, y=py, z=pz),
                rotation=fm.Quaternion(x=x, y=y, z=z, w=w)).encode()))
        return [(SESSION, session), (SCENE_STATIC, scene), *mounts]

    def _shape(self, color: Any) -> dict[str, Any]:
        fm, shape = self._fm, self.robot.shape
        if shape.type == "box":
            return {"cubes": [fm.CubePrimitive(size=fm.Vector3(x=shape.size[0], y=shape.size[1], z=shape.size[2]),
                                               color=color)]}
        if shape.type == "sphere":
            d = 2.0 * shape.size[0]
            return {"spheres": [fm.SpherePrimitive(size=fm.Vector3(x=d, y=d, z=d), color=color)]}
        r, h = shape.size
        return {"cylinders": [fm.CylinderPrimitive(size=fm.Vector3(x=2 * r, y=2 * r, z=h), bottom_scale=1.0,
                                                   top_scale=1.0, color=color)]}

    # -- output -----------------------------------------------------------------------------------
    def _wanted(self, topic: str) -> list[_Output]:
        return [o for o in self.outputs if o.wants(topic)]

    def _log(self, topic: str, messages: Sequence[bytes], times: Sequence[int] | NDArray[np.int64]) -> None:
        ns = times.tolist() if isinstance(times, np.ndarray) else list(times)
        for out in self.outputs:
            out.log(topic, messages, ns)
        self.messages += len(messages)
        if ns:
            self.last_ns = max(self.last_ns, max(ns))

    def _emit(self, topic: str, times: ArrayLike, make: Any) -> None:
        """Log the messages ``make()`` builds on ``topic`` to every output that wants them (none: not built)."""
        wanted = self._wanted(topic)
        if not wanted:
            return
        ns = nanoseconds(times).tolist()
        if not ns:
            return
        messages = make()
        for out in wanted:
            out.log(topic, messages, ns)
        self.messages += len(messages)
        self.last_ns = max(self.last_ns, max(ns))

    # -- rows -------------------------------------------------------------------------------------
    def states(self, step: ArrayLike, t: ArrayLike, columns: Mapping[str, ArrayLike], scene: ArrayLike) -> None:
        """State rows: ``columns`` holds each column of STATE_COLUMNS, (n, width) — (n,) for a one-number
        column; ``scene`` marks the rows drawn in 3D (pose transform and cables)."""
        k = np.asarray(step, dtype=np.int64)
        if not len(k):
            return
        tt = np.asarray(t, dtype=float)
        values = {name: np.asarray(v) for name, v in columns.items()}
        for channel, parts in state_channels().items():
            rows = k >= max(c.since for c, _ in parts)

            def make(rows: NDArray[np.bool_] = rows, parts: list[tuple[Column, ChannelField]] = parts,
                     channel: str = channel) -> list[bytes]:
                fields = {"step": k[rows], "t": tt[rows]}
                for c, f in parts:
                    v = values[c.name][rows]
                    fields[f.name] = v if v.ndim == 1 else v[:, f.first:f.end]
                return json_rows(fields, self._limits if channel == TENSIONS else None)

            self._emit(channel, tt[rows], make)
        p, f = values["pose"].astype(float).reshape(-1, 7), values["tensions"].astype(float)
        sc = np.asarray(scene, dtype=bool)
        self._emit(PLATFORM_POSE, tt[sc], lambda: self._transforms(PLATFORM_FRAME, tt[sc], p[sc]))
        self._emit(SCENE_CABLES, tt[sc], lambda: self._cables(tt[sc], p[sc], f[sc]))

    def setpoints(self, step: ArrayLike, t: ArrayLike, pose: ArrayLike, scene: ArrayLike) -> None:
        k = np.asarray(step, dtype=np.int64)
        if not len(k):
            return
        tt, p = np.asarray(t, dtype=float), np.asarray(pose, dtype=float).reshape(-1, 7)
        self._emit(SETPOINT, tt, lambda: json_rows({"step": k, "t": tt, "position": p[:, :3], "quaternion": p[:, 3:]}))
        sc = np.asarray(scene, dtype=bool)
        self._emit(DESIRED_POSE, tt[sc], lambda: self._transforms(DESIRED_FRAME, tt[sc], p[sc]))

    def errors(self, step: ArrayLike, t: ArrayLike, position: ArrayLike, orientation: ArrayLike) -> None:
        k = np.asarray(step, dtype=np.int64)
        if not len(k):
            return
        tt = np.asarray(t, dtype=float)
        e, r = np.asarray(position, dtype=float).reshape(-1, 3), np.asarray(orientation, dtype=float).reshape(-1, 3)
        self._emit(ERROR, tt, lambda: json_rows({
            "step": k, "t": tt, "position": e, "position_norm": np.linalg.norm(e, axis=1),
            "orientation": r, "orientation_norm": np.linalg.norm(r, axis=1)}))

    def commands(self, step: ArrayLike, t: ArrayLike, kind: str, values: ArrayLike, feasible: ArrayLike,
                 status: Sequence[str], solve_time: ArrayLike, lag: ArrayLike) -> None:
        """Command rows; a NaN ``solve_time`` (the controller sent none) is written as null."""
        k = np.asarray(step, dtype=np.int64)
        if not len(k):
            return
        tt = np.asarray(t, dtype=float)
        self._emit(COMMAND, tt, lambda: json_rows({
            "step": k, "t": tt, "values": np.asarray(values, dtype=float), "feasible": np.asarray(feasible, dtype=bool),
            "status": status, "solve_time": np.asarray(solve_time, dtype=float), "lag": np.asarray(lag, dtype=float),
        }, {"kind": kind}))

    def sensors(self, step: ArrayLike, t: ArrayLike, columns: Mapping[str, ArrayLike]) -> None:
        """Sensor rows: ``columns`` holds each channel of SENSOR_COLUMNS that some row has, (n, width), NaN in the
        rows without it; a JSON channel gets the rows that have one of its fields, a field without a reading in a
        row written as nulls there (a kind with another rate, or a lost reading)."""
        self._column_rows(SENSOR_COLUMNS, step, t, columns)

    def estimates(self, step: ArrayLike, t: ArrayLike, columns: Mapping[str, ArrayLike]) -> None:
        """Estimate rows (``ESTIMATE_STREAM``'s columns, NaN in the rows of commands without one): the
        /platform/estimate channel."""
        self._column_rows(ESTIMATE_STREAM, step, t, columns)

    def _column_rows(self, declared: Sequence[Column], step: ArrayLike, t: ArrayLike,
                     columns: Mapping[str, ArrayLike]) -> None:
        k = np.asarray(step, dtype=np.int64)
        if not len(k):
            return
        tt = np.asarray(t, dtype=float)
        values = {name: np.asarray(v, dtype=float).reshape(len(k), -1) for name, v in columns.items()}
        for channel, all_parts in state_channels(declared).items():
            parts = [(c, f) for c, f in all_parts if c.name in values]  # the fields of the kinds configured
            if not parts:
                continue
            rows = np.logical_or.reduce([~np.isnan(values[c.name][:, 0]) for c, _ in parts])

            def make(rows: NDArray[np.bool_] = rows, parts: list[tuple[Column, ChannelField]] = parts) -> list[bytes]:
                fields: dict[str, Any] = {"step": k[rows], "t": tt[rows]}
                for c, f in parts:
                    part = values[c.name][rows][:, f.first:f.end]
                    fields[f.name] = part[:, 0] if c.width == 1 else part  # a one-number column: a number
                return json_rows(fields)

            self._emit(channel, tt[rows], make)

    def statuses(self, rows: Iterable[Any]) -> None:
        """Clock status rows, each with ``step``, ``t``, ``state``, ``reason``, ``stats`` and ``changed``."""
        rows = list(rows)
        if not rows:
            return
        self._emit(CLOCK, [r.t for r in rows], lambda: [json.dumps({
            "step": int(r.step), "t": float(r.t), "state": r.state, "reason": r.reason, "changed": bool(r.changed),
            "stats": {key: float(r.stats[key]) for key in sorted(r.stats)},
        }).encode() for r in rows])

    def path(self, steps: Sequence[int], times: Sequence[float], paths: Sequence[ArrayLike]) -> None:
        """The travelled path: row j is the whole path so far, (k_j, 3)."""
        if not len(steps):
            return
        fm = self._fm

        def make() -> list[bytes]:
            out = []
            color = _color(220, 50, 47, 255)
            for ns, pts in zip(nanoseconds(times).tolist(), paths, strict=True):
                xyz = np.asarray(pts, dtype=float).reshape(-1, 3).tolist()
                line = fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineStrip, thickness=0.01, color=color,
                                        points=[fm.Point3(x=x, y=y, z=z) for x, y, z in xyz])
                out.append(fm.SceneUpdate(entities=[fm.SceneEntity(
                    timestamp=_stamp(ns), frame_id=WORLD_FRAME, id="path", lines=[line])]).encode())
            return out

        self._emit(SCENE_PATH, times, make)

    def end_batch(self) -> None:
        """After a batch: a live viewer gets the static messages again (one that connected late missed
        them) and the time of the latest message."""
        if self._live is None:
            return
        for topic, msg in self._static:
            if self._live.wants(topic):
                self._live.log(topic, [msg], [self.last_ns])
        assert self.live is not None
        self.live.broadcast_time(self.last_ns)

    def close(self) -> None:
        """Close the MCAP file (with its summary and footer); the live server is closed by its owner."""
        for out in self.outputs:
            out.close()
        if self.writer is not None:
            self.writer.close()
            self.writer = None

    def camera_frames(self, name: str, t: Sequence[float], pixels: Sequence[Sequence[float]]) -> None:
        """A camera's frames: the markers it saw (pixels, flat u, v) as image annotations, with its calibration."""
        fm = self._fm
        ns = nanoseconds(t).tolist()
        self._emit(f"/camera/{name}/markers", t, lambda: [fm.ImageAnnotations(points=[fm.PointsAnnotation(
            timestamp=_stamp(n), type=fm.PointsAnnotationType.Points, thickness=8.0,
            outline_color=_color(220, 40, 40, 255),
            points=[fm.Point2(x=u, y=v) for u, v in zip(px[0::2], px[1::2], strict=True)])]).encode()
            for n, px in zip(ns, pixels, strict=True)])
        self._emit(f"/camera/{name}/calibration", t, lambda: [self._calibration(name, n) for n in ns])

    def camera_images(self, name: str, t: Sequence[float], images: Sequence[bytes]) -> None:
        """A camera's images (JPEG); its calibration goes with each frame (:meth:`camera_frames`)."""
        fm = self._fm
        ns = nanoseconds(t).tolist()
        self._emit(f"/camera/{name}/image", t, lambda: [fm.CompressedImage(
            timestamp=_stamp(n), frame_id=f"camera_{name}", data=data, format="jpeg").encode()
            for n, data in zip(ns, images, strict=True)])

    def _calibration(self, name: str, ns: int) -> bytes:
        fm, k = self._fm, self.cameras[name].intrinsics
        K = k.matrix.ravel().tolist()
        return fm.CameraCalibration(
            timestamp=_stamp(ns), frame_id=f"camera_{name}", width=k.width, height=k.height,
            distortion_model="plumb_bob", D=list(k.distortion), K=K, R=[1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0],
            P=[K[0], K[1], K[2], 0.0, K[3], K[4], K[5], 0.0, K[6], K[7], K[8], 0.0]).encode()

    # -- 3D messages ------------------------------------------------------------------------------
    def _transforms(self, child: str, t: NDArray[np.float64], poses: NDArray[np.float64]) -> list[bytes]:
        fm = self._fm
        out = []
        for ns, p in zip(nanoseconds(t).tolist(), poses.tolist(), strict=True):
            out.append(fm.FrameTransform(
                timestamp=_stamp(ns), parent_frame_id=WORLD_FRAME, child_frame_id=child,
                translation=fm.Vector3(x=p[0], y=p[1], z=p[2]),
                rotation=fm.Quaternion(x=p[3], y=p[4], z=p[5], w=p[6]),
            ).encode())
        return out

    def _cables(self, t: NDArray[np.float64], poses: NDArray[np.float64], tensions: NDArray[np.float64]) -> list[bytes]:
        """One LineList per row: segment i from b_i (world) to a_i, both ends coloured by cable i's tension."""
        fm, robot = self._fm, self.robot
        n = len(t)
        strips = cable_strips(robot, poses[:, :3], poses[:, 3:]).reshape(n, 2 * self.m, 3).tolist()
        rgba = (tension_colors(tensions, robot.tmin, robot.tmax) / 255.0).tolist()  # (n, m, 4)
        out = []
        for ns, pts, colors in zip(nanoseconds(t).tolist(), strips, rgba, strict=True):
            cs = [fm.Color(r=c[0], g=c[1], b=c[2], a=c[3]) for c in colors]
            line = fm.LinePrimitive(type=fm.LinePrimitiveLineType.LineList, thickness=0.02,
                                    points=[fm.Point3(x=p[0], y=p[1], z=p[2]) for p in pts],
                                    colors=[c for c in cs for _ in (0, 1)])
            out.append(fm.SceneUpdate(entities=[fm.SceneEntity(
                timestamp=_stamp(ns), frame_id=WORLD_FRAME, id="cables", lines=[line])]).encode())
        return out


def _stamp(ns: int) -> Any:
    from foxglove.messages import Timestamp

    return Timestamp(sec=ns // 1_000_000_000, nsec=ns % 1_000_000_000)


def _color(r: int, g: int, b: int, a: int) -> Any:
    from foxglove.messages import Color

    return Color(r=r / 255.0, g=g / 255.0, b=b / 255.0, a=a / 255.0)


def _point(p: ArrayLike) -> Any:
    from foxglove.messages import Point3

    x, y, z = np.asarray(p, dtype=float).reshape(3).tolist()
    return Point3(x=x, y=y, z=z)


def _sphere(p: ArrayLike, d: float, color: Any) -> Any:
    from foxglove.messages import Pose, Quaternion, SpherePrimitive, Vector3

    x, y, z = (float(v) for v in np.asarray(p, dtype=float).reshape(3))
    pose = Pose(position=Vector3(x=x, y=y, z=z), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))
    return SpherePrimitive(pose=pose, size=Vector3(x=d, y=d, z=d), color=color)


def _text(p: ArrayLike, text: str) -> Any:
    from foxglove.messages import Color, Pose, Quaternion, TextPrimitive, Vector3

    x, y, z = (float(v) for v in np.asarray(p, dtype=float).reshape(3))
    pose = Pose(position=Vector3(x=x, y=y, z=z + 0.1), orientation=Quaternion(x=0.0, y=0.0, z=0.0, w=1.0))
    return TextPrimitive(pose=pose, billboard=True, font_size=14.0, scale_invariant=True,
                         color=Color(r=0.1, g=0.1, b=0.1, a=1.0), text=text)
