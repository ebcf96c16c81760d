"""Calibration metrics on cases whose answer is known exactly."""

from __future__ import annotations

import dataclasses
import json

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from cascalib import Calibration, CalibrationFileError, Camera
from cascalib.camera import look_at
from cascalib.geometry import rot_z
from cascalib.metrics import compare_calibrations, reprojection_stats, rotation_error_in_sigmas


def rig(n: int = 4, *, seed: int = 0, world: str = "z-up, ground z=0") -> Calibration:
    rng = np.random.default_rng(seed)
    cams = []
    for i in range(n):
        a = 2 * np.pi * i / n + rng.uniform(-0.3, 0.3)
        eye = [7 * np.cos(a), 5 * np.sin(a), rng.uniform(1.5, 4)]
        R, t = look_at(eye, [rng.uniform(-1, 1), rng.uniform(-1, 1), 1])
        cams.append(Camera.from_params(f"c{i}", (1920, 1080), rng.uniform(900, 1800), R, t,
                                       fps=30.0, time_offset=0.0 if i == 0 else 7.0 * i,
                                       time_rate=1.0 if i == 0 else 1.0 + 0.001 * i))
    return Calibration(cams, world=world)


def transformed(calib: Calibration, s: float, Rw: np.ndarray, tw: np.ndarray) -> Calibration:
    """The same rig in another world: ``x_new = s Rw x + tw`` (images unchanged)."""
    cams = []
    for c in calib.cameras:
        R = c.R @ Rw.T
        cams.append(c.with_(R=R, t=s * c.t - R @ tw))
    return Calibration(cams, reference_camera=calib.reference_camera, world=calib.world)


def perturbed(calib: Calibration, name: str, **changes) -> Calibration:
    return Calibration([c.with_(**changes) if c.name == name else c for c in calib.cameras],
                       reference_camera=calib.reference_camera, world=calib.world)


def test_transformed_rig_has_no_error_but_the_scale():
    truth = rig()
    Rw = Rotation.from_rotvec([0.3, -0.5, 1.2]).as_matrix()
    tw = np.array([3.0, -2.0, 5.0])
    est = transformed(truth, 1.1, Rw, tw)
    X = np.array([[0.3, 0.2, 1.0]])  # the same images, as the docstring of transformed() says
    np.testing.assert_allclose(est["c2"].project(1.1 * X @ Rw.T + tw), truth["c2"].project(X),
                               atol=1e-9)
    res = compare_calibrations(est, truth)
    for row in res.cameras:
        assert abs(row.focal_error_pct) < 1e-12
        assert row.rotation_error_deg < 1e-5
        assert row.center_error_similarity < 1e-9
        assert abs(row.time_offset_error_frames) < 1e-12 and abs(row.time_rate_error_pct) < 1e-12
    assert res.summary.alignment == "umeyama"
    assert res.summary.scale_error_pct == pytest.approx(10.0, abs=1e-9)
    assert res.summary.pairwise_rotation_error_deg_max < 1e-5
    # a tilted world is not a ground-plane motion: the ground alignment sees it
    assert res.summary.center_error_ground_max > 0.5


def test_yaw_and_floor_translation_give_no_ground_error_but_height_does():
    truth = rig()
    est = transformed(truth, 1.0, rot_z(0.7), np.array([1.0, -2.0, 0.0]))
    res = compare_calibrations(est, truth)
    assert res.summary.center_error_ground_max < 1e-9
    lifted = transformed(truth, 1.0, rot_z(0.7), np.array([1.0, -2.0, 0.5]))
    res = compare_calibrations(lifted, truth)
    np.testing.assert_allclose([r.center_error_ground for r in res.cameras], 0.5, atol=1e-9)
    assert res.summary.center_error_similarity_max < 1e-9  # a similarity absorbs the lift


def test_ground_alignment_needs_ground_worlds():
    truth = rig(world="camera 'c0' frame")
    res = compare_calibrations(truth, truth)
    assert np.isnan(res.summary.center_error_ground_max)
    assert np.isnan(res.cameras[0].center_error_ground)
    assert compare_calibrations(truth, truth, ground=True).summary.center_error_ground_max < 1e-9


@pytest.mark.parametrize("axis", [[0, 0, 1], [1, 0, 0], [0.3, -0.8, 0.5]])
def test_five_degree_perturbation_of_one_camera(axis):
    truth = rig()
    axis = np.asarray(axis, float) / np.linalg.norm(axis)
    dR = Rotation.from_rotvec(np.radians(5) * axis).as_matrix()
    c2 = truth["c2"]
    # rotate the camera about its own centre (centre unchanged)
    est = perturbed(truth, "c2", R=dR @ c2.R, t=-(dR @ c2.R) @ c2.center)
    res = compare_calibrations(est, truth)
    assert res["c2"].rotation_error_deg == pytest.approx(5.0, abs=1e-9)
    assert res["c0"].rotation_error_deg < 1e-9 and res["c3"].rotation_error_deg < 1e-9
    assert res.summary.pairwise_rotation_error_deg_max == pytest.approx(5.0, abs=1e-9)
    # 3 of the 6 pairs involve c2
    assert res.summary.pairwise_rotation_error_deg_median == pytest.approx(2.5, abs=1e-9)
    # perturbing the reference camera instead shows on every other camera
    est = perturbed(truth, "c0", R=dR @ truth["c0"].R)
    res = compare_calibrations(est, truth)
    np.testing.assert_allclose([r.rotation_error_deg for r in res.cameras], [0, 5, 5, 5],
                               atol=1e-9)


def test_rotation_errors_in_units_of_the_reported_sigmas():
    truth = rig()
    dR = Rotation.from_rotvec(np.radians(3) * np.array([0.0, 1.0, 0.0])).as_matrix()
    c2 = truth["c2"]
    res = compare_calibrations(perturbed(truth, "c2", R=dR @ c2.R, t=-(dR @ c2.R) @ c2.center),
                               truth)
    sigma = {"c0": 0.3, "c1": 0.4, "c2": 0.4, "c3": np.nan}
    z = rotation_error_in_sigmas(res, sigma)  # c1, c2, c3: the reference c0 is left out
    assert len(z) == 3
    assert z[0] == pytest.approx(0.0, abs=1e-9)
    assert z[1] == pytest.approx(3.0 / 0.5, rel=1e-9)  # hypot(0.4, 0.3) = 0.5
    assert np.isnan(z[2])


def test_rotation_error_is_geodesic_not_a_difference_of_angles():
    """Same relative angle magnitude (30 deg) about a different axis: a large error."""
    R0 = np.eye(3)
    truth = Calibration([Camera.from_params("a", (640, 480), 500, R0, [0, 0, 5]),
                         Camera.from_params("b", (640, 480), 500, rot_z(np.radians(30)),
                                            [0, 0, 5])], world="x")
    Rx = Rotation.from_rotvec([np.radians(30), 0, 0]).as_matrix()
    est = perturbed(truth, "b", R=Rx)
    expected = np.degrees(Rotation.from_matrix(Rx @ rot_z(np.radians(30)).T).magnitude())
    res = compare_calibrations(est, truth)
    assert res["b"].rotation_error_deg == pytest.approx(expected, abs=1e-9)
    assert expected > 40


def test_focal_principal_point_and_time_errors():
    truth = rig()
    c1 = truth["c1"]
    K = c1.K.copy()
    K[0, 0] *= 1.02
    K[1, 1] *= 1.02
    K[:2, 2] += [3.0, 4.0]
    est = perturbed(truth, "c1", K=K, time_offset=c1.time_offset + 2.5,
                    time_rate=c1.time_rate * 1.001)
    res = compare_calibrations(est, truth)
    assert res["c1"].focal_error_pct == pytest.approx(2.0, abs=1e-9)
    assert res["c1"].principal_point_error_px == pytest.approx(5.0, abs=1e-9)
    assert res["c1"].time_offset_error_frames == pytest.approx(2.5, abs=1e-9)
    assert res["c1"].time_rate_error_pct == pytest.approx(0.1, abs=1e-9)
    assert res["c2"].focal_error_pct == 0 and res["c2"].time_offset_error_frames == 0
    assert res.summary.focal_error_pct_max == pytest.approx(2.0, abs=1e-9)


def test_time_mappings_relative_to_different_reference_cameras_agree():
    truth = rig(2)  # c0 reference; c1 frame k shows c0 frame 1.001 k + 7
    S, O = truth["c1"].time_rate, truth["c1"].time_offset
    est = Calibration([truth["c0"].with_(time_offset=-O / S, time_rate=1 / S),
                       truth["c1"].with_(time_offset=0.0, time_rate=1.0)],
                      reference_camera="c1", world=truth.world)
    res = compare_calibrations(est, truth)
    assert res.summary.reference_camera == "c1"
    for row in res.cameras:
        assert abs(row.time_offset_error_frames) < 1e-12
        assert abs(row.time_rate_error_pct) < 1e-12


@pytest.mark.parametrize("n", [1, 2])
def test_small_rigs_align_on_the_reference_camera(n):
    truth = rig(n)
    Rw = Rotation.from_rotvec([0.2, 0.1, -0.9]).as_matrix()
    est = transformed(truth, 0.8, Rw, np.array([1.0, 2.0, 3.0]))
    res = compare_calibrations(est, truth)
    assert res.summary.alignment == "reference-pose"
    assert res.summary.center_error_similarity_max < 1e-9
    if n == 2:
        assert res.summary.scale_error_pct == pytest.approx(-20.0, abs=1e-9)
        # a wrong baseline direction shows on the second camera only
        c1 = est["c1"]
        moved = perturbed(est, "c1", t=c1.t - c1.R @ np.array([0.1, 0.0, 0.0]))
        res = compare_calibrations(moved, truth)
        assert res["c0"].center_error_similarity < 1e-12
        assert res["c1"].center_error_similarity > 0.01
    else:
        assert np.isnan(res.summary.scale_error_pct)


def test_mapping_unmatched_and_errors():
    truth = rig(3)
    est = Calibration([c.with_(name=f"cam_{i}") for i, c in enumerate(truth.cameras[:2])],
                      world=truth.world)
    with pytest.raises(CalibrationFileError, match="no camera names in common"):
        compare_calibrations(est, truth)
    with pytest.raises(CalibrationFileError, match="the reference has no camera 'c9'") as info:
        compare_calibrations(est, truth, mapping={"cam_0": "c9"})
    assert info.value.field == "mapping"
    res = compare_calibrations(est, truth, mapping={"cam_0": "c0", "cam_1": "c1"})
    assert [r.truth_camera for r in res.cameras] == ["c0", "c1"]
    assert res.summary.unmatched_truth == ("c2",)
    assert res.summary.center_error_similarity_max < 1e-9
    table = res.table()
    assert "cam_0=c0" in table and "without an estimate: c2" in table


def test_result_is_frozen_printable_and_json_ready():
    truth = rig()
    est = perturbed(truth, "c3", K=truth["c3"].K * [[1.05], [1.05], [1]])
    res = compare_calibrations(est, truth)
    with pytest.raises(dataclasses.FrozenInstanceError):
        res.summary.n_cameras = 3  # type: ignore[misc]
    lines = res.table().splitlines()
    assert lines[0].split()[:3] == ["camera", "focal", "%"]
    row = next(ln for ln in lines if ln.startswith("c3"))
    assert "+5.00" in row
    data = json.loads(json.dumps(compare_calibrations(rig(1), rig(1)).to_dict()))
    assert data["summary"]["scale_error_pct"] is None  # NaN -> null


def test_reprojection_stats_skips_nan():
    obs = np.array([[[0.0, 0.0], [3.0, 4.0]], [[np.nan, 1.0], [10.0, 10.0]]])
    proj = np.array([[[0.0, 1.0], [0.0, 0.0]], [[0.0, 0.0], [10.0, np.nan]]])
    stats = reprojection_stats(obs, proj)
    assert stats["n"] == 2
    assert stats["median"] == pytest.approx(3.0) and stats["mean"] == pytest.approx(3.0)
    assert stats["p90"] == pytest.approx(1 + 0.9 * 4)
    assert np.isnan(reprojection_stats([[np.nan, 0]], [[0, 0]])["median"])
    with pytest.raises(ValueError, match="must both be"):
        reprojection_stats(np.zeros((3, 2)), np.zeros((2, 2)))
