"""The cases real recordings bring, as simulator presets through the whole cascade.

Each slow test calibrates one preset (:mod:`cascalib.simulate.presets`) and compares with the
simulator's truth; the bounds and the seeds that miss them are in
docs/decisions/real-case-presets.md. The fast tests check that the presets draw what they say.
"""

from __future__ import annotations

import numpy as np
import pytest

from cascalib.config import CalibrationConfig
from cascalib.metrics import ErrorSummary, compare_calibrations
from cascalib.pipeline import CalibrationResult, calibrate
from cascalib.simulate import simulate
from cascalib.simulate.presets import preset
from cascalib.stages.multiview_path import MultiviewInitial

REAL_CASES = ("gait", "horizontal", "short_clip", "fisheye_webcam", "mixed_rates")
GAIT_ROT_MEDIAN = 1.6  # deg, relative rotations (all pairs)
GAIT_FOCAL_MAX = 2.5  # %
GAIT_OFFSET_MAX = 0.3  # frames
GAIT_ROT_MEDIAN_LOOSE = 5.0  # deg, seed 2


def _calibrate(name: str, seed: int, **overrides: object
               ) -> tuple[CalibrationResult, ErrorSummary]:
    scene = simulate(name, seed=seed, **overrides)
    res = calibrate(scene.tracks, CalibrationConfig())
    ground = "ground z=0" in res.calibration.world
    return res, compare_calibrations(res.calibration, scene.truth, ground=ground).summary


@pytest.mark.parametrize("name", REAL_CASES)
def test_the_real_case_presets_are_listed_with_a_description(name: str) -> None:
    assert preset(name).description


def test_gait_is_three_portrait_phones_watching_one_walker_for_65_s() -> None:
    scene = simulate("gait", seed=0)
    assert len(scene.truth) == 3 and len(scene.people) == 1
    assert all(c.image_size == (480, 640) for c in scene.truth)
    assert all(t.keypoints.shape[0] > 1800 for t in scene.tracks)


def test_horizontal_cameras_look_down_by_at_most_a_few_degrees() -> None:
    scene = simulate("horizontal", seed=0, duration_s=5.0)
    pitch = [np.degrees(np.arcsin(-c.R[2, 2])) for c in scene.truth]  # optical axis below level
    assert all(-0.5 < p < 4.0 for p in pitch)
    assert all(1.0 <= c.center[2] <= 1.5 for c in scene.truth)


def test_fisheye_webcams_bend_as_much_as_caliscopes() -> None:
    scene = simulate("fisheye_webcam", seed=0, duration_s=5.0)
    assert all(-0.37 < c.dist[0] < -0.30 for c in scene.truth)


def test_mixed_rates_gives_the_cameras_30_25_30_and_29_97_fps() -> None:
    scene = simulate("mixed_rates", seed=0, duration_s=5.0)
    assert [round(c.fps or 0.0, 2) for c in scene.truth] == [30.0, 25.0, 30.0, 29.97]


@pytest.mark.slow
def test_gait_one_walker_back_and_forth_gives_all_three_phones() -> None:
    res, s = _calibrate("gait", 0)
    assert len(res.calibration) == 3 and not res.left_out
    # stage III flags cam1 and cam2 ambiguous; the joints find their clocks, the multi-view start
    # places the cameras. Gap: the relative rotations stay 1-1.5 deg off (stage V rates every
    # camera suspicious).
    assert s.pairwise_rotation_error_deg_median < GAIT_ROT_MEDIAN
    assert s.focal_error_pct_max < GAIT_FOCAL_MAX
    assert s.time_offset_error_frames_max < GAIT_OFFSET_MAX


@pytest.mark.slow
def test_gait_clocks_are_found_on_every_seed() -> None:
    # stages II-III leave cam1 and cam2 'ambiguous' and frames off; the joints find their clocks
    # and the multi-view start places the cameras on them
    res, s = _calibrate("gait", 2)
    assert isinstance(res.alignment, MultiviewInitial) and len(res.calibration) == 3
    assert s.time_offset_error_frames_max < GAIT_OFFSET_MAX
    assert s.focal_error_pct_max < GAIT_FOCAL_MAX
    # Gap: one walker on a line leaves the principal points, and with them the relative
    # rotations, poorly determined (decision record)
    assert s.pairwise_rotation_error_deg_median < GAIT_ROT_MEDIAN_LOOSE


@pytest.mark.slow
def test_horizontal_cameras_are_placed_though_the_ground_is_seen_edge_on() -> None:
    res, s = _calibrate("horizontal", 1)
    # stage I cannot decide some of the level cameras: the multi-view start places them
    assert res.stage_i_advice and len(res.calibration) == 4 and not res.left_out
    assert s.pairwise_rotation_error_deg_median < 0.6 and s.pairwise_rotation_error_deg_max < 0.8
    assert s.focal_error_pct_max < 1.0
    assert s.time_offset_error_frames_max < 0.15


@pytest.mark.slow
def test_a_short_clip_of_people_standing_and_turning_gives_every_camera() -> None:
    res, s = _calibrate("short_clip", 1)
    assert len(res.calibration) == 4 and not res.left_out
    # Gap: with so little walking the clocks stay 0.6-0.7 frame off and the rig 0.4-1 deg
    # (other seeds: one camera left out, see the decision record).
    assert s.pairwise_rotation_error_deg_median < 1.5
    assert s.focal_error_pct_max < 3.0
    assert s.time_offset_error_frames_max < 1.0


@pytest.mark.slow
def test_fisheye_webcams_are_placed_from_the_joints_seen_together() -> None:
    res, s = _calibrate("fisheye_webcam", 0)
    assert len(res.calibration) == 4 and not res.left_out
    # Gap: stage I cannot decide half the cameras through k1 -0.34, and the multi-view start
    # with stage V leaves the rig 1.5-3 deg off, every camera suspicious.
    assert s.pairwise_rotation_error_deg_median < 2.0 and s.pairwise_rotation_error_deg_max < 3.5
    assert s.focal_error_pct_max < 1.5


@pytest.mark.slow
@pytest.mark.xfail(strict=True, reason="stage I cannot decide the reference camera cam0 (too few "
                   "upright detections through the distortion); the clocks the multi-view start "
                   "takes put cam0 13 s off the others and the rig ends 5-10 deg off")
def test_fisheye_webcams_are_placed_on_every_seed() -> None:
    res, s = _calibrate("fisheye_webcam", 1)
    assert s.time_offset_error_frames_max < 1.0
    assert s.pairwise_rotation_error_deg_median < 3.5


@pytest.mark.slow
def test_mixed_frame_rates_30_25_30_29_97_calibrate_like_constant_rates() -> None:
    res, s = _calibrate("mixed_rates", 0)
    assert len(res.calibration) == 4 and res.accepted
    assert s.pairwise_rotation_error_deg_median < 0.6 and s.pairwise_rotation_error_deg_max < 0.8
    assert s.focal_error_pct_max < 0.6
    assert s.time_offset_error_frames_max < 0.1 and s.time_rate_error_pct_max < 0.02
