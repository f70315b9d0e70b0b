"""The recorder's logic, free of I/O: buffer the session's messages and cut them into column batches.

Messages arrive one at a time (decoded by the node); :meth:`RecorderCore.take` returns everything new
as numpy columns, ready for one ``rr.send_columns`` per entity. Rules:

* Messages come in blocks (``sim/telemetry``: states, commands, sensor readings; ``trajectory/setpoints``).
* One row per step and stream: a repeated state, setpoint or command (the clock's resends) is dropped,
  the first copy is kept (as in :class:`cdpr.tools.metrics.RunMetrics`).
* The tracking error of step k pairs state k with setpoint k, whatever their arrival order; the final
  state (after the last tick) has no setpoint and no error — the definitions of
  :meth:`cdpr.tools.metrics.RunMetrics.errors`.
* Tensions are those the sim applied over [t − dt, t], so state 0 (nothing applied yet) has none.
* A command's estimate (a controller fed from the sensors) is of the state of its step: its errors pair the two
  (:func:`cdpr.mechanics.estimation.estimate_errors`), the state kept for the last :data:`POSE_HISTORY` steps.
* 3D rows are decimated: every ``scene_every``-th state, plus the final one. The travelled path gets a
  point every ``path_every`` steps (and the final state) and is re-sent whole at each new point.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cdpr.mechanics.estimation import estimate_errors
from cdpr.protocol import Command, Sensors, Setpoint, State, Status
from cdpr.protocol.streams import ESTIMATE_COLUMNS, ESTIMATE_ERROR_COLUMNS, ESTIMATE_WIDTH, STATE_COLUMNS
from cdpr.sensors import SENSOR_COLUMNS

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
POSE_HISTORY = 10_000  # steps of state poses kept for the estimates that answer them (a command comes after its state)


@dataclass(frozen=True)
class RecorderSettings:
    cables: int
    batch_steps: int = 200  # states buffered before a batch is due
    scene_every: int = 10  # 3D decimation: every n-th step
    path_every: int = 50  # travelled path: one point every n steps

    def __post_init__(self) -> None:
        if self.cables < 1 or min(self.batch_steps, self.scene_every, self.path_every) < 1:
            raise ValueError("cables, batch_steps, scene_every and path_every must be >= 1")


@dataclass(frozen=True)
class StateRows:
    step: I64  # (n,) sorted
    t: F64
    columns: dict[str, NDArray[Any]]  # each column of STATE_COLUMNS: (n, width), (n,) for a one-number column
    scene: NDArray[np.bool_]  # rows that go to the 3D scene

    @property
    def pose(self) -> F64:
        return self.columns["pose"]

    @property
    def tensions(self) -> F64:
        return self.columns["tensions"]


@dataclass(frozen=True)
class SetpointRows:
    step: I64
    t: F64
    pose: F64  # (n, 7)
    scene: NDArray[np.bool_]


@dataclass(frozen=True)
class CommandRows:
    step: I64
    t: F64
    feasible: NDArray[np.bool_]
    status: tuple[str, ...]
    kind: str  # "tensions" or "lengths": what ``values`` holds
    values: F64  # (n, m) the commanded tensions (N) or unstretched lengths (m)
    solve_time: F64  # s the controller took (NaN: not reported)
    lag: F64  # s from the state going out to the step's integration
    estimate: dict[str, F64]  # the estimate's and its errors' columns: (n, width) or (n,), NaN where none


@dataclass(frozen=True)
class SensorRows:
    step: I64
    t: F64
    columns: dict[str, F64]  # each channel of SENSOR_COLUMNS some reading has: (n, width), NaN where absent


@dataclass(frozen=True)
class ErrorRows:
    step: I64
    t: F64
    position: F64  # (n, 3) desired − actual
    orientation: F64  # (n, 3) rotation vector e with exp([e]×) R = R_desired


@dataclass(frozen=True)
class StatusRow:
    step: int
    t: float
    state: str
    reason: str
    stats: dict[str, float]  # the numeric fields of the clock's stats
    changed: bool  # state or reason differ from the previous status


@dataclass(frozen=True)
class PathRows:
    step: tuple[int, ...]
    t: tuple[float, ...]
    points: tuple[F64, ...]  # the whole path at each update, (k, 3)


@dataclass(frozen=True)
class Batch:
    states: StateRows
    setpoints: SetpointRows
    commands: CommandRows
    errors: ErrorRows
    statuses: tuple[StatusRow, ...]
    path: PathRows
    sensors: SensorRows

    @property
    def empty(self) -> bool:
        return not (
            len(self.states.step)
            or len(self.setpoints.step)
            or len(self.commands.step)
            or len(self.sensors.step)
            or len(self.errors.step)
            or self.statuses
            or self.path.step
        )


def _quat_mul(a: F64, b: F64) -> F64:
    """Hamilton product of quaternion rows [x, y, z, w]."""
    av, aw = a[:, :3], a[:, 3:]
    bv, bw = b[:, :3], b[:, 3:]
    v = aw * bv + bw * av + np.cross(av, bv)
    w = aw * bw - np.sum(av * bv, axis=1, keepdims=True)
    return np.concatenate([v, w], axis=1)


def orientation_errors(q_desired: ArrayLike, q: ArrayLike) -> F64:
    """Rows of :func:`cdpr.mechanics.rotation.orientation_error`, vectorised: the rotation vector of R_d Rᵀ.

    The quaternion of R_d Rᵀ is q_d ⊗ q⁻¹; with its scalar part made ≥ 0 the angle is in [0, π].
    """
    qd = np.asarray(q_desired, dtype=float).reshape(-1, 4)
    qa = np.asarray(q, dtype=float).reshape(-1, 4)
    qd = qd / np.linalg.norm(qd, axis=1, keepdims=True)
    qa = qa / np.linalg.norm(qa, axis=1, keepdims=True)
    inv = qa * np.array([-1.0, -1.0, -1.0, 1.0])
    e = _quat_mul(qd, inv)
    e = np.where(e[:, 3:] < 0.0, -e, e)
    s = np.linalg.norm(e[:, :3], axis=1)
    angle = 2.0 * np.arctan2(s, e[:, 3])
    small = s < 1e-12
    scale = np.where(small, 2.0, angle / np.where(small, 1.0, s))
    return e[:, :3] * scale[:, None]


def flatten_stats(stats: dict[str, Any], prefix: str = "") -> dict[str, float]:
    """The finite numbers of a (nested) stats map, keyed by path: ``{"faults": {"sim": {"x": 1}}}`` →
    ``{"faults/sim/x": 1.0}``. Anything else (text, lists, booleans) is left out."""
    out: dict[str, float] = {}
    for key, value in stats.items():
        name = f"{prefix}{key}"
        if isinstance(value, dict):
            out.update(flatten_stats(value, f"{name}/"))
        elif isinstance(value, (int, float)) and not isinstance(value, bool) and np.isfinite(value):
            out[name] = float(value)
    return out


def _ids(values: list[int]) -> I64:
    return np.asarray(values, dtype=np.int64)


def _rows(values: list[tuple[float, ...]], width: int) -> F64:
    return np.asarray(values, dtype=float).reshape(-1, width)


@dataclass
class RecorderCore:
    """Buffers decoded messages; the node owns one and calls :meth:`take` when :attr:`due` and at the end."""

    settings: RecorderSettings
    states: list[State] = field(default_factory=list)
    setpoints: list[Setpoint] = field(default_factory=list)
    commands: list[tuple[Command, float]] = field(default_factory=list)  # (command, lag)
    sensors: list[Sensors] = field(default_factory=list)
    statuses: list[StatusRow] = field(default_factory=list)
    pairs: list[tuple[State, Setpoint]] = field(default_factory=list)
    seen_states: set[int] = field(default_factory=set)
    seen_setpoints: set[int] = field(default_factory=set)
    seen_commands: set[int] = field(default_factory=set)
    seen_sensors: set[int] = field(default_factory=set)
    poses: dict[int, tuple[float, ...]] = field(default_factory=dict)  # the last POSE_HISTORY states' poses
    waiting_states: dict[int, State] = field(default_factory=dict)  # no setpoint yet
    waiting_setpoints: dict[int, Setpoint] = field(default_factory=dict)  # no state yet
    last_setpoint: Setpoint | None = None
    last_state: State | None = None
    path: list[tuple[float, float, float]] = field(default_factory=list)
    path_step: int = -1  # step of the last path point
    duplicates: int = 0
    recorded_states: int = 0
    _last_clock: tuple[str, str] | None = None

    # -- input ------------------------------------------------------------------------------------
    def add_state(self, s: State) -> bool:
        """Buffer state ``s``; False if that step was already recorded (a resend)."""
        if len(s.tensions) != self.settings.cables:
            raise ValueError(f"expected {self.settings.cables} tensions, got {len(s.tensions)}")
        if s.step in self.seen_states:
            self.duplicates += 1
            return False
        self.seen_states.add(s.step)
        self.states.append(s)
        self.poses[s.step] = s.pose
        if len(self.poses) > POSE_HISTORY:
            del self.poses[next(iter(self.poses))]
        if self.last_state is None or s.step > self.last_state.step:
            self.last_state = s
        sp = self.waiting_setpoints.pop(s.step, None)
        if sp is None:
            self.waiting_states[s.step] = s
        else:
            self.pairs.append((s, sp))
        return True

    def add_setpoint(self, sp: Setpoint) -> bool:
        if sp.step in self.seen_setpoints:
            self.duplicates += 1
            return False
        self.seen_setpoints.add(sp.step)
        self.setpoints.append(sp)
        if self.last_setpoint is None or sp.step > self.last_setpoint.step:
            self.last_setpoint = sp
        s = self.waiting_states.pop(sp.step, None)
        if s is None:
            self.waiting_setpoints[sp.step] = sp
        else:
            self.pairs.append((s, sp))
        return True

    def add_command(self, cmd: Command, lag: float = float("nan")) -> bool:
        if cmd.step in self.seen_commands:
            self.duplicates += 1
            return False
        self.seen_commands.add(cmd.step)
        self.commands.append((cmd, lag))
        return True

    def add_sensors(self, reading: Sensors) -> bool:
        if reading.step in self.seen_sensors:
            self.duplicates += 1
            return False
        self.seen_sensors.add(reading.step)
        self.sensors.append(reading)
        return True

    def add_status(self, st: Status) -> None:
        stats = flatten_stats(st.stats)
        key = (st.state, st.reason)
        self.statuses.append(StatusRow(st.step, st.t, st.state, st.reason, stats, key != self._last_clock))
        self._last_clock = key

    @property
    def due(self) -> bool:
        return len(self.states) >= self.settings.batch_steps

    @property
    def pending(self) -> bool:
        return bool(self.states or self.setpoints or self.commands or self.statuses or self.pairs or self.sensors)

    # -- output -----------------------------------------------------------------------------------
    def take(self, final: bool = False) -> Batch:
        """Everything buffered since the last call, as columns. ``final``: the recording ends now."""
        p = self.settings
        final_step = self.last_state.step if final and self.last_state is not None else None
        states = sorted(self.states, key=lambda s: s.step)
        setpoints = sorted(self.setpoints, key=lambda s: s.step)
        commands = sorted(self.commands, key=lambda c: c[0].step)
        sensors = sorted(self.sensors, key=lambda r: r.step)
        pairs = sorted(self.pairs, key=lambda sp: sp[0].step)
        self.states, self.setpoints, self.commands, self.pairs, self.sensors = [], [], [], [], []
        statuses, self.statuses = tuple(self.statuses), []
        self.recorded_states += len(states)

        m = p.cables
        s_step = _ids([s.step for s in states])
        scene = (s_step % p.scene_every) == 0
        if final_step is not None:
            scene |= s_step == final_step
        state_rows = StateRows(
            step=s_step,
            t=np.asarray([s.t for s in states], dtype=float),
            columns={c.name: _ids([getattr(s, c.name) for s in states]) if c.integer
                     else np.asarray([getattr(s, c.name) for s in states], dtype=float) if c.width == 1
                     else _rows([getattr(s, c.name) for s in states], c.size(m)) for c in STATE_COLUMNS},
            scene=scene,
        )
        sp_step = _ids([s.step for s in setpoints])
        setpoint_rows = SetpointRows(
            step=sp_step,
            t=np.asarray([s.t for s in setpoints], dtype=float),
            pose=_rows([s.pose for s in setpoints], 7),
            scene=(sp_step % p.scene_every) == 0,
        )
        command_rows = CommandRows(
            step=_ids([c.step for c, _ in commands]),
            t=np.asarray([c.t for c, _ in commands], dtype=float),
            feasible=np.asarray([c.feasible for c, _ in commands], dtype=bool),
            status=tuple(c.status for c, _ in commands),
            kind=commands[0][0].kind if commands else "tensions",
            values=_rows([c.values for c, _ in commands], m),
            solve_time=np.asarray([np.nan if c.solve_time is None else c.solve_time for c, _ in commands], dtype=float),
            lag=np.asarray([lag for _, lag in commands], dtype=float),
            estimate=self._estimates([c for c, _ in commands]),
        )
        sensor_rows = SensorRows(
            step=_ids([r.step for r in sensors]),
            t=np.asarray([r.t for r in sensors], dtype=float),
            columns={c.name: _rows([(v if (v := r.get(c.name)) is not None else (np.nan,) * c.size(m))
                                    for r in sensors], c.size(m))
                     for c in SENSOR_COLUMNS if any(r.get(c.name) is not None for r in sensors)},
        )
        actual = _rows([s.pose for s, _ in pairs], 7)
        desired = _rows([d.pose for _, d in pairs], 7)
        error_rows = ErrorRows(
            step=_ids([s.step for s, _ in pairs]),
            t=np.asarray([s.t for s, _ in pairs], dtype=float),
            position=desired[:, :3] - actual[:, :3],
            orientation=orientation_errors(desired[:, 3:], actual[:, 3:]) if pairs else np.zeros((0, 3)),
        )
        return Batch(
            state_rows, setpoint_rows, command_rows, error_rows, statuses, self._path_rows(states, final_step),
            sensor_rows,
        )

    def _estimates(self, commands: list[Command]) -> dict[str, F64]:
        """The commands' estimates and their errors against the states of their steps, NaN where none."""
        n = len(commands)
        rows = np.full((n, ESTIMATE_WIDTH), np.nan)
        position, orientation = np.full(n, np.nan), np.full(n, np.nan)
        have = [j for j, c in enumerate(commands) if c.estimate is not None]
        if have:
            rows[have] = [commands[j].estimate for j in have]
            paired = [j for j in have if commands[j].step in self.poses]
            if paired:
                position[paired], orientation[paired] = estimate_errors(
                    rows[paired, :7], [self.poses[commands[j].step] for j in paired])
        out, first = {}, 0
        for c in ESTIMATE_COLUMNS:  # the command's estimate, split as its columns declare
            out[c.name], first = rows[:, first:first + (c.width or 0)], first + (c.width or 0)
        position_error, orientation_error = ESTIMATE_ERROR_COLUMNS
        return {**out, position_error.name: position, orientation_error.name: orientation}

    def _path_rows(self, states: list[State], final_step: int | None) -> PathRows:
        steps: list[int] = []
        times: list[float] = []
        points: list[F64] = []
        for s in states:
            on_grid = s.step % self.settings.path_every == 0 or s.step == final_step
            if on_grid and s.step > self.path_step:
                self.path.append((s.pose[0], s.pose[1], s.pose[2]))
                self.path_step = s.step
                steps.append(s.step)
                times.append(s.t)
                points.append(np.asarray(self.path, dtype=float))
        return PathRows(tuple(steps), tuple(times), tuple(points))
