"""The sim node: a Zenoh shell around :class:`cdpr_sim.core.PlatformSim`.

Step k is integrated only when the clock has granted it (a ``clock/tick`` whose window covers k) and a
valid command k has arrived; the state k+1 goes out on ``sim/state`` right after. The first state of a
grant goes out when the grant arrives; a tick marked ``resend`` publishes the current state again (how
the clock asks for one). Every state, the command applied with it and the sensor readings also go into
``sim/telemetry``, in blocks of :data:`TELEMETRY_EVERY` steps, at the end, and when the clock asks for a
report (``flush``, ``resend``); a slow loop sends one at least every :data:`TELEMETRY_PERIOD` seconds (the
clock takes a long silence for a stall). Bad commands are dropped with a one-line log; out-of-range tensions are
clamped to [0, tmax] and counted.

Realtime (ticks marked ``paced``; docs/realtime.md): the sim keeps the wall clock. Step k is due at its
deadline, ``dt`` apart from the first paced grant (from the grant that ends a wait for one: a pause; and,
in lock-step, from a ``resend`` tick: after a stall the deadlines restart, no burst to catch up). In
lock-step a command that comes before its step's deadline waits for it (on the thread that received it:
the sim expects nothing else before that step), one that comes after it acts at once; each step's lateness
(the start of its integration after its deadline) goes into the telemetry.

Two variations, both through :mod:`cdpr_sim.hold`:

* a scenario ``sim.command_latency`` (lock-step): step k still waits for command k, then applies the newest
  command whose delayed step has come (free-running, the modelled latency adds to the link's);
* free-running realtime (ticks marked ``free`` too): the sim no longer waits for commands. It integrates each
  granted step at its deadline with the newest command it holds, or its watchdog policy.
"""

from __future__ import annotations

import time
from concurrent.futures import Future, ThreadPoolExecutor
from typing import Any

import numpy as np
import zenoh
from msgspec.structs import replace

from cdpr.config.scenario import Scenario
from cdpr.mechanics.camera import Camera
from cdpr.mechanics.rotation import quat_matrix
from cdpr.protocol import (
    TELEMETRY_EVERY,
    TELEMETRY_PERIOD,
    CameraImage,
    Command,
    Keys,
    Resume,
    Sensors,
    State,
    Telemetry,
    Tick,
)
from cdpr.runtime.service import Node, sleep_precisely
from cdpr.runtime.transport import PUBLISH_OPTS, Event, Inbox, log
from cdpr_sim.cameras import CameraSuite
from cdpr_sim.hold import Applied, CommandHold, LatencyModel, StaticPolicy
from cdpr_sim.models import make_sim
from cdpr_sim.render import RenderProcess
from cdpr_sim.sensors import SensorSuite


class SimNode(Node):
    name = "sim"
    direct = True  # handled on Zenoh's receive thread: no hand-off between a message and its answer

    make_core = staticmethod(make_sim)  # the model: .step(values), .message(clamped) (sim/state), .state()

    @classmethod
    def make_sensors(cls, scenario: Scenario) -> SensorSuite | None:
        """The scenario's sensors (``sim.sensors``; None without), to ``read(model)`` once per step."""
        spec = scenario.spec.sim.sensors
        return None if spec is None else SensorSuite(spec, scenario.robot, scenario.dt)

    def __init__(self, scenario: Scenario, keys: Keys) -> None:
        super().__init__(keys)
        self.scenario = scenario
        self.total_steps = scenario.total_steps
        self.sim = make_sim(scenario)
        self.m = scenario.robot.m
        self.allowed = -1  # the last step granted by the clock
        self.flush_at = -1  # a report is due once this step is integrated (-1: none asked)
        self.published_step = -1
        self.published_at = 0.0  # monotonic time the current state went out
        self.pending: Command | None = None  # a valid command for the current step, waiting for its tick
        self.clamped = 0
        self.last_command: Command | None = None  # the command of the last step taken
        self._pub: zenoh.Publisher | None = None
        self.command_kind = scenario.output  # "tensions" or "lengths": the commands this sim takes
        sensors = scenario.spec.sim.sensors
        self.sensors = self.make_sensors(scenario)
        self._sensors_pub: zenoh.Publisher | None = None
        seed = 0 if sensors is None else sensors.seed
        self.cameras = CameraSuite(scenario.cameras, seed) if scenario.cameras else None
        self._camera_pubs: dict[str, zenoh.Publisher] = {}
        # images (cameras with image: true): drawn and encoded in a process of their own, handed over by a thread
        drawn = tuple(c for c in scenario.cameras if c.image)
        self.renderer = RenderProcess(drawn, scenario.robot) if drawn else None
        self._image_pubs: dict[str, zenoh.Publisher] = {}
        self._images = ThreadPoolExecutor(1, thread_name_prefix="camera-images") if drawn else None
        self._image_busy: Future[None] | None = None
        self._images_in_background = False
        self._telemetry_pub: zenoh.Publisher | None = None
        self.flushed_at = time.monotonic()
        self.block_states: list[State] = []
        self.block_commands: list[Command] = []
        self.block_lags: list[float] = []
        self.block_sensors: list[Sensors] = []
        self.block_lateness: list[float] = []
        self._state_msg: State | None = None
        # what acts on each step when commands may be late (cdpr_sim.hold): None in plain lock-step
        spec = scenario.spec.sim
        self.watchdog = spec.watchdog
        self.latency = None if spec.command_latency is None else LatencyModel(spec.command_latency)
        self.hold: CommandHold[Command] | None = None if self.latency is None else self._new_hold()
        self.static = StaticPolicy(scenario.robot, scenario.variant, spec.watchdog.decay, scenario.output)
        if self.latency is not None and scenario.output == "tensions":
            self.static.warm_up()  # the first steps, before a command acts
        self.applied: Applied[Command] | None = None  # what acted on the last step (free, latency)
        self.watchdog_active = False
        self.paced = False  # realtime: set by the first paced (or free) tick
        self.free = False  # free-running realtime: set by the first free tick
        self.base: float | None = None  # paced: the wall time (monotonic) at which step base_step is due
        self.base_step = 0

    def _new_hold(self) -> CommandHold[Command]:
        return CommandHold(self.watchdog.steps(self.scenario.dt))

    def declare(self, session: zenoh.Session, inbox: Inbox) -> list[Any]:
        self._pub, self._telemetry_pub = self.publishers["state"], self.publishers["telemetry"]
        self._sensors_pub = self.publishers["sensors"]
        for cam in self.scenario.cameras:  # one key per camera: sim/camera/<name>
            # a frame is an IBVS controller's input of a step: reliable, never dropped, express (as the state)
            self._camera_pubs[cam.name] = session.declare_publisher(self.keys.topic("camera", cam.name),
                                                                    **PUBLISH_OPTS)
            if cam.image:
                # reliable, never dropped, in the lane of the sim's telemetry (not express: no need): an image put
                # before the session's last state reaches the recorder before that state does (Zenoh keeps the
                # order within a priority, and the recorder queues its topics in that order: Node.ordered; an image on
                # a lower priority could come after the session's end)
                self._image_pubs[cam.name] = session.declare_publisher(self.keys.topic("camera_image", cam.name),
                                                                       **{**PUBLISH_OPTS, "express": False})
        if self.renderer is not None and (reason := self.renderer.ready()):  # before the sim says it is there
            self.warn("camera_image", f"no camera images in this session: {reason}")
        return [*self._camera_pubs.values(), *self._image_pubs.values()]

    def handle(self, event: Event) -> None:
        if event.topic == "tick":
            if (tick := self.decode(event)) is not None:
                self.on_tick(tick)
        elif event.topic == "resume":
            if (resume := self.decode(event)) is not None:
                self.on_resume(resume)
        elif (cmd := self.decode(event, self.m, self.command_kind)) is not None:
            self.on_command(cmd)

    # -- the step logic ---------------------------------------------------------------------------
    @property
    def step(self) -> int:
        return self.sim.step_count

    def publish_state(self, again: bool = False) -> None:
        """State k on sim/state (and its sensor readings); the first time, into the telemetry block too."""
        assert self._pub is not None
        if again and self._state_msg is not None and self._state_msg.step == self.step:
            msg = self._state_msg
        else:
            msg = self.sim.message(self.clamped)
            if (applied := self.applied) is not None and (applied.age or applied.watchdog):
                msg = replace(msg, command_age=applied.age, watchdog=int(applied.watchdog))
            self._state_msg = msg
        camera_pose = None
        if self.published_step != self.step and self.cameras is not None and self.cameras.due(self.step):
            # the frames delivered at step k go out before state k: a controller that waits for its frame (IBVS)
            # takes state k again as a frame lost, so the state must never come first — not even from a sim
            # killed between the two and started again, which sends state k again
            camera_pose = (msg.pose[:3], quat_matrix(*msg.pose[3:]))
            for frame in self.cameras.step(self.step, msg.t, *camera_pose):
                self._camera_pubs[frame.camera].put(frame.encode())
        self._pub.put(msg.encode())
        self.published_at = time.monotonic()
        if self.published_step == self.step:
            if self.sensors is not None and self._sensors_pub is not None:  # a repeated state: its readings too
                self._sensors_pub.put(self.sensors.read(self.sim).encode())  # (the same reading: read once per step)
            return
        self.published_step = self.step
        self.block_states.append(msg)
        if self.sensors is not None:
            reading = self.sensors.read(self.sim)
            self.block_sensors.append(reading)
            if self._sensors_pub is not None:  # for an estimator or a monitor (Zenoh drops it if nobody listens)
                self._sensors_pub.put(reading.encode())
        if camera_pose is not None:
            due = [c for c in self.scenario.cameras if c.image and self.step % c.every == 0]
            if due:
                self.take_images(due, self.step, msg.t, np.array(camera_pose[0]), camera_pose[1])
        if self.step >= self.total_steps:
            self.images_out()  # the last state's images too, before the last telemetry block

    def take_images(self, cameras: list[Camera], step: int, t: float, position: np.ndarray,
                    rotation: np.ndarray) -> None:
        """Draw and send these cameras' images of step ``step`` on the image thread, while the loop goes on.
        Realtime, the loop never waits for it: while the previous images are still being drawn, these are
        skipped (counted in ``camera_images_skipped``). Fast mode has no deadline: every image is drawn, the
        loop waiting for the previous ones (if not done yet) before it hands these over."""
        assert self._images is not None
        if self._image_busy is not None and not self._image_busy.done():
            if self.paced:
                self.count("camera_images_skipped")
                return
            self._image_busy.result()
        self._image_busy = self._images.submit(self._draw_images, cameras, step, t, position, rotation)

    def images_out(self) -> None:
        """Fast mode: the images in hand, the last state's included, are out before the session's last telemetry
        block (and so before its end: the recorder queues its topics in the order they came)."""
        if self._image_busy is not None and not self.paced:
            self._image_busy.result()

    def _draw_images(self, cameras: list[Camera], step: int, t: float, position: np.ndarray,
                     rotation: np.ndarray) -> None:
        assert self.renderer is not None
        if self.paced and not self._images_in_background:
            self._images_in_background = True
            self.renderer.background()  # realtime: the loop's deadlines before the images
        for cam in cameras:
            try:
                data = self.renderer.image(cam.name, position, rotation)
            except Exception as exc:  # an image is never worth the session: counted, said once, skipped
                self.count("camera_image_errors")
                self.warn("camera_image", f"camera {cam.name}: no image of step {step}: {exc}")
                continue
            k = cam.intrinsics
            self._image_pubs[cam.name].put(CameraImage(cam.name, step, t, k.width, k.height, "jpeg", data).encode())

    def flush(self) -> None:
        """Send the telemetry block (with the current state again if nothing is new: a heartbeat)."""
        assert self._telemetry_pub is not None
        if not self.block_states and self._state_msg is not None:
            self.block_states.append(self._state_msg)
        self._telemetry_pub.put(Telemetry(tuple(self.block_states), tuple(self.block_commands),
                                          tuple(self.block_lags), tuple(self.block_sensors),
                                          tuple(self.block_lateness), self.snapshot()).encode())
        self.block_states, self.block_commands, self.block_lags, self.block_sensors = [], [], [], []
        self.block_lateness = []
        self.flushed_at = time.monotonic()

    # -- restarting: go on from the session's last snapshot (docs/faults.md) ------------------------
    def snapshot(self) -> Resume | None:
        """What a sim that replaces this one needs to go on from the current state (None before it is out)."""
        if self.published_step != self.step:
            return None
        snapshot = self.sim.snapshot()
        snapshot["clamped"] = self.clamped
        snapshot.update({"sensors_previous": None} if self.sensors is None else self.sensors.snapshot())
        if self.cameras is not None:
            snapshot.update(self.cameras.snapshot())
        return Resume(self.step, self.scenario.spec.sim.cable_model, snapshot)

    def on_resume(self, resume: Resume) -> None:
        """A session under way (this sim joined it late): take up its last snapshot, before anything is out."""
        if self.published_step >= 0 or resume.step == self.step:
            return  # this sim has its own state (a reconnection), or nothing to take up
        model = self.scenario.spec.sim.cable_model
        try:
            if resume.model != model:
                raise ValueError(f"it is of cable model {resume.model}, this sim's is {model}")
            if resume.snapshot.get("step") != resume.step:
                raise ValueError("its step and its snapshot's differ")
            self.sim.restore(resume.snapshot)
            self.clamped = int(resume.snapshot.get("clamped", 0))
            if self.sensors is not None:
                self.sensors.restore(resume.snapshot)
            if self.cameras is not None:
                self.cameras.restore(resume.snapshot)
        except (ValueError, TypeError, IndexError) as exc:
            self.sim = make_sim(self.scenario)  # from the start: the clock sees a state that goes back, says so
            self.count("bad_resume")
            log(self.name, f"cannot go on from the session's step {resume.step}: {exc}")
            return
        log(self.name, f"joined a session under way: going on from step {self.step} (its last snapshot)")

    def on_tick(self, tick: Tick) -> None:
        if self.published_step < 0 and tick.step != self.step:
            # A sim that joins a session already under way announces where it is (step 0): the clock
            # sees the step go back and ends the session, since this sim's state is not the session's.
            self.publish_state()
            self.flush()
            return
        if (tick.paced or tick.free) and not self.paced:
            self.paced = True
        if tick.free and not self.free:
            self.free = True
            if self.hold is None:
                self.hold = self._new_hold()
            if self.command_kind == "tensions":
                self.static.warm_up()  # before the deadlines start
            if self.last_command is not None:  # the handshake's step, taken in lock-step
                self.hold.offer(self.last_command, self.last_command.step, self.step - 1)
        if self.paced and ((tick.until > self.allowed and (self.base is None or self.step > self.allowed))
                           or (tick.resend and not self.free and tick.until >= self.step)):
            # the first paced grant, one that ends a wait for a grant (a pause), or (lock-step) a grant repeated
            # after a stall or a pause: the deadlines start now
            self.base, self.base_step = time.monotonic(), self.step
        if tick.until > self.allowed:
            self.allowed = tick.until
        if tick.flush:
            self.flush_at = max(self.flush_at, tick.until)
        if tick.resend:
            if tick.step == self.step:
                self.publish_state(again=True)
            self.flush()
        elif self.step <= self.allowed and self.published_step != self.step:
            self.publish_state()
        if self.pending is not None and self.step <= self.allowed:
            cmd, self.pending = self.pending, None
            self.on_command(cmd)

    # -- realtime ---------------------------------------------------------------------------------
    def deadline(self, k: int) -> float:
        assert self.base is not None
        return self.base + (k - self.base_step) * self.scenario.dt

    def timeout(self, now: float) -> float:
        if not self.free or self.base is None or self.step > self.allowed or self.step >= self.total_steps:
            return self.idle_period
        return max(0.0, self.deadline(self.step) - now)

    def idle(self, now: float) -> None:
        if not self.free or self.base is None:
            return
        while self.step <= self.allowed and self.step < self.total_steps and now >= self.deadline(self.step):
            self.integrate(None, now - self.deadline(self.step))
            now = time.monotonic()

    def take(self, cmd: Command) -> None:
        """Lock-step: step k's command is here and the step granted: integrate it now, or (realtime) at its
        deadline if that is still to come — at most a step away (state k went out after step k − 1's
        deadline), and the sim expects nothing else before it, so the thread that received the command
        waits (no hand-off to another thread)."""
        if not self.paced or self.base is None:
            self.integrate(cmd, None)
            return
        now = time.monotonic()
        deadline = self.deadline(self.step)
        lag = now - self.published_at
        if deadline > now:
            sleep_precisely(deadline - now)
            now = time.monotonic()
        self.integrate(cmd, now - deadline, lag)

    def offer_free(self, cmd: Command) -> None:
        """Free-running: a command answering a state already out; it acts from the next step integrated."""
        assert self.hold is not None
        acts_from = self.step
        if self.latency is not None and cmd.step > self.hold.newest:  # a modelled latency on top of the link's
            delay = self.latency.delay()
            if delay is None:
                self.count("lost_commands")
                return
            acts_from += delay
        if not self.hold.offer(cmd, cmd.step, acts_from) and cmd.step == self.hold.newest:
            self.count("stale_commands")  # a repeated answer (after a resend); a late one: the hold counts it

    def on_command(self, cmd: Command) -> None:
        if self.free and cmd.step <= self.step and cmd.step < self.total_steps:
            self.offer_free(cmd)
            return
        if cmd.step < self.step:
            last = self.last_command
            if last is not None and cmd.step == last.step and cmd.values != last.values:
                # The first valid command of a step wins; a different one for the same step means
                # a second controller is publishing in this session.
                self.count("conflicting_commands")
                self.warn("conflict", f"step {cmd.step}: a different command arrived after the one applied "
                          "(is a second controller publishing in this session?); ignored")
            else:
                self.count("stale_commands")  # a repeated answer (after a resend) or a late one
            return
        if cmd.step > self.step or cmd.step >= self.total_steps:
            self.count("future_commands")
            self.warn("future_command",
                      f"dropped controller/command for step {cmd.step}: the sim is at step {self.step}")
            return
        if self.step > self.allowed:
            self.pending = cmd  # the controller was quicker than the tick: wait for the clock
            return
        if self.hold is not None:  # a command latency: this one acts later (or is lost)
            assert self.latency is not None
            delay = self.latency.delay()
            if delay is None:
                self.count("lost_commands")
            else:
                self.hold.offer(cmd, cmd.step, cmd.step + delay)
        self.take(cmd)

    def select(self, k: int) -> tuple[Command, str]:
        """What acts on step k when commands may be late: the held command, or the watchdog's policy."""
        assert self.hold is not None
        applied = self.applied = self.hold.select(k)
        if self.hold.late != self.counters.get("late_commands", 0):
            self.counters["late_commands"] = self.hold.late  # never acted: overtaken or too old (cdpr_sim.hold)
        cmd = applied.command
        if cmd is not None and not applied.watchdog:
            if self.watchdog_active:
                self.watchdog_active = False
                log(self.name, f"step {k}: commands again (answering state {applied.answered}); the watchdog is off")
            return cmd, cmd.status
        policy = self.watchdog.policy
        if applied.watchdog:
            self.count("watchdog_steps")
            if not self.watchdog_active:
                self.watchdog_active = True
                log(self.name, f"step {k}: no new command for {self.watchdog.timeout_ms:g} ms (the last answered "
                    f"state {applied.answered}); watchdog policy {policy}")
        if cmd is not None and policy == "hold":
            return cmd, "watchdog:hold"
        # static (also before the first command acts, and while an abort is on its way)
        if self.command_kind == "lengths":
            values = tuple(self.sim.encoder_lengths().tolist())
            return Command(k, k * self.scenario.dt, (), True, "watchdog:static", values), "watchdog:static"
        s = self.sim.state()
        tensions = self.static.tensions(s.position, s.rotation, s.twist)
        return Command(k, k * self.scenario.dt, tuple(tensions.tolist())), "watchdog:static"

    def integrate(self, received: Command | None, lateness: float | None, lag: float | None = None) -> None:
        """Step k: with ``received`` (lock-step) or what the hold selects (free-running, a latency).
        ``lateness``: realtime, s after the step's deadline; ``lag``: s from the state going out to the
        command's coming (default: to now)."""
        k = self.step
        if self.hold is None:
            assert received is not None
            cmd = received
        else:
            cmd, status = self.select(k)
            if cmd.step != k or cmd.status != status:  # recorded as what acted on step k
                cmd = replace(cmd, step=k, t=k * self.scenario.dt, status=status)
        # The loop waits for the next state: it goes out first, the bookkeeping after.
        if lag is None:
            lag = time.monotonic() - self.published_at
        report = self.sim.step(np.asarray(cmd.values))
        clamped = report.clamped_low or report.clamped_high
        self.clamped += bool(clamped)
        self.publish_state()
        if self.sim.fallbacks > self.counters.get("cable_fallbacks", 0):  # the cable law fell back
            self.count("cable_fallbacks")
            if self.counters["cable_fallbacks"] == 1:
                log(self.name, f"step {k}: the cable model fell back: {self.sim.fallback_reason} "
                    "(such steps are counted in cable_fallbacks; logged once)")
        self.last_command = cmd if received is None else received
        self.block_commands.append(cmd)
        self.block_lags.append(lag)
        if lateness is not None:
            self.block_lateness.append(lateness)
        if clamped:
            self.count("clamped_commands")
            self.warn(
                "clamped",
                f"step {k}: clamped {report.clamped_low} tension(s) below 0 and "
                f"{report.clamped_high} above tmax = {_limit_text(self.scenario.robot.tmax)} N"
                if cmd.lengths is None else
                f"step {k}: clamped {report.clamped_high} length(s) above max_length = "
                f"{_limit_text(self.scenario.robot.max_length)} m",
            )
        if (len(self.block_states) >= TELEMETRY_EVERY or self.step >= self.total_steps
                or 0 <= self.flush_at <= k or time.monotonic() - self.flushed_at >= TELEMETRY_PERIOD):
            if self.flush_at <= k:
                self.flush_at = -1
            self.flush()

    def close(self) -> None:
        if self._images is not None:
            self._images.shutdown(wait=True, cancel_futures=True)  # the last image out before the session closes
        if self.renderer is not None:
            self.renderer.close()
        log(self.name, f"stopped at step {self.step}/{self.total_steps}; clamped commands: {self.clamped}"
            + (f"; {self.counters}" if self.counters else ""))


def _limit_text(limit: np.ndarray) -> str:
    """A per-cable limit for a log line: one number when every cable has it, else the list."""
    values = limit.tolist()
    return f"{values[0]:g}" if min(values) == max(values) else "[" + ", ".join(f"{v:g}" for v in values) + "]"
