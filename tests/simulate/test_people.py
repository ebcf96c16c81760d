"""Physical plausibility of the simulated people: gait, speed, heights, bone lengths, actions."""

from __future__ import annotations

import numpy as np
import pytest

from cascalib.simulate.body import BodyModel, two_bone_ik
from cascalib.simulate.people import PeopleConfig, make_people
from cascalib.skeletons import CANONICAL_BONES, CANONICAL_INDEX

J = CANONICAL_INDEX
FPS = 50.0


@pytest.fixture(scope="module")
def people():
    cfg = PeopleConfig(n_persons=6, pause_prob=0.5, action_prob=1.0, walk_mean_s=4.0)
    return make_people(cfg, 40.0, np.random.default_rng(3))


@pytest.fixture(scope="module")
def motion(people):
    t = np.arange(0, 40.0, 1 / FPS)
    return t, [p.joints(t) for p in people]


def test_bone_lengths_constant_over_time(people, motion):
    _, xs = motion
    for p, x in zip(people, xs, strict=True):
        for a, b in CANONICAL_BONES:
            length = np.linalg.norm(x[:, J[a]] - x[:, J[b]], axis=-1)
            assert np.ptp(length) < 1e-9, (a, b)
        # left and right limbs are equally long
        thigh_l = np.linalg.norm(x[:, J["left_hip"]] - x[:, J["left_knee"]], axis=-1)
        assert thigh_l[0] == pytest.approx(p.body.thigh, rel=1e-9)


def test_stance_ankle_height_constant(people, motion):
    _, xs = motion
    for p, x in zip(people, xs, strict=True):
        for side in ("left", "right"):
            a = x[:, J[f"{side}_ankle"]]
            still = np.linalg.norm(np.diff(a[:, :2], axis=0), axis=1) < 1e-9
            assert still.mean() > 0.4  # planted for a good part of the time
            z = a[1:][still, 2]
            np.testing.assert_allclose(z, p.body.ankle_height, atol=1e-9)
            # swinging feet lift off: the ankle rises by a few centimetres
            assert a[:, 2].max() > p.body.ankle_height + 0.03


def test_feet_on_or_above_ground_and_head_at_height(people, motion):
    _, xs = motion
    for x in xs:
        assert x[..., 2].min() > -0.02
    cfg = PeopleConfig(n_persons=3, pause_prob=1.0, action_prob=0.0, walk_mean_s=3.0)
    t = np.arange(0, 30.0, 1 / FPS)
    for p in make_people(cfg, 30.0, np.random.default_rng(0)):
        x = p.joints(t)
        # Standing still with the feet together: upright, head top at the body height.
        standing = np.abs(x[:, J["mid_hip"], 2] - p.body.standing_hip_height) < 1e-6
        assert standing.mean() > 0.1
        np.testing.assert_allclose(x[standing, J["head_top"], 2], p.height, atol=0.03)
        # Walking lowers the head by a few percent at most.
        walking = p.speed_at(t) > 0.99 * p.speed
        head = x[walking, J["head_top"], 2] / p.height
        assert 0.95 < head.mean() < 0.99 and head.min() > 0.9


def test_walking_speed_in_range(people, motion):
    t, xs = motion
    for p, x in zip(people, xs, strict=True):
        assert 0.8 <= p.speed <= 1.6
        v = np.linalg.norm(np.diff(x[:, J["mid_hip"], :2], axis=0), axis=1) * FPS
        walking = p.speed_at(t[1:]) > 0.99 * p.speed
        # Stopping in double support stretches a bout by at most half a stride.
        assert np.median(v[walking]) == pytest.approx(p.speed, rel=0.15)
        assert v.max() < 2.2


def test_heights_follow_the_distribution():
    cfg = PeopleConfig(n_persons=20, height_mean=1.70, height_sd=0.07)
    h = np.concatenate([[p.height for p in make_people(cfg, 5.0, np.random.default_rng(s))]
                        for s in range(15)])
    assert h.mean() == pytest.approx(1.70, abs=0.015)
    assert 0.055 < h.std() < 0.085


def test_actions_change_the_posture():
    cfg = PeopleConfig(n_persons=8, pause_prob=1.0, action_prob=1.0, walk_mean_s=2.0,
                       actions=("sit",))
    people = make_people(cfg, 30.0, np.random.default_rng(0))
    sat = 0
    for p in people:
        for t0, t1, name in p.actions:
            assert name == "sit"
            mid = np.array([(t0 + t1) / 2])
            x = p.joints(mid)[0]
            if t1 - t0 > 2.0 and t1 < 30.0:  # long enough to sit down fully, within the scene
                assert x[J["mid_hip"], 2] < 0.7 * p.body.standing_hip_height
                sat += 1
    assert sat > 0


def test_periodic_paths_repeat():
    cfg = PeopleConfig(n_persons=2, periodic=True, pause_prob=0.0)
    people = make_people(cfg, 60.0, np.random.default_rng(1))
    for p in people:
        t = np.arange(5.0, 30.0, 0.05)
        x = p.joints(t)[:, J["mid_hip"], :2]
        # Kasa circle fit: x^2 + y^2 = 2 a x + 2 b y + c
        A = np.column_stack([2 * x, np.ones(len(x))])
        a, b, _ = np.linalg.lstsq(A, (x**2).sum(1), rcond=None)[0]
        r = np.linalg.norm(x - [a, b], axis=1)
        assert np.ptp(r) < 0.1  # on a circle (up to the hip sway)
        assert 1.5 - 0.05 < r.mean() < 2.5 + 0.05
        assert p.actions == ()


def _lap_spread(p, t: np.ndarray) -> float:
    """Largest spread (m) over the laps of the hip's distance from the path's centre in one
    direction from it."""
    x = p.joints(t)[:, J["mid_hip"], :2]
    centre = x.mean(0)
    ang = np.unwrap(np.arctan2(*(x - centre).T[::-1]))
    r = np.linalg.norm(x - centre, axis=1)
    lap = np.floor(np.abs(ang - ang[0]) / (2 * np.pi)).astype(int)
    at = np.mod(ang, 2 * np.pi)
    spread = []
    for direction in np.linspace(0.3, 6.0, 12):
        rad = [np.interp(direction, np.sort(at[lap == k]), r[lap == k][np.argsort(at[lap == k])])
               for k in range(1, lap.max())]
        spread.append(np.ptp(rad))
    return float(max(spread))


def test_circle_wobble_varies_the_laps_and_keeps_the_heading_on_the_path():
    kw = dict(n_persons=1, periodic=True, pause_prob=0.0, speed_range=(1.3, 1.3),
              circle_radius=(1.66, 1.66))
    t = np.arange(2.0, 58.0, 0.02)
    (still,) = make_people(PeopleConfig(**kw), 60.0, np.random.default_rng(1))
    (p,) = make_people(PeopleConfig(**kw, circle_wobble_m=0.15), 60.0, np.random.default_rng(1))
    # the same direction on different laps: a perfect circle repeats to the hip sway, a
    # wobbling one differs by decimetres
    assert _lap_spread(still, t) < 0.06  # measured 0.04 (hip sway), wobbling 0.23
    assert _lap_spread(p, t) > 0.12
    # walking forward along the wobbly path: facing within a few degrees of the velocity
    x = p.joints(t)[:, J["mid_hip"], :2]
    v = np.gradient(x, axis=0)
    fwd = p.joints(t)[:, J["nose"], :2] - x
    cos = (v * fwd).sum(1) / np.linalg.norm(v, axis=1) / np.linalg.norm(fwd, axis=1)
    assert np.median(cos) > 0.95


def test_two_bone_ik_exact_and_bends_forward():
    root = np.array([[0.0, 0.0, 1.0]])
    end = np.array([[0.1, 0.0, 0.3]])
    mid, reached = two_bone_ik(root, end, 0.4, 0.4, np.array([[1.0, 0.0, 0.0]]))
    assert np.linalg.norm(mid - root) == pytest.approx(0.4)
    assert np.linalg.norm(mid - end) == pytest.approx(0.4)
    np.testing.assert_allclose(reached, end)
    assert mid[0, 0] > 0.1  # the knee points along the hint
    body = BodyModel(1.8)
    assert body.leg == pytest.approx((0.530 - 0.039) * 1.8)
