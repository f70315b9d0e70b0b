"""The recorder node: a Zenoh shell around :class:`cdpr_recorder.core.RecorderCore`, writing to its sinks.

It subscribes to every stream of the session (tick, state, setpoint, command, and status through
:func:`cdpr.runtime.service.serve`), decodes and buffers the messages, and cuts them into column batches
every ``batch_steps`` states (2 000 for files alone, 200 with a live viewer), at least once a second (so a
live viewer never lags much), and at the end.
Each batch goes to every sink: Rerun (``--rrd``, ``--spawn``, ``--connect-viewer``: ``rr.send_columns``, one
call per entity) and Foxglove (``--mcap`` file, ``--foxglove`` live WebSocket server:
:class:`cdpr.recording.mcap.FoxgloveSink`, the same rows as Foxglove messages). Nothing is logged per step,
so the loop is not slowed down.
The end is the clock's ``finished`` status once the final state is in (or after ``FINISH_GRACE``), an
``aborted`` status, or SIGINT/SIGTERM: :meth:`RecorderNode.close` then flushes what is left and closes
the file, which is complete and readable in every case.
"""

from __future__ import annotations

import argparse
import time
from collections.abc import Sequence
from typing import TYPE_CHECKING

import numpy as np
import rerun as rr

from cdpr import recording
from cdpr.config.scenario import Scenario
from cdpr.errors import InputError
from cdpr.protocol import CameraFrame, CameraImage, Keys, ProtocolError, Setpoints, Status, Telemetry
from cdpr.protocol.session import session_info
from cdpr.protocol.streams import ESTIMATE_COLUMNS, ESTIMATE_ERROR_COLUMNS, STATE, STATE_COLUMNS
from cdpr.runtime.options import RECORDER_OPTIONS, add_options
from cdpr.runtime.service import Node
from cdpr.runtime.transport import Event, RateLimitedLog, log
from cdpr.sensors import SENSOR_COLUMNS
from cdpr_recorder.core import Batch, RecorderCore, RecorderSettings

if TYPE_CHECKING:
    from cdpr.recording.live import LiveServer
    from cdpr.recording.mcap import FoxgloveSink

FINISH_GRACE = 1.0  # seconds to wait for the final state after the clock says "finished"
FLUSH_PERIOD = 1.0  # seconds after the last batch at which buffered data is sent even if a batch is not full
# States per batch. Rerun's cost is mostly per ``send_columns`` call (~0.4 ms for 200 rows, ~0.5 ms for
# 2 000): files alone take large batches; a live viewer, small ones so that it follows the session closely.
FILE_BATCH_STEPS = 2000
LIVE_BATCH_STEPS = 200
PLANNED_PATH_POINTS = 200


class RecorderNode(Node):
    name = "recorder"
    ordered = True  # the session's last images and frames before its last telemetry, as the sim put them

    def __init__(
        self,
        scenario: Scenario,
        keys: Keys,
        rrd: str | None = None,
        spawn: bool = False,
        viewer: str | None = None,
        settings: RecorderSettings | None = None,
        mcap: str | None = None,
        foxglove: int | None = None,
        foxglove_host: str = "127.0.0.1",
    ) -> None:
        super().__init__(keys)
        self.scenario = scenario
        self.robot = scenario.robot
        self.m = scenario.robot.m
        self.rrd = rrd
        self.mcap = mcap
        rerun = bool(rrd or spawn or viewer)
        if not (rerun or mcap or foxglove is not None):
            raise InputError("the recorder needs a sink: --rrd, --spawn, --connect-viewer, --mcap or --foxglove")
        live = bool(spawn or viewer or foxglove is not None)
        self.core = RecorderCore(settings or RecorderSettings(cables=self.m,
                                                  batch_steps=LIVE_BATCH_STEPS if live else FILE_BATCH_STEPS))
        self.warn = RateLimitedLog(self.name)
        self.bad_messages = 0
        self.last_flush = time.monotonic()
        self._last_status = "ok"  # the status of the last command logged (statuses_to_log)
        self.finish_by: float | None = None  # set when the clock has finished, until the final state is in
        self.closed = False
        self.tension_peak = 0.0  # highest applied tension seen: sets the tension plot's range at the end
        self.cameras = {c.name: c for c in scenario.cameras}
        self.frames: dict[str, dict[int, CameraFrame]] = {name: {} for name in self.cameras}  # not sent yet, by step
        self.frames_sent: dict[str, int] = dict.fromkeys(self.cameras, -1)  # the last step sent, per camera
        self.images: dict[str, dict[int, CameraImage]] = {name: {} for name in self.cameras}
        self.images_sent: dict[str, int] = dict.fromkeys(self.cameras, -1)
        self.recording_id = recording.recording_id(keys.session)
        times = np.linspace(0.0, scenario.duration, PLANNED_PATH_POINTS)
        self.planned_path = [scenario.trajectory.sample(float(t)).position for t in times]
        self.rec: recording.Recording | None = None
        self.fox: FoxgloveSink | None = None
        self.live: LiveServer | None = None
        try:
            if rerun:
                self.rec = recording.Recording(
                    self.recording_id, rrd=rrd, spawn=spawn, viewer=viewer,
                    blueprint=recording.blueprint(cameras=scenario.cameras),
                )
                self._log_static()
            if mcap or foxglove is not None:
                from cdpr.recording.live import LiveServer
                from cdpr.recording.mcap import FoxgloveSink

                if foxglove is not None:
                    self.live = LiveServer(foxglove, foxglove_host, name=f"cdpr {scenario.name} ({keys.session})")
                    log(self.name, f"Foxglove WebSocket server at {self.live.url}")
                self.fox = FoxgloveSink(self.robot, self.session_description(), mcap=mcap, live=self.live,
                                        planned_path=self.planned_path, cameras=scenario.cameras)
        except BaseException:
            self._close_sinks()
            raise

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        add_options(parser.add_argument_group("recorder"), RECORDER_OPTIONS)

    @classmethod
    def from_args(cls, scenario: Scenario, keys: Keys, args: argparse.Namespace) -> RecorderNode:
        return cls(scenario, keys, rrd=args.rrd, spawn=args.spawn, viewer=args.connect_viewer, mcap=args.mcap,
                   foxglove=args.foxglove, foxglove_host=args.foxglove_host)

    def session_description(self) -> dict[str, object]:
        """The session's static description: Rerun's ``session`` document and the MCAP metadata."""
        sc = self.scenario
        return {
            "scenario": sc.name,
            "session": self.keys.session,
            "recording_id": self.recording_id,
            "dt": sc.dt,
            "duration": sc.duration,
            "total_steps": sc.total_steps,
            "cables": self.m,
            "tmin": self.robot.common_tension_range[0],
            "tmax": self.robot.common_tension_range[1],
            **({} if self.robot.uniform_limits else {"cable_tmin": self.robot.tmin.tolist(),
                                                     "cable_tmax": self.robot.tmax.tolist()}),
            "scene_every": self.core.settings.scene_every,
            "path_every": self.core.settings.path_every,
            "info": session_info(sc),
        }

    def _log_static(self) -> None:
        sc, rec = self.scenario, self.rec
        assert rec is not None
        rec.send_recording_name(f"{sc.name} ({self.keys.session})")
        recording.log_session(rec, self.session_description())
        recording.log_scene(rec, self.robot)
        recording.log_series_styles(rec, self.m, per_cable_limits=not self.robot.uniform_limits)
        recording.log_planned_path(rec, self.planned_path)
        recording.log_cameras(rec, self.scenario.cameras)

    def handle(self, event: Event) -> None:
        core = self.core
        try:
            if event.topic == "camera_image":
                image = CameraImage.decode(event.payload)
                if image.camera not in self.cameras:
                    raise ProtocolError(f"camera: {image.camera!r} is not a camera of this scenario")
                if image.step > self.images_sent[image.camera]:
                    self.images[image.camera].setdefault(image.step, image)
                return
            if event.topic == "camera":
                frame = CameraFrame.decode(event.payload)
                if frame.camera not in self.cameras:
                    raise ProtocolError(f"camera: {frame.camera!r} is not a camera of this scenario")
                if frame.step > self.frames_sent[frame.camera]:  # a frame sent again (a resend): kept once
                    self.frames[frame.camera].setdefault(frame.step, frame)
                return
            if event.topic == "telemetry":
                block = Telemetry.decode(event.payload, self.m)
                for state in block.states:
                    core.add_state(state)
                    self.tension_peak = max(self.tension_peak, *state.tensions)
                for cmd, lag in zip(block.commands, block.lags, strict=True):
                    core.add_command(cmd, lag)
                for reading in block.sensors:
                    core.add_sensors(reading)
            else:
                for sp in Setpoints.decode(event.payload).items:
                    core.add_setpoint(sp)
        except ProtocolError as exc:
            self.bad_messages += 1
            self.count(f"bad_{event.topic}")
            self.warn(f"bad_{event.topic}", f"dropped a bad {event.topic} message: {exc}")
            return
        if self.core.due:
            self.flush()
        self._check_finished(time.monotonic())

    def on_status(self, status: Status) -> None:
        self.core.add_status(status)
        if status.state == "aborted":
            super().on_status(status)
        elif status.state == "finished" and self.finish_by is None:
            self.final_status = status
            self.finish_by = time.monotonic() + FINISH_GRACE
            self._check_finished(time.monotonic())

    def _check_finished(self, now: float) -> None:
        if self.finish_by is None or self.final_status is None:
            return
        last = self.core.last_state.step if self.core.last_state is not None else -1
        if last >= self.final_status.step:
            self.done = True
        elif now > self.finish_by:
            log(
                self.name,
                f"the session finished at step {self.final_status.step} but the last state "
                f"received is {last}; closing the recording anyway",
            )
            self.done = True

    def idle(self, now: float) -> None:
        self._check_finished(now)
        if self.core.pending and now - self.last_flush >= FLUSH_PERIOD:
            self.flush()

    # -- sinks ------------------------------------------------------------------------------------
    def flush(self, final: bool = False) -> None:
        batch = self.core.take(final)
        if self.rec is not None:
            self.send(batch)
        if self.fox is not None:
            self.send_foxglove(batch)
        self.send_frames()
        self.last_flush = time.monotonic()

    def send_foxglove(self, b: Batch) -> None:
        """The batch as Foxglove messages (MCAP file and/or live server): the same rows as :meth:`send`."""
        fox = self.fox
        assert fox is not None
        s = b.states
        fox.states(s.step, s.t, s.columns, s.scene)
        sp = b.setpoints
        fox.setpoints(sp.step, sp.t, sp.pose, sp.scene)
        c = b.commands
        fox.commands(c.step, c.t, c.kind, c.values, c.feasible, c.status, c.solve_time, c.lag)
        fox.estimates(c.step, c.t, c.estimate)
        e = b.errors
        fox.errors(e.step, e.t, e.position, e.orientation)
        r = b.sensors
        fox.sensors(r.step, r.t, r.columns)
        fox.statuses(b.statuses)
        fox.path(b.path.step, b.path.t, b.path.points)
        fox.end_batch()

    # -- Rerun ------------------------------------------------------------------------------------
    def statuses_to_log(self, statuses: Sequence[str]) -> list[int]:
        """The commands whose status goes to the event log: every one that is not ``ok``, but only the first
        of a run of the watchdog's (``watchdog:static`` every step while it acts would flood the log)."""
        out = []
        for j, status in enumerate(statuses):
            if status != "ok" and not (status.startswith("watchdog:") and status == self._last_status):
                out.append(j)
            self._last_status = status
        return out

    def send(self, b: Batch) -> None:
        """One ``send_columns`` per entity for the whole batch."""
        rec, robot = self.rec, self.robot
        assert rec is not None
        s = b.states
        if len(s.step):
            recording.send_columns_series(rec, STATE_COLUMNS, s.step, s.t, s.columns)
            applied = s.step >= STATE["tensions"].since  # state 0 has no applied tensions
            k, t = s.step[applied], s.t[applied]
            ends = (
                [0, len(k) - 1] if len(k) > 1 else list(range(len(k)))
            )  # a straight line: two points a batch
            for path, limit in ((recording.TENSION_MIN, robot.tmin), (recording.TENSION_MAX, robot.tmax)):
                # one line, or one per cable with per-cable limits
                values = np.full(len(ends), limit[0]) if robot.uniform_limits else np.tile(limit, (len(ends), 1))
                recording.send_scalars(rec, path, k[ends], t[ends], values)
            sc = s.scene
            recording.send_poses(rec, recording.PLATFORM, s.step[sc], s.t[sc], s.pose[sc])
            recording.send_cables(rec, robot, s.step[sc], s.t[sc], s.pose[sc], s.tensions[sc])
        sp = b.setpoints
        if len(sp.step):
            recording.send_scalars(rec, recording.DESIRED_POSITION, sp.step, sp.t, sp.pose[:, :3])
            recording.send_scalars(rec, recording.DESIRED_QUATERNION, sp.step, sp.t, sp.pose[:, 3:])
            recording.send_poses(rec, recording.DESIRED, sp.step[sp.scene], sp.t[sp.scene], sp.pose[sp.scene])
        c = b.commands
        if len(c.step):
            recording.send_scalars(rec, recording.COMMAND_FEASIBLE, c.step, c.t, c.feasible.astype(float))
            bad = self.statuses_to_log(c.status)
            commanded = recording.COMMAND_TENSIONS if c.kind == "tensions" else recording.COMMAND_LENGTHS
            recording.send_scalars(rec, commanded, c.step, c.t, c.values)
            timed = ~np.isnan(c.solve_time)
            recording.send_scalars(rec, recording.COMMAND_SOLVE_TIME, c.step[timed], c.t[timed], c.solve_time[timed])
            recording.send_scalars(rec, recording.LOOP_LAG, c.step, c.t, c.lag)
            for columns in (ESTIMATE_COLUMNS, ESTIMATE_ERROR_COLUMNS):  # the rows with one (feedback: sensors)
                has = ~np.isnan(c.estimate[columns[0].name].reshape(len(c.step), -1)[:, 0])
                if has.any():
                    recording.send_columns_series(rec, columns, c.step[has], c.t[has],
                                                  {col.name: c.estimate[col.name][has] for col in columns})
            recording.send_text(
                rec,
                recording.COMMAND_STATUS,
                [int(c.step[j]) for j in bad],
                [float(c.t[j]) for j in bad],
                [f"step {c.step[j]}: {c.status[j]}" for j in bad],
                level=rr.TextLogLevel.WARN,
            )
        e = b.errors
        if len(e.step):
            recording.send_scalars(rec, recording.POSITION_ERROR_AXES, e.step, e.t, e.position)
            recording.send_scalars(
                rec, recording.POSITION_ERROR_NORM, e.step, e.t, np.linalg.norm(e.position, axis=1)
            )
            recording.send_scalars(rec, recording.ORIENTATION_ERROR_AXES, e.step, e.t, e.orientation)
            recording.send_scalars(
                rec, recording.ORIENTATION_ERROR_NORM, e.step, e.t, np.linalg.norm(e.orientation, axis=1)
            )
        if b.statuses:
            for key in sorted({k for row in b.statuses for k in row.stats}):
                rows = [row for row in b.statuses if key in row.stats]
                recording.send_scalars(
                    rec,
                    recording.clock_series(key),
                    [r.step for r in rows],
                    [r.t for r in rows],
                    [r.stats[key] for r in rows],
                )
            changed = [row for row in b.statuses if row.changed]
            recording.send_text(
                rec,
                recording.CLOCK_STATE,
                [r.step for r in changed],
                [r.t for r in changed],
                [f"{r.state}: {r.reason}" if r.reason else r.state for r in changed],
            )
        r = b.sensors
        for col in SENSOR_COLUMNS:  # each channel's series (cdpr.sensors), at the steps that have a reading
            if col.name in r.columns:
                has = ~np.isnan(r.columns[col.name][:, 0])
                recording.send_columns_series(rec, (col,), r.step[has], r.t[has], {col.name: r.columns[col.name][has]})
        recording.send_path(rec, b.path.step, b.path.t, b.path.points)

    def send_frames(self) -> None:
        """Each camera's frames (labelled 2D points) and images received since the last batch, at their exposure
        step, to every sink."""
        for name, frames in self.frames.items():
            if not frames:
                continue
            rows = [frames[k] for k in sorted(frames)]
            steps, times = [f.step for f in rows], [f.t for f in rows]
            if self.rec is not None:
                recording.send_camera_frames(self.rec, self.cameras[name], steps, times, [f.pixels for f in rows],
                                             [f.ids for f in rows])
            if self.fox is not None:
                self.fox.camera_frames(name, times, [f.pixels for f in rows])
            self.frames_sent[name] = rows[-1].step
            frames.clear()
        for name, images in self.images.items():
            if not images:
                continue
            shots = [images[k] for k in sorted(images)]
            steps, times = [i.step for i in shots], [i.t for i in shots]
            if self.rec is not None:
                recording.send_camera_images(self.rec, self.cameras[name], steps, times, [i.data for i in shots])
            if self.fox is not None:
                self.fox.camera_images(name, times, [i.data for i in shots])
            self.images_sent[name] = shots[-1].step
            images.clear()

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        closing = time.monotonic()
        try:
            self.flush(final=True)
            if self.rec is not None and self.tension_peak > 0.0:
                self.rec.send_blueprint(recording.blueprint(tension_range=(0.0, 1.15 * self.tension_peak),
                                                            cameras=self.scenario.cameras))
        finally:
            self._close_sinks()
        took = time.monotonic() - closing
        last = self.core.last_state.step if self.core.last_state is not None else -1
        where = "".join(f" to {path}" if i == 0 else f" and {path}" for i, path in
                        enumerate(p for p in (self.rrd, self.mcap) if p))
        log(
            self.name,
            f"recorded {self.core.recorded_states} states (last step {last}){where}; "
            f"recording id {self.recording_id}; duplicates {self.core.duplicates}, "
            f"bad messages {self.bad_messages}; "
            f"closed in {took:.2f} s",
        )

    def _close_sinks(self) -> None:
        """Close every sink, the files first; a sink that fails does not keep the others open."""
        try:
            if self.rec is not None:
                for problem in self.rec.close():
                    log(self.name, f"a viewer did not get everything: {problem}")
        finally:
            try:
                if self.live is not None:
                    self.live.linger()  # a live viewer receives the end before its channels close
                if self.fox is not None:
                    self.fox.close()
            finally:
                if self.live is not None:
                    self.live.close()
