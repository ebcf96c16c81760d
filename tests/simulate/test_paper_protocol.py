"""The supplement's single-view simulation protocol."""

from __future__ import annotations

import numpy as np
import pytest

from cascalib.simulate import paper_protocol as pp


def test_sample_geometry_is_consistent():
    s = pp.sample(6, 0.0, 0.1, height=1.7, rng=0)
    assert s.image_size == (1920, 1080) and s.focal == 960.0
    assert s.camera.focal == 960.0
    np.testing.assert_allclose(s.ankles, s.ankles_true)
    # shoulder centre = ankle centre + h * n, in camera coordinates
    np.testing.assert_allclose(s.shoulders3d - s.ankles3d, s.heights[:, None] * s.normal_cam,
                               atol=1e-12)
    # every ankle lies on the plane at distance camera_height from the camera centre
    np.testing.assert_allclose(-(s.ankles3d @ s.normal_cam), s.camera_height, rtol=1e-12)
    # pixels are the pinhole projection with K = [[960, 0, cx], [0, 960, cy], [0, 0, 1]]
    cx, cy = s.principal_point
    proj = 960.0 * s.ankles3d[:, :2] / s.ankles3d[:, 2:] + [cx, cy]
    np.testing.assert_allclose(proj, s.ankles_true, atol=1e-9)
    for uv in (s.ankles_true, s.shoulders_true):
        assert np.all((uv >= 0) & (uv <= [1919, 1079]))
    assert np.linalg.norm(s.normal_cam) == pytest.approx(1.0)
    assert s.normal_cam[1] < 0  # "up" points to the top of the image (camera y is down)


def test_noise_and_heights_have_the_requested_spread():
    samples = [pp.sample(10, 2.0, 0.2, height=1.7, rng=i) for i in range(60)]
    noise = np.concatenate([s.ankles - s.ankles_true for s in samples])
    assert noise.std() == pytest.approx(2.0, rel=0.1)
    h = np.concatenate([s.heights for s in samples])
    assert h.mean() == pytest.approx(1.7, abs=0.05) and h.std() == pytest.approx(0.2, rel=0.15)
    fixed = pp.sample(3, 0.5, 0.0, height=1.6, rng=1)
    np.testing.assert_array_equal(fixed.heights, 1.6)


def test_sweeps_are_the_papers():
    assert pp.SWEEPS["measurement_noise"]["values"] == (0.1, 0.2, 0.5, 1.0, 2.0, 5.0)
    assert pp.SWEEPS["measurement_noise"]["fixed"]["height"] == 1.6
    assert pp.SWEEPS["height_variation"]["values"] == (0.05, 0.1, 0.15, 0.2, 0.25)
    assert pp.SWEEPS["number_of_people"]["values"] == (5, 10, 20, 50, 100)
    trials = pp.sweep("number_of_people", 2, rng=0)
    assert [len(v[0].heights) for v in trials.values()] == [5, 10, 20, 50, 100]


def test_errors_are_zero_for_the_truth_and_grow_with_the_error():
    s = pp.sample(3, 0.5, rng=3)
    e = pp.errors(s, s.focal, s.normal_cam, s.camera_height, s.ankles3d)
    assert all(v == pytest.approx(0.0, abs=1e-9) for v in e.values())
    e = pp.errors(s, 1.1 * s.focal, s.normal_cam, 0.9 * s.camera_height, 1.05 * s.ankles3d)
    assert e["focal_pct"] == pytest.approx(10.0)
    assert e["height_pct"] == pytest.approx(10.0)
    assert e["points_pct"] == pytest.approx(5.0)


def test_deterministic_for_a_seed():
    a, b = pp.sample(5, 1.0, 0.1, rng=11), pp.sample(5, 1.0, 0.1, rng=11)
    np.testing.assert_array_equal(a.ankles, b.ankles)
    np.testing.assert_array_equal(a.normal_cam, b.normal_cam)
