"""docker/: the Dockerfile and the compose deployment, checked without a Docker engine.

``docker-compose config`` (and ``docker compose config`` where Compose v2 is installed) validates the files;
neither needs an engine. Then the compose file is read like compose reads it (``${VAR:-default}``
interpolation, YAML merge keys, override files) and each service's exact command is started as a local
process, in a directory that holds only what compose would mount into its container, with the ``router``
host mapped to 127.0.0.1 and a free port: a real session runs end to end through the router with the
example remote controller. tests/test_docker.py runs the same files in real containers.
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
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import IO, Any

import pytest
import yaml
import zenoh

from conftest import COMPOSE, DOCKER, REALTIME, ROOT, SECURE, free_port

EXAMPLE = ROOT / "examples" / "remote_controller.py"
SESSION_SERVICES = ("clock", "sim", "trajectory", "recorder")
LOOP_SERVICES = ("clock", "sim", "trajectory", "controller")  # the lock-step loop (compose.realtime.yaml)
IMAGES = {"router": "cdpr:stack", "clock": "cdpr:stack", "trajectory": "cdpr:stack", "controller": "cdpr:stack",
          "sim": "cdpr:sim", "recorder": "cdpr:recorder", "ros2": "cdpr:stack",
          "ray-head": "cdpr:study", "ray-worker": "cdpr:study", "study": "cdpr:study"}
STUDY_SERVICES = ("ray-head", "ray-worker", "study")  # studies on Ray (docker/README.md "Studies on Ray")
PROFILES = {"ros2": ["ros2"], **{name: ["study"] for name in STUDY_SERVICES}}  # run only with `--profile NAME`
BUILDS = {"router": "stack", "sim": "sim", "recorder": "recorder", "ray-head": "study"}  # one builder per image
ROUTER_PORT = 7447
COMPOSE_BIN = shutil.which("docker-compose")
NO_COMPOSE = "the docker-compose binary is absent (apt-get install -y --no-install-recommends docker-compose)"


def _compose_v2() -> list[str] | None:
    """``docker compose`` (the Compose v2 plugin of the docker CLI), if installed."""
    docker = shutil.which("docker")
    if docker is None:
        return None
    try:
        ok = subprocess.run([docker, "compose", "version"], capture_output=True, timeout=30).returncode == 0
    except (OSError, subprocess.TimeoutExpired):
        return None
    return [docker, "compose"] if ok else None


COMPOSE_V2 = _compose_v2()

_VAR = re.compile(r"\$\{(\w+)(?::-([^}]*))?\}")


def interpolate(text: str, env: Mapping[str, str]) -> str:
    """Compose's ``${VAR}`` / ``${VAR:-default}`` (an empty or unset VAR takes the default)."""
    return _VAR.sub(lambda m: env.get(m.group(1)) or (m.group(2) or ""), text)


def _merge(base: Any, over: Any, key: str = "") -> Any:
    """Compose's override rules, for what these files use: maps merge, ``volumes`` merge by target."""
    if isinstance(base, dict) and isinstance(over, dict):
        out = dict(base)
        for k, v in over.items():
            out[k] = _merge(base[k], v, k) if k in base else v
        return out
    if key == "volumes" and isinstance(base, list) and isinstance(over, list):
        by_target = {str(v).split(":")[1]: v for v in base}
        by_target.update({str(v).split(":")[1]: v for v in over})
        return list(by_target.values())
    return over


def load_compose(files: Sequence[Path], env: Mapping[str, str]) -> dict[str, dict[str, Any]]:
    """The services of ``files`` (later ones override earlier ones), interpolated with ``env``."""
    merged: dict[str, Any] = {}
    for f in files:
        merged = _merge(merged, yaml.safe_load(interpolate(f.read_text(), env)))
    return merged["services"]


def command_of(service: dict[str, Any]) -> list[str]:
    cmd = service["command"]
    return shlex.split(cmd) if isinstance(cmd, str) else [str(x) for x in cmd]


@dataclass
class Container:
    """A compose service run as a local process: its argv, its working directory, its log file."""

    name: str
    argv: list[str]
    cwd: Path
    log: Path


def localise(name: str, service: dict[str, Any], compose_dir: Path, scratch: Path, port: int) -> Container:
    """What compose would run for ``service``, as a process on this machine.

    The image's entrypoint runs ``cdpr`` and its working directory is ``/cdpr``: the process gets
    ``python -m cdpr`` and a directory of its own standing for /cdpr, in which only the files compose
    bind-mounts under /cdpr appear (sources relative to ``compose_dir``, which must exist). A mount
    elsewhere is a data folder (the recordings): it becomes the directory ``scratch/volumes/<name>``,
    wherever compose would take it from on the host. ``router:7447`` becomes ``127.0.0.1:port``, and the
    router listens on that loopback port only.
    """
    workdir = scratch / "containers" / name
    workdir.mkdir(parents=True)
    mounts: dict[str, Path] = {}
    for spec in service.get("volumes", []):
        source, target = str(spec).split(":")[:2]
        if target.startswith("/cdpr/"):
            host = (compose_dir / source).resolve()
            assert host.exists(), f"{name}: mounts {source}, which does not exist"
            inside = workdir / target.removeprefix("/cdpr/")
            inside.parent.mkdir(parents=True, exist_ok=True)
            inside.symlink_to(host)
        else:
            host = scratch / "volumes" / Path(target).name
            host.mkdir(parents=True, exist_ok=True)
            mounts[target] = host
    args = []
    for a in command_of(service):
        a = re.sub(r"^(tcp|tls)/router:7447$", rf"\1/127.0.0.1:{port}", a)
        a = re.sub(r"^(tcp|tls)/0\.0\.0\.0:7447$", rf"\1/127.0.0.1:{port}", a)
        for target, host in mounts.items():
            if a == target or a.startswith(target + "/"):
                a = str(host) + a[len(target):]
        args.append(a)
    if args[0] == "router" and "--listen" not in args:  # the config file's endpoints, kept on loopback
        conf = zenoh.Config.from_file(str(workdir / args[args.index("--zenoh-config") + 1]))
        for endpoint in json.loads(conf.get_json("listen/endpoints")):
            proto, _, address = endpoint.partition("/")
            assert address.endswith(":7447"), endpoint
            args += ["--listen", f"{proto}/127.0.0.1:{port}"]
    return Container(name, [sys.executable, "-m", "cdpr", *args], workdir, scratch / f"{name}.log")


class Processes:
    """Started processes, each logging to a file; all of them are stopped at the end, whatever happens."""

    def __init__(self) -> None:
        self.procs: dict[str, subprocess.Popen[bytes]] = {}
        self.logs: dict[str, Path] = {}
        self._files: list[IO[bytes]] = []

    def start(self, name: str, argv: Sequence[str], cwd: Path, log: Path,
              env: Mapping[str, str] | None = None) -> subprocess.Popen[bytes]:
        f = log.open("wb")
        self._files.append(f)
        self.logs[name] = log
        p = subprocess.Popen(list(argv), cwd=cwd, stdout=f, stderr=subprocess.STDOUT, env=env)
        self.procs[name] = p
        return p

    def run(self, c: Container) -> subprocess.Popen[bytes]:
        return self.start(c.name, c.argv, c.cwd, c.log)

    def log(self, name: str) -> str:
        return self.logs[name].read_text(errors="replace")

    def wait(self, names: Sequence[str], timeout: float) -> dict[str, int | None]:
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline and any(self.procs[n].poll() is None for n in names):
            time.sleep(0.05)
        return {n: self.procs[n].poll() for n in names}

    def stop(self, name: str, sig: int = signal.SIGTERM, timeout: float = 10.0) -> int:
        p = self.procs[name]
        if p.poll() is None:
            p.send_signal(sig)
        try:
            return p.wait(timeout=timeout)
        except subprocess.TimeoutExpired:
            p.kill()
            return p.wait()

    def close(self) -> None:
        for name, p in self.procs.items():
            if p.poll() is None:
                self.stop(name, signal.SIGTERM, 5.0)
        for f in self._files:
            f.close()

    def report(self) -> str:
        return "\n".join(f"--- {n} (exit {p.poll()})\n{self.log(n)[-2500:]}" for n, p in self.procs.items())


def compose_dir_with_secrets(scratch: Path, *make_args: str) -> Path:
    """A stand-in for docker/ with fresh secrets from `make certs` (``make_args``: e.g. SESSIONS=a,b) and the
    repository's zenoh/ configs."""
    d = scratch / "compose"
    d.mkdir()
    (d / "zenoh").symlink_to(DOCKER / "zenoh")
    proc = subprocess.run(["make", "-s", "-C", str(ROOT), "certs", f"CERTS_DIR={d / 'secrets'}", *make_args],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    return d


def clock_rate(log: str) -> float:
    m = re.search(r"finished (\d+) steps in [\d.]+ s \((\d+) steps/s", log)
    assert m, log[-2000:]
    return float(m.group(2))


# --------------------------------------------------------------------------------------------------


def dockerfile_stages() -> dict[str, list[str]]:
    """docker/Dockerfile's stages: name -> its instructions (the FROM line first), comments and
    continuation lines joined."""
    text = (DOCKER / "Dockerfile").read_text().replace("\\\n", " ")
    lines = [" ".join(ln.split()) for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    stages: dict[str, list[str]] = {"": []}
    current = ""
    for ln in lines:
        if ln.startswith("FROM "):
            current = ln.split()[-1]
            stages[current] = []
        stages[current].append(ln)
    return stages


def test_dockerfile_builds_one_image_per_role() -> None:
    stages = dockerfile_stages()
    assert stages[""] == ["ARG BASE=python:3.11-slim"]  # the base image is a build argument
    assert stages["base"][0] == "FROM ${BASE} AS base"
    assert "WORKDIR /cdpr" in stages["base"]
    every = [ln for lines in stages.values() for ln in lines]
    assert not [ln for ln in every if ln.startswith("VOLUME")]  # no anonymous volume per container
    # Each role's virtualenv holds its install extras, listed by requirements.py from pyproject.toml.
    lists = " ".join(stages["requirements"])
    for extras, role in (("stack", "stack"), ("sim camera", "sim"), ("record plots", "recorder"),
                         ("cluster", "study")):
        assert f"pyproject.toml {extras} >/build/{role}.txt" in lists
        assert f"COPY --from=requirements /build/{role}.txt /build/" in stages[f"deps-{role}"]
        assert any(f"pip install -r /build/{role}.txt" in ln for ln in stages[f"deps-{role}"])
    for role in ("sim", "recorder"):  # the light image's dependencies are built once, for all three
        assert stages[f"deps-{role}"][0] == f"FROM deps-stack AS deps-{role}"
    assert stages["deps-study"][0] == "FROM deps-sim AS deps-study"  # a Ray node runs the sim's sessions
    for role, entrypoint in (("stack", "cdpr"), ("sim", "cdpr"), ("recorder", "cdpr-entrypoint"), ("study", "cdpr")):
        lines = stages[role]
        assert lines[0] == f"FROM base AS {role}", role
        assert f"COPY --from=venv-{role} /opt/cdpr /opt/cdpr" in lines, role
        assert f'ENTRYPOINT ["{entrypoint}"]' in lines, role
    assert "USER cdpr" in stages["stack"]
    assert "USER cdpr" in stages["sim"]
    assert "USER cdpr" in stages["study"]
    assert "USER" not in " ".join(stages["recorder"])  # root, then the folder's owner (entrypoint.sh)
    assert "COPY --from=gl /gl/ /usr/local/lib/" in stages["sim"]  # libGL, libX11 for dartpy
    assert "COPY --from=gl /gl/ /usr/local/lib/" in stages["study"]
    assert any("import dartpy" in ln for ln in stages["sim"])  # checked at build time
    assert any("--no-viewer" in ln for ln in stages["venv-recorder"])
    # What the Dockerfile copies is in the build context the root .dockerignore lets through.
    sources = [ln.split()[1:-1] for ln in every if ln.startswith("COPY") and "--from=" not in ln]
    allowed = ("pyproject.toml", "README.md", "shared", "services", "docker/image/")
    for src in (s for group in sources for s in group):
        assert src.startswith(allowed), src
        assert (ROOT / src).exists(), src
    ignore = [ln.strip() for ln in (ROOT / ".dockerignore").read_text().splitlines()
              if ln.strip() and not ln.startswith("#")]
    assert ignore[0] == "*"
    assert {"!pyproject.toml", "!README.md", "!shared/", "!services/", "!docker/image/"} <= set(ignore)
    assert not (DOCKER / "Dockerfile.dockerignore").exists()  # BuildKit-only, and it would win over the root one


def test_requirements_of_each_role() -> None:
    sys.path.insert(0, str(DOCKER / "image"))
    try:
        from requirements import requirements
    finally:
        sys.path.pop(0)
    pyproject = str(ROOT / "pyproject.toml")
    names = {role: {re.split(r"[<>=!~\[ ;]", r, maxsplit=1)[0] for r in requirements(pyproject, extras)}
             for role, extras in (("stack", ["stack"]), ("sim", ["sim", "camera"]), ("recorder", ["record", "plots"]),
                                  ("study", ["cluster"]))}
    base = {"eclipse-zenoh", "msgpack", "msgspec", "numpy", "scipy", "qpsolvers", "osqp", "pyyaml", "pydantic", "click",
            "setproctitle"}
    assert names["stack"] == base
    assert names["sim"] == base | {"dartpy", "opencv-python-headless"}  # camera images (docs/cameras.md)
    assert base | {"rerun-sdk", "matplotlib"} <= names["recorder"]
    assert "dartpy" not in names["recorder"]
    assert names["sim"] | {"ray", "optuna", "pyarrow", "matplotlib"} == names["study"]
    with pytest.raises(SystemExit, match="no extra 'nope'"):
        requirements(pyproject, ["nope"])


def test_compose_services_are_complete() -> None:
    services = load_compose([COMPOSE], {})
    assert set(services) == {"router", *SESSION_SERVICES, "controller", "ros2", *STUDY_SERVICES}
    for name, s in services.items():
        if name in STUDY_SERVICES:  # not session services: test_the_study_profile_is_a_ray_cluster
            continue
        assert s["image"] == IMAGES[name], name
        assert s.get("profiles") == PROFILES.get(name), name
        assert s["stop_grace_period"] == "10s", name
        if name in BUILDS:  # each image is built by one service only, then shared by tag
            assert s["build"]["target"] == BUILDS[name]
            dockerfile = COMPOSE.parent / s["build"]["context"] / s["build"]["dockerfile"]
            assert dockerfile.resolve() == DOCKER / "Dockerfile"
            assert s["build"]["args"] == {"BASE": "python:3.11-slim"}
        else:
            assert "build" not in s, name
            assert s["pull_policy"] == "never", name
        cmd = command_of(s)
        assert cmd[0] == name, f"{name}: the image's command must start with the service name"
        if name == "router":
            assert cmd == ["router", "--listen", "tcp/0.0.0.0:7447"]
            assert s["ports"] == ["7447:7447"]
            assert s["healthcheck"]["test"] == ["CMD", "cdpr-health", "listening"]
            assert "depends_on" not in s
            continue
        assert cmd[1] == "caroca_15kg"
        assert s["depends_on"]["router"] == {"condition": "service_healthy"}, name
        assert s["healthcheck"]["test"] == ["CMD", "cdpr-health", "joined"], name
        assert cmd[cmd.index("--zenoh-mode") + 1] == "client"
        assert cmd[cmd.index("--connect") + 1] == "tcp/router:7447"
        assert cmd[cmd.index("--session") + 1] == "default"
        assert "--duration" not in cmd  # the scenario's own unless CDPR_ARGS says otherwise
    clock = command_of(services["clock"])
    assert clock[clock.index("--expect") + 1] == "sim,trajectory,controller,recorder"
    assert clock[clock.index("--join-timeout") + 1] == "120"
    assert clock[clock.index("--rejoin-timeout") + 1] == "120"
    assert clock[clock.index("--sync") + 1] == "lock"
    # `up ... clock` starts every participant with the clock and follows the clock alone.
    assert set(services["clock"]["depends_on"]) == {"router", "sim", "trajectory", "controller", "recorder"}
    rec = command_of(services["recorder"])
    assert rec[rec.index("--rrd") + 1] == "/recordings/default.rrd"
    assert services["recorder"]["volumes"] == ["../runs:/recordings"]  # runs/ of the repository, on the host
    assert "volumes" not in yaml.safe_load(COMPOSE.read_text())  # no named volume either
    env = dict(line.split("=", 1) for line in (DOCKER / ".env").read_text().splitlines()
               if line.strip() and not line.startswith("#"))
    assert env == {"COMPOSE_PROJECT_NAME": "cdpr"}
    # The settings reach every session service.
    env = {"CDPR_SCENARIO": "caroca_1kg", "CDPR_SESSION": "s1", "CDPR_ARGS": "--duration 0.5",
           "CDPR_PORT": "9000", "CDPR_JOIN_TIMEOUT": "7", "CDPR_REJOIN_TIMEOUT": "9", "CDPR_RECORDINGS": "/data/rec",
           "CDPR_BASE": "local/py", "CDPR_MODE": "realtime", "CDPR_SYNC": "free"}
    over = load_compose([COMPOSE], env)
    assert over["router"]["ports"] == ["9000:7447"]
    assert over["recorder"]["volumes"] == ["/data/rec:/recordings"]
    assert over["sim"]["build"]["args"] == {"BASE": "local/py"}
    assert command_of(over["clock"])[command_of(over["clock"]).index("--join-timeout") + 1] == "7"
    assert command_of(over["clock"])[command_of(over["clock"]).index("--rejoin-timeout") + 1] == "9"
    assert command_of(over["clock"])[command_of(over["clock"]).index("--sync") + 1] == "free"
    for name in (*SESSION_SERVICES, "controller", "ros2"):
        cmd = command_of(over[name])
        assert cmd[1] == "caroca_1kg"
        assert cmd[-2:] == ["--duration", "0.5"]
        assert cmd[cmd.index("--session") + 1] == "s1"


def test_the_study_profile_is_a_ray_cluster() -> None:
    services = load_compose([COMPOSE], {})
    head, worker, driver = (services[n] for n in STUDY_SERVICES)
    for s in (head, worker, driver):
        assert s["image"] == "cdpr:study"
        assert s["profiles"] == ["study"]
    assert head["build"]["target"] == "study"
    assert head["build"]["args"] == {"BASE": "python:3.11-slim", "RAY_VERSION": ""}
    assert worker["pull_policy"] == driver["pull_policy"] == "never"
    for s in (head, worker):
        assert s["entrypoint"] == ["ray"]
        assert command_of(s)[:2] == ["start", "--address" if s is worker else "--head"]
        assert "--block" in command_of(s)
    cmd = command_of(head)
    assert cmd[cmd.index("--num-cpus") + 1] == "0"  # the head schedules; points run on the workers
    assert cmd[cmd.index("--ray-client-server-port") + 1] == "10001"
    assert head["ports"] == ["10001:10001", "6379:6379", "8265:8265"]
    assert worker["depends_on"] == {"ray-head": {"condition": "service_healthy"}}
    assert command_of(worker)[command_of(worker).index("--address") + 1] == "ray-head:6379"
    assert driver["entrypoint"] == ["cdpr-entrypoint"]
    assert driver["environment"] == {"CDPR_OWNED_DIR": "/runs"}
    assert driver["volumes"] == ["../runs:/runs"]
    over = load_compose([COMPOSE], {"CDPR_RAY_CLIENT_PORT": "11001", "CDPR_RAY_WORKER_CPUS": "2",
                                    "CDPR_RAY_VERSION": "2.9.3", "CDPR_STUDIES": "/data/studies"})
    assert over["ray-head"]["ports"][0] == "11001:10001"
    assert over["ray-head"]["build"]["args"]["RAY_VERSION"] == "2.9.3"
    cmd = command_of(over["ray-worker"])
    assert cmd[cmd.index("--num-cpus") + 1] == "2"
    assert over["study"]["volumes"] == ["/data/studies:/runs"]


def test_secure_override_uses_tls_and_one_identity_per_service() -> None:
    plain = load_compose([COMPOSE], {})
    services = load_compose([COMPOSE, SECURE], {})
    assert command_of(services["router"]) == ["router", "--zenoh-config", "zenoh/router-secure.json5"]
    for name in (*SESSION_SERVICES, "controller", "ros2"):
        cmd = command_of(services[name])
        assert cmd[cmd.index("--connect") + 1] == "tls/router:7447"
        i = cmd.index("--zenoh-config")
        assert cmd[i + 1] == f"secrets/{name}.json5"
        # The rest is compose.yaml's command, word for word.
        assert [a.replace("tls/", "tcp/") for a in cmd[:i] + cmd[i + 2:]] == command_of(plain[name]), name
        targets = sorted(str(v).split(":")[1] for v in services[name].get("volumes", []))
        expected = ["/cdpr/secrets/ca.pem", f"/cdpr/secrets/{name}.json5"]
        assert targets == sorted(expected + (["/recordings"] if name == "recorder" else [])), name
        assert services[name]["image"] == plain[name]["image"]
    mounted = [str(v) for s in services.values() for v in s.get("volumes", [])]
    assert not any("ca.key" in v for v in mounted), "the CA key must never enter a container"
    assert all(v.startswith(("./secrets/", "./zenoh/", "../runs:")) for v in mounted), mounted
    elsewhere = load_compose([COMPOSE, SECURE], {"CDPR_SECRETS": "/etc/cdpr"})
    assert "/etc/cdpr/ca.pem:/cdpr/secrets/ca.pem:ro" in elsewhere["sim"]["volumes"]


def test_realtime_override_schedules_the_loop_and_keeps_the_commands() -> None:
    for files in ([COMPOSE], [COMPOSE, SECURE]):
        base = load_compose(files, {"CDPR_ARGS": "--duration 3"})
        rt = load_compose([*files, REALTIME], {"CDPR_ARGS": "--duration 3", "CDPR_RT_PRIORITY": "20"})
        for name, s in rt.items():
            assert command_of(s) == command_of(base[name]), name  # CDPR_ARGS and TLS survive
            if name in LOOP_SERVICES:
                assert s["entrypoint"] == ["chrt", "--fifo", "20", "cdpr"], name
                assert s["ulimits"] == {"rtprio": 99}, name
            else:
                assert s.get("entrypoint") == base[name].get("entrypoint"), name
                assert "ulimits" not in s, name
    assert load_compose([COMPOSE, REALTIME], {})["sim"]["entrypoint"][2] == "10"


COMPOSES = [pytest.param([COMPOSE_BIN], id="v1", marks=pytest.mark.skipif(COMPOSE_BIN is None, reason=NO_COMPOSE)),
            pytest.param(COMPOSE_V2, id="v2", marks=pytest.mark.skipif(
                COMPOSE_V2 is None, reason="Compose v2 (the `docker compose` plugin) is not installed"))]


@pytest.mark.parametrize("compose", COMPOSES)
@pytest.mark.parametrize("files", [[COMPOSE], [COMPOSE, SECURE], [COMPOSE, SECURE, REALTIME]],
                         ids=["plain", "secure", "secure+realtime"])
def test_docker_compose_validates_and_agrees(compose: list[str], files: list[Path], tmp_path: Path) -> None:
    env = {"CDPR_SESSION": "abc", "CDPR_ARGS": "--duration 0.5"}
    argv = list(compose)
    for f in files:
        argv += ["-f", str(f)]
    clean = {k: v for k, v in os.environ.items() if not k.startswith(("CDPR_", "COMPOSE_"))}
    proc = subprocess.run([*argv, "config"], capture_output=True, text=True, timeout=60,
                          env={**clean, **env}, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    config = yaml.safe_load(proc.stdout)
    resolved = config["services"]
    ours = load_compose(files, env)
    assert set(resolved) == set(ours)
    for name, s in resolved.items():
        assert command_of(s) == command_of(ours[name]), name
        assert s["image"] == IMAGES[name]
        assert ("build" in s) == (name in BUILDS), name
    assert resolved["router"]["ports"][0] in ("7447:7447", {"published": 7447, "target": 7447},
                                              {"mode": "ingress", "target": 7447, "published": "7447",
                                               "protocol": "tcp"})
    if "name" in config:  # Compose v2 prints the project's name: docker/.env's
        assert config["name"] == "cdpr"
    broken = tmp_path / "compose.yaml"  # and the same call rejects a file that breaks the schema
    broken.write_text("services:\n  sim:\n    image: cdpr\n    depends_on: 5\n")
    proc = subprocess.run([*compose, "-f", str(broken), "config"], capture_output=True, text=True,
                          timeout=60, env=clean)
    assert proc.returncode != 0
    assert "depends_on" in proc.stdout + proc.stderr


@pytest.mark.slow
def test_compose_commands_run_a_session_with_a_remote_controller(session_id: str, tmp_path: Path) -> None:
    env = {"CDPR_SESSION": session_id, "CDPR_ARGS": "--duration 0.5"}
    services = load_compose([COMPOSE], env)
    port = free_port()
    containers = {n: localise(n, services[n], DOCKER, tmp_path, port) for n in ("router", *SESSION_SERVICES)}
    procs = Processes()
    try:
        router = procs.run(containers["router"])
        for name in SESSION_SERVICES:
            procs.run(containers[name])
        time.sleep(1.0)
        assert router.poll() is None, procs.report()
        assert procs.procs["clock"].poll() is None  # waiting for its controller
        procs.start("remote", [sys.executable, str(EXAMPLE), "--connect", f"tcp/127.0.0.1:{port}",
                               "--session", session_id], tmp_path, tmp_path / "remote.log")
        codes = procs.wait([*SESSION_SERVICES, "remote"], timeout=180)
        assert codes == dict.fromkeys([*SESSION_SERVICES, "remote"], 0), procs.report()
        assert router.poll() is None  # the router outlives the session...
        assert procs.stop("router", signal.SIGTERM) == 0  # ...and stops cleanly
    finally:
        procs.close()
    assert "finished 500 steps" in procs.log("clock"), procs.report()
    assert re.search(r"answered \d+ states up to step 499 ", procs.log("remote")), procs.report()
    assert "clamped commands: 0" in procs.log("sim")
    rrd = tmp_path / "volumes" / "recordings" / f"{session_id}.rrd"
    assert rrd.read_bytes()[:4] == b"RRF2"
    assert rrd.stat().st_size > 10_000
    print(f"compose session through the router: {clock_rate(procs.log('clock')):.0f} steps/s")
