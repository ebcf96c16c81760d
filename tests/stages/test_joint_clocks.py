"""The people's joints check the clocks stages II-III call ambiguous (stages/joint_clocks.py)."""

from __future__ import annotations

import numpy as np
import pytest

from cascalib.simulate import simulate
from cascalib.stages import joint_clocks
from cascalib.stages.joint_clocks import CLOCK_TOLERANCE, checked_clocks, joint_clock
from cascalib.stages.multiview_pairs import repeats
from cascalib.stages.track_interpolation import frame_links, interpolate_views


@pytest.fixture(scope="module")
def walker() -> tuple[list, list[float]]:
    """One person walking back and forth in front of three portrait phones, 20 s."""
    scene = simulate("gait", seed=2, duration_s=20.0)
    return scene.tracks, [c.time_offset for c in scene.truth]


def test_the_joints_find_a_clock_many_frames_off(walker, monkeypatch) -> None:
    monkeypatch.setattr(joint_clocks, "WINDOW_S", 0.6)  # wide enough for 12 frames, quicker
    tracks, truth = walker
    rng = np.random.default_rng(0)
    # 12 frames late (a shift along the walker's line) and a candidate 10 s away: the grid
    # passes the lesser minimum a stride later that a descent from there ends in
    found = joint_clock(tracks[0], (0.0, 1.0), tracks[2], (truth[2] + 12.0, 1.0),
                        [truth[2] + 300.0], rng)
    assert found is not None and abs(found.offset - truth[2]) < 0.3
    # a few frames off, the descent alone finds it
    found = joint_clock(tracks[0], (0.0, 1.0), tracks[1], (truth[1] - 5.0, 1.0), None, rng)
    assert found is not None and abs(found.offset - truth[1]) < 0.3


def test_the_cameras_whose_clock_the_joints_move_are_returned(walker, monkeypatch) -> None:
    monkeypatch.setattr(joint_clocks, "WINDOW_S", 0.6)
    tracks, truth = walker
    rng = np.random.default_rng(0)
    # cam1 flagged 12 frames off, cam2 unflagged but with little confidence 5 frames off:
    # both move to the truth
    clocks = [(0.0, 1.0), (truth[1] - 12.0, 1.0), (truth[2] + 5.0, 1.0)]
    flags = {"cam1": ["ambiguous"], "cam2": []}
    moved = checked_clocks(tracks, clocks, flags, {"cam1": 0.9, "cam2": 0.3}, {}, rng)
    assert sorted(moved) == ["cam1", "cam2"]
    assert abs(moved["cam1"] - truth[1]) < 0.3 and abs(moved["cam2"] - truth[2]) < 0.3
    # a confident camera is not checked; within the tolerance a clock stays stage IV's
    assert list(checked_clocks(tracks, clocks, flags, {"cam2": 0.9}, {}, rng)) == ["cam1"]
    near = [(0.0, 1.0), (truth[1] + 0.5 * CLOCK_TOLERANCE, 1.0), (truth[2], 1.0)]
    assert checked_clocks(tracks, near, flags, {}, {}, rng) == {}


def test_a_figure_that_never_moves_repeats_and_a_walker_does_not(walker) -> None:
    tracks, _ = walker
    k = tracks[0].canonical()
    v = interpolate_views(k, frame_links(k, tracks[0].track_ids),
                          np.linspace(0, k.shape[0] - 1, 200))
    figure = v[40:41, :1] + [120.0, 0.0, 0.0]  # the walker's pose, away from the walker
    still = np.concatenate([v[:, :1], np.broadcast_to(figure, v[:, :1].shape)], axis=1)
    seen = np.isfinite(still[..., 0]).any(axis=-1)
    out = repeats(still)
    assert not out[:, 0].any()
    # each copy is compared with its nearest few by centre, which need not be earlier ones
    assert not out[np.flatnonzero(seen[:, 1])[0], 1] and out[:, 1].mean() > 0.2
