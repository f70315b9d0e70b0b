"""``cdpr report``: read a recording back and write the paper's figures and a summary.

The recording is read with :class:`rerun.chunk.RrdReader` (every scalar series, by entity path from
:mod:`cdpr.recording`). The summary uses the very definitions of ``cdpr run``'s summary: the recorded
states, setpoints and commands are rebuilt as protocol messages and fed to
:class:`cdpr.tools.metrics.RunMetrics`. A state's ``t`` is ``step · dt`` (as the sim computes it), and state 0
has zero tensions (nothing applied yet), so a complete recording gives the run's ``state_digest`` bit
for bit.
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cdpr import recording
from cdpr.columns import Column
from cdpr.errors import InputError
from cdpr.mechanics.robot import Robot
from cdpr.protocol import Command, Setpoint, State
from cdpr.protocol.streams import (
    COMMAND_AGE,
    ESTIMATE_COLUMNS,
    STATE_COLUMNS,
    WATCHDOG,
)
from cdpr.sensors import SENSOR_COLUMNS
from cdpr.tools.metrics import RunMetrics

FIGURE_SIZE = (12.0, 8.0)  # inches; at FIGURE_DPI this is the PNG's size in pixels
FIGURE_DPI = 100
TRACKING_PNG = "tracking.png"
ORIENTATION_PNG = "orientation_error.png"
LATENCY_PNG = "latency.png"
SUMMARY_JSON = "summary.json"


@dataclass(frozen=True)
class Series:
    """One entity's scalar rows, sorted by step: ``values`` is (n, k) for k scalars per row."""

    step: NDArray[np.int64]
    t: NDArray[np.float64]  # sim_time, s
    values: NDArray[np.float64]

    def at(self, steps: NDArray[np.int64]) -> NDArray[np.float64]:
        """Rows for exactly these steps (KeyError naming the first missing step)."""
        if len(self.step) == 0:
            if len(steps):
                raise KeyError(int(steps[0]))
            return self.values[:0]
        idx = np.clip(np.searchsorted(self.step, steps), 0, len(self.step) - 1)
        bad = self.step[idx] != steps
        if bad.any():
            raise KeyError(int(steps[bad][0]))
        return self.values[idx]


EMPTY = Series(np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 1)))


@dataclass(frozen=True)
class RecordingData:
    path: str
    recording_id: str
    session: dict[str, Any]
    series: dict[str, Series] = field(default_factory=dict)
    blueprints: int = 0

    def get(self, path: str) -> Series:
        return self.series.get(path, EMPTY)


def _series(parts: list[tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]]) -> Series:
    step = np.concatenate([p[0] for p in parts])
    t = np.concatenate([p[1] for p in parts])
    width = max(p[2].shape[1] for p in parts)
    values = np.concatenate([p[2] for p in parts if p[2].shape[1] == width])
    order = np.argsort(step, kind="stable")
    step, t, values = step[order], t[order], values[order]
    keep = np.ones(len(step), dtype=bool)
    keep[1:] = step[1:] != step[:-1]  # one row per step: the first one logged
    return Series(step[keep], t[keep], values[keep])


def read_recording(path: str | Path) -> RecordingData:
    """Every scalar series and the session description of a cdpr recording."""
    import pyarrow as pa
    import pyarrow.compute as pc
    from rerun.chunk import RrdReader

    p = Path(path)
    if not p.is_file():
        raise InputError(f"{p}: no such file")
    try:
        reader = RrdReader(str(p))
        recordings = reader.recordings()
        blueprints = len(reader.blueprints())
        chunks = reader.stream().to_chunks() if recordings else []
    except Exception as exc:  # the reader raises various errors on a file that is not an .rrd
        raise InputError(
            f"{p}: not a readable Rerun recording ({str(exc).splitlines()[0] if str(exc) else exc})"
        ) from None
    if not recordings:
        raise InputError(f"{p}: the file holds no recording")
    session: dict[str, Any] | None = None
    parts: dict[str, list[tuple[Any, Any, Any]]] = {}
    for chunk in chunks:
        entity = chunk.entity_path.lstrip("/")
        batch = chunk.to_record_batch()
        names = batch.schema.names
        if entity == recording.SESSION and recording.TEXT_DOCUMENT_COLUMN in names:
            session = json.loads(batch.column(recording.TEXT_DOCUMENT_COLUMN)[0].as_py()[0])
            continue
        if recording.SCALARS_COLUMN not in names or recording.STEP not in names or chunk.num_rows == 0:
            continue
        col = batch.column(recording.SCALARS_COLUMN)
        lengths = pc.list_value_length(col).fill_null(0).to_numpy(zero_copy_only=False)
        k = int(lengths.max())
        rows = lengths == k
        values = col.filter(pa.array(rows)).flatten().to_numpy(zero_copy_only=False).reshape(-1, k)
        step = batch.column(recording.STEP).to_numpy()[rows]
        t = (
            batch.column(recording.SIM_TIME).cast(pa.int64()).to_numpy()[rows] * 1e-9
            if recording.SIM_TIME in names
            else np.full(int(rows.sum()), np.nan)
        )
        parts.setdefault(entity, []).append((step.astype(np.int64), t, values.astype(float)))
    if session is None:
        raise InputError(f"{p}: not a cdpr recording (no /{recording.SESSION} description)")
    series = {name: _series(v) for name, v in parts.items()}
    return RecordingData(str(p), recordings[0].recording_id, session, series, blueprints)


def session_of(data: RecordingData, what: str) -> tuple[dict[str, Any], Robot, float, int]:
    """What a converted file needs of a recording's session description: the session/info map, the robot,
    dt and the number of cables; InputError naming the recording (``what``: the format being written)."""
    from cdpr.protocol import ProtocolError
    from cdpr.protocol.session import robot_from_summary

    session = data.session
    try:
        info = session["info"]
        return info, robot_from_summary(info["robot"]), float(session["dt"]), int(session["cables"])
    except (KeyError, TypeError, ValueError, AttributeError, ProtocolError) as exc:
        raise InputError(f"{data.path}: the session description lacks what {what} needs ({exc})") from None


def state_columns(data: RecordingData, steps: NDArray[np.int64], m: int) -> dict[str, NDArray[Any]]:
    """The state's columns (STATE_COLUMNS) at ``steps``, read back from their recorded series: (n, width),
    (n,) for a one-number column, zeros before a column's ``since`` step. KeyError(step) where a series
    lacks one of the steps."""
    out: dict[str, NDArray[Any]] = {}
    for c in STATE_COLUMNS:
        values = np.zeros((len(steps), c.size(m)))
        rows = steps >= c.since
        if rows.any():
            _fill(data, c, values, rows, steps[rows], m)
        out[c.name] = values[:, 0].astype(np.int64) if c.integer else values[:, 0] if c.width == 1 else values
    return out


def _fill(data: RecordingData, c: Column, values: NDArray[np.float64], rows: NDArray[np.bool_],
          at: NDArray[np.int64], m: int) -> None:
    """``values[rows]`` = column ``c`` at steps ``at``, from its recorded series (KeyError(step): one lacks it)."""
    size = c.size(m)
    for s in c.series:
        end = size if s.end is None else s.end
        if s.split:
            for i in range(s.first, end):
                values[rows, i] = data.get(s.path.format(i=i)).at(at)[:, 0]
        else:
            values[rows, s.first:end] = data.get(s.path).at(at)


def sensor_columns(data: RecordingData, m: int, declared: Sequence[Column] = SENSOR_COLUMNS
                   ) -> tuple[NDArray[np.int64], dict[str, NDArray[np.float64]]]:
    """The sensors' channels (SENSOR_COLUMNS; or another stream's ``declared`` columns recorded at some steps only,
    e.g. the estimate's) read back from their recorded series: the steps with a reading of any kind, and each
    recorded channel's (n, width) values there, NaN where it has none. KeyError(step) where a channel's series
    disagree on its steps."""
    found: dict[Column, NDArray[np.int64]] = {}
    for c in declared:
        first = c.series[0]
        steps = data.get(first.path.format(i=first.first) if first.split else first.path).step
        if len(steps):
            found[c] = steps
    every = np.unique(np.concatenate(list(found.values()))) if found else np.zeros(0, np.int64)
    out: dict[str, NDArray[np.float64]] = {}
    for c, steps in found.items():
        out[c.name] = values = np.full((len(every), c.size(m)), np.nan)
        _fill(data, c, values, np.isin(every, steps), steps, m)
    return every, out


def metrics_from(data: RecordingData) -> RunMetrics:
    """The recorded streams as protocol messages in a :class:`RunMetrics` (the run's own definitions)."""
    dt = float(data.session["dt"])
    m = int(data.session["cables"])
    metrics = RunMetrics()
    steps = data.get(recording.ACTUAL_POSITION).step  # the steps with a state
    if len(steps):
        try:
            columns = state_columns(data, steps, m)
        except KeyError as exc:
            raise InputError(
                f"{data.path}: incomplete recording: no state data for step {exc.args[0]}"
            ) from None
        rows = [v.tolist() if v.ndim == 1 else [tuple(row) for row in v.tolist()] for v in columns.values()]
        for k, *values in zip(steps.tolist(), *rows, strict=True):
            metrics.add_state(State(k, k * dt, *values))
    desired = data.get(recording.DESIRED_POSITION)
    if len(desired.step):
        try:
            dq = data.get(recording.DESIRED_QUATERNION).at(desired.step)
        except KeyError as exc:
            raise InputError(
                f"{data.path}: incomplete recording: no setpoint data for step {exc.args[0]}"
            ) from None
        zeros = (0.0,) * 6
        for j, k in enumerate(desired.step.tolist()):
            metrics.add_setpoint(
                Setpoint(k, k * dt, (*desired.values[j].tolist(), *dq[j].tolist()), zeros, zeros)
            )
    feasible = data.get(recording.COMMAND_FEASIBLE)
    try:  # a controller fed from the sensors: its estimate with each command (the declared columns, read back)
        e, columns = sensor_columns(data, m, ESTIMATE_COLUMNS)
    except KeyError as exc:
        raise InputError(f"{data.path}: incomplete recording: no estimate data for step {exc.args[0]}") from None
    estimated = np.hstack([columns[c.name] for c in ESTIMATE_COLUMNS]) if len(e) else np.zeros((0, 0))
    estimates = {k: tuple(row) for k, row in zip(e.tolist(), estimated.tolist(), strict=True)}
    for k, f in zip(feasible.step.tolist(), feasible.values[:, 0].tolist(), strict=True):
        metrics.add_command(Command(k, k * dt, (), bool(f >= 0.5), estimate=estimates.get(k)))
    return metrics


def summarize(data: RecordingData) -> dict[str, Any]:
    """The run summary's fields that a recording determines (same names and definitions as ``cdpr run``)."""
    metrics = metrics_from(data)
    info = data.session
    last = max(metrics.last_step, 0)
    tension_series = sum(
        1 for i in range(int(info["cables"])) if len(data.get(recording.tension_series(i)).step)
    )
    return {
        "recording": data.path,
        "recording_id": data.recording_id,
        "scenario": info.get("scenario"),
        "session": info.get("session"),
        "steps": last,
        "total_steps": info.get("total_steps"),
        "sim_time": last * float(info["dt"]),
        **metrics.summary(),
        "recorded_states": len(metrics.states),
        "recorded_setpoints": len(metrics.setpoints),
        "recorded_commands": metrics.commands,
        "tension_series": tension_series,
        **latency_summary(data),
    }


def latency_summary(data: RecordingData) -> dict[str, Any]:
    """The command ages (steps) and the watchdog's steps the recording shows (docs/realtime.md)."""
    age, watchdog = data.get(COMMAND_AGE), data.get(WATCHDOG)
    if not len(age.step):
        return {}
    ages = age.values[:, 0]
    p50, p99 = (int(np.percentile(ages, q, method="inverted_cdf")) for q in (50, 99))  # as the clock's
    return {"command_age_p50": p50, "command_age_p99": p99, "command_age_max": int(ages.max()),
            "watchdog_steps": int(watchdog.values[:, 0].sum()) if len(watchdog.step) else 0}


def _plot_xyz(ax: Any, s: Series, title: str, unit: str) -> None:
    styles = ("-", "--", "-.")  # x and y often coincide (diagonal moves): dashes keep both visible
    for j, (name, rgb) in enumerate(zip(recording.AXES, recording.AXIS_COLORS, strict=True)):
        if s.values.shape[1] > j and len(s.step):
            ax.plot(s.t, s.values[:, j], color=np.array(rgb) / 255.0, linestyle=styles[j], label=name)
    ax.set_title(title)
    ax.set_xlabel("time (s)")
    ax.set_ylabel(unit)
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize="small")


def plot_tracking(data: RecordingData, out: str | Path) -> None:
    """The paper's Fig. 2/3 layout: desired (upper left) and actual positions (upper right), position
    errors (lower left), cable tensions (lower right)."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    info = data.session
    m, tmin, tmax = int(info["cables"]), float(info["tmin"]), float(info["tmax"])
    fig, axes = plt.subplots(2, 2, figsize=FIGURE_SIZE, dpi=FIGURE_DPI)
    _plot_xyz(axes[0, 0], data.get(recording.DESIRED_POSITION), "Desired position", "m")
    _plot_xyz(axes[0, 1], data.get(recording.ACTUAL_POSITION), "Actual position", "m")
    _plot_xyz(axes[1, 0], data.get(recording.POSITION_ERROR_AXES), "Position error (desired − actual)", "m")
    norm = data.get(recording.POSITION_ERROR_NORM)
    if len(norm.step):
        axes[1, 0].plot(norm.t, norm.values[:, 0], color="black", linestyle="--", linewidth=0.8, label="norm")
        axes[1, 0].legend(loc="best", fontsize="small")
    ax = axes[1, 1]
    palette = recording.tension_palette(m)
    lo, hi = np.inf, -np.inf
    for i in range(m):
        s = data.get(recording.tension_series(i))
        if len(s.step):
            ax.plot(
                s.t, s.values[:, 0], color=np.array(palette[i]) / 255.0, linewidth=0.9, label=f"cable {i}"
            )
            lo, hi = min(lo, float(s.values.min())), max(hi, float(s.values.max()))
    if np.isfinite(lo):
        pad = max(0.05 * (hi - lo), 1e-6 * max(abs(hi), 1.0), 0.5)
        ax.set_ylim(lo - pad, hi + pad)  # the limits are drawn only where they fall inside the data's range
    if "cable_tmin" in info:  # per-cable limits: each cable's in its colour
        for i, (a, b) in enumerate(zip(info["cable_tmin"], info["cable_tmax"], strict=True)):
            color = np.array(palette[i % len(palette)]) / 255.0
            ax.axhline(float(a), color=color, linestyle=":", linewidth=0.8)
            ax.axhline(float(b), color=color, linestyle="--", linewidth=0.8)
        ax.set_title("Cable tensions (dashed: each cable's limits)")
    else:
        ax.axhline(tmin, color="grey", linestyle="--", linewidth=1.0, label="tmin")
        ax.axhline(tmax, color="red", linestyle="--", linewidth=1.0, label="tmax")
        ax.set_title(f"Cable tensions (limits {tmin:g} – {tmax:g} N)")
    ax.set_xlabel("time (s)")
    ax.set_ylabel("N")
    ax.grid(True, alpha=0.3)
    ax.legend(loc="best", fontsize="x-small", ncol=2)
    fig.suptitle(f"{info.get('scenario', '')}: session {info.get('session', '')}")
    fig.tight_layout()
    fig.savefig(out, dpi=FIGURE_DPI)
    plt.close(fig)


def plot_orientation(data: RecordingData, out: str | Path) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 1, figsize=(FIGURE_SIZE[0], FIGURE_SIZE[1] / 2), dpi=FIGURE_DPI)
    _plot_xyz(ax, data.get(recording.ORIENTATION_ERROR_AXES), "Orientation error (rotation vector)", "rad")
    norm = data.get(recording.ORIENTATION_ERROR_NORM)
    if len(norm.step):
        ax.plot(norm.t, norm.values[:, 0], color="black", linestyle="--", linewidth=0.8, label="norm")
        ax.legend(loc="best", fontsize="small")
    fig.tight_layout()
    fig.savefig(out, dpi=FIGURE_DPI)
    plt.close(fig)


def plot_latency(data: RecordingData, out: str | Path) -> None:
    """The command age over time (steps), with the steps the watchdog's policy acted shaded."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, ax = plt.subplots(1, 1, figsize=(FIGURE_SIZE[0], FIGURE_SIZE[1] / 2), dpi=FIGURE_DPI)
    age, watchdog = data.get(COMMAND_AGE), data.get(WATCHDOG)
    if len(age.step):
        ax.step(age.t, age.values[:, 0], where="post", color="tab:blue", linewidth=0.8, label="command age")
    if len(watchdog.step) and watchdog.values[:, 0].any():
        top = float(max(age.values[:, 0].max(), 1.0)) if len(age.step) else 1.0
        ax.fill_between(watchdog.t, 0.0, top * watchdog.values[:, 0], step="post", color="tab:red", alpha=0.25,
                        label=f"watchdog ({int(watchdog.values[:, 0].sum())} steps)")
    ax.set_title("Command age: how many steps old the command that acted was (0: lock-step)")
    ax.set_xlabel("sim time (s)")
    ax.set_ylabel("steps")
    ax.grid(True, alpha=0.3)
    if ax.get_legend_handles_labels()[0]:
        ax.legend(loc="best", fontsize="small")
    fig.tight_layout()
    fig.savefig(out, dpi=FIGURE_DPI)
    plt.close(fig)


def default_out_dir(rrd: str | Path) -> Path:
    p = Path(rrd)
    return p.with_name(f"{p.stem}_report")


def write_report(rrd: str | Path, out_dir: str | Path | None = None) -> dict[str, Any]:
    """Read ``rrd``; write ``tracking.png``, ``orientation_error.png``, ``latency.png`` and ``summary.json``
    into ``out_dir`` (default: ``<name>_report/`` beside the file). Returns the summary and the files written."""
    data = read_recording(rrd)
    out = Path(out_dir) if out_dir is not None else default_out_dir(rrd)
    try:
        out.mkdir(parents=True, exist_ok=True)
    except OSError as exc:
        raise InputError(f"-o: cannot create {out}: {exc.strerror or exc}") from None
    summary = summarize(data)
    files = [out / TRACKING_PNG, out / ORIENTATION_PNG, out / LATENCY_PNG, out / SUMMARY_JSON]
    plot_tracking(data, files[0])
    plot_orientation(data, files[1])
    plot_latency(data, files[2])
    files[3].write_text(json.dumps(summary, indent=2) + "\n", encoding="utf-8")
    return {"summary": summary, "files": [str(f) for f in files]}
