"""Camera images: what a camera of the scenario sees, drawn with OpenCV (the painter's algorithm). No I/O.

The scene is the frame's box (its edges), the cables (straight, platform end to frame anchor; drawn before the
platform, which hides those behind it), the platform (its shape's faces, shaded by how squarely each faces the
camera, farthest first) and the markers (a dot and the marker's id). Every point goes through the camera's own
projection, lens distortion included (:func:`cdpr.mechanics.camera.project`); a line is drawn as short
segments so that it bends as the lens bends it, and the part of a segment behind the camera is cut off (all the
cables' segments projected at once, and drawn in one OpenCV call). About 0.5 ms for 640 × 480 on one core here
(the backdrop of a camera on the frame drawn once), 0.45 ms more to encode it as JPEG. Needs
``opencv-python-headless`` (``pip install 'cdpr[camera]'``), imported by the image
process as it starts (or at the first image drawn in this process)."""

from __future__ import annotations

import contextlib
import os
import time
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cdpr.mechanics.camera import Camera, project
from cdpr.mechanics.pulley import pulley_geometry
from cdpr.mechanics.robot import Robot
from cdpr.mechanics.rotation import Array

BACKGROUND = (205, 205, 200)  # RGB
FRAME_COLOR = (90, 90, 90)
CABLE_COLOR = (25, 25, 25)
PLATFORM_COLOR = np.array([70, 130, 180], dtype=float)
MARKER_COLOR = (220, 40, 40)
NEAR = 0.05  # m: what is closer to the camera than this is not drawn
SEGMENTS = 12  # pieces of each line (the lens bends lines)
# the 6 faces of a box, as indices into its corners (x, y, z signs in binary: bit 0 → x)
BOX_FACES = ((0, 1, 3, 2), (4, 5, 7, 6), (0, 1, 5, 4), (2, 3, 7, 6), (0, 2, 6, 4), (1, 3, 7, 5))


def _cv2() -> Any:
    try:
        import cv2
    except ImportError:
        raise ImportError("camera images need OpenCV: pip install 'cdpr[camera]' (opencv-python-headless)") from None
    return cv2


def box_corners(half: ArrayLike) -> Array:
    h = np.asarray(half, dtype=float)
    return np.array([[(1 if i & 1 else -1) * h[0], (1 if i & 2 else -1) * h[1], (1 if i & 4 else -1) * h[2]]
                     for i in range(8)])


class Renderer:
    """Draws ``camera``'s view of ``robot`` (static parts set up once)."""

    def __init__(self, camera: Camera, robot: Robot) -> None:
        self.camera, self.robot = camera, robot
        lo, hi = robot.frame_min, robot.frame_max
        corners = np.array([[hi[0] if i & 1 else lo[0], hi[1] if i & 2 else lo[1], hi[2] if i & 4 else lo[2]]
                            for i in range(8)])
        edges = [(a, b) for a in range(8) for b in range(a + 1, 8) if bin(a ^ b).count("1") == 1]
        self.frame_edges = (corners[[a for a, _ in edges]], corners[[b for _, b in edges]])  # their two ends (12, 3)
        size = robot.shape.size
        half = [s / 2.0 for s in size] if robot.shape.type == "box" else [size[0]] * 3
        self.platform_corners = box_corners(half)
        k = camera.intrinsics  # the image's corners, undistorted, and a margin: how far out lines are drawn
        self.max_radius = 1.3 * float(np.hypot(max(k.cx, k.width - k.cx) / k.fx, max(k.cy, k.height - k.cy) / k.fy))
        background = np.empty((k.height, k.width, 3), dtype=np.uint8)
        background[:] = BACKGROUND  # (numpy takes ~1 ms to fill 640 × 480 pixels with a colour; a copy ~0.05 ms)
        self._background = background
        self._backdrop: NDArray[np.uint8] | None = None  # a frame camera's background with the frame's edges
        self._faces = np.array(BOX_FACES)

    def _fresh_image(self, cam_p: Array, cam_R: Array) -> NDArray[np.uint8]:
        """A new image with the background and the frame's edges drawn, the camera at ``cam_p``/``cam_R`` (for a
        camera on the frame, whose pose never changes, drawn once and then copied)."""
        if self._backdrop is not None:
            return self._backdrop.copy()
        img = self._background.copy()
        self._lines(img, *self.frame_edges, cam_p, cam_R, FRAME_COLOR, 1)
        if not self.camera.on_platform:
            self._backdrop = img.copy()
        return img

    def _lines(self, img: Any, a: Array, b: Array, cam_p: Array, cam_R: Array, color: tuple[int, int, int],
               width: int) -> None:
        """The lines from ``a[i]`` to ``b[i]`` (n, 3), each as :data:`SEGMENTS` pieces (the lens bends lines), in
        one projection and one OpenCV call: a line's points behind the near plane or where the lens model no longer
        holds are left out (a distortion polynomial folds back far outside the image); a line with fewer than two
        points left is not drawn."""
        cv2 = _cv2()
        pts = a[:, None, :] + np.linspace(0.0, 1.0, SEGMENTS + 1)[None, :, None] * (b - a)[:, None, :]
        local = (pts.reshape(-1, 3) - cam_p) @ cam_R
        depth = local[:, 2]
        keep = depth > NEAR
        with np.errstate(divide="ignore", invalid="ignore"):
            keep &= np.hypot(local[:, 0], local[:, 1]) / depth <= self.max_radius
        uv = project(pts.reshape(-1, 3)[keep], cam_p, cam_R, self.camera.intrinsics, near=NEAR).pixels
        pixels = np.full((len(depth), 2), np.nan)
        pixels[keep] = uv
        lines = pixels.reshape(len(a), SEGMENTS + 1, 2)
        finite = np.isfinite(lines).all(axis=2)
        rounded = np.round(np.where(finite[:, :, None], lines, 0.0) * 16).astype(np.int32)
        drawn = [line[ok] for line, ok in zip(rounded, finite, strict=True) if ok.sum() >= 2]
        if drawn:
            cv2.polylines(img, drawn, False, color, width, cv2.LINE_AA, 4)

    def draw(self, position: ArrayLike, rotation: ArrayLike) -> NDArray[np.uint8]:
        """The image (height, width, 3), RGB, uint8, with the platform at ``position``/``rotation``."""
        cv2 = _cv2()
        cam, k = self.camera, self.camera.intrinsics
        p, R = np.asarray(position, dtype=float), np.asarray(rotation, dtype=float)
        cam_p, cam_R = cam.pose(p, R)
        img = self._fresh_image(cam_p, cam_R)
        anchors = p + self.robot.platform_points @ R.T
        exits = self.robot.frame_points if self.robot.pulleys is None else pulley_geometry(  # or their pulleys'
            self.robot.frame_points, self.robot.pulleys, anchors).tangent_points
        self._lines(img, anchors, np.asarray(exits, dtype=float), cam_p, cam_R, CABLE_COLOR, 1)  # under the platform
        # the platform's faces, farthest first; each shaded by the cosine between its normal and the view
        quads = (p + self.platform_corners @ R.T)[self._faces]  # (6, 4, 3)
        centres = quads.mean(axis=1)
        normals = np.cross(quads[:, 1] - quads[:, 0], quads[:, 3] - quads[:, 0])
        normals /= np.linalg.norm(normals, axis=1)[:, None]
        normals *= np.where(np.einsum("ij,ij->i", normals, centres - p) < 0, -1.0, 1.0)[:, None]  # outward
        to_camera = cam_p - centres
        distances = np.linalg.norm(to_camera, axis=1)
        facing = np.einsum("ij,ij->i", normals, to_camera)
        shown = (facing > 0) & (((quads - cam_p) @ cam_R[:, 2] > NEAR).all(axis=1))  # not crossing the near plane
        order = [i for i in np.argsort(-distances, kind="stable") if shown[i]]
        if order:
            uv = project(quads[order].reshape(-1, 3), cam_p, cam_R, k, near=NEAR).pixels.reshape(len(order), 4, 2)
            for i, face in zip(order, np.round(uv * 16).astype(np.int32), strict=True):
                color = tuple(int(c) for c in PLATFORM_COLOR * (0.45 + 0.55 * facing[i] / distances[i]))
                cv2.fillConvexPoly(img, face, color, cv2.LINE_AA, 4)
        seen = cam.observe(p, R)
        for j in np.flatnonzero(seen.visible):
            u, v = seen.pixels[j]
            cv2.circle(img, (round(float(u) * 16), round(float(v) * 16)), 4 * 16, MARKER_COLOR, -1, cv2.LINE_AA, 4)
            cv2.putText(img, cam.marker_ids[j], (int(u) + 6, int(v) - 6), cv2.FONT_HERSHEY_SIMPLEX, 0.4,
                        MARKER_COLOR, 1, cv2.LINE_AA)
        return img


def encode_jpeg(image: NDArray[np.uint8], quality: int = 85) -> bytes:
    """An RGB image as JPEG bytes (OpenCV's channel swap: 0.02 ms for 640 × 480, where numpy's reversed view
    copied takes 0.9 ms; the encoding 0.4 ms)."""
    cv2 = _cv2()
    ok, data = cv2.imencode(".jpg", cv2.cvtColor(image, cv2.COLOR_RGB2BGR), [cv2.IMWRITE_JPEG_QUALITY, quality])
    if not ok:
        raise RuntimeError("OpenCV could not encode the image as JPEG")
    return bytes(data)


READY = "ready"  # the image process's first message once its first images are drawn
READY_TIMEOUT = 20.0  # s: the image process starts in ~1 s (imports, OpenCV, one image of each camera)


class RenderProcess:
    """Draws and encodes the images in a process of their own, so that drawing (numpy and Python between OpenCV's
    calls) never holds the loop's interpreter lock. The process starts at once and gets ready on its own
    (imports, OpenCV, one image of each camera drawn and encoded: the first image of a session costs what the
    others cost); :meth:`ready` waits for that — the sim does before it says it is there, so that a realtime
    session's first second does not share the CPUs with a process starting up (on two cores that cost 2–3
    points of the steps on time). :meth:`image` sends it a pose and waits for the JPEG (call it from the sim's
    image thread, not the loop's). The process ends with :meth:`close`, or when the sim's process is gone
    (its end of the pipe closes)."""

    def __init__(self, cameras: tuple[Camera, ...], robot: Robot) -> None:
        import multiprocessing

        ctx = multiprocessing.get_context("spawn")  # not fork: the sim's process has threads (Zenoh's)
        self._conn, child = ctx.Pipe()
        self._proc = ctx.Process(target=_serve, args=(child, cameras, robot), name="cdpr-camera-images",
                                 daemon=True)
        self._proc.start()
        child.close()
        self._ready: str | None = None  # "" once ready, else why it is not

    def ready(self, timeout: float = READY_TIMEOUT) -> str:
        """Wait (``timeout`` s at most) until the process has drawn its first images; "" when it has, else why
        not (then every image fails with that reason: OpenCV missing, the process gone). Waits in short slices,
        so that a process that died is seen at once."""
        if self._ready is None:
            deadline = time.monotonic() + timeout
            while not self._conn.poll(0.1) and self._proc.is_alive() and time.monotonic() < deadline:
                pass
            if not self._conn.poll(0):
                self._ready = (f"the image process was not ready after {timeout:g} s" if self._proc.is_alive()
                               else "the image process ended while starting")
            else:
                try:
                    reply = self._conn.recv()
                except (EOFError, OSError):
                    reply = "the image process ended while starting"
                self._ready = "" if reply == READY else str(reply)
        return self._ready

    def image(self, camera: str, position: ArrayLike, rotation: ArrayLike) -> bytes:
        if reason := self.ready():
            raise RuntimeError(reason)
        self._conn.send((camera, np.asarray(position, dtype=float), np.asarray(rotation, dtype=float)))
        reply = self._conn.recv()
        if isinstance(reply, str):
            raise RuntimeError(reply)
        return bytes(reply)

    def background(self) -> None:
        """From now on the images take only the CPU time the loop leaves (realtime: the loop's deadlines first;
        in fast mode, where the loop takes every CPU and waits for its images, they keep the normal priority)."""
        with contextlib.suppress(OSError):
            self._conn.send("background")

    def close(self) -> None:
        with contextlib.suppress(OSError):
            self._conn.send(None)
        self._proc.join(timeout=5.0)
        if self._proc.is_alive():
            self._proc.terminate()
            self._proc.join(timeout=5.0)
        self._conn.close()


def _serve(conn: Any, cameras: tuple[Camera, ...], robot: Robot) -> None:
    """The image process: ready (or why not) once each camera has drawn one image at the robot's home pose,
    then a pose in, a JPEG out (or the error's text), until told to stop or orphaned."""
    import signal

    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C stops the sim, which then stops this
    renderers: dict[str, Renderer] = {}
    try:
        renderers = {c.name: Renderer(c, robot) for c in cameras}
        # One thread: OpenCV's pool would split a 1 ms image over the CPUs the loop needs, its threads made
        # before the process lowers its priority (which is per thread) keeping the normal one.
        _cv2().setNumThreads(1)
        for r in renderers.values():
            encode_jpeg(r.draw(robot.home_position, robot.home_rotation))
        conn.send(READY)
    except (EOFError, OSError):
        return
    except Exception as exc:  # said to the sim, which says it once and counts the images it cannot have
        with contextlib.suppress(OSError):
            conn.send(f"{type(exc).__name__}: {exc}")
    while True:
        try:
            job = conn.recv()
        except (EOFError, OSError):
            return
        if job is None:
            return
        if job == "background":
            _lowest_priority()
            continue
        name, position, rotation = job
        try:
            conn.send(encode_jpeg(renderers[name].draw(position, rotation)))
        except (EOFError, OSError):
            return  # the sim is gone
        except Exception as exc:  # said to the sim, which counts it; the process goes on
            try:
                conn.send(f"{type(exc).__name__}: {exc}")
            except OSError:
                return


def _lowest_priority() -> None:
    """The lowest CPU priority there is: the images take only the CPU time the loop leaves (SCHED_IDLE where
    Linux has it, else the highest niceness)."""
    try:
        os.sched_setscheduler(0, os.SCHED_IDLE, os.sched_param(0))
    except (AttributeError, OSError):
        with contextlib.suppress(OSError):
            os.nice(19)
