"""``session/info``: what a session is (scenario, robot, dt, the controller's settings), one message.

The clock answers ``get`` on ``cdpr/{session}/session/info`` with :func:`encode_session_info`; the
recorder logs :func:`session_info`; a remote controller decodes the answer with
:meth:`SessionInfo.from_payload`, which rebuilds the robot as a :class:`~cdpr.mechanics.robot.Robot`.
docs/protocol.md gives every field.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import msgpack
import numpy as np

from cdpr.errors import InputError
from cdpr.mechanics.camera import Camera, camera_from_spec
from cdpr.mechanics.control import Gains, Variant, controlled_rows
from cdpr.mechanics.kinematics import check_robot
from cdpr.mechanics.pulley import Pulleys
from cdpr.mechanics.robot import PLANE_ROWS, Robot, Shape
from cdpr.protocol.messages import PROTOCOL_VERSION, ProtocolError, unpack

if TYPE_CHECKING:
    from cdpr.config.scenario import Scenario


def session_info(scenario: Scenario) -> dict[str, Any]:
    """The scenario as the ``session/info`` map (msgpack- and JSON-friendly), without the version."""
    return {
        "scenario": scenario.name,
        "dt": scenario.dt,
        "duration": scenario.duration,
        "total_steps": scenario.total_steps,
        "robot": scenario.robot.summary(),
        "sim": {"cable_model": scenario.cable_model,
                **({} if (params := scenario.spec.sim.cable_params) is None
                   else {scenario.cable_model: params.model_dump()}),
                **({"cameras": [c.model_dump() for c in cams]} if (cams := scenario.spec.sim.cameras) else {}),
                **({} if (sensors := scenario.spec.sim.sensors) is None else {"sensors": sensors.model_dump()})},
        "controller": {
            "output": scenario.output,
            "variant": scenario.variant,
            "kp": scenario.gains.kp.tolist(),
            "kd": scenario.gains.kd.tolist(),
            "tda": scenario.tda_method,
        },
    }


def encode_session_info(scenario: Scenario) -> bytes:
    """The ``session/info`` payload: :func:`session_info` with the protocol version ``v``."""
    return msgpack.packb({"v": PROTOCOL_VERSION, **session_info(scenario)}, use_bin_type=True)


def _readonly(values: Any, shape: tuple[int, ...] | None = None) -> np.ndarray:
    a = np.array(values, dtype=float)
    if shape is not None and a.shape != shape:
        raise ValueError(f"expected shape {shape}, got {a.shape}")
    if not np.all(np.isfinite(a)):
        raise ValueError("must be finite numbers")
    a.flags.writeable = False
    return a


def robot_from_summary(summary: dict[str, Any]) -> Robot:
    """The :class:`~cdpr.mechanics.robot.Robot` described by ``session/info``'s ``robot`` map (``Robot.summary()``).

    Damping is not part of the summary (a controller does not need it) and is set to zero; the frame
    box is the bounding box of the frame points. Raises :class:`ProtocolError` naming the bad field.
    """
    where = "session/info: robot"
    try:
        a = _readonly(summary["frame_points"])
        m = a.shape[0] if a.ndim == 2 else 0
        if a.shape != (m, 3) or m == 0:
            raise ProtocolError(f"{where}.frame_points: expected m rows of 3 numbers")
        if (per_cable := summary.get("cable_limits")) is not None:  # the limits of each cable
            tmin, tmax, max_length = (_readonly(per_cable[k], (m,)) for k in ("tmin", "tmax", "max_length"))
        else:  # one range for every cable
            tmin, tmax = (_readonly(x) for x in summary["tension_limits"])
            max_length = _readonly(summary["max_length"])
        robot = Robot(
            name=str(summary["name"]),
            description=str(summary.get("description", "")),
            source=str(summary.get("source", "session/info")),
            mode=summary["mode"],
            frame_points=a,
            platform_points=_readonly(summary["platform_points"], (m, 3)),
            mass=float(summary["mass"]),
            inertia=_readonly(summary["inertia"], (3, 3)),
            shape=Shape(str(summary["shape"]["type"]), tuple(float(x) for x in summary["shape"]["size"])),
            tmin=tmin,
            tmax=tmax,
            max_length=max_length,
            max_speed=float(summary["max_speed"]),
            cable_damping=0.0,
            passive_damping=0.0,
            home_position=_readonly(summary["home"]["position"], (3,)),
            home_rotation=_readonly(summary["home"]["rotation"], (3, 3)),
            frame_min=_readonly(a.min(axis=0)),
            frame_max=_readonly(a.max(axis=0)),
            plane=summary.get("plane", "xz"),
            cable_set=str(summary.get("cable_set", "default")),
            com_offset=_readonly(summary.get("com_offset", [0.0, 0.0, 0.0]), (3,)),
            encoder_offsets=_readonly(summary.get("encoder_offsets", [0.0] * m), (m,)),
            pulleys=None if (pulleys := summary.get("pulleys")) is None else Pulleys(
                _readonly(pulleys["radius"], (m,)), _readonly(pulleys["axis"], (m, 3))),
        )
    except ProtocolError:
        raise
    except KeyError as exc:
        raise ProtocolError(f"{where}.{exc.args[0]}: missing") from None
    except (TypeError, ValueError) as exc:
        raise ProtocolError(f"{where}: {exc}") from None
    if robot.mode not in ("spatial", "point_mass", "planar"):
        raise ProtocolError(f"{where}.mode: unknown mode {robot.mode!r}")
    if robot.plane not in PLANE_ROWS:
        raise ProtocolError(f"{where}.plane: unknown plane {robot.plane!r} (xz or xy)")
    try:
        check_robot(robot, where)
    except InputError as exc:
        raise ProtocolError(str(exc)) from None
    return robot


@dataclass(frozen=True)
class SessionInfo:
    """What ``session/info`` says about a session, with the robot rebuilt as a :class:`Robot`."""

    scenario: str
    dt: float
    duration: float
    total_steps: int
    robot: Robot
    variant: Variant  # "6dof" or "3dof" (the scenario's controller)
    gains: Gains  # the scenario's own controller gains (a remote controller may ignore them)
    tda: str  # the scenario's tension distribution method
    raw: dict[str, Any] = field(repr=False)  # the whole map, as received

    @property
    def rows(self) -> list[int]:
        """Rows of the 6×m wrench matrix the scenario controls (``[0, 1, 2]`` for 3dof)."""
        return list(controlled_rows(self.robot, self.variant))

    @property
    def cameras(self) -> dict[str, Camera]:
        """The scenario's cameras (``sim.cameras``) by name: intrinsics, mount, markers, frame period, latency —
        what a controller needs to read their frames (``sim/camera/<name>``). Empty without cameras."""
        try:
            return {c["name"]: camera_from_spec(c, self.dt, self.robot.com_offset)
                    for c in self.raw.get("sim", {}).get("cameras", [])}
        except (KeyError, TypeError, ValueError, AttributeError) as exc:
            raise ProtocolError(f"session/info: sim.cameras: {exc}") from None

    @classmethod
    def from_payload(cls, payload: bytes) -> SessionInfo:
        msg = unpack(payload)
        try:
            ctrl = msg.get("controller", {})
            variant = ctrl.get("variant", "6dof")
            if variant not in ("6dof", "3dof"):
                raise ProtocolError(f"session/info: controller.variant: unknown variant {variant!r}")
            return cls(
                scenario=str(msg["scenario"]),
                dt=float(msg["dt"]),
                duration=float(msg["duration"]),
                total_steps=int(msg["total_steps"]),
                robot=robot_from_summary(msg["robot"]),
                variant=variant,
                gains=Gains.of(ctrl.get("kp", 0.0), ctrl.get("kd", 0.0)),
                tda=str(ctrl.get("tda", "qp")),
                raw=msg,
            )
        except ProtocolError:
            raise
        except KeyError as exc:
            raise ProtocolError(f"session/info: {exc.args[0]}: missing") from None
        except (TypeError, ValueError, AttributeError) as exc:
            raise ProtocolError(f"session/info: {exc}") from None
