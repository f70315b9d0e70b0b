"""The loop's fast paths give what the reference code gives: the controller's set-up-once feedback law
and wrench matrix, the LAPACK tension distribution, the quaternion and clamping shortcuts, the
protocol's fast decoding, and the service dispatcher that runs handlers on Zenoh's thread."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import msgpack
import numpy as np
import pytest
import zenoh
from scipy.spatial.transform import Rotation

from cdpr.config.robot import load_robot, shipped_robots
from cdpr.mechanics.control import FeedbackLaw, Gains, controlled_rows, feedback_linearisation
from cdpr.mechanics.kinematics import WrenchMatrix, inverse_kinematics
from cdpr.mechanics.rotation import matrices_to_quats, matrix_to_quat, quat_to_matrix
from cdpr.mechanics.tda import make_tda
from cdpr.protocol import PROTOCOL_VERSION, Command, ProtocolError, State
from cdpr.runtime.service import Node, _Dispatcher
from cdpr.runtime.transport import Event, Inbox, StopFlag, zenoh_config
from cdpr_sim.core import clamp_tensions
from conftest import free_port


def _random_pose(rng: np.random.Generator) -> tuple[float, ...]:
    q = rng.standard_normal(4)
    return (*rng.uniform(-1.0, 1.0, 3), *(q / np.linalg.norm(q)))


@pytest.mark.parametrize("variant", ["6dof", "3dof"])
@pytest.mark.parametrize("name", shipped_robots())
def test_feedback_law_is_feedback_linearisation(name: str, variant: str) -> None:
    robot = load_robot(name)
    rng = np.random.default_rng(7)
    gains = Gains.of(rng.uniform(0.0, 2000.0, 6), rng.uniform(0.0, 2000.0, 6))
    law = FeedbackLaw(robot, gains, variant)  # type: ignore[arg-type]
    for i in range(200):
        pose = _random_pose(rng)
        if i % 4 == 0:
            pose_d = (*pose[:3], *(-np.array(pose[3:])))  # the same rotation: no orientation error
        elif i % 4 == 1:  # a rotation by almost π away from the measured one
            turn = Rotation.from_rotvec([0.0, 0.0, np.pi - 1e-3])
            q = (turn * Rotation.from_quat(pose[3:])).as_quat()
            pose_d = (*rng.uniform(-1.0, 1.0, 3), *q)
        else:
            pose_d = _random_pose(rng)
        twist, twist_d, accel_d = (tuple(rng.standard_normal(6)) for _ in range(3))
        position, R, wrench = law(pose, twist, pose_d, twist_d, accel_d)
        ref = feedback_linearisation(robot, pose[:3], quat_to_matrix(pose[3:]), twist, pose_d[:3],
                                     quat_to_matrix(pose_d[3:]), twist_d, accel_d, gains, variant)  # type: ignore[arg-type]
        assert wrench.shape == ref.shape == (len(controlled_rows(robot, variant)),)  # type: ignore[arg-type]
        np.testing.assert_allclose(wrench, ref, rtol=1e-11, atol=1e-9 * (1.0 + np.abs(ref).max()))
        np.testing.assert_allclose(R, quat_to_matrix(pose[3:]), rtol=0, atol=1e-15)
        assert position.tolist() == list(pose[:3])


@pytest.mark.parametrize("name", shipped_robots())
def test_wrench_matrix_is_bit_identical_to_inverse_kinematics(name: str) -> None:
    robot = load_robot(name)
    rng = np.random.default_rng(3)
    W = WrenchMatrix(robot)
    for _ in range(50):
        p = robot.home_position + rng.uniform(-0.3, 0.3, 3)
        R = Rotation.from_rotvec(rng.uniform(-0.3, 0.3, 3)).as_matrix()
        assert np.array_equal(W(p, R), inverse_kinematics(robot, p, R).wrench_matrix)


def test_matrix_to_quat_against_scipy_on_every_branch() -> None:
    rng = np.random.default_rng(11)
    rotations = [Rotation.random(random_state=rng) for _ in range(300)]
    # the four branches of Shepperd's method: trace > 0, and the largest diagonal term x, y or z
    rotations += [Rotation.from_rotvec(np.pi * axis) for axis in np.eye(3)]
    rotations += [Rotation.from_rotvec(0.999 * np.pi * axis) for axis in np.eye(3)]
    for rot in rotations:
        got = matrix_to_quat(rot.as_matrix())
        want = rot.as_quat()  # [x, y, z, w]
        want = want if want[3] > 0 or (want[3] == 0 and got @ want > 0) else -want
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-14)
        assert got[3] >= 0.0
        assert abs(np.linalg.norm(got) - 1.0) < 1e-15
    # the block version: each matrix's quaternion bit for bit, whatever its branch and its neighbours'
    matrices = np.array([rot.as_matrix() for rot in rotations])
    np.testing.assert_array_equal(matrices_to_quats(matrices), [matrix_to_quat(R) for R in matrices])
    few = matrices[::-1][:5]
    np.testing.assert_array_equal(matrices_to_quats(few), [matrix_to_quat(R) for R in few])


def test_clamp_tensions_fast_path_matches_the_formula() -> None:
    rng = np.random.default_rng(5)
    for _ in range(500):
        f = rng.uniform(-50.0, 150.0, 8) if rng.random() < 0.5 else rng.uniform(0.0, 100.0, 8)
        applied, low, high = clamp_tensions(f, 100.0)
        assert np.array_equal(applied, np.minimum(np.maximum(f, 0.0), 100.0))
        assert (low, high) == (int((f < 0).sum()), int((f > 100.0).sum()))
        assert applied is not f
    inf = np.array([1.0, np.inf, -np.inf])
    assert clamp_tensions(inf, 10.0)[0].tolist() == [1.0, 10.0, 0.0]
    with pytest.raises(ValueError, match="NaN"):
        clamp_tensions(np.array([1.0, np.nan]), 10.0)
    with pytest.raises(ValueError, match="NaN"):  # inf + (−inf) = NaN in the sum, and a real NaN too
        clamp_tensions(np.array([np.inf, -np.inf, np.nan]), 10.0)


def test_vector_fast_path_keeps_the_checks() -> None:
    def command(tensions: object) -> bytes:
        return msgpack.packb({"v": PROTOCOL_VERSION, "step": 1, "t": 0.001, "tensions": tensions})

    assert Command.decode(command([1.5, 2.5])).tensions == (1.5, 2.5)
    assert Command.decode(command([1, 2.5])).tensions == (1.0, 2.5)  # integers are numbers too
    assert Command.decode(command([1e308, 1e308])).tensions == (1e308, 1e308)  # the sum overflows
    assert Command.decode(command([])).tensions == ()
    for bad, message in [
        ([1.0, float("inf")], r"^tensions\[1\]: must be finite"),
        ([float("-inf"), float("inf")], r"^tensions\[0\]: must be finite"),
        ([True, 1.0], r"^tensions\[0\]: expected a number, got bool"),
        ([1.0, "2"], r"^tensions\[1\]: expected a number, got str"),
    ]:
        with pytest.raises(ProtocolError, match=message):
            Command.decode(command(bad))
    with pytest.raises(ProtocolError, match=r"^tensions: expected 3 numbers, got 2"):
        Command.decode(command([1.0, 2.0]), cables=3)
    state = State(2, 0.002, (0.0,) * 7, (0.0,) * 6, (1.0,) * 4, (2.0,) * 4)
    assert State.decode(state.encode(), 4) == state


def test_tda_scalar_bounds_fast_path_equals_array_bounds() -> None:
    robot = load_robot("caroca").with_mass(15.0)
    rng = np.random.default_rng(2)
    fast, slow = make_tda("qp"), make_tda("qp")
    for _ in range(100):
        p = robot.home_position + rng.uniform(-0.2, 0.2, 3)
        W = inverse_kinematics(robot, p, np.eye(3)).wrench_matrix
        w = np.r_[0.0, 0.0, 15.0 * 9.81, 0.0, 0.0, 0.0] + rng.uniform(-5.0, 5.0, 6)
        a = fast.solve(W, w, 1.0, 6500.0)
        b = slow.solve(W, w, np.full(8, 1.0), np.full(8, 6500.0))
        assert np.array_equal(a.tensions, b.tensions)
        assert a.status == b.status == "optimal"
    bad = fast.solve(np.full((6, 8), np.nan), np.zeros(6), 1.0, 6500.0)
    assert bad.status == "invalid_input"
    assert not bad.feasible
    with pytest.raises(ValueError, match="tmin must not exceed tmax"):
        fast.solve(W, w, 10.0, 1.0)
    with pytest.raises(ValueError, match="finite"):
        fast.solve(W, w, 1.0, float("inf"))


class _Recorder(Node):
    name = "recorder"
    direct = True

    def __init__(self) -> None:
        super().__init__(keys=None)  # type: ignore[arg-type]
        self.seen: list[str] = []
        self.idles = 0
        self.deliver: _Dispatcher | None = None

    def handle(self, event: Event) -> None:
        self.seen.append(event.key)
        if event.key == "first" and self.deliver is not None:
            self.deliver(Event("x", b"", "nested", 0.0))  # e.g. our own publication, delivered at once
            self.seen.append("after nested")
        if event.key == "boom":
            raise RuntimeError("boom")

    def idle(self, now: float) -> None:
        self.idles += 1


def test_dispatcher_defers_reentrant_events_and_keeps_the_first_error() -> None:
    node, wake, stop = _Recorder(), threading.Event(), StopFlag()
    dispatch = _Dispatcher(node, node.handle, wake, stop)
    node.deliver = dispatch
    dispatch(Event("x", b"", "first", 0.0))
    assert node.seen == ["first", "after nested", "nested"]  # not nested inside the first handler
    assert node.idles == 1
    assert not wake.is_set()
    node.done = True
    dispatch(Event("x", b"", "last", 0.0))
    assert wake.is_set()  # the main thread must notice the end
    node.done = False
    dispatch(Event("x", b"", "boom", 0.0))
    assert isinstance(dispatch.error, RuntimeError)
    assert dispatch.closed
    dispatch(Event("x", b"", "ignored", 0.0))
    assert "ignored" not in node.seen


class _Echo(_Recorder):
    """Publishes once from idle() to a key of its own process (as the clock's status does)."""

    def idle(self, now: float) -> None:
        super().idle(now)
        if self.idles == 1 and self.deliver is not None:
            self.deliver(Event("x", b"", "from idle", 0.0))


def test_dispatcher_handles_what_idle_published_and_nothing_after_a_signal() -> None:
    node, wake, stop = _Echo(), threading.Event(), StopFlag()
    dispatch = _Dispatcher(node, node.handle, wake, stop)
    node.deliver = dispatch
    dispatch(Event("x", b"", "a", 0.0))
    assert node.seen == ["a", "from idle"]
    assert node.idles == 2
    woken = threading.Event()
    stop.on_set(woken.set)
    stop.set()  # what SIGINT/SIGTERM do
    assert woken.is_set()
    dispatch(Event("x", b"", "after the signal", 0.0))
    assert node.seen == ["a", "from idle"]


class _Chatty(_Recorder):
    """Publishes to its own process from every idle() (as the clock's status does); on the second, the stop
    signal comes (as SIGTERM to a paused clock did, in the middle of a handler)."""

    stop: StopFlag | None = None

    def idle(self, now: float) -> None:
        super().idle(now)
        if self.idles == 2 and self.stop is not None:
            self.stop.set()
        if self.deliver is not None and self.idles < 1000:
            self.deliver(Event("x", b"", "status", 0.0))


def test_a_signal_in_the_middle_of_a_handler_ends_it_though_idle_keeps_publishing() -> None:
    """The events queued after a signal are not handled; the handler must then not go on calling idle() until
    they are (it held the dispatcher's lock for ever, and the main thread, closing, waited for it)."""
    node, stop = _Chatty(), StopFlag()
    dispatch = _Dispatcher(node, node.handle, threading.Event(), stop)
    node.deliver, node.stop = dispatch, stop
    worker = threading.Thread(target=dispatch, args=(Event("x", b"", "first", 0.0),), daemon=True)
    worker.start()
    worker.join(30.0)
    assert not worker.is_alive(), f"the handler is still running after {node.idles} idle() calls"
    assert node.idles == 2
    dispatch.close()  # the main thread's close takes the lock: not held any more


def test_inbox_handler_runs_on_zenohs_thread_message_after_message() -> None:
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    threads: list[str] = []
    got: list[bytes] = []
    done = threading.Event()

    def handler(event: Event) -> None:
        threads.append(type(threading.current_thread()).__name__)
        got.append(event.payload)
        if len(got) == 50:
            done.set()

    with zenoh.open(zenoh_config("peer", listen=[endpoint])) as a, \
            zenoh.open(zenoh_config("peer", connect=[endpoint])) as b:
        sub = Inbox(handler).subscribe(a, "test/fast/inbox", "x")
        pub = b.declare_publisher("test/fast/inbox")
        deadline = time.monotonic() + 20.0  # a peer drops puts for which it knows no subscriber yet
        while not pub.matching_status.matching:
            assert time.monotonic() < deadline, "the publisher never learned of the subscriber"
            time.sleep(0.01)
        for i in range(50):
            pub.put(bytes([i]))
        assert done.wait(10.0)
        sub.undeclare()
    assert got == [bytes([i]) for i in range(50)]
    # a thread Python did not start (Zenoh's own): the binding's indirect mode would show a "Thread"
    assert set(threads) == {"_DummyThread"}


def test_an_ordered_inbox_queues_two_topics_in_the_order_they_were_put() -> None:
    """A queued node that asks for order (the recorder: ``Node.ordered``) sees two topics of one publisher in the
    order they were put, big payloads among small ones (Zenoh keeps a session's order per priority; the queue is
    filled by Zenoh's own receive thread, not by one binding thread per subscriber)."""
    from cdpr.runtime.transport import PUBLISH_OPTS

    endpoint = f"tcp/127.0.0.1:{free_port()}"
    inbox = Inbox(direct=True)
    sent: list[tuple[str, int]] = []
    with zenoh.open(zenoh_config("peer", listen=[endpoint])) as a, \
            zenoh.open(zenoh_config("peer", connect=[endpoint])) as b:
        subs = [inbox.subscribe(a, f"test/fast/ordered/{name}", name) for name in ("image", "telemetry")]
        pubs = {"image": b.declare_publisher("test/fast/ordered/image", **{**PUBLISH_OPTS, "express": False}),
                "telemetry": b.declare_publisher("test/fast/ordered/telemetry", **PUBLISH_OPTS)}
        deadline = time.monotonic() + 20.0  # a peer drops puts for which it knows no subscriber yet
        while not all(p.matching_status.matching for p in pubs.values()):
            assert time.monotonic() < deadline, "the publishers never learned of the subscribers"
            time.sleep(0.01)
        for i in range(200):
            topic = "image" if i % 3 == 0 else "telemetry"
            pubs[topic].put(i.to_bytes(4, "little") * (5000 if topic == "image" else 10))
            sent.append((topic, i))
        got: list[tuple[str, int]] = []
        deadline = time.monotonic() + 20.0  # bounded: every message is on its way
        while len(got) < len(sent) and time.monotonic() < deadline:
            got += [(e.topic, int.from_bytes(e.payload[:4], "little")) for e in inbox.drain(0.5)]
        for sub in subs:
            sub.undeclare()
    assert got == sent


_STORM = """
import os, signal, sys, threading, time
from cdpr.runtime.transport import Inbox, StopFlag
inbox, stop = Inbox(), StopFlag().install()
if sys.argv[1] == "wake":
    stop.on_set(inbox.wake)
signal.signal(signal.SIGUSR2, lambda *_: sum(range(200_000)))  # a handler that takes a few ms
def storm():
    while True:
        time.sleep(0.037)
        os.kill(os.getpid(), signal.SIGUSR2)
threading.Thread(target=storm, daemon=True).start()
print("ready", flush=True)
while not stop:
    for _ in inbox.drain(0.1):
        pass
print("stopped", flush=True)
"""


@pytest.mark.parametrize("wake", ["wake", "no-wake"])
def test_a_stop_signal_ends_the_inbox_wait_also_amid_other_signals(wake: str) -> None:
    """CPython 3.11's ``SimpleQueue.get(timeout=…)`` interrupted by a signal whose handler returns can wait
    for the next item with no timeout at all: a queued service waiting for messages that no longer come
    (the recorder after the loop stopped) then ignored SIGTERM. ``Inbox.wake`` (which ``serve`` hooks to
    the stop flag) ends the wait. Without it the same process is usually seen stuck (the bug is still there);
    that case skips, naming the reason, on a run where the race did not show."""
    proc = subprocess.Popen([sys.executable, "-c", _STORM, wake], stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout is not None
        assert proc.stdout.readline() == "ready\n"
        time.sleep(1.0)  # ~27 signals: the wait is stuck after the first few (without the wake)
        proc.send_signal(signal.SIGTERM)
        try:
            out, _ = proc.communicate(timeout=5.0)
            stopped = "stopped" in out
        except subprocess.TimeoutExpired:
            stopped = False
    finally:
        proc.kill()
        proc.wait()
    if wake == "wake":
        assert stopped
    elif stopped:
        # The hang is a race inside CPython: it shows on most runs, not on all. When it did not show, this
        # run says nothing about the need for Inbox.wake (the case above still checked the fix).
        pytest.skip("the CPython hang did not show in this run (a race outside the project)")
    # else: the process without the wake ignored SIGTERM — the bug that Inbox.wake works around is there


class _Blocking(_Recorder):
    """Its handler of ``hold`` waits until the test lets it go (a handler busy on another thread)."""

    def __init__(self) -> None:
        super().__init__()
        self.entered, self.release = threading.Event(), threading.Event()

    def handle(self, event: Event) -> None:
        if event.key == "hold":
            self.entered.set()
            assert self.release.wait(30.0)
        super().handle(event)


def test_a_thread_never_waits_for_another_threads_handler_and_no_event_is_stranded() -> None:
    """A delivery that finds another thread inside a handler leaves its event to that thread and returns at
    once: Zenoh's receiving thread goes on receiving."""
    node = _Blocking()
    dispatch = _Dispatcher(node, node.handle, threading.Event(), StopFlag())
    busy = threading.Thread(target=dispatch, args=(Event("x", b"", "hold", 0.0),), daemon=True)
    busy.start()
    assert node.entered.wait(30.0)
    returned = threading.Event()
    other = threading.Thread(target=lambda: (dispatch(Event("x", b"", "meanwhile", 0.0)), returned.set()),
                             daemon=True)
    other.start()
    assert returned.wait(30.0), "a delivery waited for another thread's handler"
    assert node.seen == []  # not handled yet: left to the busy thread
    node.release.set()
    busy.join(30.0)
    assert not busy.is_alive()
    assert node.seen == ["hold", "meanwhile"]  # in order, by the thread that was inside
    node.done = True
    dispatch(Event("x", b"", "after the end", 0.0))  # returns (nothing more is handled), and says so
    assert node.seen == ["hold", "meanwhile"]


def test_shared_memory_is_off_unless_a_config_file_says_otherwise(tmp_path: Path) -> None:
    """Zenoh's shared-memory transport set itself up at a process's second large put (~5 ms of the sim's loop in
    a realtime session): the services' own config turns it off; a user's JSON5 config file keeps its choice."""
    import json

    assert json.loads(zenoh_config("peer", listen=["tcp/127.0.0.1:0"]).get_json("transport/shared_memory/enabled")) \
        is False
    assert json.loads(zenoh_config("client", connect=["tcp/127.0.0.1:7447"]).get_json(
        "transport/shared_memory/enabled")) is False
    path = tmp_path / "zenoh.json5"
    path.write_text("{ transport: { shared_memory: { enabled: true } } }", encoding="utf-8")
    assert json.loads(zenoh_config("peer", config_file=str(path)).get_json("transport/shared_memory/enabled")) is True
