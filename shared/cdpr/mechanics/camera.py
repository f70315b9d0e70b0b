"""Pinhole cameras with lens distortion: where markers land in an image. Pure numpy, no I/O.

Conventions are OpenCV's (and ROS's ``sensor_msgs/CameraInfo``, ``plumb_bob``): in the camera frame ``z`` looks
forward, ``x`` right, ``y`` down; a point ``X = (X, Y, Z)`` with ``Z > 0`` is projected to the normalised
coordinates ``x = X/Z``, ``y = Y/Z``, distorted by

    r² = x² + y²,  radial = 1 + k1 r² + k2 r⁴ + k3 r⁶
    x' = x·radial + 2 t1 x y + t2 (r² + 2 x²)
    y' = y·radial + t1 (r² + 2 y²) + 2 t2 x y

and mapped to pixels ``u = fx x' + cx``, ``v = fy y' + cy`` (``distortion = (k1, k2, t1, t2, k3)``,
OpenCV's order). A camera is mounted on the frame (its pose in the world) or on the platform (its pose in
the platform's body frame, so it moves with it); :func:`camera_pose` gives its pose in the world.
"""

from __future__ import annotations

from collections.abc import Mapping
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from cdpr.mechanics.rotation import Array, rpy_to_matrix


@dataclass(frozen=True)
class Intrinsics:
    """The camera matrix K = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]], the image size and the lens distortion."""

    fx: float
    fy: float
    cx: float
    cy: float
    width: int
    height: int
    distortion: tuple[float, float, float, float, float] = (0.0, 0.0, 0.0, 0.0, 0.0)  # k1, k2, t1, t2, k3

    @property
    def matrix(self) -> Array:
        return np.array([[self.fx, 0.0, self.cx], [0.0, self.fy, self.cy], [0.0, 0.0, 1.0]])


@dataclass(frozen=True)
class Projection:
    """Markers seen by a camera: pixel coordinates (n, 2), depth along the optical axis (n,) and whether each is
    in front of the camera and inside the image (n,)."""

    pixels: Array
    depth: Array
    visible: Array


def look_at(eye: ArrayLike, target: ArrayLike, up: ArrayLike = (0.0, 0.0, 1.0)) -> Array:
    """The rotation of a camera at ``eye`` whose optical axis (z) points at ``target``, its image's "up" (−y) as
    close to ``up`` as can be: columns = the camera's x, y, z axes in the parent frame."""
    z = np.asarray(target, dtype=float) - np.asarray(eye, dtype=float)
    norm = np.linalg.norm(z)
    if norm == 0.0:
        raise ValueError("look_at: the target is the camera's own position")
    z = z / norm
    x = np.cross(-np.asarray(up, dtype=float), z)  # image right = down × forward (x = y × z)
    if np.linalg.norm(x) < 1e-9:
        raise ValueError("look_at: the camera looks along its up direction (choose another up)")
    x = x / np.linalg.norm(x)
    y = np.cross(z, x)
    return np.column_stack([x, y, z])


def camera_pose(mount_position: ArrayLike, mount_rotation: ArrayLike, on_platform: bool,
                platform_position: ArrayLike | None = None, platform_rotation: ArrayLike | None = None
                ) -> tuple[Array, Array]:
    """The camera's pose in the world (position, rotation): its mount pose itself on the frame; on the platform,
    the mount pose (in the body frame) carried by the platform's pose."""
    p_c, R_c = np.asarray(mount_position, dtype=float), np.asarray(mount_rotation, dtype=float)
    if not on_platform:
        return p_c, R_c
    p, R = np.asarray(platform_position, dtype=float), np.asarray(platform_rotation, dtype=float)
    return p + R @ p_c, R @ R_c


def distort(x: Array, y: Array, distortion: tuple[float, ...]) -> tuple[Array, Array]:
    """The plumb_bob distortion of normalised coordinates (module docstring)."""
    k1, k2, t1, t2, k3 = distortion
    r2 = x * x + y * y
    radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2.0 * t1 * x * y + t2 * (r2 + 2.0 * x * x)
    yd = y * radial + t1 * (r2 + 2.0 * y * y) + 2.0 * t2 * x * y
    return xd, yd


def project(points_world: ArrayLike, position: ArrayLike, rotation: ArrayLike, intrinsics: Intrinsics,
            near: float = 1e-6) -> Projection:
    """Project world points (n, 3) into the camera at ``position``/``rotation`` (its pose in the world). A point
    closer than ``near`` along the optical axis, or behind the camera, is not visible (its pixels are NaN)."""
    P = np.asarray(points_world, dtype=float).reshape(-1, 3)
    R = np.asarray(rotation, dtype=float)
    local = (P - np.asarray(position, dtype=float)) @ R  # (R^T (P - t)) row by row
    depth = local[:, 2]
    front = depth > near
    with np.errstate(divide="ignore", invalid="ignore"):
        x = np.where(front, local[:, 0] / depth, np.nan)
        y = np.where(front, local[:, 1] / depth, np.nan)
    xd, yd = distort(x, y, intrinsics.distortion)
    u = intrinsics.fx * xd + intrinsics.cx
    v = intrinsics.fy * yd + intrinsics.cy
    inside = front & (u >= 0.0) & (u < intrinsics.width) & (v >= 0.0) & (v < intrinsics.height)
    return Projection(np.column_stack([u, v]), depth, inside)


@dataclass(frozen=True)
class Camera:
    """A camera of a scenario (``sim.cameras``): where it is mounted, what it sees, how often and how well."""

    name: str
    intrinsics: Intrinsics
    on_platform: bool  # mounted on the platform (its pose in the body frame), else on the frame (in the world)
    mount_position: Array  # (3,)
    mount_rotation: Array  # (3, 3): columns = the camera's x, y, z axes in the mount's frame
    markers: Array  # (n, 3): the points it looks at
    markers_on_platform: bool  # markers in the platform's body frame (corners, fiducials), else in the world
    marker_ids: tuple[str, ...]
    every: int  # steps between two frames (a frame at every step k with k % every == 0)
    pixel_sigma: float = 0.0  # pixels: white noise on each coordinate
    dropout: float = 0.0  # probability that a marker in view is not detected in a frame
    latency: int = 0  # steps between a frame's exposure and its measurement being out
    image: bool = False  # also render an image of each frame

    def pose(self, position: ArrayLike, rotation: ArrayLike) -> tuple[Array, Array]:
        """The camera's pose in the world with the platform at ``position``/``rotation``."""
        return camera_pose(self.mount_position, self.mount_rotation, self.on_platform, position, rotation)

    def markers_world(self, position: ArrayLike, rotation: ArrayLike) -> Array:
        """The markers in the world with the platform at ``position``/``rotation``."""
        if not self.markers_on_platform:
            return self.markers
        return np.asarray(position, dtype=float) + self.markers @ np.asarray(rotation, dtype=float).T

    def observe(self, position: ArrayLike, rotation: ArrayLike) -> Projection:
        """What it sees, without noise or dropout, with the platform at ``position``/``rotation``."""
        cam_p, cam_R = self.pose(position, rotation)
        return project(self.markers_world(position, rotation), cam_p, cam_R, self.intrinsics)


def frame_every(rate: float, dt: float) -> int:
    """Steps between two frames of a camera taking ``rate`` frames per second at the sim's ``dt``."""
    return max(1, round(1.0 / (rate * dt)))


def camera_from_spec(spec: Mapping[str, Any], dt: float, com_offset: ArrayLike | None = None) -> Camera:
    """The :class:`Camera` of a camera as a scenario writes it (``sim.cameras``: name, mount, intrinsics,
    distortion, rate, pixel_sigma, dropout, latency_steps, markers, image), already validated — the scenario's
    loader (:mod:`cdpr.config.camera`) and a remote controller reading ``session/info`` both build it here.

    A mount and markers on the platform are in the robot file's platform frame; ``com_offset`` (the robot's,
    where that frame has the centre of mass) moves them to the COM's frame, the model's body frame."""
    mount, i, markers = spec["mount"], spec["intrinsics"], spec["markers"]
    if mount.get("rpy") is not None:
        mount_rotation = rpy_to_matrix(*mount["rpy"])
    else:
        mount_rotation = look_at(mount["position"], mount["look_at"], mount.get("up", (0.0, 0.0, 1.0)))
    points = np.array(markers["points"], dtype=float).reshape(-1, 3)
    c = np.zeros(3) if com_offset is None else np.asarray(com_offset, dtype=float)
    on_platform, markers_on_platform = mount["body"] == "platform", markers.get("frame", "platform") == "platform"
    k1, k2, t1, t2, k3 = (float(x) for x in spec.get("distortion", (0.0,) * 5))
    return Camera(
        name=str(spec["name"]),
        intrinsics=Intrinsics(float(i["fx"]), float(i["fy"]), float(i["cx"]), float(i["cy"]), int(i["width"]),
                              int(i["height"]), (k1, k2, t1, t2, k3)),
        on_platform=on_platform,
        mount_position=np.array(mount["position"], dtype=float) - (c if on_platform else 0.0),
        mount_rotation=mount_rotation,
        markers=points - c if markers_on_platform else points,
        markers_on_platform=markers_on_platform,
        marker_ids=tuple(markers.get("ids") or (f"m{j}" for j in range(len(points)))),
        every=frame_every(float(spec["rate"]), dt),
        pixel_sigma=float(spec.get("pixel_sigma", 0.0)),
        dropout=float(spec.get("dropout", 0.0)),
        latency=int(spec.get("latency_steps", 0)),
        image=bool(spec.get("image", False)),
    )
