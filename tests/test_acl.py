"""The secure profile: `make certs`, Zenoh TLS, user/password authentication, the router's access control.

The router is the real ``cdpr router`` process with ``docker/zenoh/router-secure.json5`` and the secrets
`make certs` writes; participants authenticate with the identity files it writes. The access-control list
lets each service publish only its own keys: a session that is not the controller can put commands as much
as it likes, the router drops them before they reach anybody.
"""

from __future__ import annotations

import contextlib
import json
import queue
import re
import signal
import stat
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import msgpack
import pytest
import zenoh

from cdpr.protocol import PROTOCOL_VERSION, Command, Keys, State
from cdpr.runtime.transport import zenoh_config
from conftest import free_port
from test_compose import (
    COMPOSE,
    EXAMPLE,
    SECURE,
    SESSION_SERVICES,
    Processes,
    clock_rate,
    compose_dir_with_secrets,
    load_compose,
    localise,
)

ROOT = Path(__file__).resolve().parent.parent
USERS = ("clock", "sim", "trajectory", "controller", "recorder", "ros2", "observer", "ros2-controller")
WAIT = 20.0  # bound on any single expected delivery (never a measurement)
SETTLE = 0.5  # seconds given to a put that must NOT arrive before the control put that must


def certs(directory: Path, *extra: str) -> subprocess.CompletedProcess[str]:
    return subprocess.run(["make", "-s", "-C", str(ROOT), "certs", f"CERTS_DIR={directory}", *extra],
                          capture_output=True, text=True, timeout=60)


def openssl(*args: str) -> str:
    proc = subprocess.run(["openssl", *args], capture_output=True, text=True, timeout=30)
    assert proc.returncode == 0, proc.stderr
    return proc.stdout + proc.stderr


def test_make_certs_writes_a_ca_a_router_certificate_and_identities(tmp_path: Path) -> None:
    d = tmp_path / "secrets"
    proc = certs(d, "CERT_HOSTS=DNS:router,DNS:cdpr.example.org,IP:127.0.0.1")
    assert proc.returncode == 0, proc.stderr
    assert {p.name for p in d.iterdir()} == {".gitignore", "ca.pem", "ca.key", "router.pem", "router.key",
                                            "users.txt", *(f"{u}.json5" for u in USERS)}
    assert "OK" in openssl("verify", "-CAfile", str(d / "ca.pem"), str(d / "router.pem"))
    text = openssl("x509", "-in", str(d / "router.pem"), "-noout", "-text")
    assert re.search(r"DNS:router, DNS:cdpr\.example\.org, IP Address:127\.0\.0\.1", text)
    assert "CA:FALSE" in text
    assert "TLS Web Server Authentication" in text
    assert "CA:TRUE" in openssl("x509", "-in", str(d / "ca.pem"), "-noout", "-text")
    # One random password per user, the same in the router's dictionary and in the user's identity.
    lines = (d / "users.txt").read_text().split()
    users = dict(line.split(":") for line in lines)
    assert tuple(users) == USERS
    assert len(set(users.values())) == len(USERS)
    assert all(re.fullmatch(r"[0-9a-f]{48}", p) for p in users.values())
    for user, password in users.items():
        conf = zenoh.Config.from_file(str(d / f"{user}.json5"))
        assert json.loads(conf.get_json("transport/auth/usrpwd/user")) == user
        assert json.loads(conf.get_json("transport/auth/usrpwd/password")) == password
        assert json.loads(conf.get_json("transport/link/tls/root_ca_certificate")) == "secrets/ca.pem"
    # Private directory; the CA key readable by its owner only; nothing overwritten by a second run.
    assert stat.S_IMODE(d.stat().st_mode) == 0o700
    assert stat.S_IMODE((d / "ca.key").stat().st_mode) == 0o600
    assert (d / ".gitignore").read_text().strip() == "*"
    before = (d / "users.txt").read_bytes()
    again = certs(d)
    assert again.returncode == 0
    assert "keeping it" in again.stdout
    assert (d / "users.txt").read_bytes() == before


def test_identity_files_merge_with_the_command_line(tmp_path: Path) -> None:
    d = tmp_path / "secrets"
    assert certs(d).returncode == 0
    conf = zenoh_config("client", ["tls/10.1.2.3:7447"], (), str(d / "sim.json5"))
    assert json.loads(conf.get_json("mode")) == "client"
    assert json.loads(conf.get_json("connect/endpoints")) == ["tls/10.1.2.3:7447"]
    assert json.loads(conf.get_json("transport/auth/usrpwd/user")) == "sim"
    assert json.loads(conf.get_json("transport/link/tls/root_ca_certificate")) == "secrets/ca.pem"
    router = zenoh_config("router", (), ["tls/127.0.0.1:9"], str(ROOT / "docker/zenoh/router-secure.json5"))
    assert json.loads(router.get_json("mode")) == "router"
    assert json.loads(router.get_json("listen/endpoints")) == ["tls/127.0.0.1:9"]
    assert json.loads(router.get_json("access_control/default_permission")) == "deny"
    assert json.loads(router.get_json("transport/auth/usrpwd/dictionary_file")) == "secrets/users.txt"
    assert json.loads(router.get_json("transport/link/protocols")) == ["tls"]


# --------------------------------------------------------------------------------------------------
# A secure router, and sessions of each identity


@dataclass
class SecureRouter:
    compose_dir: Path  # holds secrets/ (the test's cwd, so that identities' relative paths resolve)
    port: int

    @property
    def endpoint(self) -> str:
        return f"tls/127.0.0.1:{self.port}"

    def config(self, user: str | None, password: str | None = None, endpoint: str | None = None,
               timeout: float = 30.0) -> zenoh.Config:
        if user is None:  # TLS only, no credentials
            conf = zenoh_config("client", [endpoint or self.endpoint], connect_timeout=timeout)
            conf.insert_json5("transport/link/tls/root_ca_certificate", json.dumps("secrets/ca.pem"))
            return conf
        conf = zenoh_config("client", [endpoint or self.endpoint], (),
                            str(self.compose_dir / "secrets" / f"{user}.json5"), connect_timeout=timeout)
        if password is not None:
            conf.insert_json5("transport/auth/usrpwd/password", json.dumps(password))
        return conf

    def open(self, user: str | None, **kw: str | float | None) -> zenoh.Session:
        return zenoh.open(self.config(user, **kw))  # type: ignore[arg-type]


@pytest.fixture(scope="module")
def secure_router(tmp_path_factory: pytest.TempPathFactory) -> Iterator[SecureRouter]:
    scratch = tmp_path_factory.mktemp("acl")
    compose_dir = compose_dir_with_secrets(scratch)
    port = free_port()
    container = localise("router", load_compose([COMPOSE, SECURE], {})["router"], compose_dir, scratch, port)
    procs = Processes()
    mp = pytest.MonkeyPatch()
    try:
        procs.run(container)
        mp.chdir(compose_dir)
        yield SecureRouter(compose_dir, port)
        assert procs.stop("router", signal.SIGTERM) == 0, procs.report()
    finally:
        mp.undo()
        procs.close()


def _refused(router: SecureRouter, user: str | None, **kw: str | float | None) -> bool:
    try:
        z = router.open(user, timeout=2.0, **kw)
    except Exception as exc:
        return "Unable to connect" in str(exc)
    z.close()
    return False


def test_only_known_users_with_their_password_get_in(secure_router: SecureRouter) -> None:
    with secure_router.open("observer"):  # the control: a valid identity connects
        pass
    assert _refused(secure_router, "controller", password="not-the-password")
    assert _refused(secure_router, None)  # TLS without credentials
    assert _refused(secure_router, "controller", endpoint=f"tcp/127.0.0.1:{secure_router.port}")  # no TLS


def _delivered(router: SecureRouter, publisher: str, key: str, owner: str) -> list[bytes]:
    """What a listener receives of ``publisher``'s puts on ``key``, sent before a put by its ``owner``."""
    got: queue.SimpleQueue[bytes] = queue.SimpleQueue()
    with router.open("observer") as listener, router.open(owner) as control:
        sub = listener.declare_subscriber(key, lambda s: got.put(s.payload.to_bytes()))
        # the subscription has reached the router once one of the owner's puts comes through
        deadline = time.monotonic() + WAIT
        while True:
            control.put(key, b"probe")
            with contextlib.suppress(queue.Empty):
                if got.get(timeout=0.1) == b"probe":
                    break
            assert time.monotonic() < deadline, f"the listener's subscription to {key} never reached the router"
        with router.open(publisher) as z:
            for i in range(5):
                z.put(key, f"{publisher}-{i}".encode())
            time.sleep(SETTLE)
        control.put(key, b"control")
        received = []
        while (item := got.get(timeout=WAIT)) != b"control":
            if item != b"probe":  # a probe still on its way
                received.append(item)
        sub.undeclare()
    return received


@pytest.mark.parametrize("intruder", ["observer", "sim", "trajectory", "clock", "recorder"])
def test_only_the_controller_may_command_the_sim(secure_router: SecureRouter, intruder: str) -> None:
    key = Keys("acl").command
    assert _delivered(secure_router, intruder, key, "controller") == []
    expected = [f"controller-{i}".encode() for i in range(5)]
    assert _delivered(secure_router, "controller", key, "controller") == expected


def test_each_service_publishes_its_own_keys_only(secure_router: SecureRouter) -> None:
    keys = Keys("acl")
    assert len(_delivered(secure_router, "sim", keys.state, "sim")) == 5
    assert _delivered(secure_router, "controller", keys.state, "sim") == []  # no faked states
    assert len(_delivered(secure_router, "clock", keys.tick, "clock")) == 5
    assert _delivered(secure_router, "sim", keys.tick, "clock") == []
    assert _delivered(secure_router, "observer", keys.stats("sim"), "sim") == []
    assert len(_delivered(secure_router, "sim", keys.stats("sim"), "sim")) == 5
    assert len(_delivered(secure_router, "controller", keys.end, "controller")) == 5  # a learning env's early end
    assert _delivered(secure_router, "observer", keys.end, "controller") == []


def test_liveliness_tokens_cannot_be_impersonated(secure_router: SecureRouter) -> None:
    keys = Keys("acl")
    with secure_router.open("observer") as mallory, secure_router.open("controller") as ctrl, \
            secure_router.open("observer") as watcher:
        fake = mallory.liveliness().declare_token(keys.alive("sim"))
        real = ctrl.liveliness().declare_token(keys.alive("controller"))
        deadline = time.monotonic() + WAIT
        while True:  # until the real token is seen (then the fake one had as long to show)
            seen = {str(r.ok.key_expr) for r in watcher.liveliness().get(keys.alive_all, timeout=5.0) if r.ok}
            if keys.alive("controller") in seen or time.monotonic() > deadline:
                break
            time.sleep(0.1)
        time.sleep(SETTLE)
        seen |= {str(r.ok.key_expr) for r in watcher.liveliness().get(keys.alive_all, timeout=5.0) if r.ok}
        fake.undeclare()
        real.undeclare()
    assert seen == {keys.alive("controller")}


# --------------------------------------------------------------------------------------------------
# A whole secure session under attack


@pytest.mark.slow
def test_secure_session_ignores_an_intruders_commands(session_id: str, tmp_path: Path,
                                                      monkeypatch: pytest.MonkeyPatch) -> None:
    compose_dir = compose_dir_with_secrets(tmp_path)
    services = load_compose([COMPOSE, SECURE], {"CDPR_SESSION": session_id, "CDPR_ARGS": "--duration 1"})
    port = free_port()
    endpoint = f"tls/127.0.0.1:{port}"
    monkeypatch.chdir(compose_dir)  # identities name secrets/ca.pem relative to the working directory
    keys = Keys(session_id)
    seen: list[bytes] = []  # every command payload that reached a listener
    final: list[int] = []
    attacks = {"observer": 0, "sim": 0}
    procs = Processes()
    try:
        for name in ("router", *SESSION_SERVICES):
            procs.run(localise(name, services[name], compose_dir, tmp_path, port))
        with zenoh.open(zenoh_config("client", [endpoint], (), "secrets/observer.json5")) as monitor, \
                zenoh.open(zenoh_config("client", [endpoint], (), "secrets/observer.json5")) as mallory, \
                zenoh.open(zenoh_config("client", [endpoint], (), "secrets/sim.json5")) as rogue_sim:
            monitor.declare_subscriber(keys.command, lambda s: seen.append(s.payload.to_bytes()))
            monitor.declare_subscriber(keys.state,
                                       lambda s: final.append(State.decode(s.payload.to_bytes()).step))

            def attack(sample: zenoh.Sample) -> None:
                """Answer every state first, pulling every cable at tmax, and add some garbage."""
                k = State.decode(sample.payload.to_bytes()).step
                for who, z in (("observer", mallory), ("sim", rogue_sim)):
                    z.put(keys.command, Command(k, k / 1000, (6500.0,) * 8, True, f"intruder-{who}").encode())
                    z.put(keys.command, msgpack.packb({"v": PROTOCOL_VERSION, "step": k, "tensions": "garbage"}))
                    attacks[who] += 2

            mallory.declare_subscriber(keys.state, attack)
            time.sleep(1.0)  # the intruders are in place before the controller joins
            procs.start("controller", [sys.executable, str(EXAMPLE), "--connect", endpoint,
                                       "--session", session_id, "--zenoh-config", "secrets/controller.json5"],
                        compose_dir, tmp_path / "controller.log")
            codes = procs.wait([*SESSION_SERVICES, "controller"], timeout=180)
            assert codes == dict.fromkeys([*SESSION_SERVICES, "controller"], 0), procs.report()
        assert procs.stop("router", signal.SIGTERM) == 0
    finally:
        procs.close()
    assert min(attacks.values()) >= 1000  # every state was attacked, by both
    commands = [Command.decode(p) for p in seen]  # no garbage got through either
    assert {c.status for c in commands} == {"optimal"}  # only the controller's commands got through
    assert sorted({c.step for c in commands}) == list(range(1000))
    assert max(final) == 1000
    sim_log = procs.log("sim")
    assert "clamped commands: 0" in sim_log, sim_log
    assert "dropped" not in sim_log, sim_log
    assert "finished 1000 steps" in procs.log("clock")
    # every state answered once; once more per repeated grant at most: a handshake repeat of tick 0, or a
    # resend after a stall on a starved machine (docs/protocol.md)
    counts = re.search(r"resends (\d+), handshake repeats (\d+)\)", procs.log("clock"))
    repeats = int(counts.group(1)) + int(counts.group(2))
    answered = int(re.search(r"answered (\d+) states up to step 999", procs.log("controller")).group(1))
    assert 1000 <= answered <= 1000 + repeats, (answered, repeats)
    rrd = tmp_path / "volumes" / "recordings" / f"{session_id}.rrd"
    assert rrd.read_bytes()[:4] == b"RRF2"
    print(f"secure session (TLS, auth, ACL) under attack: {clock_rate(procs.log('clock')):.0f} steps/s")


# --------------------------------------------------------------------------------------------------
# The access rules come from the topic tables (cdpr acl)


def test_the_shipped_router_config_is_what_cdpr_acl_writes(tmp_path: Path) -> None:
    """docker/zenoh/router-secure.json5 is `cdpr acl`'s output: a stream or node added to the tables and not to
    the file fails here (run `cdpr acl -o docker/zenoh/router-secure.json5`). Zenoh reads both configs."""
    from cdpr.tools.acl import render

    shipped = (ROOT / "docker" / "zenoh" / "router-secure.json5").read_text(encoding="utf-8")
    assert shipped == render(), "docker/zenoh/router-secure.json5 is not `cdpr acl`'s output: run it again"
    out = subprocess.run([sys.executable, "-m", "cdpr", "acl", "--sessions", "labA,labB", "-o",
                          str(tmp_path / "lab.json5")], capture_output=True, text=True, timeout=60, check=False)
    assert out.returncode == 0, out.stderr
    for path in (ROOT / "docker" / "zenoh" / "router-secure.json5", tmp_path / "lab.json5"):
        conf = zenoh.Config.from_file(str(path))
        assert json.loads(conf.get_json("access_control/default_permission")) == "deny"
    lab = json.loads(zenoh.Config.from_file(str(tmp_path / "lab.json5")).get_json("access_control/subjects"))
    assert any(s["id"] == "controller.labA" and s["usernames"] == ["controller.labA"] for s in lab)
    bad = subprocess.run([sys.executable, "-m", "cdpr", "acl", "--sessions", "lab-A"], capture_output=True,
                         text=True, timeout=60, check=False)
    assert bad.returncode == 2
    assert bad.stderr.strip().splitlines() == [
        "cdpr: error: --sessions: session 'lab-A' is not a ROS 2 name (letters, digits and single _, a letter "
        "first): its ROS 2 topics, /cdpr/<session>, need one"]


@dataclass
class LabRouter(SecureRouter):
    """A secure router whose config and identities `make certs SESSIONS=a,b` wrote: two sessions' own
    controller identities besides the services'."""

    sessions: tuple[str, str]


@pytest.fixture(scope="module")
def lab_router(tmp_path_factory: pytest.TempPathFactory) -> Iterator[LabRouter]:
    import uuid

    scratch = tmp_path_factory.mktemp("lab")
    tag = uuid.uuid4().hex[:6]
    sessions = (f"lab{tag}A", f"lab{tag}B")
    compose_dir = compose_dir_with_secrets(scratch, f"SESSIONS={','.join(sessions)}")
    port = free_port()
    procs = Processes()
    mp = pytest.MonkeyPatch()
    try:
        procs.start("router", [sys.executable, "-m", "cdpr", "router", "--zenoh-config", "secrets/router-secure.json5",
                               "--listen", f"tls/127.0.0.1:{port}", "--log-denials"], compose_dir,
                    scratch / "router.log")
        mp.chdir(compose_dir)
        router = LabRouter(compose_dir, port, sessions)
        with router.open("observer"):  # up and serving
            pass
        yield router
        assert procs.stop("router", signal.SIGTERM) == 0, procs.report()
    finally:
        mp.undo()
        procs.close()


def _allowed(identity: str, kind: str, what: tuple[str, str, str | None]) -> bool:
    """Whether the tables give ``identity`` the right to publish ``what`` — (session, topic name, node or None)
    of the wiring table for a cdpr key, (session, ROS 2 topic name, None) for a ROS 2 topic — read from the
    tables themselves (not from cdpr.tools.acl): its role's row publishes the topic (a node's own key only), or
    the ROS 2 node publishes the ROS 2 topic, or a ROS 2 controller sends the command topic; ``.S`` limits an
    identity to session S."""
    from cdpr.protocol.wiring import WIRING, wiring_of
    from cdpr.ros2.topics import COMMANDS, PUBLISHED

    role, _, scope = identity.partition(".")
    session, name, node = what
    if scope and session != scope:
        return False
    if kind == "cdpr":
        return role in WIRING and name in wiring_of(role).publishes and node in (None, role)
    if kind == "alive":
        return role in WIRING and name in (role, *WIRING[role].alive_as)
    return (role == "ros2" and name in PUBLISHED) or (role == "ros2-controller" and name in COMMANDS)


def test_no_identity_publishes_what_the_tables_do_not_give_it(lab_router: LabRouter) -> None:
    """Every identity of the lab router puts on every key the tables know — each topic of the wiring table in
    both sessions (a node's key for every node, a camera's), each ROS 2 topic in both sessions' namespaces — and
    declares every liveliness token: a listener gets exactly what the tables give that identity, in its own
    session only. The observer publishes nothing."""
    from cdpr.protocol.wiring import TOPICS, WIRING
    from cdpr.ros2.graph import data_key, qualify
    from cdpr.ros2.topics import COMMANDS, PUBLISHED, default_namespace
    from cdpr.tools.acl import identities

    a, b = lab_router.sessions
    keys: dict[str, tuple[str, tuple[str, str, str | None]]] = {}
    for s in (a, b):
        for name, topic in TOPICS.items():
            if topic.transport == "pubsub":
                for node in (WIRING if "{node}" in topic.key else (None,)):
                    key = f"cdpr/{s}/" + topic.key.replace("{node}", node or "").replace("{camera}", "top")
                    keys[key] = ("cdpr", (s, name, node))
        for role in WIRING:
            keys[Keys(s).alive(role)] = ("alive", (s, role, None))
        for name, t in {**PUBLISHED, **COMMANDS}.items():
            keys[data_key(0, qualify(default_namespace(s), t.name), t.ros_type)] = ("ros2", (s, name, None))
    got: queue.SimpleQueue[str] = queue.SimpleQueue()
    with lab_router.open("clock") as listener:  # the clock: it may answer session/info, the marker below
        # every callback on the listener's Zenoh thread (indirect=False), in the order its link brings them: one on
        # a thread of its own could run after the marker's answer
        def direct(f: Callable[[Any], None]) -> zenoh.handlers.Callback:
            return zenoh.handlers.Callback(f, indirect=False)

        subs = [listener.declare_subscriber(k, direct(lambda smp: got.put(smp.payload.to_bytes().decode())))
                for k in ("cdpr/**", "*/cdpr/**", "*/clock/**", "*/tf/**")]
        subs.append(listener.liveliness().declare_subscriber("cdpr/**", direct(
            lambda smp: got.put(f"token {smp.key_expr}") if smp.kind == zenoh.SampleKind.PUT else None)))
        marker = listener.declare_queryable(Keys(a).info, direct(lambda q: q.reply(q.key_expr, b"marker")))
        for identity in identities(lab_router.sessions):
            expected = {f"{identity}|{k}" if kind != "alive" else f"token {k}"
                        for k, (kind, what) in keys.items() if _allowed(identity, kind, what)}
            with lab_router.open(identity) as z:
                tokens = []
                for k, (kind, _) in keys.items():
                    if kind == "alive":
                        tokens.append(z.liveliness().declare_token(k))
                    else:
                        z.put(k, f"{identity}|{k}".encode())
                # a query the listener answers comes after every put and token before it (one link, in order)
                assert [r.ok.payload.to_bytes() for r in z.get(Keys(a).info, timeout=WAIT) if r.ok] == [b"marker"]
                received = set()
                while True:
                    try:
                        received.add(got.get_nowait())
                    except queue.Empty:
                        break
                for t in tokens:
                    t.undeclare()
            assert received == expected, (identity, sorted(received ^ expected))
            time.sleep(0.2)  # the undeclared tokens' goodbyes, before the next identity
            while not got.empty():
                got.get_nowait()
        marker.undeclare()
        for sub in subs:
            sub.undeclare()


def test_the_router_logs_each_denial(lab_router: LabRouter, tmp_path: Path) -> None:
    """`cdpr router --log-denials`: a put its rules drop is logged with the identity and the key."""
    a, _ = lab_router.sessions
    key = Keys(a).command
    with lab_router.open("observer") as z:
        z.put(key, b"not yours")
    log = lab_router.compose_dir.parent / "router.log"
    deadline = time.monotonic() + WAIT
    pattern = re.compile(rf"Username\(observer\).*is unauthorized to Put \(ingress\) on {re.escape(key)}")
    while not pattern.search(log.read_text(errors="replace")):
        assert time.monotonic() < deadline, log.read_text(errors="replace")[-2000:]
        time.sleep(0.05)


# --------------------------------------------------------------------------------------------------
# Every feature through the secure profile: whole sessions, each service with its own identity as
# docker/compose.secure.yaml runs them (local processes, tests/test_compose.localise)


class SecureSession:
    """docker/compose.yaml + compose.secure.yaml's services for one session, as processes on this machine,
    behind the secure router; ``env``: the compose variables (CDPR_SCENARIO, CDPR_ARGS …)."""

    def __init__(self, tmp: Path, session_id: str, names: tuple[str, ...], later: tuple[str, ...] = (),
                 **env: str) -> None:
        self.tmp, self.sid = tmp, session_id
        self.later = later  # services not started on entering (:meth:`restart` starts them)
        self.compose_dir = compose_dir_with_secrets(tmp)
        services = load_compose([COMPOSE, SECURE], {"CDPR_SESSION": session_id, **env})
        self.port = free_port()
        self.endpoint = f"tls/127.0.0.1:{self.port}"
        self.containers = {n: localise(n, services[n], self.compose_dir, tmp, self.port) for n in ("router", *names)}
        self.procs = Processes()

    def __enter__(self) -> SecureSession:
        for name, c in self.containers.items():
            if name not in self.later:
                self.procs.run(c)
        return self

    def __exit__(self, *exc: object) -> None:
        self.procs.close()

    def open(self, user: str) -> zenoh.Session:
        return zenoh.open(zenoh_config("client", [self.endpoint], (), str(self.compose_dir / "secrets" /
                                                                           f"{user}.json5")))

    def restart(self, name: str, as_name: str) -> None:
        """``name`` again, as compose's restart policy would: the same command in the same container."""
        c = self.containers[name]
        self.procs.start(as_name, c.argv, c.cwd, self.tmp / f"{as_name}.log")

    def finish(self, names: tuple[str, ...], timeout: float = 300.0) -> None:
        codes = self.procs.wait(list(names), timeout=timeout)
        assert codes == dict.fromkeys(names, 0), self.procs.report()

    def recording(self) -> Path:
        return self.tmp / "volumes" / "recordings" / f"{self.sid}.rrd"


def _progress(z: zenoh.Session, keys: Keys) -> list[int]:
    """The newest step of the sim's telemetry, kept up to date in the list's one item."""
    from cdpr.protocol import Telemetry

    newest = [-1]

    def on_block(sample: zenoh.Sample) -> None:
        newest[0] = max(newest[0], max(st.step for st in Telemetry.decode(sample.payload.to_bytes()).states))

    z.declare_subscriber(keys.telemetry, on_block)
    return newest


@pytest.mark.slow
def test_a_secure_ibvs_session_carries_cameras_ping_a_sim_restart_and_the_recording(
        session_id: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch, ibvs_in_process: tuple[dict, str]) -> None:
    """caroca_15kg_ibvs under TLS, passwords and the generated access rules: the controller servoes from the
    sim's camera frames, `cdpr ping` answers for every node, a sim SIGKILLed mid-way and started again goes on
    from the session's snapshot, the recorder writes the whole session — and the states are those of the same
    session without the secure profile, bit for bit (the test session's in-process run)."""
    from cdpr.protocol.wiring import WIRING
    from cdpr.tools.report import read_recording, summarize

    names = ("clock", "sim", "trajectory", "recorder", "controller")
    # every node is pinged while the session is held, whatever the machine's speed: the others while the clock
    # waits for the recorder to join (started last), the recorder while the clock waits for the killed sim
    with SecureSession(tmp_path, session_id, names, later=("recorder",), CDPR_SCENARIO="caroca_15kg_ibvs",
                       CDPR_ARGS="", CDPR_JOIN_TIMEOUT="600", CDPR_REJOIN_TIMEOUT="600") as s:
        monkeypatch.chdir(s.compose_dir)  # identities name secrets/ca.pem relative to the working directory

        def ping(node: str) -> None:
            ping = subprocess.run([sys.executable, "-m", "cdpr", "ping", "--session", session_id, "--connect",
                                   s.endpoint, "--zenoh-config", "secrets/observer.json5", "--node", node,
                                   "--count", "3", "--wait", "300"],  # a node just started: waited for
                                  capture_output=True, text=True, timeout=400, check=False)
            assert ping.returncode == 0, (node, ping.stderr[-2000:])
            assert json.loads(ping.stdout.strip().splitlines()[-1])["answered"] == 3, node

        held = [n for n in WIRING if n in names and n != "recorder"]
        assert held == ["clock", "sim", "trajectory", "controller"]
        for node in held:
            ping(node)
        with s.open("observer") as z:
            newest = _progress(z, Keys(session_id))
            s.restart("recorder", "recorder")  # the last one: the session starts
            deadline = time.monotonic() + 300
            while newest[0] < 3000:
                assert time.monotonic() < deadline, s.procs.report()
                time.sleep(0.05)
            s.procs.stop("sim", signal.SIGKILL)
            ping("recorder")
            s.restart("sim", "sim-again")
            s.finish(("clock", "sim-again", "trajectory", "recorder", "controller"))
        assert "joined a session under way: going on from step" in s.procs.log("sim-again")
        assert "has not come" not in s.procs.log("controller")  # every frame it waited for came
        assert "finished 12000 steps" in s.procs.log("clock"), s.procs.report()
        summary = summarize(read_recording(s.recording()))
    assert summary["recorded_states"] == 12001
    assert summary["state_digest"] == ibvs_in_process[0]["state_digest"]


@pytest.mark.slow
def test_a_ros2_controller_drives_a_secure_session_to_the_end(session_id: str, tmp_path: Path,
                                                              monkeypatch: pytest.MonkeyPatch,
                                                              sdk_env: dict[str, str]) -> None:
    """caroca_15kg with the ros2 node (its own identity) and a zenoh-ros2-sdk controller with the ROS 2
    controller's identity, given as rmw_zenoh is given one (docs/security.md: ZENOH_SESSION_CONFIG_URI, and
    ZENOH_CONFIG_OVERRIDE for the router's address): the whole trajectory, every state answered."""
    from cdpr.ros2.topics import default_namespace
    from cdpr.tools.bench import ros2_controller
    from cdpr.tools.report import read_recording, summarize

    names = ("clock", "sim", "trajectory", "recorder", "ros2")
    with SecureSession(tmp_path, session_id, names) as s:
        monkeypatch.chdir(s.compose_dir)
        env = {**sdk_env, "ZENOH_SESSION_CONFIG_URI": str(s.compose_dir / "secrets" / "ros2-controller.json5"),
               "ZENOH_CONFIG_OVERRIDE": f'connect/endpoints=["{s.endpoint}"]'}
        ctl = s.procs.start("ros2-controller", [sys.executable, ros2_controller.__file__, "--namespace",
                                                default_namespace(session_id)], s.compose_dir,
                            tmp_path / "ros2-controller.log", env=env)
        s.finish(("clock", "sim", "trajectory", "recorder"))
        ctl.send_signal(signal.SIGTERM)
        s.finish(("ros2", "ros2-controller"), timeout=60)
        assert "finished 11000 steps" in s.procs.log("clock"), s.procs.report()
        applied = re.search(r"applied (\d+) ROS 2 commands", s.procs.log("ros2"))
        assert applied, s.procs.report()
        assert int(applied.group(1)) >= 11000
        summary = summarize(read_recording(s.recording()))
    assert summary["recorded_states"] == 11001
    assert summary["rms_position_error"] <= 1e-3


@pytest.mark.slow
def test_a_gymnasium_episode_in_a_secure_session(session_id: str, tmp_path: Path,
                                                 monkeypatch: pytest.MonkeyPatch) -> None:
    """The Gymnasium environment in session mode, as the session's controller with the controller's identity:
    an episode to its end."""
    import numpy as np

    from cdpr.gym.env import TrackEnv

    names = ("clock", "sim", "trajectory", "recorder")
    with SecureSession(tmp_path, session_id, names, CDPR_ARGS="--duration 0.3") as s:
        monkeypatch.chdir(s.compose_dir)
        env = TrackEnv(duration=0.3, connect=s.endpoint, session=session_id,
                       zenoh_config="secrets/controller.json5", session_timeout=120.0)
        try:
            env.reset(seed=0)
            steps, done = 0, False
            while not done:
                _, _, terminated, truncated, _ = env.step(np.zeros(env.action_space.shape, np.float32))
                steps, done = steps + 1, terminated or truncated
        finally:
            env.close()
        s.finish(names)
        assert "finished 300 steps" in s.procs.log("clock"), s.procs.report()
    assert steps == 30  # 10 sim steps per environment step


@pytest.mark.slow
def test_one_group_cannot_move_another_groups_platform(lab_router: LabRouter, tmp_path: Path) -> None:
    """Two sessions through one router, each driven by the example controller with its own session's identity;
    group A's controller identity commands group B's session at every state, pulling every cable at tmax: the
    router drops it, and both sessions give the same states (the same scenario, the same law)."""
    from cdpr.protocol import Command, Telemetry

    a, b = lab_router.sessions
    procs = Processes()
    attacks = [0]
    states: dict[str, dict[int, State]] = {a: {}, b: {}}

    def keep(session: str) -> object:
        def on_block(sample: zenoh.Sample) -> None:
            for st in Telemetry.decode(sample.payload.to_bytes()).states:
                states[session].setdefault(st.step, st)
        return on_block

    try:
        for s in (a, b):
            for node in ("clock", "sim", "trajectory"):
                extra = ["--expect", "sim,trajectory,controller"] if node == "clock" else []
                procs.start(f"{node}-{s}", [sys.executable, "-m", "cdpr", node, "caroca_15kg", "--session", s,
                                            "--duration", "1", "--zenoh-mode", "client", "--connect",
                                            lab_router.endpoint, "--zenoh-config", f"secrets/{node}.json5", *extra],
                            lab_router.compose_dir, tmp_path / f"{node}-{s}.log")
        with lab_router.open(f"controller.{a}") as mallory, lab_router.open("observer") as watcher:
            blocks = [watcher.declare_subscriber(Keys(s).telemetry, keep(s)) for s in (a, b)]

            def attack(sample: zenoh.Sample) -> None:
                k = State.decode(sample.payload.to_bytes()).step
                mallory.put(Keys(b).command, Command(k, k / 1000, (6500.0,) * 8, True, "intruder").encode())
                attacks[0] += 1

            watch = mallory.declare_subscriber(Keys(b).state, attack)
            for s in (a, b):
                procs.start(f"controller-{s}", [sys.executable, str(EXAMPLE), "--connect", lab_router.endpoint,
                                                "--session", s, "--zenoh-config", f"secrets/controller.{s}.json5"],
                            lab_router.compose_dir, tmp_path / f"controller-{s}.log")
            names = [f"{n}-{s}" for s in (a, b) for n in ("clock", "sim", "trajectory", "controller")]
            codes = procs.wait(names, timeout=180)
            assert codes == dict.fromkeys(names, 0), procs.report()
            deadline = time.monotonic() + WAIT  # the last blocks on their way to the watcher (all sent by now)
            while min(len(states[a]), len(states[b])) < 1001 and time.monotonic() < deadline:
                time.sleep(0.05)
            watch.undeclare()
            for sub in blocks:
                sub.undeclare()
    finally:
        procs.close()
    assert attacks[0] >= 1000  # every state of B was attacked
    assert sorted(states[b]) == list(range(1001))
    assert states[a] == states[b]  # bit for bit: A's identity moved nothing in B
    finished = {s: re.search(r"finished 1000 steps", procs.log(f"clock-{s}")) for s in (a, b)}
    assert all(finished.values()), procs.report()
    assert "clamped commands: 0" in procs.log(f"sim-{b}")
    answered = {s: re.search(r"answered (\d+) states up to step 999", procs.log(f"controller-{s}")) for s in (a, b)}
    assert all(answered.values()), procs.report()
