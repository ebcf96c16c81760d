"""Stage II pieces: ground trajectories, the offset vote, the global clock solve, rotation search,
the assignment and ICP, on synthetic ground tracks with known answers."""

from __future__ import annotations

import numpy as np
import pytest
from align_scene import make_scene
from scipy.optimize import linear_sum_assignment

from cascalib.stages.ground import (
    GroundTracks,
    Tracklet,
    ground_points,
    ground_trajectories,
    link_tracklets,
    remove_outliers,
)
from cascalib.stages.icp import Similarity2D, assign_frames, dense_lanes, icp_pair, refine_sync
from cascalib.stages.rotation import rotation_search
from cascalib.stages.sync import _chunk_fit, resample_tracks, search_offsets, solve_time


def _walk(rng: np.random.Generator, n: int, speed: float = 0.05) -> np.ndarray:
    """Smooth random 2D path (n, 2), ``speed`` metres per frame."""
    h = np.cumsum(np.convolve(rng.normal(0, 0.08, n + 40), np.ones(20) / 20, "same"))[:n]
    return np.cumsum(speed * np.c_[np.cos(h), np.sin(h)], axis=0)


def _ground(name: str, paths: list[np.ndarray], frames: np.ndarray) -> GroundTracks:
    n = int(frames.max()) + 1
    xy = np.full((n, len(paths), 2), np.nan)
    tls = []
    for p, path in enumerate(paths):
        xy[frames, p] = path
        tls.append(Tracklet(frames.astype(np.int64), path, np.full(frames.size, p)))
    return GroundTracks(name, n, xy, tls, 0)


def _pair(offset: int, angle: float, rng: np.random.Generator, n: int = 600,
          n_persons: int = 3, noise: float = 0.02):
    """Camera B sees the world rotated by -angle and shifted; B's frame k shows A's frame
    k + offset."""
    paths = [_walk(rng, n + abs(offset) + 10) + rng.uniform(-4, 4, 2) for _ in range(n_persons)]
    lo = max(0, -offset)
    fa = np.arange(n)
    a = [p[lo + fa] + rng.normal(0, noise, (n, 2)) for p in paths]
    T = Similarity2D(angle, np.array([1.5, -2.0]))  # x_a = T(x_b)
    b = [T.inverse().apply(p[lo + fa + offset]) + rng.normal(0, noise, (n, 2)) for p in paths]
    return _ground("a", a, fa), _ground("b", b, fa), T


@pytest.mark.parametrize("offset", [0, 137, -251])
def test_search_offsets_finds_offset_and_angle(offset: int) -> None:
    rng = np.random.default_rng(offset + 500)
    ga, gb, T = _pair(offset, 2.0, rng)
    a, b = resample_tracks(ga, 1.0, 2.0), resample_tracks(gb, 1.0, 2.0)
    curve = search_offsets(a, b, chunk_seconds_frames=120, min_overlap=20)
    best = curve.candidates[0]
    assert abs(best.offset - offset) <= 4  # coarse: the ICP and the sub-frame fit refine it
    assert abs(np.angle(np.exp(1j * (best.angle - T.angle)))) < np.radians(8)
    # nearby offsets fit almost as well (a straight walk shifted in time is a translation):
    # the coarse peak is broad, the ICP verification decides; far peaks must be weaker
    far = [c for c in curve.candidates if abs(c.offset - offset) > 40]
    assert all(c.score < 0.5 * best.score for c in far)
    assert curve.score.argmax() == np.argmin(np.abs(curve.offsets - best.offset))
    # the vote's rotation at every offset (the start of the ambiguous-pair scan's ICP): at
    # the peak it is the candidate's, to the 10-degree bin
    assert curve.angles is not None and curve.angles.shape == curve.offsets.shape
    at_peak = curve.angles[curve.score.argmax()]
    assert abs(np.angle(np.exp(1j * (at_peak - T.angle)))) < np.radians(10)


def test_chunk_fit_equals_direct_procrustes_fit() -> None:
    """The FFT vote of a block of chunks against lanes with gaps equals, lag by lag, the
    closed-form similarity fit of the overlapping samples computed directly."""
    rng = np.random.default_rng(11)
    n_fft, min_samples, scale_range, sigma = 96, 6, 1.3, 0.4
    lanes = []
    for _ in range(3):
        z = np.full(60, np.nan + 0j)
        s0 = int(rng.integers(0, 20))
        z[s0:s0 + 35] = rng.normal(0, 1, 35) + 1j * rng.normal(0, 1, 35)
        z[s0 + 10:s0 + 13] = np.nan  # a gap inside the tracklet
        lanes.append(z)
    mb = np.array([np.isfinite(z) for z in lanes], float)
    zb = np.nan_to_num(np.array(lanes))
    G = (np.fft.fft(mb, n_fft), np.fft.fft(zb, n_fft), np.fft.fft(mb * np.abs(zb) ** 2, n_fft))
    parts = [rng.normal(0, 1, (n, 2)) for n in (12, 9, 12)]
    parts[0][4] = np.nan  # a missed sample in a chunk
    lags = np.arange(-11, 60)
    sup, ang = _chunk_fit(parts, G, n_fft, lags % n_fft, min_samples, scale_range, sigma)
    assert sup.shape == ang.shape == (3, lags.size)
    for k, part in enumerate(parts):
        za = part[:, 0] + 1j * part[:, 1]
        for j, lag in enumerate(lags):
            best, best_angle = 0.0, None
            for z in lanes:
                i = np.arange(len(za))
                ok = np.isfinite(za) & (i + lag >= 0) & (i + lag < len(z))
                ok[ok] &= np.isfinite(z[(i + lag)[ok]])
                n = int(ok.sum())
                if n < min_samples:
                    continue
                a, b = za[ok] - za[ok].mean(), z[i[ok] + lag] - z[i[ok] + lag].mean()
                x = np.sum(np.conj(a) * b)
                va, vb = np.sum(np.abs(a) ** 2), np.sum(np.abs(b) ** 2)
                s = np.clip(abs(x) / va, 1 / scale_range, scale_range)
                res = max(vb - 2 * s * abs(x) + s * s * va, 0.0) / n
                vote = n * np.exp(-0.5 * res / sigma**2)
                if vote > best:
                    best, best_angle = vote, np.angle(x)
            assert sup[k, j] == pytest.approx(best, rel=1e-9, abs=1e-9)
            if best_angle is not None:
                assert abs(np.angle(np.exp(1j * (ang[k, j] - best_angle)))) < 1e-9


def test_icp_and_refine_recover_subframe_offset_and_rate() -> None:
    rng = np.random.default_rng(3)
    n, rate, off = 700, 1.0004, 40.3
    paths = [_walk(rng, 900) + rng.uniform(-4, 4, 2) for _ in range(3)]
    t = np.arange(900.0)
    fa = np.arange(n)
    a = [p[100 + fa] for p in paths]
    ub = fa  # B frame k shows A frame rate * k + off
    T = Similarity2D(-1.1, np.array([0.5, 3.0]), 1.04)
    b = [T.inverse().apply(np.c_[np.interp(100 + rate * ub + off, t, p[:, 0]),
                                 np.interp(100 + rate * ub + off, t, p[:, 1])]) for p in paths]
    ga, gb = _ground("a", a, fa), _ground("b", b, fa)
    fa_, fb_ = resample_tracks(ga, 1.0, 1.0), resample_tracks(gb, 1.0, 1.0)
    la, lb = dense_lanes(fa_), dense_lanes(fb_)
    icp = icp_pair(la, lb, 40, -1.0, scale_range=1.2)
    assert icp is not None and icp.rms < 0.05
    fit = refine_sync(fa_, fb_, la, lb, icp, 40, scale_range=1.2, rng=0)
    assert fit.offset == pytest.approx(off, abs=0.02)
    assert fit.rate == pytest.approx(rate, abs=2e-5)
    assert fit.transform.angle == pytest.approx(T.angle, abs=1e-3)
    assert fit.transform.scale == pytest.approx(1.04, abs=1e-3)


def test_solve_time_outvotes_one_wrong_pair() -> None:
    # 4 cameras, true offsets 0, 100, -50, 220 and rates 1, 1.001, 1, 0.999
    a_true = np.array([1.0, 1.001, 1.0, 0.999])
    b_true = np.array([0.0, 100.0, -50.0, 220.0])
    edges = []
    for i in range(4):
        for j in range(i + 1, 4):
            rate = a_true[j] / a_true[i]
            off = (b_true[j] - b_true[i]) / a_true[i]
            edges.append((i, j, off, np.log(rate), 1.0))
    edges[4] = (1, 3, edges[4][2] + 180.0, edges[4][3], 1.0)  # a period-off pair
    a, b, ok = solve_time(4, edges, 0)
    np.testing.assert_allclose(b, b_true, atol=1e-6)
    np.testing.assert_allclose(a, a_true, rtol=1e-9)
    assert ok.tolist() == [True, True, True, True, False, True]


def test_solve_time_keeps_one_pairs_false_drift_out_of_the_rates() -> None:
    # same fps everywhere; pair 0-1 reports a 0.3 % drift at 4 s.d. (crowd, 40 s, seed 0), the
    # five others no drift. Averaging it in put 0.09-0.17 % on every camera: 1.6 frames over
    # 1000 frames
    b_true = np.array([0.0, -26.3, -62.4, -41.0])
    sd = 8e-4
    edges = [(i, j, b_true[j] - b_true[i], 0.0, 1.0, 0.5, sd)
             for i in range(4) for j in range(i + 1, 4)]
    edges[0] = (0, 1, b_true[1] - 1.5, np.log(1.003), 1.0, 0.5, sd)
    a, b, ok = solve_time(4, edges, 0)
    np.testing.assert_allclose(a, 1.0, atol=1e-9)
    np.testing.assert_allclose(b, b_true, atol=1e-6)
    assert ok.all()  # the pair's geometry stays usable
    # a drift that every pair of the camera shows is kept
    rate = np.array([1.0, 1.001, 1.0, 1.0])
    edges = [(i, j, (b_true[j] - b_true[i]) / rate[i], np.log(rate[j] / rate[i]), 1.0, 0.5, 2e-4)
             for i in range(4) for j in range(i + 1, 4)]
    a, b, _ = solve_time(4, edges, 0)
    np.testing.assert_allclose(a, rate, rtol=1e-9)
    # a camera tied to the rig by that one pair keeps it (no camera drops out)
    a, b, _ = solve_time(2, [(0, 1, 10.0, np.log(1.003), 1.0, 0.5, sd)], 0)
    assert a[1] == pytest.approx(1.003) and b[1] == pytest.approx(10.0)


def test_rotation_search_recovers_angle_with_partial_visibility() -> None:
    rng = np.random.default_rng(1)
    t = np.arange(400.0)
    paths = [_walk(rng, 400) + rng.uniform(-3, 3, 2) for _ in range(3)]
    pa = np.concatenate([np.c_[p, t] for p in paths[:3]])
    R = Similarity2D(2.5, np.array([4.0, 1.0]))
    pb = np.concatenate([np.c_[R.inverse().apply(p), t] for p in paths[1:]])  # one not seen
    res = rotation_search(pa, pb, rng=0)
    assert abs(np.angle(np.exp(1j * (res.angle - 2.5)))) < np.radians(1)
    np.testing.assert_allclose(res.translation, [4.0, 1.0], atol=0.1)  # ICP refines it


def test_assign_frames_equals_hungarian_with_gate() -> None:
    rng = np.random.default_rng(0)
    for _ in range(100):
        k, m = rng.integers(1, 9, 2)
        c = rng.uniform(0, 3, (1, k, m))
        c[0, rng.random((k, m)) < 0.2] = np.nan
        out = assign_frames(c, 2.0)[0]
        cc = np.where(np.isfinite(c[0]), np.minimum(c[0], 2.0), 2.0)
        r, col = linear_sum_assignment(cc)

        def total(o: np.ndarray, cc: np.ndarray = cc) -> float:
            return sum(cc[i, o[i]] if o[i] >= 0 else 2.0 for i in range(len(o)))

        ref = np.full(k, -1)
        good = np.isfinite(c[0, r, col]) & (c[0, r, col] < 2.0)
        ref[r[good]] = col[good]
        assert total(out) == pytest.approx(total(ref))
        assert all(c[0, i, out[i]] < 2.0 for i in range(k) if out[i] >= 0)


def test_ground_points_are_true_foot_positions() -> None:
    sc = make_scene(n_cams=2, n_persons=2, n_ref_frames=100, noise_px=0.0, outlier_rate=0.0)
    pts = ground_points(sc.tracks[0], sc.truth[0], foot_height=0.066)
    ok = np.isfinite(pts).all(-1)
    assert ok.sum() > 100
    # the two ankles are 0.2 m apart on the world y axis: their midpoint is the walker
    gt = ground_trajectories(sc.tracks[0], sc.truth[0], foot_height=0.066)
    assert len(gt.tracklets) >= 2
    steps = np.linalg.norm(np.diff(gt.tracklets[0].xy, axis=0), axis=1)
    assert np.median(steps) < 0.1  # walking, not jumping


def test_remove_outliers_keeps_separate_groups_drops_strays() -> None:
    rng = np.random.default_rng(0)
    g1 = rng.normal([0, 0], 0.5, (400, 2))
    g2 = rng.normal([15, 0], 0.5, (300, 2))  # people in a second area: kept (paper: dropped)
    stray = rng.uniform(-50, 50, (20, 2))
    keep = remove_outliers(np.concatenate([g1, g2, stray]))
    assert keep[:700].mean() > 0.97
    assert keep[700:].mean() < 0.2


def test_link_tracklets_without_ids_follows_crossing_walkers() -> None:
    n = 200
    t = np.arange(n)
    a = np.c_[0.05 * t, np.zeros(n)]
    b = np.c_[0.05 * t, 2.0 - 0.02 * t]  # crosses a at frame 100
    xy = np.stack([a, b], 1)
    xy[50:54, 0] = np.nan  # short occlusion, bridged
    xy = xy[:, ::-1].copy()
    xy[::2] = xy[::2, ::-1]  # slots alternate every frame
    tls = link_tracklets(xy, None, max_gap=5, min_length=10)
    assert len(tls) == 2
    for tl in tls:
        assert np.all(np.linalg.norm(np.diff(tl.xy, axis=0), axis=1) < 0.3)
