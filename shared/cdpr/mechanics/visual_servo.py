"""Image-based visual servoing (IBVS): the classical interaction-matrix law, for a camera on the frame looking at
markers on the platform (eye-to-hand) or a camera on the platform looking at fixed targets (eye-in-hand).
Pure numpy, no I/O.

Features are the markers' normalised image coordinates ``s = (x_1, y_1, …, x_n, y_n)`` (``x = X/Z``, ``y = Y/Z``
in the camera frame: OpenCV's convention, :mod:`cdpr.mechanics.camera`), recovered from pixels by inverting the
lens model (:func:`normalised`). For a point at depth ``Z`` the classical interaction matrix (Chaumette and
Hutchinson, "Visual servo control, Part I", IEEE RAM 2006) relates its image velocity to the camera's twist
``(v_c, ω_c)`` in the camera frame, the point being fixed:

    ṡ = L (v_c, ω_c),   L = [[-1/Z, 0, x/Z, x y, -(1 + x²), y], [0, -1/Z, y/Z, 1 + y², -x y, -x]]

:func:`platform_jacobian` turns it into ``ṡ = J (v, ω)`` for the **platform's** twist (world frame, about its
centre of mass, the project's convention) in both mountings, and :func:`ibvs_twist` is the law
``(v, ω) = −λ J⁺ (s − s*)``: the platform twist that makes the feature error decay exponentially.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

from cdpr.mechanics.camera import Intrinsics, distort
from cdpr.mechanics.rotation import Array


def normalised(pixels: ArrayLike, k: Intrinsics, iterations: int = 20) -> Array:
    """Pixels (n, 2) → normalised coordinates (n, 2) without the lens distortion (the fixed point iteration
    OpenCV's ``undistortPoints`` uses: exact to float precision inside the image for usual lenses)."""
    uv = np.asarray(pixels, dtype=float).reshape(-1, 2)
    xd = (uv[:, 0] - k.cx) / k.fx
    yd = (uv[:, 1] - k.cy) / k.fy
    x, y = xd.copy(), yd.copy()
    if any(k.distortion):
        k1, k2, t1, t2, k3 = k.distortion
        for _ in range(iterations):
            r2 = x * x + y * y
            radial = 1.0 + r2 * (k1 + r2 * (k2 + r2 * k3))
            dx = 2.0 * t1 * x * y + t2 * (r2 + 2.0 * x * x)
            dy = t1 * (r2 + 2.0 * y * y) + 2.0 * t2 * x * y
            x, y = (xd - dx) / radial, (yd - dy) / radial
    return np.column_stack([x, y])


def pixels_of(normalised_xy: ArrayLike, k: Intrinsics) -> Array:
    """Normalised coordinates (n, 2) → pixels (n, 2) through the lens (the inverse of :func:`normalised`)."""
    xy = np.asarray(normalised_xy, dtype=float).reshape(-1, 2)
    xd, yd = distort(xy[:, 0], xy[:, 1], k.distortion)
    return np.column_stack([k.fx * xd + k.cx, k.fy * yd + k.cy])


def interaction_matrix(xy: ArrayLike, depth: ArrayLike) -> Array:
    """The classical interaction matrix (2n, 6) of points at normalised ``xy`` (n, 2) and depths (n,): image
    velocity per camera twist (v_c, ω_c), camera frame, the points fixed (module docstring)."""
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    Z = np.asarray(depth, dtype=float).reshape(-1)
    x, y = xy[:, 0], xy[:, 1]
    n = len(x)
    L = np.zeros((2 * n, 6))
    L[0::2, 0] = -1.0 / Z
    L[0::2, 2] = x / Z
    L[0::2, 3] = x * y
    L[0::2, 4] = -(1.0 + x * x)
    L[0::2, 5] = y
    L[1::2, 1] = -1.0 / Z
    L[1::2, 2] = y / Z
    L[1::2, 3] = 1.0 + y * y
    L[1::2, 4] = -x * y
    L[1::2, 5] = -x
    return L


def platform_jacobian(xy: ArrayLike, depth: ArrayLike, camera_rotation: ArrayLike, camera_position: ArrayLike,
                      platform_position: ArrayLike, eye_in_hand: bool) -> Array:
    """``J`` (2n, 6) with ``ṡ = J (v, ω)``, ``(v, ω)`` the platform's twist (world frame, about its centre of
    mass ``platform_position``). ``camera_rotation``/``camera_position``: the camera's pose in the world now.

    Eye-to-hand (a fixed camera, markers on the platform): each marker P moves at ``Ṗ = v + ω × (P − p)``,
    which the image sees as a fixed point seen from a camera translating at ``v_c = −Rcᵀ Ṗ`` (the translational
    columns of L, point by point; the camera does not turn). Eye-in-hand (the camera on the
    platform, fixed targets): the camera's twist is the platform's carried to the camera's centre, ``v_c =
    Rcᵀ (v + ω × (c − p))``, ``ω_c = Rcᵀ ω``.
    """
    xy = np.asarray(xy, dtype=float).reshape(-1, 2)
    Z = np.asarray(depth, dtype=float).reshape(-1)
    Rc = np.asarray(camera_rotation, dtype=float)
    c = np.asarray(camera_position, dtype=float)
    p = np.asarray(platform_position, dtype=float)
    L = interaction_matrix(xy, Z)
    n = len(Z)
    J = np.empty((2 * n, 6))
    if eye_in_hand:
        lever = c - p
        # (v_c, ω_c) = T (v, ω): v_c = Rcᵀ v − Rcᵀ [lever]× ω, ω_c = Rcᵀ ω
        T = np.zeros((6, 6))
        T[:3, :3] = Rc.T
        T[:3, 3:] = -Rc.T @ _skew(lever)
        T[3:, 3:] = Rc.T
        return L @ T
    points = c + (np.column_stack([xy, np.ones(n)]) * Z[:, None]) @ Rc.T  # the markers in the world
    arms = points - p
    for i in range(n):
        # the marker's velocity Ṗ = v + ω × a (a = P − p), in the camera frame Rcᵀ Ṗ: to the image as a fixed
        # point seen from a camera translating by −Rcᵀ Ṗ (the translational columns of L; no camera rotation)
        T = np.zeros((3, 6))
        T[:, :3] = -Rc.T
        T[:, 3:] = Rc.T @ _skew(arms[i])  # −Rcᵀ (ω × a) = Rcᵀ [a]× ω
        J[2 * i:2 * i + 2] = L[2 * i:2 * i + 2, :3] @ T
    return J


def ibvs_twist(features: ArrayLike, desired: ArrayLike, jacobian: ArrayLike, gain: float) -> Array:
    """The platform twist (6,) of the IBVS law ``−λ J⁺ (s − s*)``: the feature error, driven as ṡ = J (v, ω),
    decays as ``e^{−λ t}`` where J is right."""
    e = np.asarray(features, dtype=float).reshape(-1) - np.asarray(desired, dtype=float).reshape(-1)
    return -gain * (np.linalg.pinv(np.asarray(jacobian, dtype=float)) @ e)


def _skew(a: Array) -> Array:
    return np.array([[0.0, -a[2], a[1]], [a[2], 0.0, -a[0]], [-a[1], a[0], 0.0]])

