"""Image-based visual servoing math (cdpr.mechanics.visual_servo): the lens inverted against OpenCV, the
interaction matrix and the platform Jacobians against finite differences of the projection, and the law's
exponential convergence in a kinematic loop."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from cdpr.mechanics.camera import Camera, Intrinsics, look_at, project
from cdpr.mechanics.rotation import rotvec_to_matrix, rpy_to_matrix
from cdpr.mechanics.visual_servo import (
    ibvs_twist,
    interaction_matrix,
    normalised,
    pixels_of,
    platform_jacobian,
)

K = Intrinsics(610.0, 605.0, 322.5, 241.0, 640, 480, (-0.21, 0.08, 0.0012, -0.0007, -0.015))
CORNERS = np.array([[0.6, 0.3, 0.2], [-0.6, 0.3, 0.2], [-0.6, -0.3, 0.2], [0.6, -0.3, 0.2]])


def test_normalised_inverts_the_lens_as_opencv_does() -> None:
    rng = np.random.default_rng(1)
    px = np.column_stack([rng.uniform(0, 640, 200), rng.uniform(0, 480, 200)])
    mine = normalised(px, K)
    cv = cv2.undistortPoints(px.reshape(-1, 1, 2), K.matrix, np.array(K.distortion),
                             criteria=(cv2.TERM_CRITERIA_COUNT, 20, 0.0)).reshape(-1, 2)
    np.testing.assert_allclose(mine, cv, atol=1e-9)
    np.testing.assert_allclose(pixels_of(mine, K), px, atol=1e-6)  # through the lens again


def _features(points_world: np.ndarray, c: np.ndarray, Rc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    local = (points_world - c) @ Rc
    return local[:, :2] / local[:, 2:3], local[:, 2]


def test_interaction_matrix_is_the_image_velocity_of_a_moving_camera() -> None:
    rng = np.random.default_rng(2)
    c, Rc = np.array([0.2, -0.1, 3.0]), look_at((0.2, -0.1, 3.0), (0.0, 0.1, 0.5))
    points = rng.uniform([-0.8, -0.6, 0.2], [0.8, 0.6, 1.0], (6, 3))
    xy, Z = _features(points, c, Rc)
    twist = np.array([0.1, -0.2, 0.05, 0.3, -0.1, 0.2])  # camera frame
    h = 1e-6
    c2 = c + Rc @ twist[:3] * h
    R2 = Rc @ rotvec_to_matrix(twist[3:] * h)
    xy2, _ = _features(points, c2, R2)
    np.testing.assert_allclose(interaction_matrix(xy, Z) @ twist, ((xy2 - xy) / h).ravel(), atol=1e-5)


@pytest.mark.parametrize("eye_in_hand", [False, True], ids=["eye_to_hand", "eye_in_hand"])
def test_platform_jacobian_is_the_image_velocity_of_a_moving_platform(eye_in_hand: bool) -> None:
    p, R = np.array([0.3, -0.2, 0.9]), rpy_to_matrix(0.05, -0.03, 0.2)
    if eye_in_hand:  # a camera under the platform, looking down at targets on the floor
        cam = Camera("down", K, True, np.array([0.0, 0.0, -0.25]), rpy_to_matrix(np.pi, 0.0, 0.0),
                     np.array([[0.2, -0.1, 0.0], [0.45, -0.1, 0.0], [0.3, -0.35, 0.0], [0.15, -0.3, 0.0]]),
                     False, ("a", "b", "c", "d"), 10)
    else:
        cam = Camera("top", K, False, np.array([0.0, 0.0, 3.4]), look_at((0, 0, 3.4), (0, 0, 0), (0, 1, 0)),
                     CORNERS, True, ("1", "2", "3", "4"), 10)

    def features(p: np.ndarray, R: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        c, Rc = cam.pose(p, R)
        xy, Z = _features(cam.markers_world(p, R), c, Rc)
        return xy, Z, c, Rc

    xy, Z, c, Rc = features(p, R)
    twist = np.array([0.1, -0.2, 0.05, 0.3, -0.1, 0.2])  # world frame, about the centre of mass
    h = 1e-6
    xy2, *_ = features(p + twist[:3] * h, rotvec_to_matrix(twist[3:] * h) @ R)
    J = platform_jacobian(xy, Z, Rc, c, p, eye_in_hand)
    np.testing.assert_allclose(J @ twist, ((xy2 - xy) / h).ravel(), atol=1e-5)


def test_the_law_drives_the_features_to_the_desired_image() -> None:
    """A kinematic loop (the platform moves with the commanded twist): the feature error decays as e^{−λt},
    to the desired image of a pose 0.3 m and 0.2 rad away."""
    cam = Camera("top", K, False, np.array([0.0, 0.0, 3.4]), look_at((0, 0, 3.4), (0, 0, 0), (0, 1, 0)),
                 CORNERS, True, ("1", "2", "3", "4"), 10)
    goal_p, goal_R = np.array([-0.1, 0.2, 0.8]), rpy_to_matrix(0.0, 0.0, 0.2)
    seen = cam.observe(goal_p, goal_R)
    desired = normalised(seen.pixels, K).ravel()
    p, R = np.array([0.15, -0.05, 0.6]), np.eye(3)
    dt, gain, errors = 0.01, 2.0, []
    for _ in range(1000):
        obs = cam.observe(p, R)
        assert obs.visible.all()
        s = normalised(obs.pixels, K)
        errors.append(np.linalg.norm(s.ravel() - desired))
        c, Rc = cam.pose(p, R)
        twist = ibvs_twist(s, desired, platform_jacobian(s, obs.depth, Rc, c, p, False), gain)
        p, R = p + twist[:3] * dt, rotvec_to_matrix(twist[3:] * dt) @ R
    assert errors[-1] < 1e-7 * errors[0]  # 10 s at λ = 2: e^-20
    rate = np.log(errors[100] / errors[200]) / (100 * dt)
    assert rate == pytest.approx(gain, rel=0.05)  # exponential, at the gain
    np.testing.assert_allclose(p, goal_p, atol=1e-6)
    np.testing.assert_allclose(R, goal_R, atol=1e-6)
    np.testing.assert_allclose(project(cam.markers_world(p, R), *cam.pose(p, R), K).pixels, seen.pixels, atol=1e-4)
