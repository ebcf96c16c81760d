"""Upright torsos: ground velocities along person tracks and the fitted walking lean."""

from __future__ import annotations

import numpy as np

from cascalib.stages.association import Association, ground_velocity
from cascalib.stages.torso_lean import expected_torso_offsets, torso_offsets


def _association(times, tracks, ground) -> Association:
    n = len(times)
    return Association(np.asarray(times, float), np.full((n, 2, 26, 3), np.nan),
                       np.asarray(tracks), np.asarray(ground, float))


def test_ground_velocity_follows_each_track():
    rng = np.random.default_rng(0)
    t = np.arange(0.0, 60.0, 2.0)
    v_a, v_b = np.array([0.05, 0.0]), np.array([-0.02, 0.03])  # m per frame
    times = np.concatenate([t, t, [10.0]])
    tracks = np.concatenate([np.zeros(t.size, int), np.ones(t.size, int), [-1]])
    ground = np.concatenate([v_a * t[:, None], [3.0, 1.0] + v_b * t[:, None], [[0.0, 0.0]]])
    perm = rng.permutation(times.size)  # groups come in any order
    vel = ground_velocity(_association(times[perm], tracks[perm], ground[perm]))
    back = np.empty_like(perm)
    back[perm] = np.arange(perm.size)
    vel = vel[back]
    np.testing.assert_allclose(vel[: t.size], np.tile(v_a, (t.size, 1)), atol=1e-12)
    np.testing.assert_allclose(vel[t.size: 2 * t.size], np.tile(v_b, (t.size, 1)), atol=1e-12)
    assert np.isnan(vel[-1]).all()  # untracked


def test_ground_velocity_not_across_a_gap_or_another_track():
    # track 0 seen at 0..8 and again at 100..108; track 1 stands still in between
    times = np.array([0, 2, 4, 6, 8, 100, 102, 104, 106, 108, 50, 52], float)
    tracks = np.array([0] * 10 + [1, 1])
    ground = np.column_stack([times * 0.04, np.zeros(12)])
    ground[10:] = [7.0, 7.0]
    vel = ground_velocity(_association(times, tracks, ground), steps=2, max_gap=30.0)
    np.testing.assert_allclose(vel[:10, 0], 0.04, atol=1e-12)  # each piece on its own
    np.testing.assert_allclose(vel[10:], 0.0, atol=1e-12)


def test_expected_offsets_fit_the_walking_lean():
    rng = np.random.default_rng(1)
    n = 400
    heading = rng.uniform(0, 2 * np.pi, n)
    speed = rng.uniform(0.0, 0.06, n)  # m per frame (0-1.5 m/s at 25 fps)
    v = speed[:, None] * np.column_stack([np.cos(heading), np.sin(heading)])
    lean = 0.55  # frames: 3.3 cm ahead at 1.5 m/s
    off = lean * v + rng.normal(0, 0.01, (n, 2))
    off[:20] += 0.5  # bending persons: no walkers, left out of the fit
    upright = np.ones(n, bool)
    upright[20:60] = False
    off[20:60] = 0.15 * np.column_stack([np.cos(heading[20:60]), np.sin(heading[20:60])])
    v[-5:] = np.nan  # a person whose velocity is unknown: no lean expected
    exp = expected_torso_offsets(off, v, upright)
    np.testing.assert_allclose(exp[:-5], lean * v[:-5], atol=0.002)  # m
    assert (exp[-5:] == 0).all()
    # what the fit is worth: without it, the expected offset would be 0, off by the lean
    assert np.abs(lean * v[:-5]).max() > 0.03


def test_expected_offsets_are_zero_without_evidence():
    off = np.full((50, 2), 0.02)
    v = np.full((50, 2), 0.04)
    up = np.ones(50, bool)
    assert (expected_torso_offsets(off, None, up) == 0).all()
    assert (expected_torso_offsets(off[:10], v[:10], up[:10]) == 0).all()  # < min_groups
    assert (expected_torso_offsets(off, v, np.zeros(50, bool)) == 0).all()  # nobody upright


def test_torso_offsets_need_both_joints():
    pts = np.zeros((3, 3, 3))
    pts[:, 1] = [0.0, 0.0, 0.5]
    pts[:, 2] = [0.03, -0.01, 1.0]
    np.testing.assert_allclose(torso_offsets(pts, ("left_ankle", "mid_hip", "neck")),
                               [[0.03, -0.01]] * 3)
    assert np.isnan(torso_offsets(pts, ("left_ankle", "mid_hip", "nose"))).all()
