"""Cameras in a scenario (``sim.cameras``): the YAML model and the :class:`cdpr.mechanics.camera.Camera` it builds.

Each camera has a name, a mount (on the ``frame``: its pose in the world; on the ``platform``: its pose in the
platform's body frame), pinhole intrinsics and plumb_bob distortion (OpenCV's and ROS CameraInfo's
conventions: :mod:`cdpr.mechanics.camera`), a frame rate, pixel noise, marker dropout, a latency, and the
markers it looks at (points in the platform's body frame, or in the world).
"""

from __future__ import annotations

import math
from typing import Literal

from numpy.typing import ArrayLike
from pydantic import Field, FiniteFloat, PositiveFloat, field_validator, model_validator

from cdpr.config.loading import Strict
from cdpr.mechanics.camera import Camera, camera_from_spec, frame_every, look_at

Vec3 = list[FiniteFloat]


class IntrinsicsSpec(Strict):
    fx: FiniteFloat = Field(description="focal length, pixels")
    fy: FiniteFloat = Field(description="focal length, pixels")
    cx: FiniteFloat = Field(description="principal point, pixels")
    cy: FiniteFloat = Field(description="principal point, pixels")
    width: int = Field(ge=1, le=16384, description="pixels")
    height: int = Field(ge=1, le=16384, description="pixels")

    @model_validator(mode="after")
    def _regular(self) -> IntrinsicsSpec:
        if not (self.fx > 0 and self.fy > 0):
            raise ValueError(f"fx and fy must be > 0 (got {self.fx:g}, {self.fy:g}): a camera matrix with a zero "
                             "or negative focal length is singular")
        return self


class MountSpec(Strict):
    body: Literal["frame", "platform"] = Field(description="frame: fixed in the world; platform: carried by it")
    position: Vec3 = Field(min_length=3, max_length=3, description="m, in the world or the platform's body frame")
    rpy: Vec3 | None = Field(None, min_length=3, max_length=3, description="rad: R = Rz(yaw) Ry(pitch) Rx(roll) "
                             "of the camera frame (z forward, x right, y down)")
    look_at: Vec3 | None = Field(None, min_length=3, max_length=3, description="a point the optical axis goes "
                                 "through, in the same frame as position (instead of rpy)")
    up: Vec3 = Field(default_factory=lambda: [0.0, 0.0, 1.0], min_length=3, max_length=3,
                     description="with look_at: the image's up direction, as near as can be")

    @model_validator(mode="after")
    def _one_orientation(self) -> MountSpec:
        if (self.rpy is None) == (self.look_at is None):
            raise ValueError("give the camera's orientation as rpy or as look_at (one of them)")
        if self.look_at is not None:
            look_at(self.position, self.look_at, self.up)  # raises ValueError naming the problem
        return self


class MarkersSpec(Strict):
    frame: Literal["platform", "world"] = Field("platform", description="platform: points in its body frame "
                                                "(corners, fiducials); world: fixed targets")
    points: list[Vec3] = Field(min_length=1, description="m")
    ids: list[str] | None = Field(None, description="a name per point (default m0, m1, …)")

    @field_validator("points")
    @classmethod
    def _three(cls, v: list[list[float]]) -> list[list[float]]:
        for i, p in enumerate(v):
            if len(p) != 3:
                raise ValueError(f"point {i}: expected [x, y, z], got {len(p)} numbers")
        return v

    @model_validator(mode="after")
    def _ids(self) -> MarkersSpec:
        if self.ids is not None and (len(self.ids) != len(self.points) or len(set(self.ids)) != len(self.ids)):
            raise ValueError(f"ids: expected {len(self.points)} distinct names (one per point), got {self.ids}")
        return self


class CameraSpec(Strict):
    name: str = Field(pattern=r"^[A-Za-z0-9_]{1,32}$", description="its topic is sim/camera/<name>")
    mount: MountSpec = Field(description="where it is, and where it looks")
    intrinsics: IntrinsicsSpec = Field(description="the pinhole model (OpenCV's K)")
    distortion: list[FiniteFloat] = Field(default_factory=lambda: [0.0] * 5, min_length=5, max_length=5,
                                          description="plumb_bob: k1, k2, t1, t2, k3 (OpenCV's order)")
    rate: PositiveFloat = Field(description="frames per second (a frame every round(1 / (rate dt)) steps)")
    pixel_sigma: FiniteFloat = Field(0.0, ge=0.0, description="white noise on each pixel coordinate")
    dropout: FiniteFloat = Field(0.0, ge=0.0, lt=1.0, description="probability that a marker in view is missed")
    latency_steps: int = Field(0, ge=0, le=10_000, description="steps from a frame's exposure to its measurement")
    markers: MarkersSpec = Field(description="the points it measures")
    image: bool = Field(False, description="also render an RGB image of each frame")

    def every(self, dt: float) -> int:
        """Steps between two frames at ``dt``."""
        return frame_every(self.rate, dt)

    def build(self, dt: float, com_offset: ArrayLike | None = None) -> Camera:
        return camera_from_spec(self.model_dump(), dt, com_offset)


def check_rate(camera: CameraSpec, dt: float) -> None:
    """A camera cannot take more than a frame per step, nor round its period far from the rate asked."""
    if camera.rate * dt > 1.0 + 1e-9:
        raise ValueError(f"sim.cameras: camera {camera.name}: rate {camera.rate:g} Hz is above the sim's step rate "
                         f"1/dt = {1.0 / dt:g} Hz")
    actual = 1.0 / (camera.every(dt) * dt)
    if not math.isclose(actual, camera.rate, rel_tol=0.05):
        raise ValueError(f"sim.cameras: camera {camera.name}: rate {camera.rate:g} Hz is not a frame every whole "
                         f"number of steps at dt = {dt:g} s (the nearest: {actual:g} Hz)")
