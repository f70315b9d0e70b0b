"""docker/ for real: the three images built from this checkout, sessions run by Docker Compose.

Marked ``docker``: ``make test`` leaves these out, ``make test-docker`` runs exactly them (it first makes
sure there is an engine and a base image: see the Makefile). Without a reachable Docker engine they
skip, saying why. Each test is a compose project of its own (a random name, a free host port, a
temporary recordings folder), removed with ``down`` at its end; short sessions (``--duration 2``).

Settings (environment): ``CDPR_BASE`` the base image of the builds (default python:3.11-slim; the
Makefile passes a local one where no registry is reachable), ``CDPR_COMPOSE`` the Compose command
(``docker compose`` or ``docker-compose``; default: v2 when installed, else v1).
"""

from __future__ import annotations

import json
import os
import re
import shlex
import shutil
import signal
import subprocess
import sys
import time
import uuid
from collections.abc import Iterator
from functools import cache
from pathlib import Path

import pytest

from conftest import COMPOSE, REALTIME, ROOT, SECURE, free_port

pytestmark = pytest.mark.docker

EXAMPLE = ROOT / "examples" / "remote_controller.py"
BASE = os.environ.get("CDPR_BASE") or "python:3.11-slim"
IMAGES = ("cdpr:stack", "cdpr:sim", "cdpr:recorder")
DURATION = 2.0  # seconds of sim time per session: 2000 steps of 1 ms
STEPS = 2000
BUILD_TIMEOUT = 1800.0
SESSION_TIMEOUT = 300.0
# The host side (a remote controller, cdpr report) runs this checkout's code, as the images do.
HOST_ENV = {**os.environ, "PYTHONPATH": os.pathsep.join(
    [str(ROOT / "shared"), *(str(p) for p in sorted((ROOT / "services").iterdir()) if p.is_dir())])}


def _run(argv: list[str], timeout: float = 60.0, **kw: object) -> subprocess.CompletedProcess[str]:
    return subprocess.run(argv, capture_output=True, text=True, timeout=timeout, check=False, **kw)  # type: ignore[call-overload]


@cache
def compose_command() -> list[str] | None:
    """The Compose to test with: $CDPR_COMPOSE, else v2 (`docker compose`) when installed, else v1."""
    if os.environ.get("CDPR_COMPOSE"):
        return shlex.split(os.environ["CDPR_COMPOSE"]) or None
    if shutil.which("docker") and _run(["docker", "compose", "version"]).returncode == 0:
        return ["docker", "compose"]
    return ["docker-compose"] if shutil.which("docker-compose") else None


def no_engine() -> str | None:
    """Why these tests cannot run here, or None."""
    if shutil.which("docker") is None:
        return "no docker command (make test-docker installs an engine where it may: see the Makefile)"
    try:
        info = _run(["docker", "info", "--format", "{{.ServerVersion}}"], timeout=30)
    except subprocess.TimeoutExpired:
        return "the Docker engine does not answer (docker info timed out)"
    if info.returncode != 0 or not info.stdout.strip():
        return f"no reachable Docker engine: {(info.stderr.strip().splitlines() or ['?'])[-1]}"
    if compose_command() is None:
        return "neither `docker compose` (v2) nor `docker-compose` (v1) is installed"
    return None


def volumes() -> set[str]:
    return set(_run(["docker", "volume", "ls", "-q"]).stdout.split())


@pytest.fixture(scope="module")
def engine() -> set[str]:
    """Skips without an engine; yields the volumes that existed before these tests."""
    reason = no_engine()
    if reason is not None:
        pytest.skip(reason)
    return volumes()


@pytest.fixture(scope="module")
def images(engine: set[str], tmp_path_factory: pytest.TempPathFactory) -> dict[str, int]:
    """Builds the three images (once per test session; layers cached by the engine); their sizes."""
    log = tmp_path_factory.mktemp("build") / "build.log"
    started = time.monotonic()
    with log.open("w") as f:
        proc = subprocess.run([*compose_command(), "-f", str(COMPOSE), "build"], stdout=f, stderr=subprocess.STDOUT,
                              env={**_clean_env(), "CDPR_BASE": BASE}, cwd=ROOT, timeout=BUILD_TIMEOUT, check=False)
    elapsed = time.monotonic() - started
    assert proc.returncode == 0, log.read_text()[-4000:]
    sizes = {tag: int(_run(["docker", "image", "inspect", "-f", "{{.Size}}", tag]).stdout) for tag in IMAGES}
    print(f"\nimages built in {elapsed:.0f} s from {BASE}: "
          + ", ".join(f"{tag} {size / 1e6:.0f} MB" for tag, size in sizes.items()))
    return sizes


def _clean_env() -> dict[str, str]:
    return {k: v for k, v in os.environ.items() if not k.startswith(("CDPR_", "COMPOSE_"))}


class Project:
    """One compose project: its own name, host port, recordings folder and session id."""

    def __init__(self, tmp_path: Path, *files: Path, **settings: str) -> None:
        self.name = f"cdprtest{uuid.uuid4().hex[:8]}"
        self.session = f"s{uuid.uuid4().hex[:8]}"
        self.port = free_port()
        self.recordings = tmp_path / "recordings"
        self.recordings.mkdir()
        self.files = files or (COMPOSE,)
        self.env = {**_clean_env(), "CDPR_BASE": BASE, "CDPR_SESSION": self.session, "CDPR_PORT": str(self.port),
                    "CDPR_RECORDINGS": str(self.recordings), "CDPR_ARGS": f"--duration {DURATION:g}", **settings}

    def argv(self, *args: str) -> list[str]:
        files = [a for f in self.files for a in ("-f", str(f))]
        return [*compose_command(), "-p", self.name, *files, *args]

    def compose(self, *args: str, timeout: float = 120.0) -> subprocess.CompletedProcess[str]:
        return _run(self.argv(*args), timeout=timeout, env=self.env, cwd=ROOT)

    def session_command(self, *extra: str) -> list[str]:
        """The documented command that runs one session and returns with the clock's exit code."""
        return self.argv("up", *extra, "--exit-code-from", "clock", "clock")

    def up(self, *extra: str) -> tuple[subprocess.CompletedProcess[str], float]:
        """The session command; its output (Compose v2 passes the services' stderr to its stderr) in stdout."""
        return self.up_argv(self.session_command(*extra))

    def up_argv(self, argv: list[str]) -> tuple[subprocess.CompletedProcess[str], float]:
        started = time.monotonic()
        proc = subprocess.run(argv, stdout=subprocess.PIPE, stderr=subprocess.STDOUT,
                              text=True, timeout=SESSION_TIMEOUT, env=self.env, cwd=ROOT, check=False)
        return proc, time.monotonic() - started

    def container(self, service: str) -> str:
        ids = _run(["docker", "ps", "-aq", "--filter", f"label=com.docker.compose.project={self.name}",
                    "--filter", f"label=com.docker.compose.service={service}"]).stdout.split()
        assert len(ids) == 1, f"{service}: containers {ids}"
        return ids[0]

    def inspect(self, service: str) -> dict:
        return json.loads(_run(["docker", "inspect", self.container(service)]).stdout)[0]

    def logs(self, service: str) -> str:
        proc = _run(["docker", "logs", self.container(service)])
        return proc.stdout + proc.stderr

    def wait_exit(self, service: str, timeout: float = 60.0) -> int:
        return int(_run(["docker", "wait", self.container(service)], timeout=timeout).stdout)

    def report(self) -> str:
        proc = _run(self.argv("logs", "--no-color"), env=self.env, cwd=ROOT)
        return (proc.stdout + proc.stderr)[-6000:]

    def down(self) -> None:
        proc = self.compose("down", "--remove-orphans", "-t", "5", timeout=180)
        assert proc.returncode == 0, proc.stderr
        left = _run(["docker", "ps", "-aq", "--filter", f"label=com.docker.compose.project={self.name}"]).stdout
        assert not left.split(), f"containers of {self.name} left after down: {left}"
        nets = _run(["docker", "network", "ls", "-q", "--filter", f"label=com.docker.compose.project={self.name}"])
        assert not nets.stdout.split(), f"networks of {self.name} left after down"


@pytest.fixture
def project(images: dict[str, int], tmp_path: Path) -> Iterator[list[Project]]:
    """Projects a test makes (append them); each is taken down at the end, whatever happened."""
    made: list[Project] = []
    yield made
    for p in made:
        p.down()


def host_report(rrd: Path, out: Path) -> dict:
    """`cdpr report` on the host (this checkout's code, the test's Python): the recording's summary."""
    proc = _run([sys.executable, "-m", "cdpr", "report", str(rrd), "-o", str(out)], timeout=300, env=HOST_ENV)
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])["summary"]


def finished(log: str) -> int:
    m = re.search(r"\[clock\] finished (\d+) steps", log)
    assert m, log[-3000:]
    return int(m.group(1))


# --------------------------------------------------------------------------------------------------


def test_one_image_per_role(images: dict[str, int]) -> None:
    probe = ("import importlib.util as u, json, os, pathlib, sys; "
             "v = u.find_spec('rerun_cli'); "
             "print(json.dumps({'modules': {m: u.find_spec(m) is not None for m in sys.argv[1:]}, "
             "'viewer': v is not None and (pathlib.Path(v.origin).parent / 'rerun').exists(), "
             "'pip': u.find_spec('pip') is not None}))")
    modules = ["cdpr_clock", "cdpr_trajectory", "cdpr_controller", "cdpr_sim", "cdpr_recorder", "dartpy", "rerun",
               "matplotlib", "cv2"]
    facts = {}
    for tag in IMAGES:
        proc = _run(["docker", "run", "--rm", "--entrypoint", "python", tag, "-c", probe, *modules], timeout=120)
        assert proc.returncode == 0, f"{tag}: {proc.stderr}"
        facts[tag] = json.loads(proc.stdout)
        config = json.loads(_run(["docker", "image", "inspect", tag]).stdout)[0]["Config"]
        assert not config.get("Volumes"), f"{tag} declares volumes: {config['Volumes']}"
        assert config["WorkingDir"] == "/cdpr"
        assert config["User"] == ("" if tag == "cdpr:recorder" else "cdpr"), tag  # the recorder: entrypoint.sh
        assert facts[tag]["pip"] is False, tag
    has = {tag: {m for m, ok in f["modules"].items() if ok} for tag, f in facts.items()}
    every = {"cdpr_clock", "cdpr_trajectory", "cdpr_controller", "cdpr_sim", "cdpr_recorder"}  # the cdpr wheel
    assert has["cdpr:stack"] == every  # the light image: no physics, no Rerun, no plots
    assert has["cdpr:sim"] == every | {"dartpy", "cv2"}  # OpenCV: camera images (docs/cameras.md)
    assert has["cdpr:recorder"] == every | {"rerun", "matplotlib"}
    assert facts["cdpr:recorder"]["viewer"] is False  # 280 MB that no service runs
    # dartpy loads (its libGL.so.1 and libX11.so.6 are there), and each image's entrypoint answers.
    proc = _run(["docker", "run", "--rm", "--entrypoint", "python", "cdpr:sim", "-c", "import dartpy; print('ok')"])
    assert proc.stdout.strip() == "ok", proc.stderr
    for tag in IMAGES:
        assert _run(["docker", "run", "--rm", tag, "--version"], timeout=120).stdout.startswith("cdpr, version"), tag
    base = int(_run(["docker", "image", "inspect", "-f", "{{.Size}}", BASE]).stdout or 0)
    assert images["cdpr:stack"] - base < 260e6  # the light image's own layers (numpy, scipy, zenoh, ...)
    assert images["cdpr:stack"] < images["cdpr:sim"] < images["cdpr:recorder"] < 1.2e9


def test_session_with_the_in_stack_controller(project: list[Project], tmp_path: Path) -> None:
    p = Project(tmp_path)
    project.append(p)
    owner = 4321 if os.geteuid() == 0 else os.geteuid()  # the folder's owner: the recording's owner
    if os.geteuid() == 0:
        os.chown(p.recordings, owner, owner)
    proc, elapsed = p.up()
    assert proc.returncode == 0, proc.stdout[-3000:] + p.report()
    assert finished(proc.stdout) == STEPS  # `up` showed the clock, and returned when it ended
    for service in ("sim", "trajectory", "controller", "recorder"):
        assert p.wait_exit(service) == 0, p.report()
    assert p.inspect("router")["State"]["Health"]["Status"] == "healthy"  # up for the next session
    rrd = p.recordings / f"{p.session}.rrd"
    assert rrd.stat().st_uid == owner
    summary = host_report(rrd, tmp_path / "report")
    assert summary["steps"] == summary["total_steps"] == STEPS, summary
    assert summary["session"] == p.session
    # `cdpr report` also runs in the recorder's image, into the same host folder.
    proc = p.compose("run", "--rm", "--no-deps", "recorder", "report", f"/recordings/{p.session}.rrd", timeout=300)
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert json.loads(proc.stdout.strip().splitlines()[-1])["summary"]["steps"] == STEPS
    assert (p.recordings / f"{p.session}_report" / "tracking.png").stat().st_uid == owner
    print(f"compose session, in-stack controller: {elapsed:.0f} s from `up` to its return")


def _wait_for(what: str, predicate: object, timeout: float, report: object) -> None:
    deadline = time.monotonic() + timeout
    while not predicate():  # type: ignore[operator]
        assert time.monotonic() < deadline, f"timed out waiting for {what}\n{report()}"  # type: ignore[operator]
        time.sleep(0.5)


def _with_host_controller(p: Project, tmp_path: Path, argv: list[str], before: object = None,
                          ) -> tuple[subprocess.CompletedProcess[str], int, str]:
    """`up --scale controller=0` and ``argv`` on the host as its controller (after ``before()``, if given): the
    controller's run, the stack's exit code, the stack's log."""
    out = (tmp_path / "up.log").open("w")
    up = subprocess.Popen(p.session_command("--scale", "controller=0"), stdout=out, stderr=subprocess.STDOUT,
                          env=p.env, cwd=ROOT)
    try:
        if before is not None:
            before()  # type: ignore[operator]
        host = subprocess.run(argv, capture_output=True, text=True, timeout=SESSION_TIMEOUT, env=HOST_ENV,
                              check=False)
        code = up.wait(timeout=120)
    finally:
        if up.poll() is None:
            up.kill()
            up.wait()
        out.close()
    return host, code, (tmp_path / "up.log").read_text()


def test_session_with_a_controller_on_the_host(project: list[Project], tmp_path: Path) -> None:
    p = Project(tmp_path)
    project.append(p)

    def joined() -> None:  # the clock says whom it waits for, and the healthchecks show who has joined the session
        _wait_for("the clock to wait for the controller",
                  lambda: "[clock] waiting for controller to join" in _try(lambda: p.logs("clock")), 180, p.report)
        _wait_for("every container to be healthy",
                  lambda: all(_try(lambda s=s: p.inspect(s)["State"]["Health"]["Status"]) == "healthy"
                              for s in ("router", "clock", "sim", "trajectory", "recorder")), 60, p.report)

    remote, code, log = _with_host_controller(p, tmp_path, [sys.executable, str(EXAMPLE), "--connect",
                                                            f"tcp/127.0.0.1:{p.port}", "--session", p.session], joined)
    assert remote.returncode == 0, remote.stderr[-3000:]
    assert re.search(rf"answered \d+ states up to step {STEPS - 1} ", remote.stderr), remote.stderr[-3000:]
    assert code == 0, log[-3000:] + p.report()
    assert finished(log) == STEPS
    assert p.wait_exit("recorder") == 0
    rrd = p.recordings / f"{p.session}.rrd"
    assert host_report(rrd, tmp_path / "report")["steps"] == STEPS


def test_a_learning_environment_on_the_host_completes_episodes(project: list[Project], tmp_path: Path) -> None:
    """cdpr/Track-v0 in session mode is the stack's controller: one episode per `up`, twice (the router stays up
    between them), the second ended early by the environment (session/end) and the stack still returning 0."""
    p = Project(tmp_path)
    project.append(p)
    code = f"""
import json, sys, numpy as np, gymnasium as gym, cdpr.gym
env = gym.make("cdpr/Track-v0", scenario="caroca_15kg", duration={DURATION!r}, connect="tcp/127.0.0.1:{p.port}",
               session="{p.session}", session_timeout=240.0)
obs, _ = env.reset(seed=0)
steps, done = 0, False
while not done and steps < int(sys.argv[1]):
    obs, reward, terminated, truncated, info = env.step(np.zeros(6, dtype=np.float32))
    steps, done = steps + 1, terminated or truncated
env.close()
print(json.dumps({{"env_steps": steps, "truncated": bool(done), "sim_step": info["step"]}}))
"""
    for limit, expected in ((10_000, STEPS), (50, None)):
        learner, status, log = _with_host_controller(p, tmp_path, [sys.executable, "-c", code, str(limit)])
        assert learner.returncode == 0, learner.stderr[-3000:] + log[-2000:]
        result = json.loads(learner.stdout.strip().splitlines()[-1])
        assert status == 0, log[-3000:] + p.report()
        if expected is not None:  # to the trajectory's end: truncated at the last state
            assert result == {"env_steps": STEPS // 10, "truncated": True, "sim_step": STEPS}, result
            assert finished(log) == STEPS
        else:  # ended by the environment after 50 env steps
            assert result["env_steps"] == 50
            assert "ended by the controller at step" in log, log[-3000:]


def test_a_ros2_controller_on_the_host_through_the_ros2_profile(project: list[Project], tmp_path: Path) -> None:
    """`--profile ros2 up --scale controller=0 ... clock ros2`: the ros2 service in its container, and a ROS 2
    controller on the host (zenoh-ros2-sdk, a peer of the router's mapped port, as rmw_zenoh's nodes are)."""
    from cdpr.ros2.topics import default_namespace
    from cdpr.tools.bench import ros2_controller
    from cdpr.tools.bench.ros2_messages import make_cache

    (tmp_path / "gitconfig").write_text("")
    env = {**HOST_ENV, "ZENOH_ROS2_SDK_CACHE": str(make_cache(tmp_path / "cache")),
           "GIT_CONFIG_GLOBAL": str(tmp_path / "gitconfig")}
    p = Project(tmp_path)
    project.append(p)
    with (tmp_path / "controller.log").open("w") as log:
        ctl = subprocess.Popen([sys.executable, str(ros2_controller.__file__), "--router-port", str(p.port),
                                "--namespace", default_namespace(p.session)],
                               stdout=log, stderr=subprocess.STDOUT, env=env)
        try:
            up, _ = p.up_argv(p.argv("--profile", "ros2", "up", "--scale", "controller=0", "--exit-code-from",
                                     "clock", "clock", "ros2"))
        finally:
            ctl.send_signal(signal.SIGTERM)
            try:
                ctl.wait(timeout=30)
            except subprocess.TimeoutExpired:
                ctl.kill()
    assert up.returncode == 0, up.stdout[-3000:] + p.report()
    assert finished(up.stdout) == STEPS
    ros2 = p.logs("ros2")
    applied = re.search(r"applied (\d+) ROS 2 commands", ros2)
    assert applied, ros2[-3000:]
    assert int(applied.group(1)) >= STEPS  # every step, and again any the clock asked for again


def _try(f: object) -> str:
    try:
        return f()  # type: ignore[operator,no-any-return]
    except (AssertionError, KeyError, IndexError, TypeError, json.JSONDecodeError):
        return ""


def test_secure_profile_runs_with_tls_and_refuses_a_plain_intruder(project: list[Project], tmp_path: Path,
                                                                   monkeypatch: pytest.MonkeyPatch) -> None:
    import zenoh

    from cdpr.runtime.transport import zenoh_config

    secrets = tmp_path / "secrets"
    made = _run(["make", "-s", "-C", str(ROOT), "certs", f"CERTS_DIR={secrets}"])
    assert made.returncode == 0, made.stderr
    p = Project(tmp_path, COMPOSE, SECURE, CDPR_SECRETS=str(secrets))
    project.append(p)
    proc, _ = p.up()
    assert proc.returncode == 0, proc.stdout[-3000:] + p.report()
    assert finished(proc.stdout) == STEPS
    for service in ("clock", "sim", "recorder"):
        assert "--connect tls/router:7447" in " ".join(p.inspect(service)["Config"]["Cmd"])
    assert p.inspect("router")["State"]["Running"]
    # The router, still up after the session, on the published port: identities from `make certs` get
    # in over TLS, a plain TCP client does not, nor a TLS client without a password.
    monkeypatch.chdir(tmp_path)  # the identity files name secrets/ca.pem relative to the working directory
    tls, plain = f"tls/127.0.0.1:{p.port}", f"tcp/127.0.0.1:{p.port}"
    with zenoh.open(zenoh_config("client", [tls], (), "secrets/observer.json5", connect_timeout=30)):
        pass
    for endpoint, identity in ((plain, None), (plain, "secrets/controller.json5"), (tls, None)):
        conf = zenoh_config("client", [endpoint], (), identity, connect_timeout=3)
        if identity is None and endpoint == tls:
            conf.insert_json5("transport/link/tls/root_ca_certificate", json.dumps("secrets/ca.pem"))
        with pytest.raises(Exception, match="Unable to connect"):
            zenoh.open(conf).close()


def test_the_secure_profile_carries_an_ibvs_session_ping_and_a_sim_crash(project: list[Project], tmp_path: Path,
                                                                        monkeypatch: pytest.MonkeyPatch) -> None:
    """compose.secure.yaml with caroca_15kg_ibvs, each container with its identity and the generated access rules:
    the camera frames reach the controller, `cdpr ping` from the host answers for every node, the sim's container
    killed mid-way and started again goes on from the snapshot — and the recording's states are the same
    session's without the secure profile, bit for bit (an in-process run on the host). (A crash that the restart
    policy brings back: test_a_sim_container_that_crashes_comes_back_and_the_session_goes_on.)"""
    import zenoh

    from cdpr.protocol import Keys
    from cdpr.runtime.transport import zenoh_config
    from cdpr.tools.soak import SessionWatcher

    secrets = tmp_path / "secrets"
    made = _run(["make", "-s", "-C", str(ROOT), "certs", f"CERTS_DIR={secrets}"])
    assert made.returncode == 0, made.stderr
    p = Project(tmp_path, COMPOSE, SECURE, CDPR_SECRETS=str(secrets), CDPR_SCENARIO="caroca_15kg_ibvs", CDPR_ARGS="",
                CDPR_JOIN_TIMEOUT="600", CDPR_REJOIN_TIMEOUT="600")
    project.append(p)
    monkeypatch.chdir(tmp_path)  # the identity files name secrets/ca.pem relative to the working directory
    tls = f"tls/127.0.0.1:{p.port}"

    def ping(node: str) -> None:
        # (--wait: a container just started may take a while to be there)
        run = _run([sys.executable, "-m", "cdpr", "ping", "--session", p.session, "--connect", tls, "--zenoh-config",
                    "secrets/observer.json5", "--node", node, "--count", "3", "--wait", "300"], timeout=400,
                   env=HOST_ENV, cwd=tmp_path)
        assert run.returncode == 0, (node, run.stderr[-2000:])
        assert json.loads(run.stdout.strip().splitlines()[-1])["answered"] == 3, node

    # Every node is pinged while the session is held, whatever the machine's speed: the others while the clock
    # waits for the recorder (started last) to join, the recorder while the clock waits for the killed sim.
    started = p.compose("up", "-d", "router", timeout=300)
    assert started.returncode == 0, started.stderr[-3000:]
    _wait_for("the router", lambda: _try(lambda: p.inspect("router")["State"]["Health"]["Status"]) == "healthy",
              180, p.report)
    held = ("clock", "sim", "trajectory", "controller")
    started = p.compose("up", "-d", "--no-deps", *held, timeout=300)
    assert started.returncode == 0, started.stderr[-3000:]
    for node in held:
        ping(node)
    with zenoh.open(zenoh_config("client", [tls], (), "secrets/observer.json5", connect_timeout=30)) as z:
        watch = SessionWatcher(z, Keys(p.session))
        started = p.compose("up", "-d", "--no-deps", "recorder", timeout=300)
        assert started.returncode == 0, started.stderr[-3000:]
        _wait_for("3000 steps", lambda: len(watch.states) > 3000, 300, p.report)
        # docker kill: the process SIGKILLed, and the container left down (a stop, for the restart policy)
        assert _run(["docker", "kill", p.container("sim")]).returncode == 0
        ping("recorder")
        assert _run(["docker", "start", p.container("sim")]).returncode == 0
        code = p.wait_exit("clock", timeout=SESSION_TIMEOUT)
    log = p.logs("clock")
    assert code == 0, log[-3000:] + p.report()
    assert finished(log) == 12000
    assert "joined a session under way: going on from step" in p.logs("sim")
    assert "has not come" not in p.logs("controller")  # every frame it waited for came through the router
    assert p.wait_exit("recorder") == 0
    summary = host_report(p.recordings / f"{p.session}.rrd", tmp_path / "report")
    assert summary["recorded_states"] == 12001
    whole = _run([sys.executable, "-m", "cdpr", "run", "caroca_15kg_ibvs", "--in-process", "--quiet"],
                 timeout=600, env=HOST_ENV)
    assert summary["state_digest"] == json.loads(whole.stdout.strip().splitlines()[-1])["state_digest"]


def test_a_missing_participant_ends_the_session_with_its_name(project: list[Project], tmp_path: Path) -> None:
    p = Project(tmp_path, CDPR_JOIN_TIMEOUT="10")
    project.append(p)
    proc, elapsed = p.up("--scale", "sim=0")  # a stack without its sim
    assert proc.returncode == 1, proc.stdout[-3000:] + p.report()
    print(f"compose session without its sim: {elapsed:.0f} s from `up` to its return")
    reason = re.search(rf"\[clock\] aborted: sim did not join session '{p.session}' within 10 s \(joined: (.*)\)",
                       proc.stdout)
    assert reason, proc.stdout[-3000:]
    assert "[clock] waiting for sim" in proc.stdout  # said from the start, before giving up
    state = p.inspect("clock")["State"]
    ran = _seconds(state["FinishedAt"]) - _seconds(state["StartedAt"])
    assert 10 < ran < 10 + 20, ran  # start-up, the timeout, the participants leaving (LINGER)
    for service in ("trajectory", "controller", "recorder"):  # the others heard it, and stopped
        assert p.wait_exit(service) == 0, p.report()
        assert "session aborted by the clock: sim did not join" in p.logs(service), p.logs(service)


def _seconds(stamp: str) -> float:
    """Docker's RFC 3339 time stamp (nanoseconds) as seconds since the epoch."""
    from datetime import datetime

    head, _, frac = stamp.rstrip("Z").partition(".")
    return datetime.fromisoformat(head + "+00:00").timestamp() + float(f"0.{frac or 0}")


def _realtime_refused() -> str | None:
    proc = _run(["docker", "run", "--rm", "--ulimit", "rtprio=99", "--entrypoint", "chrt", "cdpr:stack",
                 "--fifo", "10", "true"], timeout=120)
    if proc.returncode != 0:
        lines = [ln for ln in proc.stderr.splitlines() if ln.strip()] or ["?"]
        why = next((ln for ln in lines if "rror" in ln or "not permitted" in ln), lines[0])
        return f"this Docker engine does not let containers use realtime scheduling ({why.strip()[:300]})"
    return None


def test_realtime_session(project: list[Project], tmp_path: Path) -> None:
    reason = _realtime_refused()
    if reason is not None:
        pytest.skip(reason)
    p = Project(tmp_path, COMPOSE, REALTIME, CDPR_MODE="realtime", CDPR_ARGS="--duration 1")
    project.append(p)
    proc, _ = p.up()
    assert proc.returncode == 0, proc.stdout[-3000:] + p.report()
    assert finished(proc.stdout) == 1000
    assert p.inspect("sim")["Config"]["Entrypoint"] == ["chrt", "--fifo", "10", "cdpr"]


def test_no_volume_left_behind(engine: set[str]) -> None:
    """After every session above (and their `down`): not one Docker volume more than before."""
    assert volumes() - engine == set()


def _kill_the_sim_mid_session(p: Project, tmp_path: Path, kill: object) -> tuple[int, str]:
    """A realtime session of the compose stack whose sim container is killed (``kill()``) after 1 000 steps:
    ``up``'s exit code and output."""
    import zenoh

    from cdpr.protocol import Keys
    from cdpr.runtime.transport import zenoh_config
    from cdpr.tools.soak import SessionWatcher

    out = (tmp_path / "up.log").open("w")
    up = subprocess.Popen(p.session_command(), stdout=out, stderr=subprocess.STDOUT, env=p.env, cwd=ROOT)
    try:
        _wait_for("the router", lambda: _try(lambda: p.inspect("router")["State"]["Health"]["Status"]) == "healthy",
                  180, p.report)
        with zenoh.open(zenoh_config("client", connect=[f"tcp/127.0.0.1:{p.port}"])) as z:
            watch = SessionWatcher(z, Keys(p.session))
            _wait_for("1000 steps", lambda: len(watch.states) > 1000, 180, p.report)
            kill()  # type: ignore[operator]
            code = up.wait(timeout=SESSION_TIMEOUT)
    finally:
        if up.poll() is None:
            up.kill()
            up.wait()
        out.close()
    return code, (tmp_path / "up.log").read_text()


def test_a_sim_container_killed_for_good_ends_the_session(project: list[Project], tmp_path: Path) -> None:
    """`docker kill`: a stop Docker's restart policy leaves alone. The clock waits CDPR_REJOIN_TIMEOUT, then
    ends the session naming the sim; `up` returns 1 and the recording holds every step before."""
    p = Project(tmp_path, CDPR_MODE="realtime", CDPR_ARGS="--duration 6", CDPR_REJOIN_TIMEOUT="5")
    project.append(p)
    code, log = _kill_the_sim_mid_session(p, tmp_path, lambda: _run(["docker", "kill", p.container("sim")]))
    assert code == 1, log[-3000:] + p.report()
    m = re.search(r"\[clock\] aborted: sim left the session at step (\d+) and did not come back within 5 s", log)
    assert m, log[-3000:] + p.report()
    assert p.wait_exit("recorder") == 0
    summary = host_report(p.recordings / f"{p.session}.rrd", tmp_path / "report")
    assert summary["steps"] == int(m.group(1)), summary


def test_a_sim_container_that_crashes_comes_back_and_the_session_goes_on(project: list[Project],
                                                                        tmp_path: Path) -> None:
    """The sim's process killed (a crash: SIGKILL from outside): `restart: on-failure` starts the container again,
    the new sim goes on from the session's last snapshot, and the session finishes every step with the states
    of an uninterrupted run (same digest)."""
    p = Project(tmp_path, CDPR_MODE="realtime", CDPR_ARGS="--duration 4")
    project.append(p)

    def crash() -> None:
        os.kill(int(p.inspect("sim")["State"]["Pid"]), signal.SIGKILL)

    code, log = _kill_the_sim_mid_session(p, tmp_path, crash)
    assert code == 0, log[-3000:] + p.report()
    assert finished(log) == 4000
    assert p.inspect("sim")["RestartCount"] == 1
    assert "joined a session under way: going on from step" in p.logs("sim")
    assert p.wait_exit("recorder") == 0
    summary = host_report(p.recordings / f"{p.session}.rrd", tmp_path / "report")
    assert summary["steps"] == 4000
    assert summary["recorded_states"] == 4001  # every step once
    whole = _run([sys.executable, "-m", "cdpr", "run", "caroca_15kg", "--duration", "4", "--in-process", "--quiet"],
                 timeout=300, env=HOST_ENV)
    assert summary["state_digest"] == json.loads(whole.stdout.strip().splitlines()[-1])["state_digest"]


# -- Studies on a Ray cluster of containers (docker/README.md "Studies on Ray") ---------------------------

RAY_STUDY = """\
name: {name}
scenario: caroca_15kg
set: {{duration: 5.0}}
samples: {samples}
seed: {seed}
mode: in-process
parameters:
  - {{name: mass_factor, path: platform.mass, op: scale, uniform: [0.9, 1.1]}}
metrics: [rms_position_error, tension_min, tension_max, infeasible_commands]
"""


def _ray_version() -> str:
    import ray

    return str(ray.__version__)


@pytest.fixture(scope="module")
def study_image(engine: set[str], tmp_path_factory: pytest.TempPathFactory) -> str:
    """cdpr:study, with the host's Ray (a Ray Client driver needs the cluster's Ray version)."""
    log = tmp_path_factory.mktemp("build") / "study.log"
    with log.open("w") as f:
        proc = subprocess.run([*compose_command(), "-f", str(COMPOSE), "--profile", "study", "build", "ray-head"],
                              stdout=f, stderr=subprocess.STDOUT, cwd=ROOT, timeout=BUILD_TIMEOUT, check=False,
                              env={**_clean_env(), "CDPR_BASE": BASE, "CDPR_RAY_VERSION": _ray_version()})
    assert proc.returncode == 0, log.read_text()[-4000:]
    return "cdpr:study"


def _study(p: Project, folder: Path, name: str, samples: int, seed: int) -> tuple[list[str], Path]:
    """The host's `cdpr study` command of a study run through the project's head (Ray Client); its output folder."""
    path = folder / f"{name}.yaml"
    path.write_text(RAY_STUDY.format(name=name, samples=samples, seed=seed), encoding="utf-8")
    out = folder / name
    return [sys.executable, "-m", "cdpr", "study", str(path), "--quiet", "--out", str(out), "--address",
            f"ray://127.0.0.1:{p.env['CDPR_RAY_CLIENT_PORT']}"], out


def _ray_client_logs(head: str) -> str:
    """The head's Ray Client server logs (the proxy and each client's server): why a connection was refused."""
    proc = _run(["docker", "exec", head, "sh", "-c",
                 "cd /tmp/ray/session_latest/logs && tail -n 25 ray_client_server*"], timeout=60)
    return (proc.stdout + proc.stderr)[-6000:]


def _rows(out: Path) -> list[dict[str, str]]:
    import csv

    with (out / "results.csv").open(newline="", encoding="utf-8") as f:
        return list(csv.DictReader(f))


def test_a_study_runs_on_a_ray_cluster_of_containers_and_survives_a_lost_worker(
        study_image: str, project: list[Project], tmp_path: Path, engine: set[str]) -> None:
    (tmp_path / "studies").mkdir()
    p = Project(tmp_path, COMPOSE, COMPOSE_PROFILES="study", CDPR_RAY_VERSION=_ray_version(),
                CDPR_STUDIES=str(tmp_path / "studies"),
                CDPR_RAY_CLIENT_PORT=str(free_port()), CDPR_RAY_PORT=str(free_port()),
                CDPR_RAY_DASHBOARD_PORT=str(free_port()))
    project.append(p)
    up = p.compose("up", "-d", "--scale", "ray-worker=2", "ray-head", "ray-worker", timeout=600)
    assert up.returncode == 0, up.stdout[-2000:] + up.stderr[-3000:]
    head = p.container("ray-head")
    alive = ["python", "-c",
             "import ray; ray.init(address='auto', logging_level='ERROR'); "
             "print('alive nodes:', sum(1 for n in ray.nodes() if n['Alive']))"]

    def nodes() -> int:
        # the count's own line: Ray may print more on stdout (a native stack's addresses, 2026-11-28)
        proc = _run(["docker", "exec", head, *alive], timeout=60)
        found = re.findall(r"^alive nodes: (\d+)$", proc.stdout, re.MULTILINE) if proc.returncode == 0 else []
        return int(found[-1]) if found else 0

    _wait_for("the head and two workers", lambda: nodes() == 3, 180, p.report)

    # 16 points through the two workers (their throughput: docker/README.md)
    argv, out = _study(p, tmp_path, "sixteen", 16, 2)
    run = _run(argv, timeout=900, env=HOST_ENV)
    assert run.returncode == 0, run.stderr[-3000:] + _ray_client_logs(head)
    two = json.loads(run.stdout.splitlines()[-1])
    assert (two["points"], two["ok"], two["nodes"]) == (16, 16, 3), two
    spread = _rows(out)
    assert len({r["node"] for r in spread}) == 2, [r["node"] for r in spread]  # points on both workers
    assert len({r["host"] for r in spread}) == 2
    assert all(float(r["rms_position_error"]) < 1e-3 for r in spread)

    # the driver in a container of the cluster's network (the `study` service): files in CDPR_STUDIES
    (studies := Path(p.env["CDPR_STUDIES"])).joinpath("four.yaml").write_text(
        RAY_STUDY.format(name="four", samples=4, seed=2), encoding="utf-8")
    inside = p.compose("run", "--rm", "-T", "study", "study", "/runs/four.yaml", "--quiet", "--address",
                       "ray://ray-head:10001", "--out", "/runs/studies/four", timeout=600)
    assert inside.returncode == 0, inside.stdout[-2000:] + inside.stderr[-3000:] + _ray_client_logs(head)
    assert json.loads(inside.stdout.strip().splitlines()[-1])["ok"] == 4
    assert len(_rows(studies / "studies" / "four")) == 4

    # a worker killed during a study: every row still comes back (ok, or failed with its error)
    argv, out = _study(p, tmp_path, "lost_worker", 16, 3)

    def done() -> int:
        return len(list((out / "points").glob("*/result.json"))) if (out / "points").is_dir() else 0

    with subprocess.Popen(argv, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True, env=HOST_ENV) as study:
        try:
            _wait_for("the study's first point", lambda: done() >= 1 or study.poll() is not None, 300, p.report)
            assert study.poll() is None, study.communicate()[1][-3000:] + _ray_client_logs(head)
            before = done()
            workers = _run(["docker", "ps", "-q", "--filter", f"label=com.docker.compose.project={p.name}",
                            "--filter", "label=com.docker.compose.service=ray-worker"]).stdout.split()
            assert len(workers) == 2
            assert _run(["docker", "kill", workers[0]]).returncode == 0
            stdout, stderr = study.communicate(timeout=900)
        finally:
            if study.poll() is None:
                study.kill()
    assert before < 16  # the kill came while points were still running or waiting
    assert study.returncode == 0, stderr[-3000:]
    summary = json.loads(stdout.splitlines()[-1])
    assert summary["points"] == 16, summary
    rows = _rows(out)
    assert len(rows) == 16
    assert {r["status"] for r in rows} <= {"ok", "failed"}
    assert all(r["error"] for r in rows if r["status"] == "failed")
    print(f"\nlost worker: {summary['ok']} ok, {summary['failed']} failed of 16 ({before} finished before the kill)")

    # the same 16 points one at a time on the worker left (one Ray CPU): one session alone, in the same mode
    argv, out = _study(p, tmp_path, "one_at_a_time", 16, 2)
    run = _run(argv, timeout=900, env=HOST_ENV)
    assert run.returncode == 0, run.stderr[-3000:] + _ray_client_logs(head)
    one = json.loads(run.stdout.splitlines()[-1])
    assert (one["ok"], one["nodes"]) == (16, 2), one
    assert {r["state_digest"] for r in _rows(out)} == {r["state_digest"] for r in spread}  # the same sessions
    print(f"16 points on 2 workers: {two['steps_per_s']:.0f} steps/s, one at a time: {one['steps_per_s']:.0f} "
          f"steps/s: {two['steps_per_s'] / one['steps_per_s']:.2f}x")
    p.down()
    project.remove(p)
    assert volumes() - engine == set()
