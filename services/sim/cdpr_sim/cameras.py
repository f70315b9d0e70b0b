"""Simulated cameras: what each camera of ``sim.cameras`` measures of its markers, frame by frame. No I/O.

A camera takes a frame at every step ``k`` with ``k % every == 0`` (its rate), from the platform's pose at
that step: each marker's pixel coordinates (:func:`cdpr.mechanics.camera.project`), plus white Gaussian noise of
``pixel_sigma`` on each coordinate; a marker is reported when it is in front of the camera, inside the image
after the noise, and not dropped (probability ``dropout``, drawn per marker and frame). The frame goes out
``latency`` steps after its exposure (with the state of step ``k + latency``), stamped with its exposure step.

Determinism: the noise of camera ``c``'s frame at step ``k`` is drawn from
``numpy.random.default_rng([seed, c, k])`` (``seed`` of ``sim.sensors``, 0 without), in the same order
(2 n pixel noises, then n dropout draws), so a frame is a pure function of the seed, the camera, the step and
the platform's pose: the same on a resend and in another run. The sim draws them with :class:`FrameDraws`: the same
numbers as ``default_rng``, made cheaper in the loop.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable
from typing import Any

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


# a frame's draws: (camera, its index, seed, step, markers) -> pixel noise (n, 2), dropped (n,)
Draws = Callable[[Camera, int, int, int, int], tuple[np.ndarray, np.ndarray]]


def _draws(camera: Camera, index: int, seed: int, step: int, n: int) -> tuple[np.ndarray, np.ndarray]:
    """The frame's pixel noise (n, 2) and dropouts (n,), from ``default_rng([seed, index, step])``."""
    rng = np.random.default_rng([seed, index, step])
    return rng.normal(0.0, 1.0, (n, 2)) * camera.pixel_sigma, rng.random(n) < camera.dropout


# numpy's SeedSequence (its hash of the entropy into a pool of 4 words, then the state words) and PCG64's seeding
_M32, _M128 = 0xFFFFFFFF, (1 << 128) - 1
_INIT_A, _MULT_A, _INIT_B, _MULT_B = 0x43B0D7E5, 0x931E8875, 0x8B51F9DD, 0x58F38DED
_MIX_L, _MIX_R = 0xCA01F9DD, 0x4973F715
_PCG_MULT = (2549297995355413924 << 64) + 4865540595714422341


def _powers(init: int, mult: int, n: int) -> tuple[int, ...]:
    out = [init]
    while len(out) < n:
        out.append((out[-1] * mult) & _M32)
    return tuple(out)


_HASH_A = _powers(_INIT_A, _MULT_A, 18)  # the pool's hash constants in turn (extended for longer entropy)
_HASH_B = _powers(_INIT_B, _MULT_B, 9)
_CROSS = tuple((d, s) for s in range(4) for d in range(4) if s != d)


def _words(value: int) -> list[int]:
    """An integer >= 0 as SeedSequence takes it: its 32-bit words, least significant first ([0] for 0)."""
    out = [value & _M32]
    value >>= 32
    while value:
        out.append(value & _M32)
        value >>= 32
    return out


def pcg64_state(entropy: tuple[int, ...] | list[int]) -> tuple[int, int]:
    """``(state, inc)`` of ``numpy.random.PCG64(numpy.random.SeedSequence(entropy))`` (integers >= 0), on Python
    ints: SeedSequence's mixing of the entropy's 32-bit words into its pool, the pool's 8 output words, and
    PCG64's seeding from them (its state stepped twice). tests/test_camera.py checks it against numpy."""
    ent = [w for value in entropy for w in _words(value)]
    h = _HASH_A if len(ent) <= 4 else _powers(_INIT_A, _MULT_A, 18 + 4 * (len(ent) - 4))
    n = len(ent)
    pool = []
    for i in range(4):  # hashmix(x, h): x ^= h; h *= MULT_A; x *= h; x ^= x >> 16 (mod 2**32)
        v = (((ent[i] if i < n else 0) ^ h[i]) * h[i + 1]) & _M32
        pool.append(v ^ (v >> 16))
    k = 4
    for d, src in _CROSS:  # mix(pool[d], hashmix(pool[src])): (L x - R y) ^ >> 16
        v = ((pool[src] ^ h[k]) * h[k + 1]) & _M32
        k += 1
        r = (_MIX_L * pool[d] - _MIX_R * (v ^ (v >> 16))) & _M32
        pool[d] = r ^ (r >> 16)
    for src in range(4, n):  # entropy beyond the pool's 4 words
        for d in range(4):
            v = ((ent[src] ^ h[k]) * h[k + 1]) & _M32
            k += 1
            r = (_MIX_L * pool[d] - _MIX_R * (v ^ (v >> 16))) & _M32
            pool[d] = r ^ (r >> 16)
    w = []
    for i in range(8):  # generate_state(4, uint64): 8 words, the pool in turn hashed with INIT_B, MULT_B
        v = ((pool[i & 3] ^ _HASH_B[i]) * _HASH_B[i + 1]) & _M32
        w.append(v ^ (v >> 16))
    initstate = (((w[1] << 32) | w[0]) << 64) | ((w[3] << 32) | w[2])  # 64-bit words high, low
    inc = ((((((w[5] << 32) | w[4]) << 64) | ((w[7] << 32) | w[6])) << 1) | 1) & _M128
    return ((((inc + initstate) & _M128) * _PCG_MULT + inc) & _M128), inc  # state = 0; step; += initstate; step


class FrameDraws:
    """:func:`_draws` for the sim's loop: the same numbers (``default_rng([seed, index, step])``'s), drawn from one
    PCG64 generator reused frame after frame, set to the state that seed would give it (:func:`pcg64_state`)
    instead of numpy making a SeedSequence, a PCG64 and a Generator each frame: ~75 µs of a frame's ~160 after a
    physics step left the CPU's caches cold, against ~30 this way (docs/benchmarks.md)."""

    def __init__(self) -> None:
        self._bits = np.random.PCG64()
        self._rng = np.random.Generator(self._bits)

    def __call__(self, camera: Camera, index: int, seed: int, step: int, n: int) -> tuple[np.ndarray, np.ndarray]:
        state, inc = pcg64_state((seed, index, step))
        self._bits.state = {"bit_generator": "PCG64", "state": {"state": state, "inc": inc},
                            "has_uint32": 0, "uinteger": 0}
        rng = self._rng
        return rng.normal(0.0, 1.0, (n, 2)) * camera.pixel_sigma, rng.random(n) < camera.dropout


def measure_fast(camera: Camera, index: int, seed: int, step: int, t: float, position: ArrayLike,
                 rotation: ArrayLike, near: float = 1e-6, draws: Draws = _draws) -> CameraFrame:
    """:func:`measure` for the loop: the markers into the camera's frame in one product, then the lens and the
    visibility marker by marker in floats. A frame comes every few steps, after a physics step that left the CPU's
    caches cold, where each of :func:`measure`'s ~40 numpy calls on a handful of points costs microseconds: this
    is ~3 times cheaper there (docs/benchmarks.md). The same arithmetic in the same order: the same frame.
    ``draws``: :func:`_draws`, or a :class:`FrameDraws` (the same numbers)."""
    p, R = np.asarray(position, dtype=float), np.asarray(rotation, dtype=float)
    cam_p, cam_R = camera.pose(p, R)
    if camera.markers_on_platform:  # (R^T (p + R b - cam_p)) row by row, as project does
        local = ((p + camera.markers @ R.T) - cam_p) @ cam_R
    else:
        local = (camera.markers - cam_p) @ cam_R
    noise, dropped = draws(camera, index, seed, step, len(local))
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
        self._next: float = 0  # the next step at which something happens (every camera exposes at step 0)
        self._last = -1  # the step of the last call of step()
        self._taken = -1  # a step whose exposures are already pending (a restored snapshot's)
        self._draws = FrameDraws()

    def snapshot(self) -> dict[str, Any]:
        """What a restarted sim needs to deliver on from here (the resume snapshot's ``cameras_*`` fields): the
        frames exposed and not yet out — without them a sim started again from step k would never send the frames
        exposed in the ``latency`` steps before k, which a controller waits for."""
        return {"cameras_step": self._last,
                "cameras_pending": [[due, f.camera, f.step, f.t, list(f.ids), list(f.pixels), list(f.depth)]
                                    for due, f in self.pending]}

    def restore(self, snapshot: dict[str, Any]) -> None:
        self.pending = deque((int(due), CameraFrame(str(cam), int(step), float(t), tuple(map(str, ids)),
                                                    tuple(map(float, pixels)), tuple(map(float, depth))))
                             for due, cam, step, t, ids, pixels, depth in snapshot.get("cameras_pending", ()))
        self._taken = int(snapshot.get("cameras_step", -1))  # its exposures are among the pending
        self._next, self._last = 0, -1

    def due(self, step: int) -> bool:
        """Whether anything happens at ``step``: a frame exposed, or one whose latency has run out. (Asked every
        step: two comparisons. A step not after the last one taken, after a restore, is said due: :meth:`step`
        finds out.)"""
        return step >= self._next or step <= self._last

    def step(self, step: int, t: float, position: ArrayLike, rotation: ArrayLike) -> list[CameraFrame]:
        """The frames exposed at ``step`` are taken; those whose latency has run out by ``step`` come back."""
        for i, cam in enumerate(self.cameras):
            if step % cam.every == 0 and step != self._taken:
                frame = measure_fast(cam, i, self.seed, step, t, position, rotation, draws=self._draws)
                self.pending.append((step + cam.latency, frame))
        out = [frame for due, frame in self.pending if due <= step]
        if out:
            self.pending = deque((due, f) for due, f in self.pending if due > step)
        exposure = min((step // cam.every + 1) * cam.every for cam in self.cameras) if self.cameras else math.inf
        self._next = min(exposure, min((due for due, _ in self.pending), default=math.inf))
        self._last = step
        return out
