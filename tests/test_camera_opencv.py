"""Camera model and geometry helpers against OpenCV, beyond tests/test_core.py: the projection
matrix, camera centre, rays, Rodrigues near 0 and 180 degrees, Umeyama, and undistortion over
whole images with the strong real lenses of the caliscope rig."""

from __future__ import annotations

import cv2
import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cascalib import Camera
from cascalib.camera import distort_normalized, look_at
from cascalib.formats import load_calibration
from cascalib.geometry import (
    matrix_to_rodrigues,
    project_to_so3,
    rodrigues_to_matrix,
    rotation_angle_deg,
    umeyama,
)


def _camera(dist=None) -> Camera:
    R, t = look_at([3.0, -5.0, 2.2], [0.2, 0.4, 0.9])
    return Camera.from_params("c", (1280, 720), (910.0, 905.0), R, t, c=(650.0, 350.0),
                              dist=dist)


def test_projection_matrix_and_centre_match_opencv_decomposition():
    cam = _camera()
    X = np.random.default_rng(0).uniform(-2, 2, (50, 3))
    h = np.c_[X, np.ones(50)] @ cam.P.T
    np.testing.assert_allclose(h[:, :2] / h[:, 2:], cam.project(X), atol=1e-9)
    K, R, C, *_ = cv2.decomposeProjectionMatrix(cam.P)
    np.testing.assert_allclose(K / K[2, 2], cam.K, atol=1e-9)
    np.testing.assert_allclose(R, cam.R, atol=1e-12)
    np.testing.assert_allclose(C[:3, 0] / C[3, 0], cam.center, atol=1e-9)


@pytest.mark.parametrize("dist", [None, [-0.3, 0.1, 0.001, -0.002, -0.02]])
def test_rays_pass_through_the_projected_points(dist):
    cam = _camera(dist)
    X = np.random.default_rng(1).uniform(-1.5, 1.5, (100, 3)) + [0, 0, 1]
    d = cam.rays(cam.project(X))
    np.testing.assert_allclose(np.linalg.norm(d, axis=1), 1, atol=1e-12)
    to_point = X - cam.center
    along = (to_point * d).sum(1)
    assert (along > 0).all()  # rays point forward, towards the points
    np.testing.assert_allclose(cam.center + along[:, None] * d, X, atol=1e-7)


def test_nan_pixels_and_points_stay_nan():
    cam = _camera([-0.2, 0.05, 0, 0, 0])
    uv = np.array([[np.nan, 10.0], [100.0, 200.0]])
    assert np.isnan(cam.undistort(uv)[0]).all() and np.isfinite(cam.undistort(uv)[1]).all()
    assert np.isnan(cam.project(np.array([[np.nan, 0, 0]]))).all()
    assert cam.rays(np.zeros((4, 0, 2))).shape == (4, 0, 3)


def test_undistortion_inverts_the_real_strong_lenses_over_the_whole_image(shared_data):
    """caliscope webcams have k1 = -0.34 (cam_0) and k1 = +0.19 with k3 = 0.15: the iterative
    inversion must still reach every pixel, corners included."""
    calib = load_calibration(shared_data / "caliscope_4cam" / "config.toml")
    for cam in calib:
        W, H = cam.image_size
        u, v = np.meshgrid(np.linspace(0, W - 1, 33), np.linspace(0, H - 1, 19))
        uv = np.stack([u.ravel(), v.ravel()], axis=1)
        xy = cam.undistort(uv)
        back = cam._normalized_to_pixels(distort_normalized(xy, cam.dist))
        np.testing.assert_allclose(back, uv, atol=1e-6, err_msg=cam.name)
        # and projecting the back-projected rays lands on the same pixels, as OpenCV says
        X = cam.center + 3.0 * cam.rays(uv)
        ref, _ = cv2.projectPoints(X, cv2.Rodrigues(cam.R)[0], cam.t, cam.K, cam.dist)
        np.testing.assert_allclose(ref.reshape(-1, 2), uv, atol=1e-6, err_msg=cam.name)


@pytest.mark.parametrize("angle", [0.0, 1e-9, 1e-4, 0.7, 2.0, np.pi - 1e-6, np.pi])
def test_rodrigues_matches_opencv_near_0_and_180_degrees(angle):
    axis = np.array([0.36, -0.48, 0.8])
    rvec = angle * axis
    R = rodrigues_to_matrix(rvec)
    np.testing.assert_allclose(R, cv2.Rodrigues(rvec)[0], atol=1e-12)
    back = matrix_to_rodrigues(R)
    # at exactly 180 degrees +axis and -axis are the same rotation
    np.testing.assert_allclose(rodrigues_to_matrix(back), R, atol=1e-12)
    assert rotation_angle_deg(R) == pytest.approx(np.degrees(angle), abs=1e-9)


def test_project_to_so3_and_umeyama():
    rng = np.random.default_rng(4)
    R = Rotation.from_rotvec([0.4, -1.1, 0.3]).as_matrix()
    noisy = R + rng.normal(0, 1e-3, (3, 3))
    P = project_to_so3(noisy)
    np.testing.assert_allclose(P @ P.T, np.eye(3), atol=1e-12)
    assert np.linalg.det(P) == pytest.approx(1.0)
    assert rotation_angle_deg(P @ R.T) < 0.2
    reflection = project_to_so3(np.diag([1.0, 1.0, -1.0]))
    assert np.linalg.det(reflection) == pytest.approx(1.0)
    src = rng.normal(size=(10, 3))
    dst = 2.5 * src @ R.T + [1.0, -2.0, 0.5]
    s, R_est, t = umeyama(src, dst)
    assert s == pytest.approx(2.5) and rotation_angle_deg(R_est @ R.T) < 1e-9
    np.testing.assert_allclose(t, [1.0, -2.0, 0.5], atol=1e-12)
    # mirrored data must still give a rotation, never a reflection
    _, R_m, _ = umeyama(src, src * [1, 1, -1], with_scale=False)
    assert np.linalg.det(R_m) == pytest.approx(1.0)


def test_look_at_axes_follow_opencv_convention():
    eye, target = np.array([4.0, 3.0, 2.0]), np.array([0.0, 0.0, 1.0])
    R, t = look_at(eye, target)
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-12)
    cam = Camera.from_params("c", (640, 480), 500.0, R, t)
    np.testing.assert_allclose(cam.project(target[None])[0], [319.5, 239.5], atol=1e-9)
    above = cam.project((target + [0, 0, 0.5])[None])[0]
    assert above[1] < 239.5  # world up is image up (OpenCV y points down)
    # straight down: still a valid rotation
    R, _ = look_at([0, 0, 5.0], [0, 0, 0.0])
    assert np.linalg.det(R) == pytest.approx(1.0)


@pytest.mark.parametrize("dist", [None, [-0.25, 0.07, 0.001, -0.002, -0.01]])
def test_skewed_camera_undistort_inverts_project(dist):
    """OpenCV's projectPoints/undistortPoints ignore K[0, 1]; cascalib applies the full K in both
    directions, so a skewed camera stays self-consistent (and equals OpenCV when skew = 0)."""
    R, t = look_at([3.0, -5.0, 2.2], [0.2, 0.4, 0.9])
    K = np.array([[910.0, 4.0, 650.0], [0.0, 905.0, 350.0], [0.0, 0.0, 1.0]])
    cam = Camera("c", (1280, 720), K, dist, R, t)
    X = np.random.default_rng(5).uniform(-1.5, 1.5, (100, 3)) + [0, 0, 1]
    Xc = cam.world_to_cam(X)
    np.testing.assert_allclose(cam.undistort(cam.project(X)), Xc[:, :2] / Xc[:, 2:], atol=1e-12)
    no_skew = cam.with_(K=K * [[1, 0, 1], [1, 1, 1], [1, 1, 1]])
    shift = cam.project(X) - no_skew.project(X)
    xy = distort_normalized(Xc[:, :2] / Xc[:, 2:], cam.dist) if dist else Xc[:, :2] / Xc[:, 2:]
    np.testing.assert_allclose(shift[:, 0], 4.0 * xy[:, 1], atol=1e-9)  # u += s * y
