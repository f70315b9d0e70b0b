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
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

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
