"""Remote controllers: the cdpr.runtime.client SDK, its two examples, and a router restarted under a session."""

from __future__ import annotations

import ast
import queue
import re
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path
from typing import Any

import msgpack
import numpy as np
import pytest
import zenoh

from cdpr.config.scenario import load_scenario
from cdpr.mechanics.kinematics import inverse_kinematics
from cdpr.mechanics.rotation import rpy_to_matrix
from cdpr.protocol import PROTOCOL_VERSION, Command, Keys, ProtocolError, Setpoint, Setpoints, State, Status
from cdpr.protocol.session import SessionInfo, encode_session_info, robot_from_summary, session_info
from cdpr.runtime.client import (
    FunctionController,
    RemoteController,
    controller,
)
from cdpr.runtime.transport import StopFlag, zenoh_config
from conftest import CDPR, free_port, last_json_line, realtime
from test_compose import Processes

ROOT = Path(__file__).resolve().parent.parent
EXAMPLES = ROOT / "examples"
WAIT = 20.0  # seconds any single expected message may take (a bound, never a measurement)


def info_payload(name: str = "caroca_15kg") -> bytes:
    return encode_session_info(load_scenario(name))


# --------------------------------------------------------------------------------------------------
# session/info


def test_session_info_rebuilds_the_scenario_robot() -> None:
    sc = load_scenario("caroca_15kg")
    info = SessionInfo.from_payload(info_payload())
    r = info.robot
    assert (info.scenario, info.dt, info.total_steps) == ("caroca_15kg", 0.001, 11000)
    assert (info.variant, info.tda) == ("6dof", "qp")
    assert r.mass == 15.0
    assert r.m == 8
    assert (r.tmin.tolist(), r.tmax.tolist()) == ([1.0] * 8, [6500.0] * 8)
    np.testing.assert_array_equal(r.frame_points, sc.robot.frame_points)
    np.testing.assert_array_equal(r.platform_points, sc.robot.platform_points)
    np.testing.assert_array_equal(r.inertia, sc.robot.inertia)
    np.testing.assert_array_equal(info.gains.kp, np.full(6, 1500.0))
    assert info.rows == [0, 1, 2, 3, 4, 5]
    # The same wrench matrix as the scenario's own robot, away from home.
    p, R = np.array([-0.3, 0.4, 0.9]), rpy_to_matrix(0.05, -0.02, 0.1)
    np.testing.assert_allclose(inverse_kinematics(r, p, R).wrench_matrix,
                               inverse_kinematics(sc.robot, p, R).wrench_matrix, rtol=0, atol=1e-15)


def test_session_info_of_a_3dof_point_mass_robot() -> None:
    sc = load_scenario("caroca_1kg")
    msg = {"v": PROTOCOL_VERSION, **session_info(sc)}
    msg["robot"] = load_scenario("caroca_1kg").robot.replace(
        mode="point_mass", platform_points=np.zeros((8, 3))).summary()
    info = SessionInfo.from_payload(msgpack.packb(msg))
    assert info.robot.mode == "point_mass"
    assert info.rows == [0, 1, 2]


@pytest.mark.parametrize(("change", "field"), [
    (lambda m: m["robot"].pop("mass"), "robot.mass: missing"),
    (lambda m: m["robot"].update(platform_points=[[0, 0, 0]] * 7), "robot"),
    (lambda m: m["robot"].update(frame_points=[[0, 0, float("nan")]] * 8), "robot"),
    (lambda m: m.pop("dt"), "dt: missing"),
    (lambda m: m["controller"].update(variant="9dof"), "controller.variant"),
    (lambda m: m["robot"].update(mode="hexapod"), "robot.mode"),
])
def test_bad_session_info_names_the_field(change: Any, field: str) -> None:
    msg = {"v": PROTOCOL_VERSION, **session_info(load_scenario("caroca_15kg"))}
    change(msg)
    with pytest.raises(ProtocolError, match=f"session/info: {field.split(':')[0]}"):
        SessionInfo.from_payload(msgpack.packb(msg))


def test_robot_from_summary_rejects_a_rank_deficient_robot() -> None:
    summary = load_scenario("caroca_15kg").robot.summary()
    summary["frame_points"] = [summary["frame_points"][0]] * 8
    summary["platform_points"] = [[0.0, 0.0, 0.0]] * 8
    with pytest.raises(ProtocolError, match="rank"):
        robot_from_summary(summary)


def test_controller_decorator_takes_two_or_three_parameters() -> None:
    assert not controller(lambda state, setpoint: [0.0]).wants_info
    assert controller(lambda state, setpoint, info: [0.0]).wants_info
    with pytest.raises(TypeError, match="takes"):
        controller(lambda state: [0.0])
    assert isinstance(controller(lambda s, p: 0), FunctionController)


# --------------------------------------------------------------------------------------------------
# The protocol, step by step, against a real Zenoh router played by the test


class Harness:
    """The test plays clock, sim and trajectory on a Zenoh router session; the SDK joins as a client."""

    def __init__(self, session_id: str) -> None:
        self.keys = Keys(session_id)
        self.port = free_port()
        self.z = zenoh.open(zenoh_config("router", listen=[f"tcp/127.0.0.1:{self.port}"]))
        self.commands: queue.SimpleQueue[Command] = queue.SimpleQueue()
        self.alive = threading.Event()
        payload = info_payload()
        self.entities: list[Any] = [
            self.z.declare_queryable(self.keys.info, lambda q: q.reply(q.key_expr, payload)),
            self.z.declare_subscriber(self.keys.command,
                                      lambda s: self.commands.put(Command.decode(s.payload.to_bytes()))),
            self.z.liveliness().declare_subscriber(self.keys.alive("controller"), self._token, history=True),
        ]

    def _token(self, sample: zenoh.Sample) -> None:
        if sample.kind == zenoh.SampleKind.PUT:
            self.alive.set()

    @property
    def endpoint(self) -> str:
        return f"tcp/127.0.0.1:{self.port}"

    def state(self, k: int) -> None:
        self.z.put(self.keys.state, State(k, k / 1000, (0.9, 0.9, 0.2, 0, 0, 0, 1), (0.0,) * 6,
                                          (4.0,) * 8, (0.0,) * 8).encode())

    def setpoint(self, k: int, n: int = 1) -> None:
        """A block of setpoints k … k + n − 1, as the trajectory publishes them."""
        self.z.put(self.keys.setpoints, Setpoints(tuple(
            Setpoint(j, j / 1000, (0.9, 0.9, 0.2 + j, 0, 0, 0, 1), (0.0,) * 6, (0.0,) * 6) for j in range(k, k + n)
        )).encode())

    def status(self, state: str) -> None:
        self.z.put(self.keys.status, Status(state, 3, 0.003, 4, reason="test").encode())

    def next_command(self) -> Command:
        return self.commands.get(timeout=WAIT)

    def close(self) -> None:
        for e in self.entities:
            e.undeclare()
        self.z.close()


def run_in_thread(ctrl: RemoteController, h: Harness,
                  **kw: Any) -> tuple[threading.Thread, dict[str, Any], StopFlag]:
    out: dict[str, Any] = {}
    stop = StopFlag()

    def target() -> None:
        try:
            out["report"] = ctrl.run(h.endpoint, h.keys.session, handle_signals=False, stop=stop, **kw)
        except BaseException as exc:  # handed to the test
            out["error"] = exc

    t = threading.Thread(target=target, daemon=True)
    t.start()
    return t, out, stop


def test_sdk_answers_each_state_once_its_setpoint_is_there(session_id: str) -> None:
    calls: list[tuple[int, int, float]] = []

    @controller
    def echo(state: State, setpoint: Setpoint, info: SessionInfo) -> list[float]:
        calls.append((state.step, setpoint.step, info.robot.mass))
        return [float(state.step) + i + setpoint.pose[2] for i in range(info.robot.m)]

    h = Harness(session_id)
    try:
        t, out, _ = run_in_thread(echo, h)
        assert h.alive.wait(WAIT), out
        h.setpoint(0)
        h.state(0)
        c = h.next_command()
        assert (c.step, c.t) == (0, 0.0)
        assert c.tensions == tuple(0.2 + i for i in range(8))
        h.state(1)  # no setpoint 1 yet: nothing to answer...
        h.setpoint(1)  # ...until it comes
        assert h.next_command().step == 1
        h.state(1)  # the same state again (a resend): answered again
        assert h.next_command().step == 1
        h.setpoint(1)  # a repeated setpoint alone is no reason to answer
        h.z.put(h.keys.state, b"\x93 garbage")  # dropped, counted, survived
        h.state(2)
        h.setpoint(2)
        c = h.next_command()
        assert c.step == 2
        assert c.tensions[0] == pytest.approx(2.0 + 2.2)
        h.setpoint(3, n=3)  # a block ahead of the states, as the trajectory sends them
        for k in (3, 4, 5):
            h.state(k)
            assert h.next_command().step == k
        h.status("finished")
        t.join(WAIT)
        assert not t.is_alive()
    finally:
        h.close()
    assert "error" not in out, out
    report = out["report"]
    assert report.exit_code == 0
    assert report.status is not None
    assert report.status.state == "finished"
    assert (report.answered, report.last_step) == (7, 5)
    assert [(k, j) for k, j, _ in calls] == [(0, 0), (1, 1), (1, 1), (2, 2), (3, 3), (4, 4), (5, 5)]
    assert {mass for _, _, mass in calls} == {15.0}
    assert report.info is not None
    assert report.info.scenario == "caroca_15kg"
    assert h.commands.empty()


def test_sdk_exits_on_aborted_and_on_a_bad_answer(session_id: str) -> None:
    class Wrong(RemoteController):
        def step(self, state: State, setpoint: Setpoint) -> list[float]:
            return [1.0] * 7  # one tension short

    h = Harness(session_id)
    try:
        t, out, _ = run_in_thread(controller(lambda s, p: np.ones(8)), h)
        assert h.alive.wait(WAIT)
        h.status("aborted")
        t.join(WAIT)
        assert out["report"].exit_code == 1
        assert out["report"].status.state == "aborted"
        h.alive.clear()
        t, out, _ = run_in_thread(Wrong(), h)
        assert h.alive.wait(WAIT)
        h.setpoint(0)
        h.state(0)
        t.join(WAIT)
        assert not t.is_alive()
        assert isinstance(out.get("error"), ValueError)
        assert "8 finite tensions" in str(out["error"])
    finally:
        h.close()


def test_sdk_gives_up_without_a_session(session_id: str) -> None:
    h = Harness(session_id)
    h.entities.pop(0).undeclare()  # nobody answers session/info
    try:
        t, out, _ = run_in_thread(controller(lambda s, p: [0.0]), h, info_timeout=0.5)
        t.join(WAIT)
        assert out["report"].exit_code == 1
        assert out["report"].answered == 0
        t, out, _ = run_in_thread(controller(lambda s, p: [0.0]), h, fetch_session_info=False,
                                  idle_timeout=0.5)
        t.join(WAIT)
        assert out["report"].exit_code == 1
        t, out, stop = run_in_thread(controller(lambda s, p: [0.0]), h)  # waits for the session...
        time.sleep(0.3)
        stop.set()  # ...until told to stop
        t.join(WAIT)
        assert not t.is_alive()
        assert out["report"].info is None
    finally:
        h.close()


# --------------------------------------------------------------------------------------------------
# The examples against real sessions


def test_example_remote_controller_is_short_and_uses_the_sdk() -> None:
    src = (EXAMPLES / "remote_controller.py").read_text()
    assert len(src.splitlines()) <= 25
    imported = {n.module for n in ast.walk(ast.parse(src)) if isinstance(n, ast.ImportFrom)}
    assert "cdpr.runtime.client" in imported
    assert "cdpr_controller" not in str(imported)


def test_plain_example_imports_nothing_from_cdpr() -> None:
    tree = ast.parse((EXAMPLES / "plain_zenoh_controller.py").read_text())
    modules = {a.name for n in ast.walk(tree) if isinstance(n, ast.Import) for a in n.names}
    modules |= {n.module or "" for n in ast.walk(tree) if isinstance(n, ast.ImportFrom)}
    assert not any(m.startswith("cdpr") for m in modules)
    assert {"zenoh", "msgpack"} <= modules


def _up_with(example: str, session_id: str, duration: str | None, tmp_path: Path, *extra: str,
             scenario: str = "caroca_15kg") -> tuple[dict[str, Any], str]:
    """`cdpr up SCENARIO --without controller` with ``examples/EXAMPLE`` as its controller: (summary, its log). A
    realtime session (``--mode realtime`` in ``extra``) and its controller run under SCHED_FIFO where that is
    permitted (conftest.realtime): their wall-clock figures are then theirs, not the machine's load's."""
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    rt = realtime if "realtime" in extra else list
    procs = Processes()
    try:
        up = procs.start("up", rt([*CDPR, "up", scenario, *(["--duration", duration] if duration else []),
                                   "--session", session_id, "--without", "controller", "--listen", endpoint,
                                   "--quiet", "--join-timeout", "60", *extra]), tmp_path, tmp_path / "up.log")
        procs.start("remote", rt([sys.executable, str(EXAMPLES / example), "--connect", endpoint,
                                  "--session", session_id]), tmp_path, tmp_path / "remote.log")
        codes = procs.wait(["up", "remote"], timeout=300)
        assert codes == {"up": 0, "remote": 0}, procs.report()
        assert up.returncode == 0
    finally:
        procs.close()
    return last_json_line(procs.log("up")), procs.log("remote")


@pytest.mark.slow
@pytest.mark.parametrize("scenario", ["caroca_15kg", "caroca_15kg_pulleys"])
def test_both_example_controllers_complete_a_15kg_session_alike(scenario: str, session_id: str,
                                                                tmp_path: Path) -> None:
    """The SDK example (cdpr's kinematics, QP tensions) and the plain one (written from docs/protocol.md
    with its own quaternions, wrench matrix and least-norm tensions) drive the sim along the same path; over
    exit pulleys too (the plain one's tangent points from docs/robots.md's closed form)."""
    runs = {}
    for i, example in enumerate(("remote_controller.py", "plain_zenoh_controller.py")):
        d = tmp_path / str(i)
        d.mkdir()
        s, remote_log = _up_with(example, f"{session_id}{i}", "1.5", d, scenario=scenario)
        assert s["exit_ok"] is True
        assert s["steps"] == s["total_steps"] == 1500
        assert s["rms_position_error"] < 1e-3  # ~0.3 mm: PD without acceleration feedforward
        assert s["final_position_error"] < 1e-3
        assert s["rms_orientation_error"] < 1e-3
        assert s["clamped_commands"] == 0
        assert 1.0 <= s["tension_min"] <= s["tension_max"] < 200.0  # 15 kg on 8 cables: no tension fighting
        assert "up to step 1499" in remote_log
        runs[example] = s
        print(f"{example}: {s['rate']:.0f} steps/s")
    sdk, plain = runs.values()
    for key in ("rms_position_error", "max_position_error", "rms_orientation_error", "tension_max"):
        assert plain[key] == pytest.approx(sdk[key], rel=1e-6), key


@pytest.mark.slow
@pytest.mark.parametrize("example", ["remote_controller.py", "plain_zenoh_controller.py"])
def test_both_examples_run_unchanged_in_free_running_realtime(example: str, session_id: str, tmp_path: Path) -> None:
    """--sync free changes nothing a controller must do (docs/protocol.md): the same examples, as they are."""
    s, remote_log = _up_with(example, session_id, "1.5", tmp_path, "--mode", "realtime", "--sync", "free")
    assert s["exit_ok"] is True
    assert s["sync"] == "free"
    assert s["steps"] == 1500
    assert s["rms_position_error"] < 1e-3
    assert s["command_age_max"] < 100  # the watchdog (100 ms) never acted
    assert s["watchdog_steps"] == 0
    assert "up to step" in remote_log


@pytest.mark.slow
def test_sdk_controller_stops_on_sigint_and_the_session_pauses(session_id: str, tmp_path: Path) -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    procs = Processes()
    try:
        up = procs.start("up", [*CDPR, "up", "caroca_15kg", "--duration", "60", "--session", session_id,
                                "--without", "controller", "--listen", endpoint],
                         tmp_path, tmp_path / "up.log")
        remote = procs.start("remote", [sys.executable, str(EXAMPLES / "remote_controller.py"),
                                        "--connect", endpoint, "--session", session_id],
                             tmp_path, tmp_path / "remote.log")
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline and "joined session" not in procs.log("remote"):
            time.sleep(0.05)
        with zenoh.open(zenoh_config("client", connect=[endpoint])) as z:
            sub = z.declare_subscriber(Keys(session_id).status)
            step = 0
            while time.monotonic() < deadline and step < 200:
                sample = sub.try_recv()
                if sample is None:
                    time.sleep(0.05)
                else:
                    step = Status.decode(sample.payload.to_bytes()).step
        assert step >= 200, procs.report()
        remote.send_signal(signal.SIGINT)
        assert remote.wait(timeout=10) == 128 + signal.SIGINT
        log = ""
        paused = "paused: waiting for controller"
        while time.monotonic() < deadline and paused not in (log := procs.log("up")):
            time.sleep(0.05)
        assert "paused: waiting for controller" in log
        assert up.poll() is None
        assert procs.stop("up", signal.SIGINT, timeout=20) == 128 + signal.SIGINT
    finally:
        procs.close()
    assert "answered" in procs.log("remote")
    assert last_json_line(procs.log("up"))["exit_ok"] is False


@pytest.mark.slow
def test_sdk_controller_reconnects_through_a_restarted_router(session_id: str, tmp_path: Path) -> None:
    """The session (`cdpr up`) hosts router A; the remote controller reaches it through router B
    (`cdpr router --connect A`), which is killed in the middle of the run and started again."""
    a, b = (f"tcp/127.0.0.1:{free_port()}" for _ in range(2))
    router_b = [*CDPR, "router", "--listen", b, "--connect", a]
    procs = Processes()
    try:
        procs.start("up", [*CDPR, "up", "caroca_15kg", "--duration", "3", "--session", session_id,
                           "--without", "controller", "--listen", a, "--quiet"],
                    tmp_path, tmp_path / "up.log")
        procs.start("router", router_b, tmp_path, tmp_path / "router.log")
        procs.start("remote", [sys.executable, str(EXAMPLES / "remote_controller.py"), "--connect", b,
                               "--session", session_id], tmp_path, tmp_path / "remote.log")
        steps: list[int] = []
        with zenoh.open(zenoh_config("client", connect=[a])) as z:
            sub = z.declare_subscriber(Keys(session_id).state,
                                       lambda s: steps.append(State.decode(s.payload.to_bytes()).step))
            deadline = time.monotonic() + 90
            while time.monotonic() < deadline and (not steps or steps[-1] < 800):
                time.sleep(0.02)
            assert steps, procs.report()
            assert steps[-1] >= 800, procs.report()
            assert procs.stop("router", signal.SIGKILL) == -signal.SIGKILL
            killed_at = steps[-1]
            time.sleep(1.0)
            procs.start("router2", router_b, tmp_path, tmp_path / "router2.log")
            codes = procs.wait(["up", "remote"], timeout=120)
            sub.undeclare()
        assert codes == {"up": 0, "remote": 0}, procs.report()
        assert procs.stop("router2", signal.SIGTERM) == 0
    finally:
        procs.close()
    s = last_json_line(procs.log("up"))
    assert s["exit_ok"] is True
    assert s["steps"] == 3000
    assert killed_at < 3000
    assert s["final_position_error"] < 1e-3
    log = procs.log("up")
    assert "controller left the session" in log, log
    assert "resuming" in log, log
    assert "up to step 2999" in procs.log("remote")
    print(f"router B restarted at step {killed_at}; session rate {s['rate']:.0f} steps/s")


def _port_free(port: int) -> bool:
    import socket

    with socket.socket() as s:
        try:
            s.bind(("127.0.0.1", port))
        except OSError:
            return False
    return True


@pytest.mark.slow
@pytest.mark.skipif(not _port_free(7447), reason="port 7447 is taken on this machine")
def test_the_readme_commands_on_the_default_port(session_id: str, tmp_path: Path) -> None:
    """Exactly the README's recipe: `cdpr up --without controller` (default endpoint tcp/127.0.0.1:7447)
    and `python examples/remote_controller.py --connect tcp/127.0.0.1:7447`."""
    procs = Processes()
    try:
        up = procs.start("up", [*CDPR, "up", "caroca_15kg", "--duration", "1", "--session", session_id,
                                "--without", "controller", "--listen", "tcp/127.0.0.1:7447", "--quiet"],
                         tmp_path, tmp_path / "up.log")
        procs.start("remote", [sys.executable, str(EXAMPLES / "remote_controller.py"),
                               "--connect", "tcp/127.0.0.1:7447", "--session", session_id],
                    tmp_path, tmp_path / "remote.log")
        codes = procs.wait(["up", "remote"], timeout=180)
        assert codes == {"up": 0, "remote": 0}, procs.report()
        assert up.returncode == 0
    finally:
        procs.close()
    s = last_json_line(procs.log("up"))
    assert s["exit_ok"] is True
    assert s["steps"] == 1000


WHEELHOUSE = Path(sys.prefix) / "wheelhouse"  # `make .venv`: the base requirements' and the build's wheels


def _source_copy(destination: Path) -> Path:
    """The work tree's files (git's tracked and untracked ones but the ignored: no .venv, build/, runs), copied to
    ``destination``: setuptools builds in the source tree, and a `pip install .` of the repository would leave a
    build/ folder in it."""
    listed = subprocess.run(["git", "-C", str(ROOT), "ls-files", "-z", "--cached", "--others", "--exclude-standard"],
                            capture_output=True, check=True).stdout.decode().split("\0")
    for name in filter(None, listed):
        source = ROOT / name
        if source.is_file():  # (a tracked file deleted in the work tree is not)
            (destination / name).parent.mkdir(parents=True, exist_ok=True)
            shutil.copy2(source, destination / name)
    return destination


@pytest.mark.slow
def test_a_base_install_runs_the_remote_controller_example(session_id: str, tmp_path: Path) -> None:
    """`pip install .` (no extras) in a fresh venv: no dartpy, rerun-sdk, matplotlib, pydantic or click; the
    example controller still completes a session started by `cdpr up` (the full install, here). Offline: pip
    takes the base requirements and the build's from the wheelhouse `make .venv` downloads (--no-index); the
    project's own pip installs into the new venv (--python: no pip of its own to set up), without byte-compiling
    every module of numpy and scipy (--no-compile: the example compiles what it imports)."""
    assert (WHEELHOUSE / ".complete").exists(), f"no wheelhouse {WHEELHOUSE}: `make .venv` downloads it"
    venv = tmp_path / "base-venv"
    subprocess.run([sys.executable, "-m", "venv", "--without-pip", str(venv)], check=True, timeout=120)
    python = venv / "bin" / "python"
    install = subprocess.run([sys.executable, "-m", "pip", "--python", str(python), "install", "--quiet",
                              "--disable-pip-version-check", "--no-index", "--find-links", str(WHEELHOUSE),
                              "--no-compile", str(_source_copy(tmp_path / "source"))],
                             capture_output=True, text=True, timeout=900, check=False)
    assert install.returncode == 0, install.stderr[-3000:]
    probe = ("import importlib.util as u; print(sorted(m for m in ('dartpy', 'rerun', 'matplotlib', 'pydantic', "
             "'click', 'yaml', 'cdpr_sim', 'cdpr') if u.find_spec(m)))")
    found = subprocess.run([str(python), "-c", probe], capture_output=True, text=True, check=True).stdout
    assert found.strip() == "['cdpr', 'cdpr_sim']", found  # the service packages come along, their extras do not
    port = free_port()
    procs = Processes()
    try:
        procs.start("up", [*CDPR, "up", "caroca_15kg", "--duration", "1", "--session", session_id,
                           "--without", "controller", "--listen", f"tcp/127.0.0.1:{port}", "--quiet"],
                    tmp_path, tmp_path / "up.log")
        procs.start("remote", [str(python), str(EXAMPLES / "remote_controller.py"),
                               "--connect", f"tcp/127.0.0.1:{port}", "--session", session_id],
                    tmp_path, tmp_path / "remote.log")
        codes = procs.wait(["up", "remote"], timeout=180)
        assert codes == {"up": 0, "remote": 0}, procs.report()
    finally:
        procs.close()
    s = last_json_line(procs.log("up"))
    assert s["exit_ok"] is True
    assert s["steps"] == 1000
    assert s["final_position_error"] < 1e-3


# -- cameras: the SDK hands a controller the session's cameras and their frames ---------------------------


def test_session_info_gives_the_scenarios_cameras() -> None:
    scenario = load_scenario("caroca_15kg_ibvs")
    info = SessionInfo.from_payload(encode_session_info(scenario))
    assert list(info.cameras) == ["top"]
    got, want = info.cameras["top"], scenario.cameras[0]
    for name in ("name", "intrinsics", "on_platform", "markers_on_platform", "marker_ids", "every", "pixel_sigma",
                 "dropout", "latency", "image"):
        assert getattr(got, name) == getattr(want, name), name
    for name in ("mount_position", "mount_rotation", "markers"):
        np.testing.assert_array_equal(getattr(got, name), getattr(want, name))
    assert SessionInfo.from_payload(encode_session_info(load_scenario("caroca_15kg"))).cameras == {}
    bad = msgpack.unpackb(encode_session_info(scenario))
    del bad["sim"]["cameras"][0]["intrinsics"]
    with pytest.raises(ProtocolError, match=r"session/info: sim\.cameras: 'intrinsics'"):
        SessionInfo.from_payload(msgpack.packb(bad)).cameras  # noqa: B018


@pytest.mark.slow
def test_the_remote_ibvs_example_servoes_from_the_camera_alone(session_id: str, tmp_path: Path) -> None:
    """examples/remote_ibvs.py against `cdpr up caroca_15kg_ibvs --without controller`: the platform ends at B
    (whose image is the target) as under the in-stack IBVS controller; the SDK decodes frames only for it."""
    s, log = _up_with("remote_ibvs.py", session_id, None, tmp_path, scenario="caroca_15kg_ibvs")
    # every state to the last one awaiting a command (a state the clock asked for again is answered again)
    answered = re.search(r"answered (\d+) states up to step (\d+)", log)
    assert answered is not None, log[-3000:]
    assert (int(answered[1]) >= 12000, int(answered[2])) == (True, 11999), answered[0]
    assert s["exit_ok"] is True
    assert s["steps"] == 12000
    assert s["final_position_error"] < 1e-3  # at B: ~0.14 mm, as the in-stack servo
    assert s["clamped_commands"] == 0
    robot = load_scenario("caroca_15kg_ibvs").robot
    assert robot.tmin.max() <= s["tension_min"] <= s["tension_max"] <= robot.tmax.min()
    assert s["rms_position_error"] > 0.1  # it never followed the quintic: the setpoints are not used
