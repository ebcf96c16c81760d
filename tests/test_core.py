"""Core data model: skeletons, tracks, camera against OpenCV."""

from __future__ import annotations

import cv2
import numpy as np
import pytest

from cascalib import Camera, InputError, Tracks
from cascalib.camera import look_at
from cascalib.errors import CalibrationFileError
from cascalib.skeletons import (
    CANONICAL_INDEX,
    CANONICAL_JOINTS,
    SKELETONS,
    get_skeleton,
    infer_skeleton,
    to_canonical,
)


@pytest.mark.parametrize("name", sorted(SKELETONS))
def test_every_skeleton_maps_the_joints_the_cascade_needs(name):
    sk = SKELETONS[name]
    kp = np.random.default_rng(0).uniform(0, 100, (2, sk.n_joints, 3))
    can = to_canonical(kp, sk)
    for joint in ("left_ankle", "right_ankle", "left_knee", "right_knee", "left_hip",
                  "right_hip", "left_shoulder", "right_shoulder", "neck", "mid_hip"):
        assert np.isfinite(can[:, CANONICAL_INDEX[joint]]).all(), (name, joint)
    # every mapped joint lands where its canonical name says
    for j, c in enumerate(sk.canonical):
        if c is not None:
            np.testing.assert_array_equal(can[:, CANONICAL_INDEX[c]], kp[:, j])


def test_derived_neck_is_mid_shoulder_with_min_confidence():
    sk = SKELETONS["coco17"]
    kp = np.zeros((17, 3))
    kp[5] = [10, 20, 0.9]
    kp[6] = [30, 40, 0.5]
    can = to_canonical(kp, sk)
    np.testing.assert_allclose(can[CANONICAL_INDEX["neck"]], [20, 30, 0.5])
    assert len(CANONICAL_JOINTS) == 26


def _body(n_joints_names, sk_name):
    """A plausible upright person in a skeleton's layout, from canonical positions."""
    sk = SKELETONS[sk_name]
    can = {
        "nose": (0, -160), "left_eye": (3, -163), "right_eye": (-3, -163),
        "left_ear": (6, -160), "right_ear": (-6, -160), "head_top": (0, -175),
        "neck": (0, -140), "left_shoulder": (20, -140), "right_shoulder": (-20, -140),
        "left_elbow": (25, -110), "right_elbow": (-25, -110), "left_wrist": (27, -85),
        "right_wrist": (-27, -85), "mid_hip": (0, -90), "left_hip": (10, -90),
        "right_hip": (-10, -90), "left_knee": (11, -45), "right_knee": (-11, -45),
        "left_ankle": (12, 0), "right_ankle": (-12, 0), "left_big_toe": (14, 5),
        "right_big_toe": (-14, 5), "left_small_toe": (18, 4), "right_small_toe": (-18, 4),
        "left_heel": (12, 2), "right_heel": (-12, 2),
    }
    kp = np.full((sk.n_joints, 3), np.nan)
    for j, c in enumerate(sk.canonical):
        if c is not None:
            kp[j] = [500 + can[c][0], 500 + can[c][1], 1.0]
    if sk_name == "h36m17":
        kp[7] = [500, 385, 1.0]  # spine
    return kp


@pytest.mark.parametrize("name", ["coco17", "h36m17", "body25", "body25b", "halpe26",
                                  "coco18", "blazepose33"])
def test_infer_skeleton_from_count_and_content(name):
    kp = _body(None, name)
    assert infer_skeleton(kp.shape[0], kp[None]).name == name


def test_unknown_joint_count_and_name_are_clear_errors():
    with pytest.raises(InputError, match="no known skeleton has 12 joints"):
        infer_skeleton(12)
    with pytest.raises(InputError, match="unknown skeleton 'foo'"):
        get_skeleton("foo")
    assert get_skeleton("BODY_25B").name == "body25b"
    assert get_skeleton("mediapipe").name == "blazepose33"


def _tracks(**kw):
    kp = np.random.default_rng(1).uniform(0, 400, (5, 2, 17, 3))
    kp[..., 2] = 0.8
    args = dict(camera="cam0", keypoints=kp, skeleton="coco17", image_size=(640, 480))
    args.update(kw)
    return Tracks(**args)


def test_tracks_shape_and_views():
    t = _tracks(fps=30.0)
    assert (t.n_frames, t.n_persons, t.n_joints) == (5, 2, 17)
    assert t.joint("left_ankle").shape == (5, 2, 3)
    np.testing.assert_allclose(t.frame_times(), np.arange(5) / 30)


def test_frame_rate_is_the_given_fps_else_the_timestamps_median_interval():
    assert _tracks(fps=25.0).frame_rate() == 25.0
    stamps = 10.0 + np.array([0.0, 1 / 30, 2 / 30, 3 / 30 + 0.02, 4 / 30 + 0.02])  # one late frame
    assert _tracks(timestamps=stamps).frame_rate() == pytest.approx(30.0)
    assert _tracks(fps=60.0, timestamps=stamps).frame_rate() == 60.0
    assert _tracks().frame_rate() is None


@pytest.mark.parametrize("change, message", [
    (lambda kp: kp.__setitem__((2, 0, 3, 0), np.inf), "frame 2.*infinite"),
    (lambda kp: kp.__setitem__((3, 1, 0, 2), -0.5), "frame 3.*negative confidence"),
    (lambda kp: kp.__setitem__((1, 0, 4, 1), np.nan), "frame 1.*NaN in some"),
    (lambda kp: kp.__setitem__((4, 0, 0, 0), 5000.0), "frame 4.*image size contradicts"),
    (lambda kp: kp.__setitem__(slice(None), np.nan), "empty"),
])
def test_tracks_reject_bad_values_naming_camera_and_frame(change, message):
    kp = np.random.default_rng(1).uniform(0, 400, (5, 2, 17, 3))
    change(kp)
    with pytest.raises(InputError, match=message) as info:
        Tracks("cam7", kp, "coco17", image_size=(640, 480), source="cam7.json")
    assert info.value.camera == "cam7" and info.value.file == "cam7.json"


def test_tracks_wrong_joint_count_and_missing_image_size():
    with pytest.raises(InputError, match="coco17 has 17 joints, keypoints have 25"):
        Tracks("c", np.ones((2, 1, 25, 3)), "coco17")
    t = Tracks("c", np.ones((2, 1, 17, 3)), "coco17")
    with pytest.raises(InputError, match="--image-size"):
        t.require_image_size()


def _rig_camera(dist):
    R, t = look_at([4.0, -3.0, 2.5], [0.0, 0.0, 1.0])
    return Camera.from_params("c", (1920, 1080), (1100.0, 1090.0), R, t, c=(950.0, 530.0),
                              dist=dist)


@pytest.mark.parametrize("dist", [np.zeros(5), [-0.28, 0.09, 0.0008, -0.0011, -0.015],
                                  [0.12, -0.2, -0.002, 0.003, 0.1]])
def test_projection_matches_opencv(dist):
    cam = _rig_camera(dist)
    X = np.random.default_rng(2).uniform(-1.5, 1.5, (200, 3)) + [0, 0, 1.0]
    ours = cam.project(X)
    ref, _ = cv2.projectPoints(X, cv2.Rodrigues(cam.R)[0], cam.t, cam.K, cam.dist)
    np.testing.assert_allclose(ours, ref.reshape(-1, 2), atol=1e-6)


@pytest.mark.parametrize("dist", [np.zeros(5), [-0.28, 0.09, 0.0008, -0.0011, -0.015]])
def test_undistort_inverts_projection_and_matches_opencv(dist):
    cam = _rig_camera(dist)
    X = np.random.default_rng(3).uniform(-1.5, 1.5, (200, 3)) + [0, 0, 1.0]
    uv = cam.project(X)
    Xc = cam.world_to_cam(X)
    np.testing.assert_allclose(cam.undistort(uv), Xc[:, :2] / Xc[:, 2:], atol=1e-9)
    ref = cv2.undistortPoints(uv.reshape(-1, 1, 2), cam.K, cam.dist, None, np.eye(3), cam.K,
                              (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14))
    np.testing.assert_allclose(cam.undistort_pixels(uv), ref.reshape(-1, 2), atol=1e-6)


def test_backprojection_to_ground_and_behind_camera():
    cam = _rig_camera([-0.2, 0.05, 0, 0, 0])
    G = np.array([[0.5, -0.3, 0.0], [-1.0, 1.2, 0.0]])
    np.testing.assert_allclose(cam.backproject_to_plane(cam.project(G)), G, atol=1e-8)
    behind = cam.center + (cam.center - [0, 0, 1.0])
    assert np.isnan(cam.project(behind[None])).all()
    np.testing.assert_allclose(cam.center, [4.0, -3.0, 2.5], atol=1e-12)


def test_centred_principal_point_moves_only_the_principal_point():
    cam = Camera.from_params("c", (640, 480), (510.0, 505.0), np.eye(3), [0.1, 0.2, 3.0],
                             c=(331.0, 228.5), dist=[-0.1, 0.01, 0, 0, 0])
    np.testing.assert_allclose(cam.image_centre, [319.5, 239.5])
    centred = cam.with_centred_principal_point()
    np.testing.assert_allclose(centred.principal_point, [319.5, 239.5])
    assert (centred.fx, centred.fy) == (510.0, 505.0) and centred.K[0, 1] == 0.0
    np.testing.assert_array_equal(centred.dist, cam.dist)
    np.testing.assert_array_equal(centred.t, cam.t)
    # a point on the optical axis images at the image centre
    np.testing.assert_allclose(centred.project((centred.center + [0, 0, 5.0])[None])[0],
                               [319.5, 239.5], atol=1e-9)
    np.testing.assert_allclose(cam.principal_point, [331.0, 228.5])  # the original is unchanged


def test_calibration_subset_rebases_the_clocks_without_the_reference():
    from cascalib.calibration import Calibration

    cams = [Camera.from_params(n, (640, 480), 500.0, np.eye(3), np.zeros(3), time_offset=o,
                               time_rate=s)
            for n, o, s in (("ref", 0.0, 1.0), ("a", 12.5, 1.2), ("b", -3.0, 0.5))]
    rig = Calibration(cams, reference_camera="ref")
    sub = rig.subset(["b", "a"])
    assert sub.names == ["a", "b"] and sub.reference_camera == "a"
    assert sub["a"].time_offset == 0.0 and sub["a"].time_rate == 1.0
    k = np.arange(0.0, 50.0, 7.0)
    # the same instant, through the old reference and through the new one
    old = rig["b"].time_rate * k + rig["b"].time_offset
    new = sub["b"].time_rate * k + sub["b"].time_offset  # frames of camera a
    np.testing.assert_allclose(rig["a"].time_rate * new + rig["a"].time_offset, old)
    assert rig.subset(["ref", "b"])["b"].time_offset == -3.0  # reference kept: unchanged
    with pytest.raises(CalibrationFileError, match="no camera"):
        rig.subset(["zzz"])


def test_norm_xy_equals_numpy_norm_bit_for_bit():
    from cascalib.geometry import norm_xy
    v = np.random.default_rng(2).normal(size=(50, 7, 2)) * np.logspace(-3, 4, 7)[:, None]
    v[3, 2, 0] = np.nan
    got = norm_xy(v)
    assert got.shape == (50, 7)
    assert np.array_equal(got, np.linalg.norm(v, axis=-1), equal_nan=True)
    assert np.isnan(got[3, 2]) and np.all(np.isfinite(np.delete(got.ravel(), 3 * 7 + 2)))


def test_nan_statistics_equal_numpy():
    import warnings

    from cascalib.nanstats import joint_extent, nanmean, nanmedian_last
    kp = np.random.default_rng(4).normal(size=(40, 3, 26, 3)) * 100
    kp[np.random.default_rng(5).random(kp.shape[:3]) < 0.5] = np.nan
    kp[0, 1] = np.nan  # a person with no joint
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        want_ext = np.nanmax(kp[..., :2], axis=2) - np.nanmin(kp[..., :2], axis=2)
        want_med = np.nanmedian(kp[..., 0], axis=-1)
        want_mean = np.nanmean(kp[..., :2], axis=-2)
    ext = joint_extent(kp)
    assert ext.shape == (40, 3, 2) and np.isnan(ext[0, 1]).all()
    assert np.array_equal(ext, want_ext, equal_nan=True)
    assert np.array_equal(nanmedian_last(kp[..., 0]), want_med, equal_nan=True)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # no "mean of empty slice" for the empty person
        mean = nanmean(kp[..., :2], axis=-2)
    assert np.isnan(mean[0, 1]).all()
    assert np.array_equal(mean, want_mean, equal_nan=True)
