"""The batched assignments of the cross-view association equal one Hungarian solve per problem,
and its steps stay silent on missing data (they run in stage III's threads, where a
``warnings.catch_warnings`` block is not safe)."""

from __future__ import annotations

import warnings

import numpy as np
from scipy.optimize import linear_sum_assignment

from cascalib.camera import Camera, look_at
from cascalib.stages.association import _cluster_all, check_consistency, row_minima_assignment
from cascalib.stages.track_interpolation import frame_links


def _clusters_one_time(grounds: list[np.ndarray], gate: float) -> list[list[int]]:
    """The clustering rule written out for one time: cameras in order, each camera's persons
    matched to the clusters' mean positions by the Hungarian method, the rest start clusters."""
    members: list[list[int]] = []
    sums: list[np.ndarray] = []
    for c, g in enumerate(grounds):
        valid = np.flatnonzero(np.isfinite(g).all(1))
        matched = np.zeros(valid.size, dtype=bool)
        if members and valid.size:
            centres = np.array(sums) / np.array([sum(m >= 0 for m in row) for row in members]
                                                )[:, None]
            cost = np.linalg.norm(g[valid, None] - centres[None], axis=-1)
            for i, k in zip(*linear_sum_assignment(cost), strict=True):
                if cost[i, k] < gate:
                    members[k][c] = int(valid[i])
                    sums[k] = sums[k] + g[valid[i]]
                    matched[i] = True
        for i in np.flatnonzero(~matched):
            members.append([-1] * len(grounds))
            members[-1][c] = int(valid[i])
            sums.append(g[valid[i]].copy())
    return members


def _random_grounds(rng: np.random.Generator, ties: bool) -> list[np.ndarray]:
    n_t = int(rng.integers(1, 30))
    out = []
    for _ in range(int(rng.integers(1, 5))):
        n_p = int(rng.integers(0, 6))
        g = rng.normal(size=(n_t, n_p, 2)) * rng.choice([0.3, 1.0, 3.0])
        g[rng.random((n_t, n_p)) < 0.3] = np.nan
        if ties and n_p > 1:
            g[:, -1] = g[:, 0]  # a duplicated detection: equal costs
        out.append(g)
    return out


def test_row_minima_assignment_agrees_with_hungarian():
    rng = np.random.default_rng(3)
    cost = rng.random((400, 4, 5))
    cost[rng.random(cost.shape) < 0.2] = np.inf
    rows = rng.random((400, 4)) < 0.8
    cost[~rows] = np.inf
    best, solved = row_minima_assignment(cost, rows)
    assert 0.1 < solved.mean() < 0.9  # both branches are exercised
    for n in np.flatnonzero(solved):
        r = np.flatnonzero(rows[n])
        if r.size == 0:
            continue
        c = np.where(np.isfinite(cost[n][r]), cost[n][r], 1e9)
        rr, qq = linear_sum_assignment(c)
        assert np.array_equal(best[n, r[rr]], qq)


def test_clusters_equal_the_per_time_rule():
    rng = np.random.default_rng(5)
    n_checked = 0
    for trial in range(150):
        grounds = _random_grounds(rng, ties=trial % 3 == 0)
        t_all, s_all = _cluster_all(grounds, 0.8)
        want_t, want_s = [], []
        for t in range(grounds[0].shape[0]):
            for row in _clusters_one_time([g[t] for g in grounds], 0.8):
                if sum(m >= 0 for m in row) >= 2:
                    want_t.append(t)
                    want_s.append(row)
        assert np.array_equal(t_all, want_t)
        assert np.array_equal(s_all.reshape(-1, len(grounds)),
                              np.array(want_s, dtype=np.int64).reshape(-1, len(grounds)))
        n_checked += len(want_t)
    assert n_checked > 200


def test_frame_links_equal_per_frame_hungarian():
    rng = np.random.default_rng(7)
    for trial in range(100):
        n_f, n_p = int(rng.integers(2, 30)), int(rng.integers(1, 6))
        kp = np.cumsum(rng.normal(size=(n_f, n_p, 5, 3)), axis=0) + \
            rng.normal(size=(1, n_p, 5, 3)) * 30 + 100
        kp[rng.random((n_f, n_p)) < 0.3] = np.nan
        kp[rng.random((n_f, n_p, 5)) < 0.2] = np.nan  # single joints missing too
        if trial % 3 == 0 and n_p > 1:
            kp[:, -1] = kp[:, 0]
        with warnings.catch_warnings():
            warnings.simplefilter("error")  # rows with no joints in common are expected
            links = frame_links(kp, gate=0.5)
        for k in range(n_f - 1):
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", RuntimeWarning)
                d = np.nanmean(np.linalg.norm(kp[k, :, None, :, :2] - kp[k + 1, None, :, :, :2],
                                              axis=-1), axis=-1)
                ext = np.nanmax(kp[k, ..., :2], axis=1) - np.nanmin(kp[k, ..., :2], axis=1)
            c = np.where(np.isfinite(d), d / np.maximum(np.linalg.norm(ext, axis=-1), 1.0)[:, None],
                         np.inf)
            want = np.full(n_p, -1)
            if np.isfinite(c).any():
                r, q = linear_sum_assignment(np.where(np.isfinite(c), c, 1e9))
                good = c[r, q] < 0.5
                want[r[good]] = q[good]
            assert np.array_equal(links[k], want), (trial, k)


def test_check_consistency_drops_the_wrong_view_silently():
    rng = np.random.default_rng(3)
    cams = []
    for c, a in enumerate(np.linspace(0, 2 * np.pi, 4, endpoint=False)):
        R, t = look_at([6 * np.cos(a), 6 * np.sin(a), 2.5], [0.0, 0.0, 0.9])
        cams.append(Camera.from_params(f"c{c}", (1280, 720), (900.0, 900.0), R, t))
    n_g = 40
    body = rng.uniform([-1, -1, 0], [1, 1, 1.8], (n_g, 1, 3)) + rng.normal(0, 0.2, (n_g, 26, 3))
    obs = np.ones((n_g, 4, 26, 3))
    for c, cam in enumerate(cams):
        obs[:, c, :, :2] = cam.project(body.reshape(-1, 3)).reshape(n_g, 26, 2)
    obs[..., :2] += rng.normal(0, 1.0, obs[..., :2].shape)
    obs[0] = np.nan  # a group nobody sees: no residual
    obs[1, 2, :, :2] += 150.0  # a wrong person in camera 2
    with warnings.catch_warnings():
        warnings.simplefilter("error")
        out, residual = check_consistency(obs, cams, tolerance=0.3)
    assert np.isnan(residual[0]) and np.isfinite(residual[1:]).all()
    assert np.isnan(out[1, 2]).all() and np.isfinite(out[1, [0, 1, 3], :, :2]).all()
    kept = np.isfinite(out[2:, :, :, 0]).any(-1)
    assert kept.all()  # every right view stays
    assert (residual[1:] < 0.3).all()
