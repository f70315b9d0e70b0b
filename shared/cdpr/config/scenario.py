"""Scenarios: one YAML file says which robot, which trajectory, which controller, for how long.

Like robot files, scenarios are data, validated at load into a frozen :class:`Scenario`; a bad file
raises :class:`cdpr.errors.InputError` naming the file and the field. Shipped scenarios live in
``cdpr/scenarios/`` (the repository's ``shared/cdpr/scenarios/``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path
from typing import Annotated, Any, Literal

import numpy as np
from pydantic import (
    Field,
    FiniteFloat,
    PositiveFloat,
    create_model,
    field_validator,
    model_validator,
)

from cdpr.config.camera import CameraSpec, check_rate
from cdpr.config.loading import Strict, parse_model, read_yaml, resolve, shipped_names
from cdpr.config.robot import load_robot
from cdpr.config.trajectory import TrajectorySpec
from cdpr.errors import InputError
from cdpr.laws import LAWS
from cdpr.mechanics.camera import Camera
from cdpr.mechanics.control import Gains, Variant
from cdpr.mechanics.interference import Obstacle
from cdpr.mechanics.outputs import CommandKind
from cdpr.mechanics.robot import GRAVITY, Robot
from cdpr.mechanics.rotation import matrix_to_rotvec, rpy_to_matrix
from cdpr.mechanics.trajectory import PlatformPoint, Trajectory
from cdpr.sensors import COMMON, SENSOR_KINDS, Param, SensorKind


class PlatformOverride(Strict):
    mass: PositiveFloat | None = Field(None, description="whole platform mass; inertia becomes the solid shape's")
    payload: FiniteFloat = Field(0.0, ge=0.0, description="point mass rigidly attached at the centre of mass, kg")


class LimitsOverride(Strict):
    """The scenario's tension limits: each one given replaces the robot's for every cable (per-cable limits of
    the robot file included); one left out keeps the robot's."""

    tmin: FiniteFloat | None = Field(None, ge=0.0, description="N, for every cable")
    tmax: PositiveFloat | None = Field(None, description="N, for every cable")


def _tda_methods() -> str:
    from cdpr.mechanics.tda import METHOD_NAMES

    return ", ".join(sorted(METHOD_NAMES))


class TdaSpec(Strict):
    method: str = Field("qp", description=f"the tension distribution: {_tda_methods()}")
    options: dict[str, Any] = Field(default_factory=dict, description="the method's options (e.g. qp: solver, "
                                    "exact, atol; docs/protocol.md's TDA section)")

    @field_validator("method")
    @classmethod
    def _known(cls, v: str) -> str:
        from cdpr.mechanics.tda import METHOD_NAMES

        if v not in METHOD_NAMES:
            raise ValueError(f"unknown TDA method {v!r} (known: {', '.join(sorted(METHOD_NAMES))})")
        return v


Gain = FiniteFloat | list[FiniteFloat]


class ControllerBase(Strict):
    """The control law and the tension distribution; a law with parameters of its own has a section named after it
    (:data:`cdpr.laws.LAWS`)."""

    law: str = Field("feedback_linearisation", description="; ".join(f"{law.name}: {law.doc}"
                                                                     for law in LAWS.values()))
    feedback: Literal["state", "sensors"] = Field(
        "state", description="what the law is fed: state (sim/state, the truth) or sensors (an estimate of the pose "
        "and twist from sim/sensors — the encoders through forward kinematics, fused with the IMU in a Kalman "
        "filter, cdpr.mechanics.estimation —: the controller never reads sim/state)")
    variant: Literal["6dof", "3dof"] = Field("6dof", description="6dof: position and orientation (eq. 7); 3dof: "
                                             "position only, the paper's variant")
    kp: Gain = Field(1500.0, description="proportional gain, 1/s²: one number, or [x, y, z, rx, ry, rz]")
    kd: Gain = Field(1500.0, description="derivative gain, 1/s: one number, or [x, y, z, rx, ry, rz]")
    tda: TdaSpec = Field(default_factory=TdaSpec, description="how the wrench becomes cable tensions (eq. 8)")
    output: CommandKind = Field(
        "tensions",
        description="what the controller commands: cable tensions, or unstretched cable lengths (winch "
        "position control; needs sim.cable_model elastic or sag)",
    )

    @field_validator("kp", "kd")
    @classmethod
    def _six(cls, v: float | list[float]) -> float | list[float]:
        if isinstance(v, list) and len(v) != 6:
            raise ValueError(f"a gain is one number or 6 numbers [x, y, z, rx, ry, rz], got {len(v)}")
        if np.any(np.asarray(v) < 0):
            raise ValueError("gains must be >= 0")
        return v

    @field_validator("law")
    @classmethod
    def _known_law(cls, v: str) -> str:
        if v not in LAWS:
            raise ValueError(f"unknown control law {v!r} (known: {', '.join(LAWS)})")
        return v

    def section(self, name: str) -> Any:
        """Law ``name``'s section (None: not given)."""
        return getattr(self, name, None)


_LAW_SECTIONS: dict[str, Any] = {law.name: (law.section | None, Field(None, description=f"law {law.name}: its "
                                                                   "parameters"))
                                 for law in LAWS.values() if law.section is not None}
ControllerSpec: type[ControllerBase] = create_model(  # the laws' sections follow the table (cdpr.laws)
    "ControllerSpec", __base__=ControllerBase, __doc__=ControllerBase.__doc__, **_LAW_SECTIONS)


class StretchSpec(Strict):
    """The parameters every stretching cable model has (the controller's stretch compensation uses EA)."""

    EA: FiniteFloat = Field(1.0e6, gt=0.0, description="axial stiffness, N (k = EA / l0)")
    damping: FiniteFloat = Field(200.0, ge=0.0, description="damping of the stretch rate, N·s/m")


class ElasticSpec(StretchSpec):
    """Straight elastic cables (cdpr_sim.elastic)."""


class SagSpec(StretchSpec):
    """Heavy elastic cables hanging as Irvine's elastic catenary (cdpr_sim.sag)."""

    mass_per_length: FiniteFloat = Field(0.1, gt=0.0, description="kg/m")
    tension_at: Literal["platform", "frame"] = Field("platform", description="where a tension command holds")

    @property
    def weight_per_length(self) -> float:
        """w, N/m."""
        return self.mass_per_length * float(-GRAVITY[2])


class WinchSpec(Strict):
    """The winch drives of the winch-driven cable models (cdpr_sim.winch): all winches of a robot alike, SI units,
    gains on the drum angle."""

    radius: FiniteFloat = Field(0.05, gt=0.0, description="drum radius, m (l0 = r θ)")
    inertia: FiniteFloat = Field(1e-3, gt=0.0, description="rotor and drum inertia about the drum axis, kg·m²")
    friction: FiniteFloat = Field(0.01, ge=0.0, description="viscous friction, N·m·s/rad")
    torque_max: FiniteFloat = Field(50.0, gt=0.0, description="torque (current) limit, N·m")
    kp: FiniteFloat = Field(400.0, ge=0.0, description="PID on the drum angle, N·m/rad")
    ki: FiniteFloat = Field(8000.0, ge=0.0, description="N·m/(rad·s)")
    kd: FiniteFloat = Field(1.0, ge=0.0, description="N·m·s/rad")


class SensorsBase(Strict):
    """Simulated sensors, published on sim/sensors (cdpr_sim.sensors): one entry per kind of
    :data:`cdpr.sensors.SENSOR_KINDS` (a kind with ``default`` is there unless set to null)."""

    seed: int = Field(0, ge=0, description="seed of the noise (a reading is a function of seed, sensor and step)")

    def kinds(self) -> list[tuple[SensorKind, Any]]:
        """The kinds configured, in the table's order, each with its entry."""
        return [(k, spec) for k in SENSOR_KINDS if (spec := getattr(self, k.name)) is not None]


_THREE = Annotated[list[FiniteFloat], Field(min_length=3, max_length=3)]
_PARAM_TYPES: dict[str, Any] = {"number": FiniteFloat, "vec3": _THREE, "bias": FiniteFloat | list[FiniteFloat],
                                "bias3": FiniteFloat | _THREE}


def _param_field(p: Param) -> Any:
    bounds = {k: v for k in ("ge", "gt", "le", "lt") if (v := getattr(p, k)) is not None}
    return (_PARAM_TYPES[p.kind], Field(p.default, description=p.doc, **bounds))


def _kind_model(kind: SensorKind) -> type[Strict]:
    """The model of a kind's entry ``sim.sensors.<kind>``: :data:`cdpr.sensors.COMMON`'s keys and its own."""
    name = "".join(part.title() for part in kind.name.split("_")) + "Spec"
    return create_model(name, __base__=Strict, __doc__=kind.doc,
                        **{p.name: _param_field(p) for p in (*COMMON, *kind.params)})


def _kind_field(kind: SensorKind) -> Any:
    model = _kind_model(kind)
    if kind.default:
        return (model | None, Field(default_factory=model, description=kind.doc))
    return (model | None, Field(None, description=f"{kind.doc} (none by default)"))


SensorsSpec: type[SensorsBase] = create_model(  # the sections follow the table (cdpr.sensors)
    "SensorsSpec", __base__=SensorsBase, __doc__=SensorsBase.__doc__,
    **{k.name: _kind_field(k) for k in SENSOR_KINDS})


WatchdogPolicy = Literal["hold", "static", "abort"]
WATCHDOG_POLICIES: tuple[WatchdogPolicy, ...] = ("hold", "static", "abort")


class WatchdogSpec(Strict):
    """What the sim does when no new command has come for ``timeout_ms`` (cdpr_sim.hold; docs/realtime.md)."""

    policy: WatchdogPolicy = Field("static", description="hold: keep the last command; static: the tensions "
                                   "that hold the current pose against gravity (and damp its motion); abort: "
                                   "end the session, naming the controller")
    timeout_ms: FiniteFloat = Field(100.0, gt=0.0, description="ms without a new command before the policy applies")
    decay: FiniteFloat = Field(10.0, ge=0.0, description="static: the platform's speed decays at this rate, 1/s "
                               "(the wrench adds -decay·M·twist; 0: gravity only)")

    def steps(self, dt: float) -> int:
        """The timeout in steps of ``dt`` (at least 1)."""
        return max(1, math.ceil(self.timeout_ms * 1e-3 / dt - 1e-9))


class CommandLatencySpec(Strict):
    """A deterministic command latency in lock-step (cdpr_sim.hold): the command answering state k acts from
    step k + steps + j, j drawn uniformly in [0, jitter], lost with probability ``loss`` (then the previous one
    holds); drawn from ``seed``, so that a run is bit-identical to the next."""

    steps: int = Field(0, ge=0, le=100_000, description="the fixed delay, steps")
    jitter: int = Field(0, ge=0, le=100_000, description="an extra delay of 0 … jitter steps, uniform")
    loss: FiniteFloat = Field(0.0, ge=0.0, lt=1.0, description="probability that a command is lost")
    seed: int = Field(0, ge=0, description="seed of the jitter and the losses")


@dataclass(frozen=True)
class CableModel:
    """A cable model a scenario may name in ``sim.cable_model`` (the sim's class for it: cdpr_sim.models)."""

    description: str
    params: type[StretchSpec] | None = None  # its parameters: the SimSpec field of the model's name
    winch: bool = False  # wound on winches: tension or length commands; sim.winch and sim.substeps apply


CABLE_MODELS: dict[str, CableModel] = {
    "ideal": CableModel("massless inextensible pull-only force elements"),
    "ups": CableModel("the seed paper's universal-prismatic-spherical legs closed with ball-joint constraints"),
    "elastic": CableModel("straight elastic cables on winches", ElasticSpec, winch=True),
    "sag": CableModel("heavy elastic cables (elastic catenary) on winches", SagSpec, winch=True),
}
WINCH_MODELS = tuple(name for name, model in CABLE_MODELS.items() if model.winch)


class SimSpec(Strict):
    cable_model: str = Field(
        "ideal", description="; ".join(f"{name}: {model.description}" for name, model in CABLE_MODELS.items())
    )
    elastic: ElasticSpec = Field(default_factory=lambda: ElasticSpec(), description="cable_model elastic: its cables")
    sag: SagSpec = Field(default_factory=lambda: SagSpec(), description="cable_model sag: its cables")
    winch: WinchSpec = Field(default_factory=lambda: WinchSpec(), description="the winches of cable_model elastic or "
                             "sag")
    substeps: int | None = Field(None, ge=1, description="sub-steps per dt in lengths mode (default: chosen "
                                 "for stability and accuracy from the cables' stiffness)")
    sensors: SensorsSpec | None = Field(None, description="publish simulated sensor readings on sim/sensors")
    cameras: list[CameraSpec] = Field(default_factory=list, description="cameras (cdpr.config.camera): marker "
                                      "measurements on sim/camera/<name> every frame")
    watchdog: WatchdogSpec = Field(default_factory=lambda: WatchdogSpec(),
                                   description="when commands stop coming (free-running realtime, lost commands)")
    command_latency: CommandLatencySpec | None = Field(None, description="a deterministic command latency "
                                                       "(lock-step): latency studies in fast mode")

    @field_validator("cable_model")
    @classmethod
    def _known_model(cls, v: str) -> str:
        if v not in CABLE_MODELS:
            raise ValueError(f"unknown cable model {v!r} (known: {', '.join(CABLE_MODELS)})")
        return v

    @field_validator("cameras")
    @classmethod
    def _distinct_cameras(cls, v: list[CameraSpec]) -> list[CameraSpec]:
        return _distinct_names(v, "camera")

    @model_validator(mode="after")
    def _params_match_model(self) -> SimSpec:
        sections = {name: (name,) for name, model in CABLE_MODELS.items() if model.params is not None}
        for name, models in (*sections.items(), ("winch", WINCH_MODELS), ("substeps", WINCH_MODELS)):
            if name in self.model_fields_set and self.cable_model not in models:
                raise ValueError(f"{name}: used by cable_model {' or '.join(models)} only "
                                 f"(this scenario's is {self.cable_model})")
        return self

    @property
    def model(self) -> CableModel:
        return CABLE_MODELS[self.cable_model]

    @property
    def cable_params(self) -> StretchSpec | None:
        """The parameters of the scenario's cable model (its section of ``sim``), or None if it has none."""
        return getattr(self, self.cable_model) if self.model.params is not None else None


def _distinct_names(items: list[Any], what: str) -> list[Any]:
    names = [x.name for x in items]
    if len(set(names)) != len(names):
        raise ValueError(f"{what} names must be distinct, got {names}")
    return items


class ObstacleSpec(Strict):
    """An obstacle of the scene (docs/scenarios.md): a solid box, cylinder, sphere, or a mesh's surface."""

    name: str = Field(min_length=1, description="what reports name it by")
    type: Literal["box", "cylinder", "sphere", "mesh"] = Field(description="its shape: box, cylinder, sphere or "
                                                                "mesh (a triangle mesh's surface)")
    position: list[FiniteFloat] = Field(min_length=3, max_length=3, description="its centre (a mesh: its file's "
                                        "origin), world frame, m")
    rpy: list[FiniteFloat] = Field(default_factory=lambda: [0.0, 0.0, 0.0], min_length=3, max_length=3,
                                   description="roll, pitch, yaw, rad (a cylinder's axis is its z)")
    size: list[PositiveFloat] | None = Field(None, min_length=3, max_length=3, description="box: full sizes, m")
    radius: PositiveFloat | None = Field(None, description="cylinder and sphere, m")
    length: PositiveFloat | None = Field(None, description="cylinder: along its axis, m")
    file: str | None = Field(None, description="mesh: an .stl or .obj file, relative to the scenario's folder")
    scale: PositiveFloat = Field(1.0, description="mesh: its file's units in m (0.001 for a file in mm)")

    @model_validator(mode="after")
    def _fields_of_its_type(self) -> ObstacleSpec:
        needs = {"box": ("size",), "cylinder": ("radius", "length"), "sphere": ("radius",), "mesh": ("file",)}
        for key in needs[self.type]:
            if getattr(self, key) is None:
                raise ValueError(f"{key}: a {self.type} needs it")
        for key in ("size", "radius", "length", "file"):
            if key not in needs[self.type] and getattr(self, key) is not None:
                owners = ", ".join(t for t, k in needs.items() if key in k)
                raise ValueError(f"{key}: a {self.type} has none (it is for {owners})")
        return self


class SceneSpec(Strict):
    """What the cables and the platform may meet: ``cdpr check`` reports how near they come (docs/scenarios.md)."""

    floor: FiniteFloat | None = Field(None, description="the floor's height (a plane z = floor), m")
    obstacles: list[ObstacleSpec] = Field(default_factory=list, description="solid obstacles, each named")

    @field_validator("obstacles")
    @classmethod
    def _distinct(cls, v: list[ObstacleSpec]) -> list[ObstacleSpec]:
        return _distinct_names(v, "obstacle")


class InitialSpec(Strict):
    position: list[FiniteFloat] = Field(min_length=3, max_length=3, description="the platform frame's origin, "
                                        "world frame, m")
    rpy: list[FiniteFloat] = Field(default_factory=lambda: [0.0, 0.0, 0.0], min_length=3, max_length=3,
                                   description="roll, pitch, yaw, rad")


class ScenarioSpec(Strict):
    name: str = Field(description="the scenario's name (summaries, recordings)")
    description: str = Field("", description="what it is, in a sentence or two")
    robot: str = Field(description="a shipped robot's name (cdpr robots) or a robot file's path, relative to the "
                       "scenario's folder")
    cable_set: str | None = Field(None, description="which of the robot file's cable sets (default: its cables)")
    platform: PlatformOverride = Field(default_factory=lambda: PlatformOverride(), description="the platform's mass "
                                       "or a payload, instead of the robot file's")
    limits: LimitsOverride = Field(default_factory=lambda: LimitsOverride(), description="tension limits instead of "
                                   "the robot file's")
    dt: PositiveFloat = Field(0.001, description="the step, s (at most 0.1)")
    duration: PositiveFloat | None = Field(None, description="s; default: the trajectory's duration plus 1 s")
    initial: InitialSpec | None = Field(None, description="where the session starts, at rest; default: the "
                                        "trajectory's first pose")
    trajectory: TrajectorySpec = Field(description="the setpoints: type quintic or scurve")
    controller: ControllerSpec = Field(default_factory=lambda: ControllerSpec(), description="the control law and "
                                       "the tension distribution")
    sim: SimSpec = Field(default_factory=lambda: SimSpec(), description="the plant: cable model, sensors, cameras, "
                         "watchdog")
    scene: SceneSpec = Field(default_factory=lambda: SceneSpec(), description="obstacles and the floor (cdpr check)")

    @model_validator(mode="after")
    def _dt_sane(self) -> ScenarioSpec:
        if self.dt > 0.1:
            raise ValueError(f"dt: {self.dt} s is too coarse for a cable robot (at most 0.1)")
        if self.controller.output == "lengths" and not self.sim.model.winch:
            raise ValueError(f"controller.output: lengths needs sim.cable_model {' or '.join(WINCH_MODELS)} "
                             f"(winch-driven cables), not {self.sim.cable_model}")
        for camera in self.sim.cameras:
            check_rate(camera, self.dt)
        ctrl, law = self.controller, LAWS[self.controller.law]
        for other in LAWS.values():
            if other is not law and other.section is not None and ctrl.section(other.name) is not None:
                raise ValueError(f"controller.{other.name}: used by law {other.name} only (this controller's law is "
                                 f"{law.name})")
        if law.section is not None:
            section = ctrl.section(law.name)
            if section is None:
                raise ValueError(f"controller.{law.name}: law {law.name} needs its section")
            law.check(section, self)
        if ctrl.feedback == "sensors":
            if "setpoints" not in law.inputs:
                raise ValueError(f"controller.feedback: sensors feeds a law of states; law {law.name} reads "
                                 f"{', '.join(law.inputs)}")
            if self.sim.sensors is None or getattr(self.sim.sensors, "encoders", None) is None:
                raise ValueError("controller.feedback: sensors needs sim.sensors.encoders (the estimate's pose is "
                                 "their forward kinematics)")
            # the filter takes a reading as measured at its step, every step (the load cells: with stretching cables,
            # whose stretch it takes out with them)
            stretching = getattr(self.sim.cable_params, "EA", None) is not None
            for name in ("encoders", "imu", *(["load_cells"] if stretching else [])):
                entry = getattr(self.sim.sensors, name, None)
                if entry is not None and (entry.rate or entry.latency or entry.dropout):
                    raise ValueError(f"controller.feedback: sensors reads sim.sensors.{name} every step as measured "
                                     "then: its rate, latency and dropout must stay 0")
        latency, watchdog = self.sim.command_latency, self.sim.watchdog
        if latency is not None:
            most = latency.steps + latency.jitter
            limit = watchdog.steps(self.dt)
            if most >= limit:
                raise ValueError(
                    f"sim.command_latency: steps + jitter = {most} steps must stay below the watchdog's "
                    f"sim.watchdog.timeout_ms = {watchdog.timeout_ms:g} ms ({limit} steps at dt = {self.dt:g} s): a "
                    "command that old never acts (raise timeout_ms)")
        return self


@dataclass(frozen=True)
class Scenario:
    name: str
    description: str
    source: str  # the file it came from
    robot: Robot  # with the scenario's mass/payload and limits applied
    dt: float
    duration: float
    initial_position: np.ndarray
    initial_rotation: np.ndarray
    trajectory: Trajectory
    variant: Variant
    gains: Gains
    tda_method: str
    tda_options: dict[str, Any]
    cable_model: str
    spec: ScenarioSpec
    cameras: tuple[Camera, ...] = ()
    obstacles: tuple[Obstacle, ...] = ()

    def start_note(self) -> str | None:
        """None when the session starts at the robot's home pose; else where it starts and why (a scenario starts
        at ``initial``, else at its trajectory's first pose: docs/scenarios.md), in one line."""
        r = self.robot
        moved = float(np.linalg.norm(self.initial_position - r.home_position))
        turned = float(np.linalg.norm(matrix_to_rotvec(self.initial_rotation @ r.home_rotation.T)))
        if moved <= 1e-6 and turned <= 1e-6:
            return None
        origin = self.initial_position - self.initial_rotation @ r.com_offset  # the platform frame's, as files give it
        what = "its initial pose" if self.spec.initial is not None else "its trajectory's first pose"
        return (f"{self.name} starts at {what}, [{', '.join(f'{x:.4g}' for x in origin)}] m, not the robot's home: "
                f"{moved:.3g} m" + (f" and {turned:.3g} rad" if turned > 1e-6 else "") + " from it (a scenario "
                "starts at `initial`, else at its trajectory's first pose; docs/scenarios.md)")

    @property
    def total_steps(self) -> int:
        return round(self.duration / self.dt)

    @property
    def output(self) -> CommandKind:
        """What the controller commands: ``tensions`` or ``lengths`` (unstretched cable lengths)."""
        return self.spec.controller.output


CHECKS = ("workspace", "tda")  # what loading a scenario checks by default (see load_scenario)


def scenario_from_spec(spec: ScenarioSpec, where: str, base_dir: Path | None = None,
                       checks: tuple[str, ...] = CHECKS) -> Scenario:
    robot_ref = spec.robot
    if base_dir is not None and robot_ref.endswith((".yaml", ".yml")) and not Path(robot_ref).is_absolute():
        robot_ref = str(base_dir / robot_ref)
    try:
        robot = load_robot(robot_ref, spec.cable_set)
    except InputError as exc:
        raise InputError(f"{where}: robot: {exc}") from None
    if spec.platform.mass is not None:
        robot = robot.with_mass(spec.platform.mass)
    robot = robot.with_payload(spec.platform.payload)
    tmin = robot.tmin if spec.limits.tmin is None else np.full(robot.m, float(spec.limits.tmin))
    tmax = robot.tmax if spec.limits.tmax is None else np.full(robot.m, float(spec.limits.tmax))
    if np.any(tmin > tmax):
        i = int(np.argmax(tmin > tmax))
        raise InputError(f"{where}: limits: tmin ({tmin[i]:g}) must not exceed tmax ({tmax[i]:g})"
                         + ("" if robot.uniform_limits else f" (cable {i})"))
    robot = robot.replace(tmin=tmin, tmax=tmax)
    for kind, entry in () if spec.sim.sensors is None else spec.sim.sensors.kinds():
        if (problem := kind.check(entry, robot.m)) is not None:
            raise InputError(f"{where}: sim.sensors.{kind.name}.{problem}")
    if spec.controller.feedback == "sensors" and robot.mode != "spatial":
        raise InputError(f"{where}: controller.feedback: sensors needs a spatial robot (its pose from the encoders' "
                         f"forward kinematics); {robot.name} is {robot.mode}")
    try:
        trajectory = spec.trajectory.build()
        if np.any(robot.com_offset != 0.0):  # waypoints of the platform frame: the COM follows its own path
            trajectory = PlatformPoint(trajectory, robot.com_offset)
    except ValueError as exc:
        raise InputError(f"{where}: trajectory: {exc}") from None
    if "workspace" in checks:
        from cdpr.mechanics.workspace import check_trajectory

        check_trajectory(robot, trajectory, spec.controller.variant, where)  # static and feed-forward wrenches
    if "tda" in checks:
        from cdpr.mechanics.tda import make_tda

        try:
            make_tda(spec.controller.tda.method, **spec.controller.tda.options)
        except (TypeError, ValueError) as exc:
            raise InputError(f"{where}: controller.tda.options: {str(exc).splitlines()[0]}") from None
    duration = spec.duration if spec.duration is not None else trajectory.duration + 1.0
    if spec.initial is not None:
        R0 = rpy_to_matrix(*spec.initial.rpy)
        p0 = robot.com_pose(spec.initial.position, R0)  # the platform frame's pose → the COM's
    else:
        first = trajectory.sample(0.0)
        p0, R0 = first.position.copy(), first.rotation.copy()
    steps = round(duration / spec.dt)
    if steps < 1:
        raise InputError(f"{where}: duration: shorter than one step of dt = {spec.dt}")
    cameras = tuple(c.build(spec.dt, robot.com_offset) for c in spec.sim.cameras)
    for camera in cameras:
        check_markers_seen(camera, trajectory, duration, where)
    obstacles = tuple(_obstacle(o, base_dir, f"{where}: scene.obstacles.{i}")
                      for i, o in enumerate(spec.scene.obstacles))
    return Scenario(
        name=spec.name,
        description=spec.description,
        source=where,
        robot=robot,
        dt=float(spec.dt),
        duration=float(duration),
        initial_position=p0,
        initial_rotation=R0,
        trajectory=trajectory,
        variant=spec.controller.variant,
        gains=Gains.of(spec.controller.kp, spec.controller.kd),
        tda_method=spec.controller.tda.method,
        tda_options=dict(spec.controller.tda.options),
        cable_model=spec.sim.cable_model,
        spec=spec,
        cameras=cameras,
        obstacles=obstacles,
    )


def _obstacle(spec: ObstacleSpec, base_dir: Path | None, where: str) -> Obstacle:
    """The obstacle a scene's entry describes (a mesh read from its file: one line naming it if it cannot be)."""
    from cdpr.config.mesh import load_mesh

    R = rpy_to_matrix(*spec.rpy)
    p = np.array(spec.position, dtype=float)
    if spec.type == "mesh":
        assert spec.file is not None
        path = Path(spec.file)
        if base_dir is not None and not path.is_absolute():
            path = base_dir / path
        try:
            local = load_mesh(path) * spec.scale
        except InputError as exc:
            raise InputError(f"{where}.file: {exc}") from None
        return Obstacle(spec.name, "mesh", p, R, triangles=local @ R.T + p)
    return Obstacle(spec.name, spec.type, p, R, size=np.array(spec.size or [0.0, 0.0, 0.0], dtype=float),
                    radius=float(spec.radius or 0.0), length=float(spec.length or 0.0))


def check_markers_seen(camera: Camera, trajectory: Trajectory, duration: float, where: str) -> None:
    """Every marker of ``camera`` must be in its view somewhere along the trajectory (sampled every 0.1 s):
    a marker it can never see is a mistake in the file (a mount pose, a sign, a frame)."""
    seen = np.zeros(len(camera.markers), dtype=bool)
    for t in np.linspace(0.0, duration, max(2, int(duration / 0.1) + 1)):
        sample = trajectory.sample(float(t))
        seen |= camera.observe(sample.position, sample.rotation).visible
        if seen.all():
            return
    never = [camera.marker_ids[j] for j in np.flatnonzero(~seen)]
    raise InputError(f"{where}: sim.cameras: camera {camera.name} never sees marker(s) {', '.join(never)} along the "
                     "trajectory (behind the camera or outside its image: check the mount, the markers' frame and "
                     "the intrinsics)")


def load_scenario(name_or_path: str | Path, overrides: dict[str, Any] | None = None,
                  checks: tuple[str, ...] = CHECKS) -> Scenario:
    """A shipped scenario name or a YAML path, plus optional top-level overrides (e.g. ``{"duration": 2}``).

    Beyond the file's own validation, ``checks`` (default: both) says what else to check: ``workspace``,
    that the trajectory stays in the wrench-feasible workspace (static and feed-forward wrenches);
    ``tda``, that the tension distribution method takes its options. A node checks only what it needs
    (:attr:`cdpr.runtime.service.Node.scenario_checks`): the launcher and the clock the workspace, the
    controller its method; a session's start-up does not repeat the work in every process.
    """
    path = resolve(name_or_path, "scenarios", "scenario")
    data = read_yaml(path)
    for key, value in (overrides or {}).items():
        if value is not None:
            data[key] = value
    spec = parse_model(ScenarioSpec, data, path)
    return scenario_from_spec(spec, str(path), path.parent, checks)


def shipped_scenarios() -> list[str]:
    return shipped_names("scenarios")
