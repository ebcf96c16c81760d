"""The metric scale from the people's leg-and-trunk chains (cascalib.stages.stature)."""

from __future__ import annotations

import numpy as np
import pytest

from cascalib.camera import Camera
from cascalib.simulate.scene import simulate
from cascalib.stages.stature import (
    chain_statures,
    metric_scale,
    moving_groups,
    people_who_move,
    rescale_to_statures,
)

JOINTS = np.arange(26)


@pytest.fixture(scope="module")
def walkers():
    """True joints of four simulated walkers at 40 instants, (160, 26, 3), and their heights."""
    scene = simulate("clean", seed=0, duration_s=5)
    joints = scene.joints_at(np.linspace(0, 4, 40))
    return joints.reshape(-1, 26, 3), np.asarray(scene.heights)


def test_chain_of_a_drillis_contini_body_is_its_stature(walkers) -> None:
    points, heights = walkers
    per_person = np.median(chain_statures(points, JOINTS).reshape(40, -1), axis=0)
    np.testing.assert_allclose(per_person, heights, rtol=1e-6)


def test_metric_scale_brings_a_scaled_bundle_to_the_stature(walkers) -> None:
    points, heights = walkers
    k = metric_scale(points / 3.0, JOINTS, float(np.median(heights)))
    assert k == pytest.approx(3.0, rel=0.03)


def test_upper_bodies_fall_back_on_segments_and_nothing_raises(walkers) -> None:
    points, heights = walkers
    upper = points.copy()
    upper[:, 11:] = np.nan  # hips and legs unseen
    upper[:, 19:] = np.nan
    assert metric_scale(upper, JOINTS, 1.7) == pytest.approx(1.0, rel=0.1)
    with pytest.raises(ValueError, match="metric scale is unknown"):
        metric_scale(np.full_like(points, np.nan), JOINTS, 1.7)


def test_a_figure_that_never_moves_is_left_out_of_the_scale(walkers) -> None:
    truth, _ = walkers
    # triangulated people jitter by a centimetre or so (the simulated bodies pause exactly)
    points = truth + np.random.default_rng(0).normal(0, 0.01, truth.shape)
    still = np.repeat(0.6 * truth[:1] + [5.0, 5.0, 0.0], 60, axis=0)  # a 1 m mannequin
    both = np.concatenate([points, still])
    moving = moving_groups(both)
    assert moving[: len(points)].all() and not moving[len(points):].any()
    assert len(people_who_move(both)) == len(points)
    assert len(people_who_move(still)) == len(still)  # everyone still: all of them


def test_rescale_moves_cameras_and_joints_about_the_origin(walkers) -> None:
    points, heights = walkers
    cam = Camera.from_params("c", (640, 480), 500.0, np.eye(3), np.array([0.0, 0.0, 10.0]))
    cams, scaled, k = rescale_to_statures([cam], points / 2.0, float(np.median(heights)))
    assert k == pytest.approx(2.0, rel=0.03)
    np.testing.assert_allclose(scaled, points / 2.0 * k)
    np.testing.assert_allclose(cams[0].center, cam.center * k)
    _, _, one = rescale_to_statures([cam], np.full_like(points, np.nan), 1.7)
    assert one == 1.0
