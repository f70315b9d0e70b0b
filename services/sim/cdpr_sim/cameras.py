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
    """Camera ``index``'s frame exposed at ``step`` (time ``t``) with the platform at ``position``/``rotation``."""
    truth = camera.observe(position, rotation)
    n = len(camera.markers)
    rng = np.random.default_rng([seed, index, step])
    noise = rng.normal(0.0, 1.0, (n, 2)) * camera.pixel_sigma
    dropped = rng.random(n) < camera.dropout
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
                self.pending.append((step + cam.latency, measure(cam, i, self.seed, step, t, position, rotation)))
        out = [frame for due, frame in self.pending if due <= step]
        if out:
            self.pending = deque((due, f) for due, f in self.pending if due > step)
        return out
