"""The recorder node: a Zenoh shell around :class:`cdpr_recorder.core.RecorderCore`, writing to Rerun.

It subscribes to every stream of the session (tick, state, setpoint, command, and status through
:func:`cdpr.runtime.service.serve`), decodes and buffers the messages, and sends them to Rerun in columns
(``rr.send_columns``, one call per entity) every ``batch_steps`` states, after a quiet second (so a live
viewer never lags much), and at the end. Nothing is logged per step, so the loop is not slowed down.
The end is the clock's ``finished`` status once the final state is in (or after ``FINISH_GRACE``), an
``aborted`` status, or SIGINT/SIGTERM: :meth:`RecorderNode.close` then flushes what is left and closes
the file, which is complete and readable in every case.
"""

from __future__ import annotations

import argparse
import time

import numpy as np
import rerun as rr

from cdpr import recording
from cdpr.config.scenario import Scenario
from cdpr.protocol import Keys, ProtocolError, Setpoints, Status, Telemetry
from cdpr.protocol.session import session_info
from cdpr.runtime.service import Node
from cdpr.runtime.transport import Event, RateLimitedLog, log
from cdpr_recorder.core import Batch, Params, RecorderCore

FINISH_GRACE = 1.0  # seconds to wait for the final state after the clock says "finished"
QUIET_FLUSH = 1.0  # seconds after which buffered data is sent even if a batch is not full
PLANNED_PATH_POINTS = 200


class RecorderNode(Node):
    name = "recorder"

    def __init__(
        self,
        scenario: Scenario,
        keys: Keys,
        rrd: str | None = None,
        spawn: bool = False,
        viewer: str | None = None,
        params: Params | None = None,
    ) -> None:
        super().__init__(keys)
        self.scenario = scenario
        self.robot = scenario.robot
        self.m = scenario.robot.m
        self.rrd = rrd
        self.core = RecorderCore(params or Params(cables=self.m))
        self.warn = RateLimitedLog(self.name)
        self.bad_messages = 0
        self.last_flush = time.monotonic()
        self.finish_by: float | None = None  # set when the clock has finished, until the final state is in
        self.closed = False
        self.tension_peak = 0.0  # highest applied tension seen: sets the tension plot's range at the end
        self.recording_id = recording.recording_id(keys.session)
        self.rec = recording.Recording(
            self.recording_id, rrd=rrd, spawn=spawn, viewer=viewer, blueprint=recording.blueprint()
        )
        self._log_static()

    @classmethod
    def add_arguments(cls, parser: argparse.ArgumentParser) -> None:
        g = parser.add_argument_group("recorder")
        g.add_argument("--rrd", default=None, metavar="FILE", help="write the recording to this .rrd file")
        g.add_argument("--spawn", action="store_true", help="also stream to a new Rerun viewer")
        g.add_argument("--connect-viewer", default=None, metavar="URL",
                       help="also stream to the Rerun viewer at this gRPC URL")

    @classmethod
    def from_args(cls, scenario: Scenario, keys: Keys, args: argparse.Namespace) -> RecorderNode:
        return cls(scenario, keys, rrd=args.rrd, spawn=args.spawn, viewer=args.connect_viewer)

    def _log_static(self) -> None:
        sc, rec = self.scenario, self.rec
        rec.send_recording_name(f"{sc.name} ({self.keys.session})")
        recording.log_session(
            rec,
            {
                "scenario": sc.name,
                "session": self.keys.session,
                "recording_id": self.recording_id,
                "dt": sc.dt,
                "duration": sc.duration,
                "total_steps": sc.total_steps,
                "cables": self.m,
                "tmin": self.robot.tmin,
                "tmax": self.robot.tmax,
                "scene_every": self.core.params.scene_every,
                "path_every": self.core.params.path_every,
                "info": session_info(sc),
            },
        )
        recording.log_scene(rec, self.robot)
        recording.log_series_styles(rec, self.m)
        times = np.linspace(0.0, sc.duration, PLANNED_PATH_POINTS)
        recording.log_planned_path(rec, [sc.trajectory.sample(float(t)).position for t in times])

    # -- wiring -----------------------------------------------------------------------------------
    subscribes = ("telemetry", "setpoints")

    def handle(self, event: Event) -> None:
        core = self.core
        try:
            if event.kind == "telemetry":
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
            self.count(f"bad_{event.kind}")
            self.warn(f"bad_{event.kind}", f"dropped a bad {event.kind} message: {exc}")
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
        if self.core.pending and now - self.last_flush >= QUIET_FLUSH:
            self.flush()

    # -- Rerun ------------------------------------------------------------------------------------
    def flush(self, final: bool = False) -> None:
        self.send(self.core.take(final))
        self.last_flush = time.monotonic()

    def send(self, b: Batch) -> None:
        """One ``send_columns`` per entity for the whole batch."""
        rec, robot = self.rec, self.robot
        s = b.states
        if len(s.step):
            recording.send_scalars(rec, recording.ACTUAL_POSITION, s.step, s.t, s.pose[:, :3])
            recording.send_scalars(rec, recording.ACTUAL_QUATERNION, s.step, s.t, s.pose[:, 3:])
            recording.send_scalars(rec, recording.ACTUAL_TWIST, s.step, s.t, s.twist)
            recording.send_scalars(rec, recording.CABLE_LENGTHS, s.step, s.t, s.lengths)
            recording.send_scalars(rec, recording.CLAMPED, s.step, s.t, s.clamped)
            applied = s.step > 0  # state 0 has no applied tensions
            k, t = s.step[applied], s.t[applied]
            for i in range(self.m):
                recording.send_scalars(rec, recording.tension_series(i), k, t, s.tensions[applied, i])
            ends = (
                [0, len(k) - 1] if len(k) > 1 else list(range(len(k)))
            )  # a straight line: two points a batch
            recording.send_scalars(
                rec, recording.TENSION_MIN, k[ends], t[ends], np.full(len(ends), robot.tmin)
            )
            recording.send_scalars(
                rec, recording.TENSION_MAX, k[ends], t[ends], np.full(len(ends), robot.tmax)
            )
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
            bad = [j for j, status in enumerate(c.status) if status != "ok"]
            commanded = recording.COMMAND_TENSIONS if c.kind == "tensions" else recording.COMMAND_LENGTHS
            recording.send_scalars(rec, commanded, c.step, c.t, c.values)
            timed = ~np.isnan(c.solve_time)
            recording.send_scalars(rec, recording.COMMAND_SOLVE_TIME, c.step[timed], c.t[timed], c.solve_time[timed])
            recording.send_scalars(rec, recording.LOOP_LAG, c.step, c.t, c.lag)
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
        if len(r.step):
            recording.send_scalars(rec, recording.SENSOR_ENCODERS, r.step, r.t, r.encoders)
            recording.send_scalars(rec, recording.SENSOR_LOAD_CELLS, r.step, r.t, r.load_cells)
            recording.send_scalars(rec, recording.SENSOR_ACCEL, r.step, r.t, r.accel)
            recording.send_scalars(rec, recording.SENSOR_GYRO, r.step, r.t, r.gyro)
        recording.send_path(rec, b.path.step, b.path.t, b.path.points)

    def close(self) -> None:
        if self.closed:
            return
        self.closed = True
        closing = time.monotonic()
        try:
            self.flush(final=True)
            if self.tension_peak > 0.0:
                self.rec.send_blueprint(recording.blueprint(tension_range=(0.0, 1.15 * self.tension_peak)))
        finally:
            for problem in self.rec.close():
                log(self.name, f"a viewer did not get everything: {problem}")
        took = time.monotonic() - closing
        last = self.core.last_state.step if self.core.last_state is not None else -1
        where = f" to {self.rrd}" if self.rrd else ""
        log(
            self.name,
            f"recorded {self.core.recorded_states} states (last step {last}){where}; "
            f"recording id {self.recording_id}; duplicates {self.core.duplicates}, "
            f"bad messages {self.bad_messages}; "
            f"closed in {took:.2f} s",
        )
