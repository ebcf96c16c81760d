"""The keypoint noise model: how a view's noise reaches the triangulation residuals, and the fit
of noise that grows with the person's size in the image."""

from __future__ import annotations

import numpy as np
import pytest

from cascalib.camera import Camera, look_at
from cascalib.stages.keypoint_noise import (
    fit_size_noise,
    person_pixel_height,
    residual_gains,
    size_noise_scale,
)
from cascalib.stages.triangulation import triangulate

HEIGHT = 1.7


def ring(n: int = 4, radius: float = 9.0) -> list[Camera]:
    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n + 0.3
        R, t = look_at([radius * np.cos(a), radius * np.sin(a), 2.7], [0, 0, 0.9])
        K = np.array([[600.0, 0, 319.5], [0, 600.0, 239.5], [0, 0, 1]])
        cams.append(Camera(f"cam{i}", (640, 480), K, np.zeros(5), R, t))
    return cams


def noisy_views(cams, a: float, b: float, n_groups: int = 1500, n_joints: int = 8, seed: int = 0):
    """Person-frames spread over a 14 x 14 m floor (near and far from every camera), joints
    seen by every camera with noise of s.d. sqrt(a + b h^2), h the person's height (px)."""
    rng = np.random.default_rng(seed)
    centre = np.column_stack([rng.uniform(-7, 7, (n_groups, 2)), np.full(n_groups, 0.9)])
    pts = centre[:, None, :] + rng.normal(0, [0.15, 0.15, 0.5], (n_groups, n_joints, 3))
    size = person_pixel_height(pts, cams, HEIGHT)  # (S, C)
    sigma = np.sqrt(a + b * size**2)
    uv = np.stack([cam.project(pts.reshape(-1, 3)).reshape(n_groups, n_joints, 2)
                   for cam in cams])  # (C, S, J, 2)
    uv = uv + rng.normal(size=uv.shape) * sigma.T[:, :, None, None]
    X, err = triangulate(cams, uv.reshape(len(cams), -1, 2), huber_px=1e6)
    errors = err.reshape(len(cams), n_groups, n_joints).transpose(1, 0, 2)  # (S, C, J)
    return X.reshape(n_groups, n_joints, 3), errors, size, sigma


def test_residual_gains_count_the_degrees_of_freedom():
    """Summed over views, the residual gains are the redundancy 2k - 3 of k views; a view with
    no weight passes none of its noise to the others."""
    cams = ring()
    pts = np.random.default_rng(1).uniform([-4, -4, 0], [4, 4, 1.8], (500, 3))
    w = np.ones((4, 500))
    w[3, :200] = 0.0
    g = residual_gains(pts, cams, w)
    np.testing.assert_allclose(g[200:].sum((1, 2)), 5.0, atol=1e-9)
    np.testing.assert_allclose(g[:200, :3, :3].sum((1, 2)), 3.0, atol=1e-9)
    np.testing.assert_allclose(g[:200, :3, 3], 0.0, atol=1e-12)
    # a view's own gain is below 2 (it explains part of its own noise), and far below it for
    # the view that dominates the point
    assert np.all(g[200:, np.arange(4), np.arange(4)] < 2.0)


@pytest.mark.parametrize(("a", "b"), [(1.0, 0.01**2), (2.25, 0.0)])
def test_fit_recovers_size_dependent_noise(a, b):
    """sigma^2 = a + b h^2 is recovered from triangulation residuals alone. Near views dominate
    their points and have small residuals whatever their noise: the same fit to the raw
    residuals (every gain 1 for its own view, 0 for the others) finds no growth with size at
    all (b = 0 in the first case: sigma 1.67 px at both ends instead of 1.22 and 2.83) and fails
    this."""
    cams = ring()
    pts, errors, size, _ = noisy_views(cams, a, b)
    n_s, n_c, n_j = errors.shape
    gains = residual_gains(pts.reshape(-1, 3), cams, np.ones((n_c, n_s * n_j)))
    fit = fit_size_noise(errors.transpose(0, 2, 1).reshape(-1, n_c), gains,
                         np.repeat(size, n_j, axis=0))
    assert fit is not None
    # sigma at the small and large ends of the sizes seen, within 8 %
    for h in np.percentile(size, [10, 90]):
        true, got = np.sqrt(a + b * h * h), np.sqrt(fit[0] + fit[1] * h * h)
        assert abs(got / true - 1) < 0.08, (h, true, got, fit)


def test_scale_is_relative_and_follows_size():
    cams = ring()
    pts, errors, size, sigma = noisy_views(cams, 1.0, 0.012**2)
    w = np.where(np.isfinite(errors), 1.0, 0.0)
    scale = size_noise_scale(errors, pts, cams, w, HEIGHT)
    assert scale.shape == size.shape
    assert abs(np.median(scale) - 1.0) < 0.02
    rel = sigma / np.median(sigma)
    inside = rel < 3.5  # beyond 4 the weights are clipped (persons next to a camera)
    assert np.corrcoef(scale[inside], rel[inside])[0, 1] > 0.99
    np.testing.assert_allclose(scale[inside], rel[inside], rtol=0.1)
    assert np.all(scale[rel > 4.5] == 4.0)


def test_constant_noise_gives_equal_weights():
    cams = ring()
    pts, errors, _, _ = noisy_views(cams, 4.0, 0.0, seed=3)
    scale = size_noise_scale(errors, pts, cams, np.where(np.isfinite(errors), 1.0, 0.0), HEIGHT)
    assert np.all(np.abs(scale - 1.0) < 0.1), np.percentile(scale, [1, 99])


def test_too_few_views_give_equal_weights():
    cams = ring()
    pts, errors, _, _ = noisy_views(cams, 1.0, 1e-4, n_groups=4, n_joints=2)
    scale = size_noise_scale(errors, pts, cams, np.ones(errors.shape), HEIGHT)
    assert np.all(scale == 1.0)
