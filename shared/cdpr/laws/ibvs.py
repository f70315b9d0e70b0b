"""Image-based visual servoing through the loop (``controller.law: ibvs``): tensions from a camera's marker features
alone. No I/O.

The scenario's ``controller: {law: ibvs, ibvs: {camera: NAME, ...}}`` names a camera of ``sim.cameras`` and the
goal pose whose image is the target (``s*``: the markers' normalised coordinates there; by default the
trajectory's last pose). Every camera frame, :meth:`IbvsCore.on_frame`:

* inverts the lens (:func:`cdpr.mechanics.visual_servo.normalised`) and places each marker seen in the world
  from its depth, then fits the platform's pose to them (the markers' body coordinates are known: the rigid
  fit of Arun/Kabsch), and its twist from the previous frame's pose;
* computes the IBVS twist ``(v*, ω*) = −λ J⁺ (s − s*)`` with ``J`` the platform's image Jacobian
  (:func:`cdpr.mechanics.visual_servo.platform_jacobian`) on the markers seen, scaled down (its direction kept)
  to at most ``max_speed`` and ``max_rate``.

Every step, :meth:`IbvsCore.step` servoes the platform's twist to it: ``a = kv ((v*, ω*) − (v̂, ω̂))``, the
wrench of eq. 7 for that acceleration at the estimated pose (gravity included), and the scenario's tension
distribution at that pose (predicted from the pose and twist of the frame that step's state came with:
:func:`frame_needed`, whichever frames came since, so that a state the session asks for again — a sim that
went on from a snapshot after a restart — gets the answer it got the first time). Before the first frame the
platform is held where the scenario starts it. Nothing of the state's pose or twist is used.
"""

from __future__ import annotations

from collections import OrderedDict
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from pydantic import Field, FiniteFloat, PositiveFloat

from cdpr.laws.base import FrameLike, Law, LawSpec, SetpointLike, StateLike
from cdpr.mechanics.camera import Camera
from cdpr.mechanics.dynamics import required_wrench
from cdpr.mechanics.kinematics import WrenchMatrix
from cdpr.mechanics.robot import Robot
from cdpr.mechanics.rotation import Array, matrix_to_rotvec, rotvec_to_matrix
from cdpr.mechanics.tda import TdaResult, TensionDistributor
from cdpr.mechanics.visual_servo import ibvs_twist, normalised, platform_jacobian


class GoalSpec(LawSpec):
    position: list[FiniteFloat] = Field(min_length=3, max_length=3, description="the platform frame's origin, m")
    rpy: list[FiniteFloat] = Field(default_factory=lambda: [0.0, 0.0, 0.0], min_length=3, max_length=3,
                                   description="roll, pitch, yaw, rad")


class IbvsSpec(LawSpec):
    """Image-based visual servoing (cdpr.laws.ibvs): a camera of sim.cameras and the image to reach."""

    camera: str = Field(description="the camera (on the frame, looking at markers on the platform)")
    gain: PositiveFloat = Field(1.0, description="λ, 1/s: the feature error decays as exp(−λ t)")
    kv: PositiveFloat = Field(10.0, description="1/s: the gain of the loop that servoes the platform's twist")
    max_speed: PositiveFloat = Field(0.5, description="m/s: the IBVS twist's linear part at most (far from the goal "
                                     "the law alone would ask for metres per second)")
    max_rate: PositiveFloat = Field(0.5, description="rad/s: its angular part at most")
    goal: GoalSpec | None = Field(None, description="the pose whose image is the target (default: the "
                                  "trajectory's last pose)")


def check(section: IbvsSpec, spec: Any) -> None:
    """What a scenario (``spec``: a :class:`cdpr.config.scenario.ScenarioSpec`) with this law must have."""
    cams = {c.name: c for c in spec.sim.cameras}
    cam = cams.get(section.camera)
    if cam is None:
        raise ValueError(f"controller.ibvs.camera: no camera {section.camera!r} in sim.cameras "
                         f"(there: {', '.join(cams) or 'none'})")
    if cam.mount.body != "frame" or cam.markers.frame != "platform":
        raise ValueError(f"controller.ibvs.camera: {cam.name} must be on the frame looking at markers on the "
                         "platform (eye-to-hand)")
    if len(cam.markers.points) < 3:
        raise ValueError(f"controller.ibvs.camera: {cam.name} has {len(cam.markers.points)} marker(s); the "
                         "platform's pose needs 3 or more")
    if spec.controller.variant != "6dof" or spec.controller.output != "tensions":
        raise ValueError("controller.law: ibvs commands tensions for all 6 degrees of freedom (variant 6dof, "
                         "output tensions)")


def fit_pose(body: Array, world: Array) -> tuple[Array, Array]:
    """The rigid pose (p, R) that best maps body points (n, 3) onto world points (n, 3): world ≈ p + R body
    (least squares; Arun, Huang and Blostein 1987)."""
    cb, cw = body.mean(axis=0), world.mean(axis=0)
    H = (body - cb).T @ (world - cw)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T))
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return cw - R @ cb, R


@dataclass
class IbvsCore:
    robot: Robot
    camera: Camera
    desired: Array  # (n, 2): the markers' normalised coordinates at the goal, in the camera's marker order
    gain: float  # λ, 1/s
    kv: float  # the twist loop's gain, 1/s
    max_speed: float  # m/s: the IBVS twist's linear part at most
    max_rate: float  # rad/s: its angular part at most
    tda: TensionDistributor
    dt: float
    position: Array  # the pose estimate (the scenario's start until the first frame)
    rotation: Array
    twist: Array = field(default_factory=lambda: np.zeros(6))  # the estimate of the platform's twist
    target: Array = field(default_factory=lambda: np.zeros(6))  # the IBVS twist
    frame_step: int = -1  # the exposure of the last frame used
    feature_error: float = float("nan")  # RMS pixel error of the last frame (markers seen)
    _W: WrenchMatrix = field(init=False, repr=False)
    # each frame's estimates (position, rotation, twist, IBVS twist) by exposure, the newest HISTORY of them
    _estimates: OrderedDict[int, tuple[Array, Array, Array, Array]] = field(default_factory=OrderedDict, repr=False)

    def __post_init__(self) -> None:
        if self.camera.on_platform or not self.camera.markers_on_platform:
            raise ValueError(f"camera {self.camera.name}: IBVS here needs a camera on the frame looking at markers "
                             "on the platform (eye-to-hand)")
        self._W = WrenchMatrix(self.robot)
        self._index = {name: i for i, name in enumerate(self.camera.marker_ids)}
        self._start = (self.position, self.rotation, self.twist, self.target)

    @property
    def camera_name(self) -> str:
        return self.camera.name

    def frame_needed(self, step: int) -> int | None:
        return frame_needed(self.camera, step)

    def command(self, state: StateLike, setpoint: SetpointLike | None,
                residual: Array | None = None) -> tuple[TdaResult, Array | None]:
        """State k's tensions (:meth:`step`: only its step number is used; the setpoints are not)."""
        return self.step(state.step, residual), None

    def reset(self) -> None:
        self.tda.reset()

    def on_frame(self, frame: FrameLike) -> None:
        """A camera frame: the pose and twist estimates, and the IBVS twist. A frame with fewer than three
        markers seen changes nothing (no pose can be fitted)."""
        if frame.step <= self.frame_step or len(frame.ids) < 3:
            return
        idx = [self._index[name] for name in frame.ids]
        k = self.camera.intrinsics
        xy = normalised(np.asarray(frame.pixels).reshape(-1, 2), k)
        depth = np.asarray(frame.depth)
        c, Rc = self.camera.mount_position, self.camera.mount_rotation
        world = c + (np.column_stack([xy, np.ones(len(idx))]) * depth[:, None]) @ Rc.T
        p, R = fit_pose(self.camera.markers[idx], world)
        if self.frame_step >= 0:
            span = (frame.step - self.frame_step) * self.dt
            self.twist = np.concatenate([(p - self.position) / span, matrix_to_rotvec(R @ self.rotation.T) / span])
        self.position, self.rotation, self.frame_step = p, R, frame.step
        J = platform_jacobian(xy, depth, Rc, c, p, eye_in_hand=False)
        target = ibvs_twist(xy, self.desired[idx], J, self.gain)
        # saturated (the direction kept): far from the goal the law alone asks for metres per second
        scale = min(1.0, self.max_speed / max(float(np.linalg.norm(target[:3])), 1e-300),
                    self.max_rate / max(float(np.linalg.norm(target[3:])), 1e-300))
        self.target = target * scale
        err = (xy - self.desired[idx]) * np.array([k.fx, k.fy])
        self.feature_error = float(np.sqrt(np.mean(np.sum(err * err, axis=1))))
        self._estimates[frame.step] = (self.position, self.rotation, self.twist, self.target)
        while len(self._estimates) > HISTORY:
            self._estimates.popitem(last=False)

    def step(self, step: int, residual: Array | None = None) -> TdaResult:
        """Step ``step``'s tensions: the twist servoed to the IBVS twist through eq. 7 at the estimated pose,
        carried forward from the newest frame out by that step (its state's) at the estimated twist."""
        needed = frame_needed(self.camera, step)
        # the exposures come in order: the newest (the one in a session that never goes back) is looked at first
        frame = next((s for s in reversed(self._estimates) if needed is not None and s <= needed), -1)
        p0, R0, twist, target = self._estimates[frame] if frame >= 0 else self._start  # none yet: the start, held
        ahead = (step - frame) * self.dt if frame >= 0 else 0.0
        p = p0 + twist[:3] * ahead
        R = rotvec_to_matrix(twist[3:] * ahead) @ R0
        wrench = required_wrench(self.robot, R, twist, self.kv * (target - twist))
        if residual is not None:
            wrench = wrench + residual
        return self.tda.solve(self._W(p, R), wrench, self.robot.tmin, self.robot.tmax)


HISTORY = 1024  # frames' estimates kept for states asked for again (a sim going on from a snapshot: 50 steps back)


def ibvs_from_scenario(scenario: Any) -> IbvsCore:
    """The IBVS controller of a scenario (:class:`cdpr.config.scenario.Scenario`) whose ``controller.law`` is
    ``ibvs``."""
    from cdpr.mechanics.rotation import rpy_to_matrix
    from cdpr.mechanics.tda import make_tda

    spec = scenario.spec.controller.section("ibvs")
    camera = next(c for c in scenario.cameras if c.name == spec.camera)
    if spec.goal is not None:
        goal_R = rpy_to_matrix(*spec.goal.rpy)
        goal_p = scenario.robot.com_pose(spec.goal.position, goal_R)  # the platform frame's pose → the COM's
    else:
        last = scenario.trajectory.sample(scenario.trajectory.duration)
        goal_p, goal_R = last.position, last.rotation
    return IbvsCore(scenario.robot, camera, desired_image(camera, goal_p, goal_R), spec.gain, spec.kv,
                    spec.max_speed, spec.max_rate, make_tda(scenario.tda_method, **scenario.tda_options), scenario.dt,
                    scenario.initial_position.copy(), scenario.initial_rotation.copy())


def frame_needed(camera: Camera, step: int) -> int | None:
    """The exposure step of the newest frame out by ``step`` (released with the state of step exposure +
    latency), or None before the first: the frame the answer to state ``step`` must have used."""
    if step < camera.latency:
        return None
    return (step - camera.latency) // camera.every * camera.every


def desired_image(camera: Camera, position: ArrayLike, rotation: ArrayLike) -> Array:
    """The markers' normalised coordinates (n, 2) with the platform at the goal pose (all must be seen)."""
    seen = camera.observe(position, rotation)
    if not seen.visible.all():
        missing = [camera.marker_ids[j] for j in np.flatnonzero(np.logical_not(seen.visible))]
        raise ValueError(f"camera {camera.name} does not see marker(s) {', '.join(missing)} at the goal pose")
    return normalised(seen.pixels, camera.intrinsics)


LAW = Law(name="ibvs", build=ibvs_from_scenario, inputs=("camera",), section=IbvsSpec, check=check,
          doc="image-based visual servoing: a camera's features only (controller.ibvs)",
          summary=lambda core: (f"IBVS: the last frame (step {core.frame_step}) {core.feature_error:.3f} px RMS from "
                                "the desired image"))
