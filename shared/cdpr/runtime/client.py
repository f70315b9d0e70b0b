"""The remote-controller SDK: write ``(state, setpoint) -> tensions``, then call ``run``.

A controller that joins a cdpr session from anywhere (another process, another machine) only has to
map the platform's state and the trajectory's setpoint of a step to cable tensions::

    from cdpr.runtime.client import controller

    @controller
    def hold(state, setpoint, info):          # the third parameter is optional
        ...                                   # state, setpoint: cdpr.protocol.State / Setpoint
        return tensions                       # m numbers, or a cdpr.mechanics.tda.TdaResult

    hold.run(connect="tcp/192.168.1.10:7447", session="default")

or subclass :class:`RemoteController` and override :meth:`~RemoteController.step` (and
:meth:`~RemoteController.setup`, called once with the session's :class:`SessionInfo`).

``run`` does everything docs/protocol.md asks of a controller: it fetches ``session/info`` (robot
geometry and mass, dt, gains — retried until the session's clock answers), subscribes to the state
and setpoint streams, then holds the liveliness token ``alive/controller``; it answers state k once
setpoint k is there, exactly once, and again when the same state comes again (the clock asked for a
resend); it returns on ``clock/status`` finished (exit code 0) or aborted (1), on SIGINT/SIGTERM
(128 + signal), or when nothing was heard for ``idle_timeout`` seconds (1).

Reconnection: ``run`` opens a Zenoh *client* session. Zenoh keeps retrying the endpoints (30 s at
start, so the controller may be started before the router) and, once connected, re-establishes a lost
link by itself and declares the subscribers and the token again; the clock then sees the controller
come back and repeats the ticks of the unfinished step. So a restarted router costs a pause, not the
session (tests/test_remote.py restarts one in the middle of a run).
"""

from __future__ import annotations

import argparse
import inspect
import sys
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any, NoReturn

import numpy as np
import zenoh

from cdpr.errors import InputError
from cdpr.protocol import CameraFrame, Command, Keys, Setpoint, State, Status
from cdpr.protocol.pairing import Pairing
from cdpr.protocol.session import SessionInfo
from cdpr.runtime.feedback import SensorFeedback
from cdpr.runtime.service import Node, pair, pair_sensors, serve
from cdpr.runtime.transport import Event, Inbox, RateLimitedLog, StopFlag, log, may_be_denied, zenoh_config

INFO_RETRY = 0.5  # seconds between two `get`s of session/info while no clock answers


# --------------------------------------------------------------------------------------------------
# session/info


def fetch_info(session: zenoh.Session, keys: Keys, stop: StopFlag | None = None,
               timeout: float | None = None, who: str = "controller") -> SessionInfo | None:
    """``get`` ``session/info`` until the clock answers; None if ``stop`` is set or ``timeout`` passes.

    Raises :class:`ProtocolError` if the answer is not a valid description of a session.
    """
    deadline = None if timeout is None else time.monotonic() + timeout
    waited = False
    while not stop:
        for reply in session.get(keys.info, timeout=2.0):
            if reply.ok is not None:
                return SessionInfo.from_payload(reply.ok.payload.to_bytes())
        if deadline is not None and time.monotonic() >= deadline:
            return None
        if not waited:
            log(who, f"waiting for session {keys.session!r} to answer {keys.info} (if it runs: "
                f"{may_be_denied(keys.info)})")
            waited = True
        time.sleep(INFO_RETRY)
    return None


# --------------------------------------------------------------------------------------------------
# The controller


@dataclass
class RunReport:
    """What :meth:`RemoteController.run` did."""

    exit_code: int  # 0 finished, 1 aborted / idle timeout / no session/info, 128 + signal
    answered: int = 0  # commands published (repeats included)
    last_step: int = -1  # highest step answered
    status: Status | None = None  # the clock's last word (finished / aborted), if heard
    info: SessionInfo | None = None
    first_answer: float | None = None  # time.monotonic() of the first and last command
    last_answer: float | None = None

    @property
    def rate(self) -> float:
        """Commands per second of wall time between the first and the last one."""
        if self.first_answer is None or self.last_answer is None or self.last_answer <= self.first_answer:
            return 0.0
        return (self.answered - 1) / (self.last_answer - self.first_answer)


class RemoteController:
    """Base class of a remote controller: override :meth:`step` (and :meth:`setup`), call :meth:`run`."""

    name = "controller"  # the liveliness token this controller holds: cdpr/{session}/alive/{name}
    info: SessionInfo | None = None

    def setup(self, info: SessionInfo | None) -> None:
        """Called once before the first step with the session's info (None if not fetched)."""
        self.info = info

    def step(self, state: State, setpoint: Setpoint) -> Any:
        """Tensions for step ``state.step``: m numbers, or an object with ``.tensions`` (a TdaResult)."""
        raise NotImplementedError

    def on_camera(self, frame: CameraFrame) -> None:
        """Each frame of the session's cameras (``sim/camera/<name>``: the markers' pixels and depths), as it
        arrives, on the thread that calls :meth:`step` (no lock needed). The cameras themselves (intrinsics,
        mount, markers) are ``info.cameras``. A frame goes out ``latency`` steps after its exposure
        (``frame.step``): the state of that later step may come just before or just after it. Override it to
        servo from a camera (examples/remote_ibvs.py); by default frames are not even decoded."""

    def run(
        self,
        connect: str | Sequence[str] = (),
        session: str = "default",
        *,
        zenoh_config_file: str | None = None,
        mode: str = "client",
        fetch_session_info: bool = True,
        info_timeout: float | None = None,
        idle_timeout: float | None = None,
        handle_signals: bool = True,
        stop: StopFlag | None = None,
        feedback: str = "state",
    ) -> RunReport:
        """Join session ``session`` through the Zenoh endpoint(s) ``connect`` and answer it to the end.

        ``zenoh_config_file`` is a Zenoh JSON5 file (TLS, user/password...) merged with ``connect`` and
        ``mode`` (also read from ``$ZENOH_CONFIG``). ``info_timeout`` bounds the wait for
        ``session/info``; ``idle_timeout`` ends the run when nothing at all is heard for that long (the
        clock publishes its status every second). SIGINT/SIGTERM stop it cleanly when
        ``handle_signals`` (main thread only); ``stop`` is an alternative, caller-owned flag. ``feedback``:
        ``state`` (:meth:`step` gets ``sim/state``, the truth) or ``sensors`` (it gets an estimate from
        ``sim/sensors``: the winch encoders through forward kinematics fused with the IMU,
        :class:`cdpr.runtime.feedback.SensorFeedback`, as the session's own controller does with
        ``controller.feedback: sensors``; the controller never subscribes to ``sim/state``).
        """
        if feedback not in ("state", "sensors"):
            raise InputError(f"feedback: expected state or sensors, got {feedback!r}")
        endpoints = [connect] if isinstance(connect, str) else list(connect)
        try:
            keys = Keys(session)
        except ValueError as exc:
            raise InputError(f"session: {exc}") from None
        conf = zenoh_config(mode, endpoints, (), zenoh_config_file)
        flag = stop if stop is not None else StopFlag()
        if handle_signals:
            flag.install()
        if feedback == "sensors" and not fetch_session_info:
            raise InputError("feedback: sensors needs the session's info (its robot and sensors): fetch_session_info")
        node = _ControllerNode(self, keys, flag, fetch_session_info, info_timeout, idle_timeout, feedback)
        code = serve(node, conf, flag)
        node.report.exit_code = code
        return node.report

    def main(self, argv: Sequence[str] | None = None) -> NoReturn:
        """``run`` with the usual command-line options (``--connect``, ``--session``...), then exit."""
        doc = (type(self).__doc__ or self.__doc__ or "").strip()
        parser = argparse.ArgumentParser(description=doc.splitlines()[0] if doc else None)
        parser.add_argument("--connect", action="append", default=[],
                            help="Zenoh endpoint of the session's router (default tcp/127.0.0.1:7447)")
        parser.add_argument("--session", default="default", help="session id (default: default)")
        parser.add_argument("--zenoh-config", default=None,
                            help="Zenoh JSON5 config file (TLS, user/password), merged with --connect")
        parser.add_argument("--zenoh-mode", choices=("client", "peer"), default="client")
        parser.add_argument("--idle-timeout", type=float, default=None,
                            help="give up after this many seconds without hearing from the session")
        parser.add_argument("--feedback", choices=("state", "sensors"), default="state",
                            help="what step() gets: sim/state (the truth), or an estimate from sim/sensors (the "
                            "winch encoders and the IMU: docs/laws.md)")
        args = parser.parse_args(argv)
        try:
            report = self.run(args.connect or ["tcp/127.0.0.1:7447"], args.session,
                              zenoh_config_file=args.zenoh_config, mode=args.zenoh_mode,
                              idle_timeout=args.idle_timeout, feedback=args.feedback)
        except InputError as exc:
            sys.stderr.write(f"cdpr: error: {exc}\n")
            sys.exit(2)
        sys.exit(report.exit_code)


class FunctionController(RemoteController):
    """A :class:`RemoteController` around a function ``(state, setpoint[, info]) -> tensions``."""

    def __init__(self, fn: Callable[..., Any]) -> None:
        self.fn = fn
        params = [p for p in inspect.signature(fn).parameters.values()
                  if p.kind in (p.POSITIONAL_ONLY, p.POSITIONAL_OR_KEYWORD)]
        if len(params) not in (2, 3):
            raise TypeError(f"{fn.__name__}: a controller takes (state, setpoint) or (state, setpoint, info)")
        self.wants_info = len(params) == 3
        self.__doc__ = fn.__doc__

    def step(self, state: State, setpoint: Setpoint) -> Any:
        if self.wants_info:
            return self.fn(state, setpoint, self.info)
        return self.fn(state, setpoint)

    def __call__(self, *args: Any) -> Any:
        return self.fn(*args)


def controller(fn: Callable[..., Any]) -> FunctionController:
    """Decorator: the function ``(state, setpoint[, info]) -> tensions`` becomes a runnable controller."""
    return FunctionController(fn)


class _ControllerNode(Node):
    """The controller's side of the protocol, around a user's :class:`RemoteController`."""

    name = "controller"  # its topics are the controller's row of the wiring table (state and setpoints are
    #                      declared before session/info is fetched: queued until then)
    keep_last = ("state",)  # behind (a slow step, a stall), it answers the newest state: docs/realtime.md

    def __init__(self, ctrl: RemoteController, keys: Keys, stop: StopFlag, fetch: bool,
                 info_timeout: float | None, idle_timeout: float | None, feedback: str = "state") -> None:
        super().__init__(keys)
        self.name = ctrl.name
        self.ctrl = ctrl
        self.stop = stop
        self.fetch = fetch
        self.info_timeout = info_timeout
        self.idle_timeout = idle_timeout
        self.m: int | None = None
        self.pairing = Pairing()
        self.report = RunReport(exit_code=0)
        self.last_heard = time.monotonic()
        self.warn = RateLimitedLog(self.name)
        self._pub: zenoh.Publisher | None = None
        self.wants_frames = type(ctrl).on_camera is not RemoteController.on_camera
        if not self.wants_frames:
            self.leave_out("camera")
        self.feedback: SensorFeedback | None = None  # feedback from the sensors: made once session/info is in
        self.from_sensors = feedback == "sensors"
        self.leave_out("state" if self.from_sensors else "sensors")
        if self.from_sensors:
            self.keep_last = ("sensors",)  # behind, it answers the newest reading (the estimator predicts the gap)

    def declare(self, session: zenoh.Session, inbox: Inbox) -> list[Any]:
        info = None
        if self.fetch:
            info = fetch_info(session, self.keys, self.stop, self.info_timeout, self.name)
            if info is None:
                if not self.stop:
                    log(self.name, f"no answer on {self.keys.info} within {self.info_timeout:g} s")
                    self.exit_code = 1
                self.done = True
                return []
            self.m = info.robot.m
            log(self.name, f"joined session {self.keys.session!r}: {info.scenario}, robot {info.robot.name} "
                f"({self.m} cables, {info.robot.mass:g} kg), dt {info.dt:g} s, {info.total_steps} steps")
        self.report.info = info
        if self.from_sensors:
            assert info is not None
            try:
                self.feedback = SensorFeedback.from_info(info)
            except InputError as exc:
                log(self.name, str(exc))
                self.exit_code = 2
                self.done = True
                return []
        self.ctrl.setup(info)
        self._pub = self.publishers["command"]
        self.last_heard = time.monotonic()
        return []

    def on_status(self, status: Status) -> None:
        self.last_heard = time.monotonic()
        super().on_status(status)
        if status.state in ("finished", "aborted"):
            self.report.status = status
            if status.state == "aborted":
                self.exit_code = 1

    def handle(self, event: Event) -> None:
        self.last_heard = event.received
        if event.topic == "camera":
            if self.wants_frames and (frame := self.decode(event)) is not None:
                self.ctrl.on_camera(frame)
        elif event.topic == "sensors":
            if self.feedback is not None and (due := pair_sensors(self, self.pairing, self.feedback, event,
                                                                  self.m)) is not None:
                self.answer(*due)
        elif (due := pair(self, self.pairing, event, self.m)) is not None:
            self.answer(*due)

    def answer(self, state: State, setpoint: Setpoint) -> None:
        result = self.ctrl.step(state, setpoint)
        tensions = np.asarray(getattr(result, "tensions", result), dtype=float).reshape(-1)
        m = self.m if self.m is not None else len(state.cable_lengths)
        if tensions.shape != (m,) or not np.all(np.isfinite(tensions)):
            raise ValueError(f"step {state.step}: the controller must return {m} finite tensions, "
                             f"got {tensions!r}")
        feasible = bool(getattr(result, "feasible", True))
        status = str(getattr(result, "status", "ok"))
        assert self._pub is not None
        estimate = None if self.feedback is None else (*state.pose, *state.twist)  # what it answered: recorded
        self._pub.put(Command(state.step, state.t, tuple(tensions.tolist()), feasible, status, None, None,
                              estimate).encode())
        now = time.monotonic()
        r = self.report
        r.answered += 1
        r.first_answer = now if r.first_answer is None else r.first_answer
        r.last_answer = now
        r.last_step = max(r.last_step, state.step)
        self.pairing.done(state.step)

    def idle(self, now: float) -> None:
        if self.idle_timeout is not None and now - self.last_heard > self.idle_timeout:
            log(self.name, f"nothing heard from session {self.keys.session!r} "
                f"for {self.idle_timeout:g} s; giving up")
            self.exit_code = 1
            self.done = True

    def close(self) -> None:
        r = self.report
        if r.answered:
            log(self.name, f"answered {r.answered} states up to step {r.last_step} ({r.rate:.0f} steps/s)")

