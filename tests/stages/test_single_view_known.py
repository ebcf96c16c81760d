"""Stage I with known intrinsics (checkerboard K and distortion): only the ground plane is fitted.

Scenes: people standing straight (the Drillis-Contini body of ``test_single_view``) seen by a
camera whose principal point is 2 % off the image centre, with ``fx != fy`` and barrel distortion
``k1 = -0.2``, i.e. everything the unknown-intrinsics model (square pixels, centred principal
point, no distortion) gets wrong.
"""

from __future__ import annotations

import numpy as np
import pytest
import test_single_view as sv  # module import: its tests are not collected twice

from cascalib.camera import Camera, look_at
from cascalib.errors import EstimationFailed, InputError
from cascalib.stages.single_view import SingleViewConfig, calibrate_single_view
from cascalib.tracks import Tracks

SIZE = sv.SIZE
W, H = SIZE
K = np.array([[900.0, 0.0, (W - 1) / 2 + 0.02 * W], [0.0, 906.0, (H - 1) / 2 - 0.02 * H],
              [0.0, 0.0, 1.0]])
DIST = np.array([-0.2, 0.0, 0.0, 0.0, 0.0])
CFG = SingleViewConfig(principal_point="center")


def distorted_scene(*, noise: float, seed: int, area: float = 7.0, n_persons: int = 6,
                    n_frames: int = 40, width: float = 1.0) -> tuple[Tracks, Camera]:
    """People at random places every frame, projected with ``K`` and ``DIST`` plus pixel noise.

    ``width`` 0 puts left and right joints on the body axis (exact model, see
    ``test_single_view._standing``).
    """
    rng = np.random.default_rng(seed)
    target = np.array([0.0, 5.0, 0.0])
    R, t = look_at((0.0, -9.0, 4.0), target)
    cam = Camera("cam", SIZE, K, DIST, R, t)
    J = np.empty((n_frames, n_persons, 26, 3))
    for k in range(n_frames):
        for p in range(n_persons):
            g = target[:2] + rng.uniform(-area, area, 2)
            J[k, p] = sv._standing(g, 1.70, rng.uniform(0, 2 * np.pi), width)
    uv = cam.project(J) + noise * rng.standard_normal(J.shape[:-1] + (2,))
    kp = np.concatenate([uv, np.ones(uv.shape[:-1] + (1,))], -1)
    inside = (uv[..., 0] >= 0) & (uv[..., 0] < W) & (uv[..., 1] >= 0) & (uv[..., 1] < H)
    kp[~inside] = np.nan
    return Tracks("cam", kp, "halpe26", image_size=SIZE), cam


def errors(res, cam: Camera) -> tuple[float, float]:
    """Normal error (deg) and relative camera-height error."""
    return sv.normal_error_deg(res, cam), abs(res.camera_height / cam.center[2] - 1)


@pytest.mark.parametrize("seed", [0, 1])
def test_known_intrinsics_recover_plane_better_than_unknown(seed):
    tracks, cam = distorted_scene(noise=0.5, seed=seed)
    known = calibrate_single_view(tracks, CFG, rng=seed, known_intrinsics=(K, DIST))
    unknown = calibrate_single_view(tracks, CFG, rng=seed)
    n_err, h_err = errors(known, cam)
    n_unk, h_unk = errors(unknown, cam)
    assert n_err < 0.15 and h_err < 0.01  # measured: <= 0.051 deg, <= 0.27 %
    assert n_err < n_unk and h_err < h_unk
    assert known.focal == K[0, 0] and known.focal_interval == (K[0, 0], K[0, 0])
    assert np.array_equal(known.principal_point, K[:2, 2])
    assert not known.principal_point_estimated
    assert known.n_inliers > 0.9 * len(known.inliers)


def test_to_camera_carries_known_intrinsics_and_reprojects():
    tracks, cam = distorted_scene(noise=0.0, seed=2, width=0.0)
    res = calibrate_single_view(tracks, CFG, rng=0, known_intrinsics=(K, DIST))
    assert sv.normal_error_deg(res, cam) < 1e-4
    assert res.camera_height == pytest.approx(cam.center[2], rel=1e-5)
    pc = res.to_camera()
    assert np.array_equal(pc.K, K) and np.array_equal(pc.dist, DIST)
    assert np.array_equal(res.K, K)
    # the true world's ground points seen through the plane-frame camera land on the same
    # (distorted) pixels: same intrinsics, same pose up to a yaw and a ground shift
    kp = tracks.canonical()[res.frames, res.persons]
    ankle_px = 0.5 * (kp[:, sv.CI["left_ankle"], :2] + kp[:, sv.CI["right_ankle"], :2])
    on_plane = pc.backproject_to_plane(ankle_px, z=0.039 * 1.70)
    assert np.allclose(pc.project(on_plane), ankle_px, atol=1e-6)
    top = on_plane + np.array([0.0, 0.0, (1.0 - 0.039) * 1.70])
    seen = np.isfinite(kp[:, sv.CI["head_top"], 0])
    assert np.allclose(pc.project(top)[seen], kp[seen, sv.CI["head_top"], :2], atol=1e-3)


def test_default_result_has_zero_distortion():
    tracks, _ = distorted_scene(noise=0.5, seed=3, n_frames=10)
    res = calibrate_single_view(tracks, CFG, rng=0)
    assert np.array_equal(res.dist, np.zeros(5)) and res.known_K is None
    assert np.array_equal(res.to_camera().dist, np.zeros(5))


def test_everyone_in_one_spot_is_refused_with_known_intrinsics():
    tracks, _ = distorted_scene(noise=0.5, seed=4, area=0.05)
    with pytest.raises(EstimationFailed, match="one spot.*ground plane") as info:
        calibrate_single_view(tracks, CFG, rng=0, known_intrinsics=(K, DIST))
    assert info.value.camera == "cam"


def test_bad_intrinsics_are_rejected():
    tracks, _ = distorted_scene(noise=0.5, seed=5, n_frames=2)
    with pytest.raises(InputError, match="known intrinsics"):
        calibrate_single_view(tracks, known_intrinsics=(K[:2], DIST))
