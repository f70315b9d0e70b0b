"""Recording to Rerun: the recorder's pure core, the shared scene helpers, and real runs written to real
.rrd files, read back with ``rerun.chunk.RrdReader`` and checked against the run's own summary."""

from __future__ import annotations

import json
import math
import random
import signal
import struct
import subprocess
import sys
import uuid
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np
import pyarrow as pa
import pytest
from rerun.chunk import RrdReader

from cdpr import recording
from cdpr.config.robot import load_robot, shipped_robots
from cdpr.mechanics.kinematics import inverse_kinematics
from cdpr.mechanics.rotation import matrix_to_quat, orientation_error, quat_to_matrix, rotvec_to_matrix
from cdpr.protocol import Command, Setpoint, State, Status
from cdpr.tools.metrics import RunMetrics
from cdpr_recorder.core import RecorderCore, RecorderSettings, flatten_stats, orientation_errors
from conftest import CDPR, cdpr, last_json_line, sigterm_the_recorder, wait_no_processes

# --------------------------------------------------------------------------------------------------
# Pure helpers


def _random_rotation(rng: np.random.Generator, angle: float | None = None) -> np.ndarray:
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    return rotvec_to_matrix(axis * (rng.uniform(0.0, math.pi) if angle is None else angle))


@pytest.mark.parametrize("angle", [None, 1e-9, 1e-6, 0.3, math.pi - 1e-6])
def test_orientation_errors_match_the_rotation_module(angle: float | None) -> None:
    rng = np.random.default_rng(7)
    Rd = [_random_rotation(rng) for _ in range(20)]
    if angle is None:
        Ra = [_random_rotation(rng) for _ in Rd]
    else:  # R = Eᵀ R_d, so R_d Rᵀ = E, a rotation by exactly `angle`
        Ra = [_random_rotation(rng, angle).T @ rd for rd in Rd]
    got = orientation_errors([matrix_to_quat(r) for r in Rd], [matrix_to_quat(r) for r in Ra])
    want = np.array([orientation_error(rd, ra) for rd, ra in zip(Rd, Ra, strict=True)])
    assert np.allclose(got, want, atol=1e-12, rtol=1e-9)
    if angle is not None:
        assert np.allclose(np.linalg.norm(got, axis=1), angle, rtol=1e-6, atol=1e-12)


def _messages(n: int, m: int, seed: int) -> tuple[list[State], list[Setpoint], list[Command]]:
    rng = np.random.default_rng(seed)
    states, setpoints, commands = [], [], []
    for k in range(n + 1):
        q = matrix_to_quat(_random_rotation(rng, 0.01 * rng.uniform()))
        pos = rng.normal(size=3)
        tensions = tuple(rng.uniform(1, 100, m)) if k else (0.0,) * m
        states.append(
            State(
                k,
                k * 0.001,
                (*pos, *q),
                tuple(rng.normal(size=6)),
                tuple(rng.uniform(1, 5, m)),
                tensions,
                k // 4,
            )
        )
    for k in range(n):
        q = matrix_to_quat(_random_rotation(rng, 0.01 * rng.uniform()))
        setpoints.append(Setpoint(k, k * 0.001, (*rng.normal(size=3), *q), (0.0,) * 6, (0.0,) * 6))
        commands.append(
            Command(
                k,
                k * 0.001,
                tuple(rng.uniform(1, 100, m)),
                feasible=k % 7 != 3,
                status="ok" if k % 7 != 3 else "infeasible",
            )
        )
    return states, setpoints, commands


def test_core_errors_follow_the_run_metrics_definitions() -> None:
    """Shuffled arrival, repeated messages, small batches: the recorded errors are RunMetrics' errors."""
    m, n = 4, 57
    states, setpoints, commands = _messages(n, m, seed=1)
    stream: list[Any] = [*states, *setpoints, *commands, *states[10:20], *setpoints[:5]]
    random.Random(3).shuffle(stream)
    core = RecorderCore(RecorderSettings(cables=m, batch_steps=8))
    metrics = RunMetrics()
    batches = []
    for msg in stream:
        if isinstance(msg, State):
            new = core.add_state(msg)
            metrics.add_state(msg)
        elif isinstance(msg, Setpoint):
            new = core.add_setpoint(msg)
            metrics.add_setpoint(msg)
        else:
            new = core.add_command(msg)
        assert isinstance(new, bool)
        if core.due:
            batches.append(core.take())
    batches.append(core.take(final=True))
    assert not core.pending
    assert core.duplicates == 15
    steps = np.concatenate([b.errors.step for b in batches])
    order = np.argsort(steps)
    pos = np.concatenate([b.errors.position for b in batches])[order]
    rot = np.concatenate([b.errors.orientation for b in batches])[order]
    want_pos, want_rot = metrics.errors()
    assert steps[order].tolist() == list(range(n))  # every state with a setpoint (the final one has none)
    assert np.allclose(np.linalg.norm(pos, axis=1), want_pos, rtol=1e-12, atol=0)
    assert np.allclose(np.linalg.norm(rot, axis=1), want_rot, rtol=1e-7, atol=1e-15)
    last_sp = setpoints[-1]
    last_paired = next(s for s in states if s.step == last_sp.step)
    assert np.array_equal(pos[-1], np.subtract(last_sp.pose[:3], last_paired.pose[:3]))
    # one row per step and stream, in step order within each batch
    for kind in ("states", "setpoints", "commands"):
        got = np.concatenate([getattr(b, kind).step for b in batches])
        assert sorted(got.tolist()) == list(range(n + 1 if kind == "states" else n))
        for b in batches:
            assert np.all(np.diff(getattr(b, kind).step) > 0)
    feasible = np.concatenate([b.commands.feasible for b in batches])
    assert int((~feasible).sum()) == sum(1 for c in commands if not c.feasible)


def test_core_batches_decimate_the_scene_and_grow_the_path() -> None:
    m = 2
    states, setpoints, _ = _messages(23, m, seed=2)
    core = RecorderCore(RecorderSettings(cables=m, batch_steps=10, scene_every=3, path_every=4))
    taken = []
    for s, sp in zip(states, [*setpoints, None], strict=True):
        core.add_state(s)
        if sp is not None:
            core.add_setpoint(sp)
        if core.due:
            taken.append(core.take())
    taken.append(core.take(final=True))
    assert [len(b.states.step) for b in taken] == [10, 10, 4]
    scene = np.concatenate([b.states.step[b.states.scene] for b in taken])
    assert scene.tolist() == [0, 3, 6, 9, 12, 15, 18, 21, 23]  # every 3rd, and the final state
    path_steps = [k for b in taken for k in b.path.step]
    assert path_steps == [0, 4, 8, 12, 16, 20, 23]
    last_points = taken[-1].path.points[-1]
    assert last_points.shape == (7, 3)
    assert np.array_equal(last_points[-1], states[23].pose[:3])
    assert np.array_equal(last_points[1], states[4].pose[:3])
    b = taken[0]
    assert np.array_equal(b.states.columns["tensions"][3], states[3].tensions)
    assert np.array_equal(b.states.columns["cable_lengths"][5], states[5].cable_lengths)
    assert b.states.columns["clamped"].tolist() == [s.clamped for s in states[:10]]


def test_core_rejects_the_wrong_number_of_cables() -> None:
    core = RecorderCore(RecorderSettings(cables=3))
    states, _, _ = _messages(1, 4, seed=0)
    with pytest.raises(ValueError, match="expected 3 tensions"):
        core.add_state(states[0])


def test_status_rows_keep_the_numbers_and_mark_changes() -> None:
    core = RecorderCore(RecorderSettings(cables=1))
    stats = {
        "rate": 512.5,
        "late_ticks": 2,
        "faults": {"sim": {"clamped_commands": 3}},
        "note": "x",
        "ok": True,
    }
    core.add_status(Status("waiting", 0, 0.0, 10, ("sim",), "waiting for sim", stats))
    core.add_status(Status("waiting", 0, 0.0, 10, ("sim",), "waiting for sim", stats))
    core.add_status(Status("running", 4, 0.004, 10, (), "", {"rate": float("nan")}))
    rows = core.take().statuses
    assert [r.changed for r in rows] == [True, False, True]
    assert rows[0].stats == {"rate": 512.5, "late_ticks": 2.0, "faults/sim/clamped_commands": 3.0}
    assert rows[2].stats == {}
    assert flatten_stats({"a": {"b": {"c": 1}}, "d": [1, 2]}) == {"a/b/c": 1.0}


@pytest.mark.parametrize("name", shipped_robots())
def test_cable_strips_join_the_kinematics_attach_points(name: str) -> None:
    robot = load_robot(name)
    rng = np.random.default_rng(5)
    poses = []
    for _ in range(4):
        Rm = _random_rotation(rng, 0.2) if robot.mode == "spatial" else np.eye(3)
        poses.append((robot.home_position + 0.1 * rng.normal(size=3) * (robot.mode != "planar"), Rm))
    strips = recording.cable_strips(robot, [p for p, _ in poses], [matrix_to_quat(r) for _, r in poses])
    assert strips.shape == (4, robot.m, 2, 3)
    for j, (p, Rm) in enumerate(poses):
        k = inverse_kinematics(robot, p, Rm)
        assert np.allclose(strips[j, :, 0], k.platform_points_world, atol=1e-12)
        # to the frame point, or where the cable leaves its exit pulley: the free span (all of it without pulleys)
        assert np.allclose(strips[j, :, 1], k.platform_points_world + k.vectors, atol=1e-12)
        if robot.pulleys is None:
            assert np.allclose(strips[j, :, 1], robot.frame_points)
            assert np.allclose(np.linalg.norm(strips[j, :, 1] - strips[j, :, 0], axis=1), k.lengths, atol=1e-12)
        else:  # on its wheel (centre a + r e, e towards B across the swivel axis u), the span tangent to it
            B, T, a = strips[j, :, 0], strips[j, :, 1], robot.frame_points
            u, r = robot.pulleys.axis, robot.pulleys.radius
            across = (B - a) - np.einsum("ij,ij->i", B - a, u)[:, None] * u
            centre = a + r[:, None] * across / np.linalg.norm(across, axis=1, keepdims=True)
            assert np.allclose(np.linalg.norm(T - centre, axis=1), r, atol=1e-12)
            assert np.allclose(np.einsum("ij,ij->i", T - centre, T - B), 0.0, atol=1e-12)


def test_tension_colors_run_from_tmin_to_tmax() -> None:
    c = recording.tension_colors([-5.0, 10.0, 55.0, 100.0, 1e9], 10.0, 100.0)
    assert c.dtype == np.uint8
    assert c.shape == (5, 4)
    assert np.array_equal(c[0], c[1])
    assert np.array_equal(c[3], c[4])
    assert c[1].tolist() == [68, 1, 84, 255]
    assert c[3].tolist() == [253, 231, 37, 255]
    ramp = recording.tension_colors(np.linspace(10, 100, 50), 10.0, 100.0).astype(int)
    assert np.all(np.diff(ramp[:, 1]) >= 0)  # green rises monotonically along the scale
    assert recording.tension_colors(np.zeros((3, 8)), 0.0, 1.0).shape == (3, 8, 4)


def test_anchor_labels_group_shared_frame_points() -> None:
    robot = load_robot("caroca")
    pts, labels = recording.anchor_labels(robot.frame_points)
    assert labels == ["0,1", "2,3", "4,5", "6,7"]
    assert np.array_equal(pts, robot.frame_points[::2])
    pts, labels = recording.anchor_labels(robot.platform_points)
    assert labels == [str(i) for i in range(8)]


def test_recording_id_is_unique_per_run_unless_forced() -> None:
    a, b = recording.recording_id("s1", env={}), recording.recording_id("s1", env={})
    assert a != b
    assert a.startswith("s1-")
    assert b.startswith("s1-")
    assert recording.recording_id("s1", env={recording.RECORDING_ID_ENV: "shared"}) == "shared"


# --------------------------------------------------------------------------------------------------
# Reading recordings back, independently of cdpr.tools.report


def _scalars(path: Path, entity: str) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(steps, sim_time ns, values (n, k)) of one scalar entity, sorted by step."""
    parts = []
    for chunk in RrdReader(str(path)).stream().to_chunks():
        if chunk.entity_path != f"/{entity}" or chunk.is_static:
            continue
        rb = chunk.to_record_batch()
        rows = rb.column("Scalars:scalars").to_pylist()
        parts.append(
            (
                rb.column("step").to_numpy(),
                rb.column("sim_time").cast(pa.int64()).to_numpy(),
                np.array(rows, dtype=float),
            )
        )
    assert parts, f"no {entity} in {path}"
    steps = np.concatenate([p[0] for p in parts])
    order = np.argsort(steps)
    return (
        steps[order],
        np.concatenate([p[1] for p in parts])[order],
        np.concatenate([p[2] for p in parts])[order],
    )


def _rows(path: Path, entity: str, column: str, static: bool = False) -> list[tuple[int | None, Any]]:
    out = []
    for chunk in RrdReader(str(path)).stream().to_chunks():
        if chunk.entity_path == f"/{entity}" and chunk.is_static == static:
            rb = chunk.to_record_batch()
            if column not in rb.schema.names:
                continue
            steps = rb.column("step").to_pylist() if "step" in rb.schema.names else [None] * rb.num_rows
            out += list(zip(steps, rb.column(column).to_pylist(), strict=True))
    return sorted(out, key=lambda r: -1 if r[0] is None else r[0])


def _rerun(*args: str) -> subprocess.CompletedProcess[str]:
    exe = recording.rerun_binary()
    cmd = [exe] if exe else [sys.executable, "-m", "rerun"]
    return subprocess.run([*cmd, *args], capture_output=True, text=True, timeout=120, check=False)


def _png_size(path: Path) -> tuple[int, int]:
    head = path.read_bytes()[:24]
    assert head[:8] == b"\x89PNG\r\n\x1a\n"
    assert head[12:16] == b"IHDR"
    return struct.unpack(">II", head[16:24])


DURATION = 0.5
DT = 0.001
STEPS = 500


@pytest.fixture(scope="module")
def recorded(tmp_path_factory: pytest.TempPathFactory) -> Iterator[tuple[dict[str, Any], Path]]:
    """One real 0.5 s run with --rrd, shared by the tests below."""
    sid = f"t{uuid.uuid4().hex[:12]}"
    rrd = tmp_path_factory.mktemp("rec") / "run.rrd"
    proc = cdpr(
        "run",
        "caroca_15kg",
        "--duration",
        str(DURATION),
        "--session",
        sid,
        "--rrd",
        str(rrd),
        "--quiet",
        timeout=180,
    )
    assert proc.returncode == 0, f"{proc.stdout[-2000:]}\n{proc.stderr[-3000:]}"
    yield last_json_line(proc.stdout), rrd
    assert not wait_no_processes(sid, timeout=10.0)


@pytest.mark.slow
def test_the_recording_holds_the_whole_state_stream(recorded: tuple[dict[str, Any], Path]) -> None:
    summary, rrd = recorded
    assert summary["exit_ok"] is True
    assert summary["exit_codes"]["recorder"] == 0
    assert summary["steps"] == STEPS
    entries = RrdReader(str(rrd)).recordings()
    assert len(entries) == 1
    assert entries[0].application_id == "cdpr"
    assert entries[0].recording_id.startswith(summary["session"] + "-")
    steps, ns, pos = _scalars(rrd, recording.ACTUAL_POSITION)
    assert steps.tolist() == list(range(STEPS + 1))
    assert np.array_equal(ns, np.round(steps * DT * 1e9).astype(np.int64))  # sim_time is the message's t
    _, _, quat = _scalars(rrd, recording.ACTUAL_QUATERNION)
    _, _, twist = _scalars(rrd, recording.ACTUAL_TWIST)
    _, _, lengths = _scalars(rrd, recording.CABLE_LENGTHS)
    _, _, clamped = _scalars(rrd, recording.CLAMPED)
    tensions = np.zeros((STEPS + 1, 8))
    for i in range(8):
        k, _, v = _scalars(rrd, recording.tension_series(i))
        assert k.tolist() == list(range(1, STEPS + 1))
        tensions[1:, i] = v[:, 0]
    # Re-encode every recorded state as the sim published it: the digest is the run's, bit for bit,
    # so in particular the last recorded state is the sim's final state.
    metrics = RunMetrics()
    for k in range(STEPS + 1):
        st = State(
            k,
            k * DT,
            (*pos[k], *quat[k]),
            tuple(twist[k]),
            tuple(lengths[k]),
            tuple(tensions[k]),
            int(clamped[k, 0]),
        )
        metrics.add_state(st)
    assert metrics.digest() == summary["state_digest"]
    # the recorder's own error series ends with the run's final error (the last tick's step)
    k, _, err = _scalars(rrd, recording.POSITION_ERROR_NORM)
    assert k[-1] == STEPS - 1
    assert err[-1, 0] == pytest.approx(summary["final_position_error"], rel=1e-12)
    _, _, desired = _scalars(rrd, recording.DESIRED_POSITION)
    assert np.linalg.norm(desired[-1] - pos[-2]) == pytest.approx(summary["final_position_error"], rel=1e-12)


@pytest.mark.slow
def test_one_tension_series_per_cable_with_limits(recorded: tuple[dict[str, Any], Path]) -> None:
    summary, rrd = recorded
    entities = {c.entity_path for c in RrdReader(str(rrd)).stream().to_chunks()}
    cables = sorted(e for e in entities if e.startswith(f"/{recording.TENSION}/cable_"))
    assert cables == [f"/{recording.tension_series(i)}" for i in range(8)]
    values = np.concatenate([_scalars(rrd, recording.tension_series(i))[2][:, 0] for i in range(8)])
    assert values.min() == summary["tension_min"]
    assert values.max() == summary["tension_max"]
    robot_limits = (1.0, 6500.0)  # caroca_15kg's limits
    for entity, limit in ((recording.TENSION_MIN, robot_limits[0]), (recording.TENSION_MAX, robot_limits[1])):
        k, _, v = _scalars(rrd, entity)
        assert np.all(v == limit)
        assert k.min() == 1
        assert k.max() == STEPS
    names = _rows(rrd, recording.tension_series(3), "SeriesLines:names", static=True)
    assert names == [(None, ["cable 3"])]


@pytest.mark.slow
def test_the_scene_is_static_plus_decimated_poses(recorded: tuple[dict[str, Any], Path]) -> None:
    _, rrd = recorded
    robot = load_robot("caroca")
    frame = _rows(rrd, recording.FRAME_ANCHORS, "Points3D:labels", static=True)
    assert frame == [(None, ["0,1", "2,3", "4,5", "6,7"])]
    poses = _rows(rrd, recording.PLATFORM, "Transform3D:translation")
    assert [k for k, _ in poses] == list(range(0, STEPS + 1, 10))
    _, _, pos = _scalars(rrd, recording.ACTUAL_POSITION)
    assert np.allclose(poses[-1][1][0], pos[STEPS], atol=1e-6)  # float32 in the 3D scene
    cables = _rows(rrd, recording.CABLES, "LineStrips3D:strips")
    assert [k for k, _ in cables] == list(range(0, STEPS + 1, 10))
    last = np.array(cables[-1][1])
    assert last.shape == (8, 2, 3)
    assert np.allclose(last[:, 1], robot.frame_points, atol=1e-6)
    _, _, quat = _scalars(rrd, recording.ACTUAL_QUATERNION)
    k = inverse_kinematics(robot, pos[STEPS], quat_to_matrix(quat[STEPS]))
    assert np.allclose(last[:, 0], k.platform_points_world, atol=1e-5)
    colors = _rows(rrd, recording.CABLES, "LineStrips3D:colors")
    assert len(colors[-1][1]) == 8
    assert [k for k, _ in _rows(rrd, recording.DESIRED, "Transform3D:translation")] == list(
        range(0, STEPS, 10)
    )
    path = _rows(rrd, recording.PATH, "LineStrips3D:strips")
    assert [k for k, _ in path] == list(range(0, STEPS + 1, 50))
    assert len(path[-1][1][0]) == STEPS // 50 + 1


@pytest.mark.slow
def test_the_blueprint_is_sent_with_the_recording(recorded: tuple[dict[str, Any], Path]) -> None:
    _, rrd = recorded
    reader = RrdReader(str(rrd))
    # the layout sent at the start, and again at the end with the tension plot's range
    blueprints = reader.blueprints()
    assert len(blueprints) >= 1
    origins = set()
    names: set[str] = set()
    for bp in blueprints:
        assert bp.application_id == "cdpr"
        for chunk in reader.stream(store=bp).to_chunks():
            rb = chunk.to_record_batch()
            names.update(rb.schema.names)
            if "ViewBlueprint:space_origin" in rb.schema.names:
                origins.update(v[0].lstrip("/") for v in rb.column("ViewBlueprint:space_origin").to_pylist())
    paper = {
        recording.DESIRED_POSITION,
        recording.ACTUAL_POSITION,
        recording.POSITION_ERROR,
        recording.TENSION,
        recording.WORLD,
    }
    assert paper <= origins


@pytest.mark.slow
def test_rerun_verifies_the_file(recorded: tuple[dict[str, Any], Path]) -> None:
    _, rrd = recorded
    proc = _rerun("rrd", "verify", str(rrd))
    assert proc.returncode == 0, proc.stderr


@pytest.mark.slow
def test_report_writes_the_figure_and_the_run_summary(
    recorded: tuple[dict[str, Any], Path], tmp_path: Path
) -> None:
    summary, rrd = recorded
    proc = cdpr("report", str(rrd), "-o", str(tmp_path / "out"), timeout=120, check=True)
    out = json.loads(proc.stdout)
    png = tmp_path / "out" / "tracking.png"
    assert str(png) in out["files"]
    assert png.stat().st_size > 10_000
    assert _png_size(png) == (1200, 800)
    assert _png_size(tmp_path / "out" / "orientation_error.png") == (1200, 400)
    got = json.loads((tmp_path / "out" / "summary.json").read_text())
    assert got == out["summary"]
    for key in (
        "steps",
        "total_steps",
        "clamped_commands",
        "infeasible_commands",
        "state_digest",
        "scenario",
        "session",
    ):
        assert got[key] == summary[key], key
    for key in (
        "sim_time",
        "rms_position_error",
        "max_position_error",
        "final_position_error",
        "rms_orientation_error",
        "max_orientation_error",
        "tension_min",
        "tension_max",
    ):
        assert got[key] == pytest.approx(summary[key], rel=1e-12, abs=0), key
    assert got["tension_series"] == 8
    assert got["recorded_states"] == STEPS + 1


@pytest.mark.slow
def test_show_draws_a_robot_at_home(tmp_path: Path) -> None:
    rrd = tmp_path / "caroca.rrd"
    proc = cdpr("show", "caroca", "--rrd", str(rrd), timeout=60, check=True)
    assert json.loads(proc.stdout)["rrd"] == str(rrd)
    assert _rerun("rrd", "verify", str(rrd)).returncode == 0
    robot = load_robot("caroca")
    (row,) = _rows(rrd, recording.CABLES, "LineStrips3D:strips", static=True)
    strips = np.array(row[1])
    k = inverse_kinematics(robot, robot.home_position, robot.home_rotation)
    assert np.allclose(strips[:, 0], k.platform_points_world, atol=1e-6)
    assert np.allclose(strips[:, 1], robot.frame_points, atol=1e-6)
    assert _rows(rrd, recording.CABLES, "LineStrips3D:labels", static=True)[0][1] == [
        f"cable {i}" for i in range(8)
    ]
    assert _rows(rrd, recording.PLATFORM_ANCHORS, "Points3D:labels", static=True)[0][1] == [
        str(i) for i in range(8)
    ]
    (pose,) = _rows(rrd, recording.PLATFORM, "Transform3D:translation", static=True)
    assert np.allclose(pose[1][0], robot.home_position)


@pytest.mark.slow
def test_a_recorder_stopped_by_sigterm_leaves_a_readable_file(session_id: str, tmp_path: Path) -> None:
    rrd = tmp_path / "stopped.rrd"
    run = subprocess.Popen(
        [
            *CDPR,
            "run",
            "caroca_15kg",
            "--duration",
            "20",
            "--session",
            session_id,
            "--rrd",
            str(rrd),
            "--quiet",
        ],
        stdout=subprocess.PIPE,
        stderr=subprocess.PIPE,
        text=True,
    )
    out, err = sigterm_the_recorder(run, session_id, rrd, 500_000, timeout=120)
    summary = last_json_line(out)
    assert summary["exit_codes"]["recorder"] == 128 + signal.SIGTERM
    assert summary["exit_ok"] is False
    assert _rerun("rrd", "verify", str(rrd)).returncode == 0  # footer included: the file was closed properly
    steps, _, _ = _scalars(rrd, recording.ACTUAL_POSITION)
    last = int(steps[-1])
    assert 200 <= last < 20_000
    assert last <= summary["steps"]
    assert steps.tolist() == list(range(last + 1))  # nothing lost up to the last recorded state
    for entity in (recording.ACTUAL_TWIST, recording.CABLE_LENGTHS, recording.ACTUAL_QUATERNION):
        assert _scalars(rrd, entity)[0].tolist() == steps.tolist()
    rep = cdpr("report", str(rrd), "-o", str(tmp_path / "rep"), timeout=120, check=True)
    assert json.loads(rep.stdout)["summary"]["steps"] == last
    assert "recorded" in err


@pytest.mark.parametrize("command", ["report", "replay"])
def test_a_missing_or_bad_file_is_one_line_and_exit_2(command: str, tmp_path: Path) -> None:
    proc = cdpr(command, str(tmp_path / "nope.rrd"))
    assert proc.returncode == 2
    assert proc.stderr.strip() == f"cdpr: error: {tmp_path / 'nope.rrd'}: no such file"
    if command == "report":
        bad = tmp_path / "bad.rrd"
        bad.write_bytes(b"not a recording at all")
        proc = cdpr(command, str(bad))
        assert proc.returncode == 2
        assert proc.stderr.startswith(f"cdpr: error: {bad}: ")
        assert len(proc.stderr.strip().splitlines()) == 1


@pytest.mark.slow
def test_every_stream_for_every_step_with_a_competing_process(session_id: str, tmp_path: Path) -> None:
    """The winch scenario (length commands, sensors) recorded while another process keeps a core busy:
    pose, twist, lengths, tensions, setpoints, errors, commanded lengths, TDA status and solve time,
    loop lag and every sensor, each for every step; the clock's statistics too."""
    rrd = tmp_path / "winch.rrd"
    burner = subprocess.Popen([sys.executable, "-c", "import time\nt = time.monotonic() + 120\n"
                               "while time.monotonic() < t: pass"])
    try:
        proc = cdpr("run", "caroca_15kg_winch", "--duration", "0.4", "--session", session_id, "--rrd", str(rrd),
                    "--quiet", timeout=180)
    finally:
        burner.kill()
        burner.wait()
    assert proc.returncode == 0, proc.stderr[-3000:]
    summary = last_json_line(proc.stdout)
    n = summary["steps"]
    assert n == 400
    states, steps = list(range(n + 1)), list(range(n))
    for entity, want in [
        (recording.ACTUAL_POSITION, states), (recording.ACTUAL_QUATERNION, states), (recording.ACTUAL_TWIST, states),
        (recording.CABLE_LENGTHS, states), (recording.tension_series(0), states[1:]),
        (recording.DESIRED_POSITION, steps), (recording.POSITION_ERROR_NORM, steps),
        (recording.ORIENTATION_ERROR_NORM, steps), (recording.COMMAND_LENGTHS, steps),
        (recording.COMMAND_FEASIBLE, steps), (recording.COMMAND_SOLVE_TIME, steps), (recording.LOOP_LAG, steps),
        (recording.SENSOR_ENCODERS, states), (recording.SENSOR_LOAD_CELLS, states),
        (recording.SENSOR_ACCEL, states), (recording.SENSOR_GYRO, states),
    ]:
        got, _, values = _scalars(rrd, entity)
        assert got.tolist() == want, entity
        assert np.all(np.isfinite(values)), entity
    _, _, solve = _scalars(rrd, recording.COMMAND_SOLVE_TIME)
    assert 0.0 < float(np.median(solve)) < 0.1  # seconds, as the controller measured them
    _, _, lengths = _scalars(rrd, recording.COMMAND_LENGTHS)
    assert lengths.shape == (n, 8)
    assert len(_scalars(rrd, recording.clock_series("rate"))[0]) >= 1


@pytest.mark.slow
def test_commanded_tensions_are_recorded(recorded: tuple[dict[str, Any], Path]) -> None:
    _, rrd = recorded
    got, _, values = _scalars(rrd, recording.COMMAND_TENSIONS)
    assert got.tolist() == list(range(STEPS))
    _, _, applied = _scalars(rrd, recording.tension_series(3))
    assert np.allclose(values[:, 3], applied[:, 0])  # tensions in the loop: applied as commanded (none clamped)
