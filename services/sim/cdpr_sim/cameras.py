"""Simulated cameras: what each camera of ``sim.cameras`` measures of its markers, frame by frame. No I/O.

A camera takes a frame at every step ``k`` with ``k % every == 0`` (its rate), from the platform's pose at
that step: each marker's pixel coordinates (:func:`cdpr.mechanics.camera.project`), plus white Gaussian noise of
``pixel_sigma`` on each coordinate; a marker is reported when it is in front of the camera, inside the image
after the noise, and not dropped (probability ``dropout``, drawn per marker and frame). The frame goes out
``latency`` steps after its exposure (with the state of step ``k + latency``), stamped with its exposure step.

Determinism: the noise of camera ``c``'s frame at step ``k`` is drawn from
``numpy.random.default_rng([seed, c, k])`` (``seed`` of ``sim.sensors``, 0 without), in the same order
(2 n pixel noises, then n dropout draws), so a frame is a pure function of the seed, the camera, the step and
the platform's pose: the same on a resend and in another run.
"""

from __future__ import annotations

from collections import deque

import numpy as np
from numpy.typing import ArrayLike

from cdpr.mechanics.camera import Camera
from cdpr.protocol import CameraFrame


def measure(camera: Camera, index: int, seed: int, step: int, t: float, position: ArrayLike,
            rotation: ArrayLike) -> CameraFrame:
    """Camera ``index``'s frame exposed at ``step`` (time ``t``) with the platform at ``position``/``rotation``:
    :func:`cdpr.mechanics.camera.project` and the noise of the module docstring. The reference, in numpy;
    :func:`measure_fast`, which the sim runs, gives the same frame."""
    truth = camera.observe(position, rotation)
    n = len(camera.markers)
    noise, dropped = _draws(camera, index, seed, step, n)
    pixels = truth.pixels + noise
    k = camera.intrinsics
    u, v = pixels[:, 0], pixels[:, 1]
    with np.errstate(invalid="ignore"):
        seen = truth.depth > 0
        seen &= (u >= 0.0) & (u < k.width) & (v >= 0.0) & (v < k.height) & ~dropped
    idx = np.flatnonzero(seen)
    return CameraFrame(
        camera=camera.name,
        step=step,
        t=t,
        ids=tuple(camera.marker_ids[j] for j in idx),
        pixels=tuple(pixels[idx].ravel().tolist()),
        depth=tuple(truth.depth[idx].tolist()),
    )


def _draws(camera: Camera, index: int, seed: int, step: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The frame's pixel noise (n, 2) and dropouts (n,), from ``default_rng([seed, index, step])``."""
    rng = np.random.default_rng([seed, index, step])
    return rng.normal(0.0, 1.0, (n, 2)) * camera.pixel_sigma, rng.random(n) < camera.dropout


def measure_fast(camera: Camera, index: int, seed: int, step: int, t: float, position: ArrayLike,
                 rotation: ArrayLike, near: float = 1e-6) -> CameraFrame:
    """:func:`measure` for the loop: the markers into the camera's frame in one product, then the lens and the
    visibility marker by marker in floats. A frame comes every few steps, after a physics step that left the CPU's
    caches cold, where each of :func:`measure`'s ~40 numpy calls on a handful of points costs microseconds: this
    is ~3 times cheaper there (docs/benchmarks.md). The same arithmetic in the same order: the same frame."""
    p, R = np.asarray(position, dtype=float), np.asarray(rotation, dtype=float)
    cam_p, cam_R = camera.pose(p, R)
    if camera.markers_on_platform:  # (R^T (p + R b - cam_p)) row by row, as project does
        local = ((p + camera.markers @ R.T) - cam_p) @ cam_R
    else:
        local = (camera.markers - cam_p) @ cam_R
    noise, dropped = _draws(camera, index, seed, step, len(local))
    k = camera.intrinsics
    k1, k2, t1, t2, k3 = k.distortion
    ids: list[str] = []
    pixels: list[float] = []
    depths: list[float] = []
    for j, ((lx, ly, depth), (nu, nv), drop) in enumerate(zip(local.tolist(), noise.tolist(), dropped.tolist(),
                                                        strict=True)):
        if depth <= near or drop:
            continue
        x, y = lx / depth, ly / depth
        r2 = x * x + y * y
        radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
        xd = x * radial + 2.0 * t1 * x * y + t2 * (r2 + 2.0 * x * x)
        yd = y * radial + t1 * (r2 + 2.0 * y * y) + 2.0 * t2 * x * y
        u = (k.fx * xd + k.cx) + nu
        v = (k.fy * yd + k.cy) + nv
        if 0.0 <= u < k.width and 0.0 <= v < k.height:
            ids.append(camera.marker_ids[j])
            pixels += (u, v)
            depths.append(depth)
    return CameraFrame(camera=camera.name, step=step, t=t, ids=tuple(ids), pixels=tuple(pixels), depth=tuple(depths))


class CameraSuite:
    """The scenario's cameras: the frames due at each step, held back by their latency."""

    def __init__(self, cameras: tuple[Camera, ...], seed: int = 0) -> None:
        self.cameras = cameras
        self.seed = seed
        self.pending: deque[tuple[int, CameraFrame]] = deque()  # (step it goes out at, frame)

    def due(self, step: int) -> bool:
        """Whether anything happens at ``step``: a frame exposed, or one whose latency has run out."""
        return any(step % cam.every == 0 for cam in self.cameras) or any(d <= step for d, _ in self.pending)

    def step(self, step: int, t: float, position: ArrayLike, rotation: ArrayLike) -> list[CameraFrame]:
        """The frames exposed at ``step`` are taken; those whose latency has run out by ``step`` come back."""
        for i, cam in enumerate(self.cameras):
            if step % cam.every == 0:
                self.pending.append((step + cam.latency, measure_fast(cam, i, self.seed, step, t, position, rotation)))
        out = [frame for due, frame in self.pending if due <= step]
        if out:
            self.pending = deque((due, f) for due, f in self.pending if due > step)
        return out
