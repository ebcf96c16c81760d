"""Stage V on lenses with distortion: a lens the cameras carry is held by every later solve."""

from __future__ import annotations

import numpy as np
from refine_scene import make_scene

from cascalib.calibration import Calibration
from cascalib.geometry import rotation_angle_deg
from cascalib.stages.refine import refine
from cascalib.stages.refine_config import RefineConfig


def relative_rotation_errors(est: Calibration, truth: Calibration) -> np.ndarray:
    """Geodesic error (deg) of every camera pair's relative rotation."""
    e, t = est.cameras, truth.cameras
    return np.array([rotation_angle_deg((e[i].R @ e[j].R.T) @ (t[i].R @ t[j].R.T).T)
                     for i in range(len(t)) for j in range(i + 1, len(t))])


def test_a_lens_the_cameras_carry_is_held_by_every_pinhole_solve():
    """From the true rig with its lens (noise-free keypoints), pinhole solves (one focal, the
    principal point held) undistort the keypoints with that lens: the rig stays where it is
    and every camera comes back with its lens. A solve that ignored the lens would fit a
    pinhole to distorted keypoints (and return no lens)."""
    scene = make_scene(n_frames=30, n_persons=2, noise_px=0.0, offsets=(0, 0, 0, 0), seed=3,
                       distortion=(-0.2, 0.05, 0.001, -0.001, 0.0), principal_offset=0.01)
    cfg = RefineConfig(max_groups=40, distortion="never", principal_point="never",
                       refine_time=False, n_rounds=1)
    res = refine(scene.tracks, scene.truth, cfg, height=float(scene.heights.mean()), rng=0)
    assert not res.distortion  # no lens pass ran: the lens was given
    assert relative_rotation_errors(res.calibration, scene.truth).max() < 0.02
    for est, true in zip(res.calibration, scene.truth, strict=True):
        np.testing.assert_array_equal(est.dist, true.dist)
        assert abs(est.focal / true.focal - 1) < 1e-3
        np.testing.assert_allclose(est.principal_point, true.principal_point, atol=1e-6)
        assert res.quality[est.name].reprojection_median_px < 0.05
