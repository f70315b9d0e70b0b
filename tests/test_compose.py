"""docker/: the Dockerfile and the compose deployment, checked without a Docker engine.

``docker-compose config`` validates the files (Debian's docker-compose 1.29 needs no engine). Then the
compose file is read like compose reads it (``${VAR:-default}`` interpolation, YAML merge keys, override
files) and each service's exact command is started as a local process, in a directory that holds only
what compose would mount into its container, with the ``router`` host mapped to 127.0.0.1 and a free
port: a real session runs end to end through the router with the example remote controller.
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

from conftest import free_port

ROOT = Path(__file__).resolve().parent.parent
DOCKER = ROOT / "docker"
COMPOSE = DOCKER / "compose.yaml"
SECURE = DOCKER / "compose.secure.yaml"
EXAMPLE = ROOT / "examples" / "remote_controller.py"
SESSION_SERVICES = ("clock", "sim", "trajectory", "recorder")
ROUTER_PORT = 7447
COMPOSE_BIN = shutil.which("docker-compose")
NO_COMPOSE = "the docker-compose binary is absent (apt-get install -y --no-install-recommends docker-compose)"

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

    The image's entrypoint is ``cdpr`` and its working directory ``/cdpr``: the process gets
    ``python -m cdpr`` and a directory of its own standing for /cdpr, in which only the files compose
    bind-mounts under /cdpr appear (sources relative to ``compose_dir``). Named volumes become
    directories under ``scratch/volumes``. ``router:7447`` becomes ``127.0.0.1:port``, and the router
    listens on that loopback port only.
    """
    workdir = scratch / "containers" / name
    workdir.mkdir(parents=True)
    mounts: dict[str, Path] = {}
    for spec in service.get("volumes", []):
        source, target = str(spec).split(":")[:2]
        if source.startswith((".", "/")):
            host = (compose_dir / source).resolve()
            assert host.exists(), f"{name}: mounts {source}, which does not exist"
        else:
            host = scratch / "volumes" / source
            host.mkdir(parents=True, exist_ok=True)
        if target.startswith("/cdpr/"):
            inside = workdir / target.removeprefix("/cdpr/")
            inside.parent.mkdir(parents=True, exist_ok=True)
            inside.symlink_to(host)
        else:
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

    def start(self, name: str, argv: Sequence[str], cwd: Path, log: Path) -> subprocess.Popen[bytes]:
        f = log.open("wb")
        self._files.append(f)
        self.logs[name] = log
        p = subprocess.Popen(list(argv), cwd=cwd, stdout=f, stderr=subprocess.STDOUT)
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


def compose_dir_with_secrets(scratch: Path) -> Path:
    """A stand-in for docker/ with fresh secrets from `make certs` and the repository's zenoh/ configs."""
    d = scratch / "compose"
    d.mkdir()
    (d / "zenoh").symlink_to(DOCKER / "zenoh")
    proc = subprocess.run(["make", "-s", "-C", str(ROOT), "certs", f"CERTS_DIR={d / 'secrets'}"],
                          capture_output=True, text=True, timeout=60)
    assert proc.returncode == 0, proc.stderr
    return d


def clock_rate(log: str) -> float:
    m = re.search(r"finished (\d+) steps in [\d.]+ s \((\d+) steps/s", log)
    assert m, log[-2000:]
    return float(m.group(2))


# --------------------------------------------------------------------------------------------------


def test_dockerfile_builds_one_image_for_every_service() -> None:
    text = (DOCKER / "Dockerfile").read_text()
    lines = [ln.strip() for ln in text.splitlines() if ln.strip() and not ln.lstrip().startswith("#")]
    assert lines[0] == "FROM python:3.11-slim"
    assert any(ln.startswith("RUN pip install .") for ln in lines)
    assert 'ENTRYPOINT ["cdpr"]' in lines
    assert "WORKDIR /cdpr" in lines
    assert "USER cdpr" in lines
    copied = [ln.split()[1] for ln in lines if ln.startswith("COPY")]
    assert copied == ["pyproject.toml", "shared", "services"]
    for path in ("pyproject.toml", "README.md", "shared", "services"):
        assert (ROOT / path).exists()
    ignore = (DOCKER / "Dockerfile.dockerignore").read_text().split()
    assert "**" in ignore
    assert {"!shared/**", "!services/**", "!pyproject.toml"} <= set(ignore)


def test_compose_services_are_complete() -> None:
    services = load_compose([COMPOSE], {})
    assert set(services) == {"router", *SESSION_SERVICES, "controller"}
    for name, s in services.items():
        assert s["image"] == "cdpr:latest", name
        dockerfile = COMPOSE.parent / s["build"]["context"] / s["build"]["dockerfile"]
        assert dockerfile.resolve() == DOCKER / "Dockerfile"
        cmd = command_of(s)
        assert cmd[0] == name, f"{name}: the image's command must start with the service name"
        if name == "router":
            assert cmd == ["router", "--listen", "tcp/0.0.0.0:7447"]
            assert s["ports"] == ["7447:7447"]
            assert "depends_on" not in s
            continue
        assert cmd[1] == "caroca_15kg"
        assert s["depends_on"] == ["router"]
        assert cmd[cmd.index("--zenoh-mode") + 1] == "client"
        assert cmd[cmd.index("--connect") + 1] == "tcp/router:7447"
        assert cmd[cmd.index("--session") + 1] == "default"
        assert "--duration" not in cmd  # the scenario's own unless CDPR_ARGS says otherwise
    assert command_of(services["clock"])[command_of(services["clock"]).index("--expect") + 1] == \
        "sim,trajectory,controller,recorder"
    rec = command_of(services["recorder"])
    assert rec[rec.index("--rrd") + 1] == "/recordings/default.rrd"
    assert services["recorder"]["volumes"] == ["recordings:/recordings"]
    assert services["controller"]["profiles"] == ["controller"]
    assert all("profiles" not in services[n] for n in ("router", *SESSION_SERVICES))
    assert "recordings" in yaml.safe_load(COMPOSE.read_text())["volumes"]
    # The settings reach every session service.
    env = {"CDPR_SCENARIO": "caroca_1kg", "CDPR_SESSION": "s1", "CDPR_ARGS": "--duration 0.5",
           "CDPR_PORT": "9000"}
    over = load_compose([COMPOSE], env)
    assert over["router"]["ports"] == ["9000:7447"]
    for name in (*SESSION_SERVICES, "controller"):
        cmd = command_of(over[name])
        assert cmd[1] == "caroca_1kg"
        assert cmd[-2:] == ["--duration", "0.5"]
        assert cmd[cmd.index("--session") + 1] == "s1"


def test_secure_override_uses_tls_and_one_identity_per_service() -> None:
    services = load_compose([COMPOSE, SECURE], {})
    assert command_of(services["router"]) == ["router", "--zenoh-config", "zenoh/router-secure.json5"]
    for name in (*SESSION_SERVICES, "controller"):
        cmd = command_of(services[name])
        assert cmd[cmd.index("--connect") + 1] == "tls/router:7447"
        assert cmd[cmd.index("--zenoh-config") + 1] == f"secrets/{name}.json5"
        targets = sorted(str(v).split(":")[1] for v in services[name].get("volumes", []))
        expected = ["/cdpr/secrets/ca.pem", f"/cdpr/secrets/{name}.json5"]
        assert targets == sorted(expected + (["/recordings"] if name == "recorder" else [])), name
    mounted = [str(v) for s in services.values() for v in s.get("volumes", [])]
    assert not any("ca.key" in v for v in mounted), "the CA key must never enter a container"


@pytest.mark.skipif(COMPOSE_BIN is None, reason=NO_COMPOSE)
@pytest.mark.parametrize("files", [[COMPOSE], [COMPOSE, SECURE]], ids=["plain", "secure"])
def test_docker_compose_validates_and_agrees(files: list[Path], tmp_path: Path) -> None:
    env = {"CDPR_SESSION": "abc", "CDPR_ARGS": "--duration 0.5"}
    argv = [str(COMPOSE_BIN)]
    for f in files:
        argv += ["-f", str(f)]
    clean = {k: v for k, v in os.environ.items() if not k.startswith(("CDPR_", "COMPOSE_"))}
    proc = subprocess.run([*argv, "config"], capture_output=True, text=True, timeout=60,
                          env={**clean, **env}, cwd=ROOT)
    assert proc.returncode == 0, proc.stderr
    resolved = yaml.safe_load(proc.stdout)["services"]
    ours = load_compose(files, env)
    assert set(resolved) == set(ours)
    for name, s in resolved.items():
        assert command_of(s) == command_of(ours[name]), name
        assert s["image"] == "cdpr:latest"
    assert resolved["router"]["ports"][0] in ("7447:7447", {"published": 7447, "target": 7447})
    broken = tmp_path / "compose.yaml"  # and the same call rejects a file that breaks the schema
    broken.write_text("services:\n  sim:\n    image: cdpr\n    depends_on: 5\n")
    proc = subprocess.run([str(COMPOSE_BIN), "-f", str(broken), "config"], capture_output=True, text=True,
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
    assert "answered 500 states up to step 499" in procs.log("remote"), procs.report()
    assert "clamped commands: 0" in procs.log("sim")
    rrd = tmp_path / "volumes" / "recordings" / f"{session_id}.rrd"
    assert rrd.read_bytes()[:4] == b"RRF2"
    assert rrd.stat().st_size > 10_000
    print(f"compose session through the router: {clock_rate(procs.log('clock')):.0f} steps/s")
