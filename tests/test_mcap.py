"""Sessions as MCAP (Foxglove schemas) and live over Foxglove's WebSocket protocol.

The sink on its own (fed the recorder's core), then real sessions: ``cdpr run --rrd X --mcap Y`` read back
with the ``mcap`` reader against the .rrd of the same run, ``cdpr convert`` of that .rrd, Rerun's own
``rerun mcap convert`` of the MCAP, ``--in-process --mcap`` alone, and a WebSocket client of ``--foxglove``.
"""

from __future__ import annotations

import asyncio
import json
import math
import struct
import subprocess
import sys
import time
from collections import defaultdict
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from cdpr import recording
from cdpr.config.robot import load_robot
from cdpr.errors import InputError
from cdpr.protocol import PROTOCOL_VERSION, Command, Sensors, Setpoint, State, Status
from cdpr.recording import mcap as fox
from cdpr.tools.metrics import RunMetrics
from cdpr_recorder.core import RecorderCore, RecorderSettings
from conftest import CDPR, cdpr, free_port, last_json_line, sigterm_the_recorder

PER_STEP = (fox.PLATFORM_STATE, fox.LENGTHS, fox.TENSIONS, fox.SETPOINT, fox.ERROR, fox.COMMAND)


def read_mcap(path: Path) -> tuple[dict[str, list[tuple[int, Any]]], dict[str, dict[str, str]], dict[str, Any]]:
    """Every message by topic as (log_time, decoded JSON or raw bytes), the metadata records, the channels."""
    from mcap.reader import make_reader

    topics: dict[str, list[tuple[int, Any]]] = defaultdict(list)
    with path.open("rb") as f:
        reader = make_reader(f)
        meta = {m.name: dict(m.metadata) for m in reader.iter_metadata()}
        channels = {}
        for schema, channel, message in reader.iter_messages(log_time_order=True):
            channels[channel.topic] = (schema.name if schema else None, schema.encoding if schema else None,
                                       channel.message_encoding)
            data = json.loads(message.data) if channel.message_encoding == "json" else message.data
            topics[channel.topic].append((message.log_time, data))
    return dict(topics), meta, channels


def by_step(rows: list[tuple[int, Any]]) -> dict[int, tuple[int, Any]]:
    out: dict[int, tuple[int, Any]] = {}
    for ns, msg in rows:
        assert msg["step"] not in out, f"step {msg['step']} twice"
        out[msg["step"]] = (ns, msg)
    return out


# --------------------------------------------------------------------------------------------------
# The sink alone


def test_json_rows_read_back_as_the_same_float64() -> None:
    rng = np.random.default_rng(5)
    values = np.concatenate([rng.normal(size=200) * 10.0 ** rng.integers(-300, 300, 200),
                             [0.0, -0.0, 5e-324, 1.7976931348623157e308, 0.1, 1 / 3]])
    rows = fox.json_rows({"step": np.arange(len(values)), "v": values, "pair": np.column_stack([values, values])},
                         {"kind": "x"})
    back = [json.loads(r) for r in rows]
    assert back[0]["kind"] == "x"
    assert [b["pair"] for b in back] == [[v, v] for v in values.tolist()]
    assert [b["step"] for b in back] == list(range(len(values)))
    got = np.array([b["v"] for b in back])
    assert np.array_equal(got.view(np.int64), values.view(np.int64))  # bit for bit, -0.0 included
    assert json.loads(fox.json_rows({"v": np.array([np.nan])})[0]) == {"v": None}  # NaN: null


def test_log_times_are_sim_time_in_nanoseconds() -> None:
    assert fox.nanoseconds([0.0, 0.001, 11.0, 3 * 0.1]).tolist() == [0, 1_000_000, 11_000_000_000, 300_000_000]


def _feed_core(m: int, n: int) -> tuple[list[Any], list[State], list[Setpoint], list[Command]]:
    rng = np.random.default_rng(11)
    core = RecorderCore(RecorderSettings(cables=m, batch_steps=7, scene_every=4, path_every=6))
    states, setpoints, commands = [], [], []
    for k in range(n + 1):
        q = rng.normal(size=4)
        q /= np.linalg.norm(q)
        states.append(State(k, k * 0.001, (*rng.normal(size=3), *q), tuple(rng.normal(size=6)),
                            tuple(rng.uniform(1, 5, m)), tuple(rng.uniform(1, 90, m)) if k else (0.0,) * m, k // 5))
    for k in range(n):
        setpoints.append(Setpoint(k, k * 0.001, (*rng.normal(size=3), 0.0, 0.0, 0.0, 1.0), (0.0,) * 6, (0.0,) * 6))
        status = 'he said "no"\n' if k % 5 == 2 else "ok"
        commands.append(Command(k, k * 0.001, tuple(rng.uniform(1, 90, m)), k % 5 != 2, status,
                                solve_time=None if k % 3 == 0 else float(rng.uniform(1e-5, 1e-3))))
    batches = []
    for k in range(n + 1):
        core.add_state(states[k])
        if k < n:
            core.add_setpoint(setpoints[k])
            core.add_command(commands[k], lag=1e-4 * k)
            core.add_sensors(Sensors(k, k * 0.001, tuple(rng.normal(size=m)), tuple(rng.normal(size=m)),
                                     tuple(rng.normal(size=3)), tuple(rng.normal(size=3))))
        if k == 3:
            core.add_status(Status("running", k, k * 0.001, 30, stats={"rate": 812.5, "faults": {"sim": {"x": 2}}}))
        if core.due:
            batches.append(core.take())
    batches.append(core.take(final=True))
    return batches, states, setpoints, commands


def _send(sink: fox.FoxgloveSink, b: Any) -> None:
    """What the recorder node does with a batch (cdpr_recorder.node.RecorderNode.send_foxglove)."""
    s, sp, c, e, r = b.states, b.setpoints, b.commands, b.errors, b.sensors
    sink.states(s.step, s.t, s.columns, s.scene)
    sink.setpoints(sp.step, sp.t, sp.pose, sp.scene)
    sink.commands(c.step, c.t, c.kind, c.values, c.feasible, c.status, c.solve_time, c.lag)
    sink.errors(e.step, e.t, e.position, e.orientation)
    sink.sensors(r.step, r.t, r.columns)
    sink.statuses(b.statuses)
    sink.path(b.path.step, b.path.t, b.path.points)
    sink.end_batch()


def test_the_sink_writes_every_row_of_the_recorders_batches(tmp_path: Path) -> None:
    m, n = 4, 30
    robot = load_robot("point_mass_4")
    assert robot.m == m
    batches, states, setpoints, commands = _feed_core(m, n)
    session = {"scenario": "synthetic", "session": "s1", "dt": 0.001, "cables": m, "info": {"robot": robot.summary()}}
    path = tmp_path / "out.mcap"
    sink = fox.FoxgloveSink(robot, session, mcap=path, planned_path=np.zeros((5, 3)))
    for b in batches:
        _send(sink, b)
    sink.close()
    topics, meta, channels = read_mcap(path)

    assert meta[fox.METADATA_NAME]["scenario"] == "synthetic"
    assert meta[fox.METADATA_NAME]["protocol_version"] == str(PROTOCOL_VERSION)
    assert json.loads(meta[fox.METADATA_NAME]["info"])["robot"]["name"] == "point_mass_4"
    assert channels[fox.PLATFORM_POSE][:3] == ("foxglove.FrameTransform", "protobuf", "protobuf")
    assert channels[fox.SCENE_CABLES][0] == "foxglove.SceneUpdate"
    assert channels[fox.TENSIONS] == ("cdpr.CableTensions", "jsonschema", "json")
    assert sum(len(v) for v in topics.values()) == sink.messages

    st = by_step(topics[fox.PLATFORM_STATE])
    assert sorted(st) == list(range(n + 1))
    for s in states:
        ns, msg = st[s.step]
        assert ns == round(s.t * 1e9)
        assert msg["position"] + msg["quaternion"] == list(s.pose)
        assert msg["twist"] == list(s.twist)
        assert msg["clamped"] == s.clamped
        assert by_step(topics[fox.LENGTHS])[s.step][1]["lengths"] == list(s.cable_lengths)
    tensions = by_step(topics[fox.TENSIONS])
    assert sorted(tensions) == list(range(1, n + 1))  # state 0: nothing applied yet
    assert all(tensions[s.step][1]["tensions"] == list(s.tensions) for s in states[1:])
    assert tensions[1][1]["tmax"] == robot.tmax[0]
    assert "cable_tmax" not in tensions[1][1]  # the same limits for every cable
    cmd = by_step(topics[fox.COMMAND])
    for c in commands:
        msg = cmd[c.step][1]
        assert msg["values"] == list(c.tensions)
        assert msg["kind"] == "tensions"
        assert msg["feasible"] is c.feasible
        assert msg["status"] == c.status
        assert msg["solve_time"] == c.solve_time  # None: written as null
        assert msg["lag"] == 1e-4 * c.step
    assert sorted(by_step(topics[fox.SETPOINT])) == list(range(n))
    assert sorted(by_step(topics[fox.ERROR])) == list(range(n))  # the final state has no setpoint
    err = by_step(topics[fox.ERROR])[7][1]
    assert err["position"] == (np.subtract(setpoints[7].pose[:3], states[7].pose[:3])).tolist()
    assert err["position_norm"] == float(np.linalg.norm(err["position"]))
    assert sorted(by_step(topics[fox.SENSORS])) == list(range(n))
    clock = topics[fox.CLOCK]
    assert len(clock) == 1
    assert clock[0][1]["stats"] == {"rate": 812.5, "faults/sim/x": 2.0}
    # 3D rows: every 4th state and the final one; the path every 6th and the final one
    scene = sorted({ns for ns, _ in topics[fox.PLATFORM_POSE]})
    assert scene == [round(k * 1e6) for k in sorted({*range(0, n + 1, 4), n})]
    assert len(topics[fox.SCENE_CABLES]) == len(scene)
    assert len(topics[fox.SCENE_PATH]) == len({*range(0, n + 1, 6), n})
    assert len(topics[fox.SCENE_STATIC]) == 1
    assert topics[fox.SCENE_STATIC][0][0] == 0


def test_the_pose_transform_decodes_as_foxglove_protobuf(tmp_path: Path) -> None:
    """The FrameTransform bytes carry the pose (decoded with the schema's own descriptor set)."""
    from google.protobuf import descriptor_pb2, descriptor_pool, message_factory

    robot = load_robot("caroca")
    sink = fox.FoxgloveSink(robot, {"scenario": "x"}, mcap=tmp_path / "p.mcap")
    pose = np.array([[0.5, -0.25, 1.5, 0.0, 0.0, math.sin(0.3), math.cos(0.3)]])
    sink.states([10], [0.01], {"pose": pose, "twist": np.zeros((1, 6)), "cable_lengths": np.ones((1, robot.m)),
                               "tensions": np.ones((1, robot.m)), "clamped": np.array([0]),
                                   "command_age": np.array([0]), "watchdog": np.array([0])}, [True])
    sink.close()
    from mcap.reader import make_reader

    with (tmp_path / "p.mcap").open("rb") as f:
        schema, _, message = next(iter(make_reader(f).iter_messages(topics=[fox.PLATFORM_POSE])))
    files = descriptor_pb2.FileDescriptorSet.FromString(schema.data)
    pool = descriptor_pool.DescriptorPool()
    for fd in files.file:
        pool.Add(fd)
    cls = message_factory.GetMessageClass(pool.FindMessageTypeByName(schema.name))
    tf = cls.FromString(message.data)
    assert (tf.parent_frame_id, tf.child_frame_id) == ("world", "platform")
    assert [tf.translation.x, tf.translation.y, tf.translation.z] == pose[0, :3].tolist()
    assert [tf.rotation.x, tf.rotation.y, tf.rotation.z, tf.rotation.w] == pose[0, 3:].tolist()
    assert tf.timestamp.nanos == 10_000_000
    assert message.log_time == 10_000_000


def test_the_recorder_needs_a_sink_and_a_free_port() -> None:
    import socket

    from cdpr.config.scenario import load_scenario
    from cdpr.protocol import Keys
    from cdpr.recording.live import LiveServer
    from cdpr_recorder.node import RecorderNode

    with pytest.raises(InputError, match="needs a sink"):
        RecorderNode(load_scenario("caroca_15kg"), Keys("x"))
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        with pytest.raises(InputError, match="--foxglove: cannot listen"):
            LiveServer(s.getsockname()[1])


def test_files_alone_take_large_batches_a_live_viewer_small_ones(tmp_path: Path) -> None:
    from cdpr.config.scenario import load_scenario
    from cdpr.protocol import Keys
    from cdpr_recorder import node

    sc = load_scenario("caroca_15kg")
    for kwargs, steps in (({"rrd": str(tmp_path / "a.rrd"), "mcap": str(tmp_path / "a.mcap")}, node.FILE_BATCH_STEPS),
                          ({"mcap": str(tmp_path / "b.mcap"), "foxglove": 0}, node.LIVE_BATCH_STEPS)):
        rec = node.RecorderNode(sc, Keys("x"), **kwargs)
        try:
            assert rec.core.settings.batch_steps == steps
        finally:
            rec.close()
    assert node.LIVE_BATCH_STEPS < node.FILE_BATCH_STEPS


# --------------------------------------------------------------------------------------------------
# Real sessions


@pytest.fixture(scope="module")
def both(tmp_path_factory: pytest.TempPathFactory) -> tuple[dict[str, Any], Path, Path]:
    """One caroca_15kg session recorded to an .rrd and an .mcap at once."""
    d = tmp_path_factory.mktemp("both")
    rrd, mcap_path = d / "run.rrd", d / "run.mcap"
    proc = cdpr("run", "caroca_15kg", "--duration", "0.5", "--rrd", str(rrd), "--mcap", str(mcap_path),
                "--session", f"mcap{time.monotonic_ns() % 10**9}", "--quiet", timeout=300, check=True)
    summary = last_json_line(proc.stdout)
    assert summary["exit_ok"]
    assert summary["mcap"] == str(mcap_path)
    return summary, rrd, mcap_path


@pytest.mark.slow
def test_every_channel_for_every_step_equals_the_rrd(both: tuple[dict[str, Any], Path, Path]) -> None:
    from cdpr.tools.report import read_recording

    summary, rrd, mcap_path = both
    n = summary["total_steps"]
    topics, meta, _ = read_mcap(mcap_path)
    data = read_recording(rrd)
    md = meta[fox.METADATA_NAME]
    assert md["scenario"] == "caroca_15kg"
    assert md["robot"] == "caroca"
    assert md["recording_id"] == data.recording_id
    assert md["protocol_version"] == str(PROTOCOL_VERSION)
    assert json.loads(md["info"]) == data.session["info"]

    def rows(topic: str, steps: range) -> tuple[np.ndarray, dict[int, dict[str, Any]]]:
        got = by_step(topics[topic])
        assert sorted(got) == list(steps), topic
        return np.array([got[k][0] for k in steps]), {k: got[k][1] for k in steps}

    def same(entity: str, steps: range, values: np.ndarray, ns: np.ndarray) -> None:
        s = data.get(entity)
        assert s.step.tolist() == list(steps), entity
        assert np.array_equal(s.values, values), entity  # float64, bit for bit
        assert np.abs(np.rint(s.t * 1e9).astype(np.int64) - ns).max() <= 1, entity  # log_time = sim_time

    states, ticked = range(n + 1), range(n)
    ns, st = rows(fox.PLATFORM_STATE, states)
    same(recording.ACTUAL_POSITION, states, np.array([st[k]["position"] for k in states]), ns)
    same(recording.ACTUAL_QUATERNION, states, np.array([st[k]["quaternion"] for k in states]), ns)
    same(recording.ACTUAL_TWIST, states, np.array([st[k]["twist"] for k in states]), ns)
    same(recording.CLAMPED, states, np.array([[st[k]["clamped"]] for k in states], dtype=float), ns)
    ns, ln = rows(fox.LENGTHS, states)
    same(recording.CABLE_LENGTHS, states, np.array([ln[k]["lengths"] for k in states]), ns)
    ns, te = rows(fox.TENSIONS, range(1, n + 1))
    for i in range(8):
        same(recording.tension_series(i), range(1, n + 1), np.array([[te[k]["tensions"][i]] for k in te]), ns)
    ns, sp = rows(fox.SETPOINT, ticked)
    same(recording.DESIRED_POSITION, ticked, np.array([sp[k]["position"] for k in ticked]), ns)
    same(recording.DESIRED_QUATERNION, ticked, np.array([sp[k]["quaternion"] for k in ticked]), ns)
    ns, er = rows(fox.ERROR, ticked)
    same(recording.POSITION_ERROR_AXES, ticked, np.array([er[k]["position"] for k in ticked]), ns)
    same(recording.POSITION_ERROR_NORM, ticked, np.array([[er[k]["position_norm"]] for k in ticked]), ns)
    same(recording.ORIENTATION_ERROR_AXES, ticked, np.array([er[k]["orientation"] for k in ticked]), ns)
    same(recording.ORIENTATION_ERROR_NORM, ticked, np.array([[er[k]["orientation_norm"]] for k in ticked]), ns)
    ns, cm = rows(fox.COMMAND, ticked)
    assert {cm[k]["kind"] for k in ticked} == {"tensions"}
    same(recording.COMMAND_TENSIONS, ticked, np.array([cm[k]["values"] for k in ticked]), ns)
    same(recording.COMMAND_FEASIBLE, ticked, np.array([[float(cm[k]["feasible"])] for k in ticked]), ns)
    same(recording.COMMAND_SOLVE_TIME, ticked, np.array([[cm[k]["solve_time"]] for k in ticked]), ns)
    same(recording.LOOP_LAG, ticked, np.array([[cm[k]["lag"]] for k in ticked]), ns)
    # the 3D rows: every 10th state and the final one, the pose equal to the state's
    scene = [*range(0, n + 1, 10)] if n % 10 == 0 else [*range(0, n + 1, 10), n]
    assert [ns for ns, _ in topics[fox.PLATFORM_POSE]] == [round(k * 1e6) for k in scene]
    assert len(topics[fox.SCENE_CABLES]) == len(scene)
    assert len(topics[fox.DESIRED_POSE]) == len(range(0, n, 10))
    # the MCAP alone gives the run's state digest (every state, every number exact)
    metrics = RunMetrics()
    for k in states:
        tensions = tuple(te[k]["tensions"]) if k else (0.0,) * 8
        metrics.add_state(State(k, k * 0.001, (*st[k]["position"], *st[k]["quaternion"]), tuple(st[k]["twist"]),
                                tuple(ln[k]["lengths"]), tensions, st[k]["clamped"]))
    assert metrics.digest() == summary["state_digest"]


@pytest.mark.slow
def test_convert_writes_the_same_messages_as_the_live_recorder(
    both: tuple[dict[str, Any], Path, Path], tmp_path: Path
) -> None:
    _, rrd, live = both
    out = tmp_path / "converted.mcap"
    proc = cdpr("convert", str(rrd), "--to", "mcap", "-o", str(out), timeout=300, check=True)
    report = last_json_line(proc.stdout)
    assert report["output"] == str(out)
    assert report["states"] == 501
    assert report["bytes"] == out.stat().st_size
    a, meta_a, channels_a = read_mcap(live)
    b, meta_b, channels_b = read_mcap(out)
    assert meta_a == meta_b
    assert channels_a == channels_b
    for topic in (*PER_STEP, fox.PLATFORM_POSE, fox.DESIRED_POSE, fox.SCENE_CABLES, fox.SCENE_PATH, fox.SESSION):
        assert a[topic] == b[topic], topic  # same log times, same bytes
    assert [m["state"] for _, m in b[fox.CLOCK]] == [m["state"] for _, m in a[fox.CLOCK]]


@pytest.mark.slow
def test_rerun_reads_the_mcap_back_with_the_platform_pose(
    both: tuple[dict[str, Any], Path, Path], tmp_path: Path
) -> None:
    import pyarrow as pa
    from rerun.chunk import RrdReader

    from cdpr.tools.report import read_recording

    _, rrd, mcap_path = both
    exe = recording.rerun_binary()
    cmd = [exe] if exe else [sys.executable, "-m", "rerun"]
    back = tmp_path / "from_mcap.rrd"
    proc = subprocess.run([*cmd, "mcap", "convert", str(mcap_path), "-o", str(back), "--timeline-type", "duration"],
                          capture_output=True, text=True, timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    poses: dict[int, tuple[list[float], list[float]]] = {}
    for chunk in RrdReader(str(back)).stream().to_chunks():
        if chunk.entity_path.lstrip("/") != fox.PLATFORM_POSE.lstrip("/"):
            continue
        b = chunk.to_record_batch()
        if "Transform3D:translation" not in b.schema.names:
            continue  # the channel's and schema's description (static)
        ns = b.column("message_log_time").cast(pa.int64()).to_pylist()
        for t, tr, q in zip(ns, b.column("Transform3D:translation").to_pylist(),
                            b.column("Transform3D:quaternion").to_pylist(), strict=True):
            poses[t] = (tr[0], q[0])
    data = read_recording(rrd)
    pos, quat = data.get(recording.ACTUAL_POSITION), data.get(recording.ACTUAL_QUATERNION)
    scene = [k for k in pos.step.tolist() if k % 10 == 0]
    assert sorted(poses) == [k * 1_000_000 for k in scene]
    for k in scene:
        tr, q = poses[k * 1_000_000]
        assert np.allclose(tr, pos.at(np.array([k]))[0], rtol=0, atol=1e-6)  # Rerun keeps float32
        assert np.allclose(q, quat.at(np.array([k]))[0], rtol=0, atol=1e-6)


@pytest.mark.slow
def test_in_process_session_to_mcap_alone(tmp_path: Path) -> None:
    path = tmp_path / "alone.mcap"
    proc = cdpr("run", "caroca_15kg", "--duration", "0.3", "--in-process", "--mcap", str(path),
                "--session", f"ip{time.monotonic_ns() % 10**9}", "--quiet", timeout=300, check=True)
    summary = last_json_line(proc.stdout)
    assert summary["exit_ok"]
    assert summary["rrd"] is None
    topics, _, _ = read_mcap(path)
    assert sorted(by_step(topics[fox.PLATFORM_STATE])) == list(range(301))
    assert sorted(by_step(topics[fox.COMMAND])) == list(range(300))


@pytest.mark.slow
def test_a_recorder_stopped_by_sigterm_leaves_a_complete_mcap(session_id: str, tmp_path: Path) -> None:
    import signal

    from mcap.reader import make_reader

    path = tmp_path / "stopped.mcap"
    run = subprocess.Popen([*CDPR, "run", "caroca_15kg", "--duration", "20", "--session", session_id, "--mcap",
                            str(path), "--quiet"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    out, _ = sigterm_the_recorder(run, session_id, path, 100_000, timeout=180)
    summary = last_json_line(out)
    assert summary["exit_codes"]["recorder"] == 128 + signal.SIGTERM
    with path.open("rb") as f:
        assert make_reader(f).get_summary() is not None  # summary and footer written: closed properly
    topics, meta, _ = read_mcap(path)
    steps = sorted(by_step(topics[fox.PLATFORM_STATE]))
    assert 200 <= steps[-1] <= summary["steps"]
    assert steps == list(range(steps[-1] + 1))  # nothing lost up to the last recorded state
    assert meta[fox.METADATA_NAME]["scenario"] == "caroca_15kg"


# --------------------------------------------------------------------------------------------------
# Live: a client of Foxglove's WebSocket protocol


async def _client(port: int, connect_for: float, stop_after: float) -> dict[str, Any]:
    """Connect (retrying), subscribe to every advertised channel, collect until the server goes away."""
    import websockets

    deadline = time.monotonic() + connect_for
    while True:
        try:
            # foxglove-sdk 0.30 answers foxglove.sdk.v1 (the ws-protocol v1 messages), older servers
            # foxglove.websocket.v1: offer both, as Foxglove's app does
            ws = await websockets.connect(f"ws://127.0.0.1:{port}", max_size=None,
                                          subprotocols=["foxglove.websocket.v1", "foxglove.sdk.v1"])
            break
        except OSError:
            if time.monotonic() > deadline:
                raise
            await asyncio.sleep(0.05)
    got: dict[str, Any] = {"subprotocol": ws.subprotocol, "server": None, "channels": {}, "messages": defaultdict(list),
                           "times": []}
    subscriptions: dict[int, str] = {}
    end = time.monotonic() + stop_after
    try:
        while time.monotonic() < end:
            try:
                frame = await asyncio.wait_for(ws.recv(), timeout=max(0.1, end - time.monotonic()))
            except TimeoutError:
                break
            if isinstance(frame, str):
                msg = json.loads(frame)
                if msg["op"] == "serverInfo":
                    got["server"] = msg
                elif msg["op"] == "advertise":
                    subs = []
                    for ch in msg["channels"]:
                        got["channels"][ch["id"]] = ch
                        subscriptions[len(subscriptions) + 1] = ch["topic"]
                        subs.append({"id": len(subscriptions), "channelId": ch["id"]})
                    await ws.send(json.dumps({"op": "subscribe", "subscriptions": subs}))
            elif frame[0] == 0x01:  # message data: subscription id, log time, payload
                sub, ns = struct.unpack_from("<IQ", frame, 1)
                got["messages"][subscriptions[sub]].append((ns, bytes(frame[13:])))
            elif frame[0] == 0x02:  # time
                got["times"].append(struct.unpack_from("<Q", frame, 1)[0])
    except websockets.ConnectionClosed:
        pass
    return got


@pytest.mark.slow
def test_a_websocket_client_gets_the_channels_and_messages_live(session_id: str) -> None:
    port = free_port()
    run = subprocess.Popen([*CDPR, "run", "caroca_15kg", "--duration", "1", "--foxglove", str(port), "--session",
                            session_id, "--quiet"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        got = asyncio.run(_client(port, connect_for=120.0, stop_after=240.0))
        out, err = run.communicate(timeout=120)
    finally:
        if run.poll() is None:
            run.kill()
            run.wait()
    assert run.returncode == 0, err[-2000:]
    assert f"Foxglove WebSocket server at ws://127.0.0.1:{port}" in err
    summary = last_json_line(out)
    n = summary["total_steps"]
    assert got["subprotocol"] in ("foxglove.websocket.v1", "foxglove.sdk.v1")
    assert got["server"]["name"] == f"cdpr caroca_15kg ({session_id})"
    assert "time" in got["server"]["capabilities"]
    advertised = {ch["topic"]: ch for ch in got["channels"].values()}
    assert set(advertised) >= {*PER_STEP, fox.PLATFORM_POSE, fox.SCENE_CABLES, fox.SCENE_STATIC, fox.SESSION}
    assert advertised[fox.PLATFORM_POSE]["schemaName"] == "foxglove.FrameTransform"
    assert json.loads(advertised[fox.TENSIONS]["schema"])["title"] == "cdpr.CableTensions"
    # the clock waits for the recorder, whose server is up before it joins: the client sees every step
    # unless it connected late; either way the steps it got run without a gap to the final one
    states = [json.loads(p) for _, p in got["messages"][fox.PLATFORM_STATE]]
    steps = [s["step"] for s in states]
    assert steps
    assert steps == list(range(steps[0], n + 1)), (steps[:3], steps[-3:])
    for topic in PER_STEP:
        msgs = got["messages"][topic]
        assert msgs, topic
        assert all(ns == round(json.loads(p)["t"] * 1e9) for ns, p in msgs), topic  # log time = sim time
    assert got["messages"][fox.SCENE_STATIC]  # sent again after each batch for late clients
    assert got["times"]
    assert got["times"][-1] == n * 1_000_000
