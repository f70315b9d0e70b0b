"""Trajectory specs (pydantic): the ``trajectory`` map of a scenario file, built into a
:class:`~cdpr.mechanics.trajectory.Trajectory`. Embed :class:`TrajectorySpec` as a field and call ``.build()``."""

from __future__ import annotations

from typing import Annotated, Any, Literal

from pydantic import ConfigDict, Field, FiniteFloat, RootModel, ValidationError, model_validator

from cdpr.config.loading import Strict, describe_validation_error
from cdpr.mechanics.trajectory import QuinticWaypoints, SCurve, Trajectory

# --------------------------------------------------------------------------------------------------
# Scenario specs (pydantic): embed ``TrajectorySpec`` as a field and call ``.build()``.

Vec3 = Annotated[list[FiniteFloat], Field(min_length=3, max_length=3)]


class WaypointSpec(Strict):
    t: FiniteFloat = Field(description="time, s")
    position: Vec3 = Field(description="the platform frame's origin (its centre of mass unless the robot's "
                           "platform.com says otherwise), world frame, m")
    rpy: Vec3 | None = Field(None, description="roll, pitch, yaw (rad); omitted: the previous waypoint's")


class QuinticSpec(Strict):
    """``type: quintic``: rest-to-rest quintic segments through ``waypoints``."""

    type: Literal["quintic"] = Field(description="rest-to-rest quintic segments through the waypoints")
    waypoints: list[WaypointSpec] = Field(min_length=2, description="at least two; times strictly increasing")

    @model_validator(mode="after")
    def _increasing(self) -> QuinticSpec:
        for i in range(1, len(self.waypoints)):
            prev, cur = self.waypoints[i - 1].t, self.waypoints[i].t
            if cur <= prev:
                raise ValueError(
                    f"waypoints.{i}.t: times must be strictly increasing (got {cur} after {prev})"
                )
        return self

    def build(self) -> QuinticWaypoints:
        rpys: list[list[float]] = []
        for w in self.waypoints:
            rpys.append(list(w.rpy) if w.rpy is not None else (rpys[-1] if rpys else [0.0, 0.0, 0.0]))
        return QuinticWaypoints([w.t for w in self.waypoints], [w.position for w in self.waypoints], rpys)


class SCurveSpec(Strict):
    """``type: scurve``: lift, travel, lower (see :class:`SCurve`)."""

    type: Literal["scurve"] = Field(description="lift, travel at a height, lower (a pick-and-place path)")
    start: Vec3 = Field(description="where it starts: the platform frame's origin, world frame, m")
    goal: Vec3 = Field(description="where it ends, m")
    pass_height: FiniteFloat | Annotated[list[FiniteFloat], Field(min_length=2, max_length=2)] | None = Field(
        None, description="absolute travel z, or [z above start, z above goal]"
    )
    lift_height: FiniteFloat | None = Field(None, ge=0.0, description="travel z relative to the start")
    t_start: FiniteFloat = Field(0.0, description="when the lift starts, s")
    times: Annotated[list[FiniteFloat], Field(min_length=3, max_length=3)] = Field(
        description="absolute end times of the lift, travel and lower phases, s"
    )
    start_rpy: Vec3 | None = Field(None, description="roll, pitch, yaw at the start, rad (default: none)")
    goal_rpy: Vec3 | None = Field(None, description="at the goal, rad (default: start_rpy): turned during the travel")

    @model_validator(mode="after")
    def _consistent(self) -> SCurveSpec:
        if (self.pass_height is None) == (self.lift_height is None):
            raise ValueError(
                "give exactly one of pass_height (absolute z) and lift_height (relative to start)"
            )
        prev = self.t_start
        for i, t in enumerate(self.times):
            if t <= prev:
                before = "t_start" if i == 0 else f"times.{i - 1}"
                raise ValueError(f"times.{i}: must be after {before} (got {t} <= {prev})")
            prev = t
        self.build()  # the remaining checks (heights against the end points) live in SCurve
        return self

    def build(self) -> SCurve:
        t1, t2, t3 = self.times
        return SCurve(
            self.start,
            self.goal,
            self.lift_height,
            t1 - self.t_start,
            t2 - t1,
            t3 - t2,
            start_rpy=self.start_rpy,
            goal_rpy=self.goal_rpy,
            t_start=self.t_start,
            pass_height=self.pass_height,
        )


class TrajectorySpec(RootModel[Annotated[QuinticSpec | SCurveSpec, Field(discriminator="type")]]):
    """A trajectory in a scenario file: a union of the specs above, chosen by their ``type`` key."""

    model_config = ConfigDict(frozen=True)

    def build(self) -> Trajectory:
        return self.root.build()


TRAJECTORY_TYPES = ("quintic", "scurve")


def trajectory_from_spec(spec: dict[str, Any]) -> Trajectory:
    """A scenario's ``trajectory:`` mapping (schema in the module docstring) → a Trajectory.

    Raises ValueError with a one-line message naming the field, prefixed ``trajectory:``.
    """
    if not isinstance(spec, dict):
        raise ValueError(f"trajectory: expected a mapping with a 'type' key, got {type(spec).__name__}")
    if "type" not in spec:
        raise ValueError(f"trajectory: type: missing required key (one of {', '.join(TRAJECTORY_TYPES)})")
    if spec["type"] not in TRAJECTORY_TYPES:
        raise ValueError(
            f"trajectory: type: unknown type {spec['type']!r} (one of {', '.join(TRAJECTORY_TYPES)})"
        )
    try:
        model = TrajectorySpec.model_validate(spec)
    except ValidationError as exc:
        raise ValueError(describe_validation_error("trajectory", exc)) from None
    return model.build()
