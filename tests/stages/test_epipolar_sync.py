"""The epipolar clock step (stage IV's last): robust fundamental matrices, the pairwise shift
search and the global solve, on synthetic views and on the simulator's crowd."""

from __future__ import annotations

import numpy as np
import pytest

from cascalib.calibration import Calibration
from cascalib.camera import Camera, look_at
from cascalib.geometry import rodrigues_to_matrix
from cascalib.simulate import simulate
from cascalib.stages.epipolar_sync import (
    PairShift,
    _solve_corrections,
    epipolar_clocks,
    fit_fundamental,
    hartley_normalization,
    pair_cost,
    sampson_distance,
)
from cascalib.stages.reconstruct import prepare


def _two_views(rng: np.random.Generator, n: int, noise_px: float
               ) -> tuple[np.ndarray, np.ndarray]:
    """Points of a person-sized volume seen by two cameras 90 degrees apart."""
    X = rng.uniform([-2, -2, 0], [2, 2, 1.8], size=(n, 3))

    def camera(eye: list[float], focal: float) -> Camera:
        R, t = look_at(eye, [0, 0, 1])
        K = np.array([[focal, 0, 640], [0, focal, 360], [0, 0, 1.0]])
        return Camera("c", (1280, 720), K, np.zeros(5), R, t)

    a, b = camera([8, 0, 3], 800), camera([0, 9, 2.5], 600)
    return (a.project(X) + rng.normal(0, noise_px, (n, 2)),
            b.project(X) + rng.normal(0, noise_px, (n, 2)))


def test_hartley_normalization_centres_and_scales() -> None:
    x = np.random.default_rng(0).uniform([100, 50], [900, 700], (200, 2))
    p, T = hartley_normalization(x)
    np.testing.assert_allclose(p[:, :2].mean(0), 0, atol=1e-12)
    np.testing.assert_allclose(np.linalg.norm(p[:, :2], axis=1).mean(), np.sqrt(2))
    np.testing.assert_allclose(np.c_[x, np.ones(200)] @ T.T, p)


def test_fundamental_fit_ignores_outliers() -> None:
    rng = np.random.default_rng(4)
    xa, xb = _two_views(rng, 2000, noise_px=1.0)
    far = rng.random(2000) < 0.05  # anywhere in the image: a wrong person
    near = ~far & (rng.random(2000) < 0.10)  # 10-40 px off: a swapped or misplaced joint
    xb[far] = rng.uniform([0, 0], [1280, 720], (far.sum(), 2))
    angle = rng.uniform(0, 2 * np.pi, near.sum())
    xb[near] += rng.uniform(10, 40, near.sum())[:, None] * np.c_[np.cos(angle), np.sin(angle)]
    bad = far | near
    F, d = fit_fundamental(xa, xb)
    assert np.linalg.matrix_rank(F) == 2
    np.testing.assert_allclose(d, sampson_distance(F, xa, xb))
    # the inliers fit to their noise: 1 px per coordinate puts 90 % within 1.7 px
    assert np.percentile(d[~bad], 90) < 2.0
    assert np.median(d[far]) > 20
    # without the reweighting the outliers drag the fit (90 % within 48 px)
    _, d_plain = fit_fundamental(xa, xb, n_iter=0)
    assert np.percentile(d_plain[~bad], 90) > 10


def _pair(i: int, j: int, shift: float, sd: float = 0.05) -> PairShift:
    return PairShift(i, j, shift, sd, 1000, np.zeros(0), np.zeros(0))


def test_global_solve_outvotes_a_wrong_pair() -> None:
    truth = np.array([0.0, 0.4, -0.3, 0.2])
    pairs = [_pair(i, j, truth[j] - truth[i]) for i in range(4) for j in range(i + 1, 4)]
    pairs[1] = _pair(0, 2, 0.9)  # one pair 1.2 frames off
    d, reached = _solve_corrections(4, 0, pairs, 0.3)
    np.testing.assert_allclose(d, truth, atol=1e-3)
    assert reached.all()
    # a camera that only a rejected pair reaches keeps its clock
    d, reached = _solve_corrections(3, 0, [_pair(0, 1, 0.2)], 0.3)
    assert reached.tolist() == [True, True, False] and d[2] == 0.0


@pytest.fixture(scope="module")
def terrace() -> tuple[list, Calibration]:
    sc = simulate("terrace", seed=0, duration_s=24.0)
    return sc.tracks, sc.truth


def _rig_with_errors(truth: Calibration, offsets: list[float]) -> Calibration:
    """The true rig with clock errors and the geometry errors stage IV leaves (2 deg, 4 %
    focal): the step must not depend on the geometry beyond matching persons."""
    rng = np.random.default_rng(3)
    cams = []
    for cam, err in zip(truth.cameras, offsets, strict=True):
        axis = rng.normal(size=3)
        R = rodrigues_to_matrix(axis / np.linalg.norm(axis) * np.radians(2.0)) @ cam.R
        K = cam.K.copy()
        K[:2, :2] *= 1.04
        cams.append(cam.with_(R=R, t=-R @ cam.center, K=K, time_offset=cam.time_offset + err))
    return Calibration(cams, reference_camera=truth.reference_camera)


def _corrected(scene: tuple[list, Calibration], errors: list[float], tolerance: float
               ) -> None:
    tracks, truth = scene
    start = _rig_with_errors(truth, errors)
    res = epipolar_clocks(tracks, start, rng=0)
    after = [c.time_offset - t.time_offset for c, t in zip(res.calibration, truth, strict=True)]
    assert after[0] == 0.0
    assert np.abs(after).max() < tolerance, after
    # only the clocks change
    for c, before in zip(res.calibration, start, strict=True):
        np.testing.assert_array_equal(c.R, before.R)
        assert c.time_rate == before.time_rate
    assert all(res.accepted.values())
    for name, err in zip(truth.names, errors, strict=True):
        assert res.corrections[name] == pytest.approx(-err, abs=tolerance)


def test_offsets_up_to_a_frame_are_corrected(terrace: tuple[list, Calibration]) -> None:
    _corrected(terrace, [0.0, 0.7, -0.6, 0.45], 0.15)


def test_offsets_beyond_the_window_are_found_by_widening(terrace: tuple[list, Calibration]
                                                        ) -> None:
    # 2.2 frames: the first search (+-1.5) ends on its edge and looks twice as far
    _corrected(terrace, [0.0, 2.2, -0.4, 0.3], 0.15)


def test_right_clocks_stay(terrace: tuple[list, Calibration]) -> None:
    tracks, truth = terrace
    res = epipolar_clocks(tracks, _rig_with_errors(truth, [0.0] * 4), rng=0)
    assert max(abs(v) for v in res.corrections.values()) < 0.1
    assert {(p.i, p.j) for p in res.pairs} >= {(0, 1), (0, 2), (0, 3)}


@pytest.mark.slow
def test_crowd_offsets_are_corrected() -> None:
    """A crowd of 15 on 640 x 480 cameras, where stage III's ground tracks leave offsets
    about half a frame off (bench_sync.py)."""
    sc = simulate("crowd", seed=1, duration_s=40.0)
    _corrected((sc.tracks, sc.truth), [0.0, 0.7, -0.6, 0.45], 0.25)


def test_pair_cost_grows_with_the_clock_error(terrace: tuple[list, Calibration]) -> None:
    tracks, truth = terrace
    cams = list(truth.cameras[:2])
    data = prepare(tracks[:2], Calibration(cams))
    times = np.linspace(0, data.times[-1], 300)

    def cost(shift: float) -> float:
        moved = [cams[0], cams[1].with_(time_offset=cams[1].time_offset + shift)]
        found = pair_cost(data.keypoints, data.links, moved, times, height=1.70, rng=0)
        assert found is not None and found[1] > 5000  # joints of hundreds of person-frames
        return found[0]

    # measured 2.02, 3.04, 5.78: people seen 2 and 5 frames apart fit no two-view geometry
    assert cost(0.0) < 0.75 * cost(2.0) < 0.75 * 0.75 * cost(5.0)
    blind = [np.full_like(k, np.nan) for k in data.keypoints]
    assert pair_cost(blind, data.links, cams, times, height=1.70) is None
