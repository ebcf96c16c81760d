"""write_tracks -> read_tracks for every format: lossless for what each format can store."""

from __future__ import annotations

import numpy as np
import pytest

from cascalib import InputError, Tracks
from cascalib.formats import read_tracks, read_tracks_many, write_tracks
from cascalib.formats.keypoints import FORMATS, detect_format
from cascalib.skeletons import CANONICAL_INDEX, SKELETONS, Skeleton

SUFFIX = {"native-json": ".json", "native-npz": ".npz", "openpose": "", "mmpose": ".json",
          "cascalib-ref": ".json", "coco": ".json", "mediapipe-csv": ".csv"}


def make_tracks(skeleton="coco17", n_frames=6, n_persons=2, *, seed=0, ids=True,
                camera="cam0", **kw) -> Tracks:
    """Random detections with missing joints, an empty slot and an empty frame; the last frame
    and the person slots are filled so that formats without frame counts keep the shape."""
    rng = np.random.default_rng(seed)
    sk = SKELETONS[skeleton] if isinstance(skeleton, str) else skeleton
    kp = np.empty((n_frames, n_persons, sk.n_joints, 3))
    kp[..., 0] = rng.uniform(0, 640, kp.shape[:3])
    kp[..., 1] = rng.uniform(0, 480, kp.shape[:3])
    kp[..., 2] = rng.uniform(0.05, 0.99, kp.shape[:3])
    kp[0, 0, 3] = np.nan  # a missing joint
    if n_persons > 1:
        kp[1, -1] = np.nan  # an empty person slot (the last slot: slots stay packed)
    kp[2] = np.nan  # a frame without detections
    tid = np.tile(np.arange(n_persons) + 3, (n_frames, 1))
    tid[np.isnan(kp[..., 0]).all(-1)] = -1
    tid[-2, 0] = -1  # a detection without id
    return Tracks(camera=camera, keypoints=kp, skeleton=sk, track_ids=tid if ids else None,
                  **kw)


def _path(tmp_path, fmt, name="cam0"):
    return tmp_path / f"{name}{SUFFIX[fmt]}"


def assert_same_detections(a: Tracks, b: Tracks):
    np.testing.assert_array_equal(a.keypoints, b.keypoints)
    if a.track_ids is None:
        assert b.track_ids is None
    else:
        np.testing.assert_array_equal(a.track_ids, b.track_ids)


@pytest.mark.parametrize("fmt", ["native-json", "native-npz"])
def test_native_round_trip_is_lossless(tmp_path, fmt):
    ts = np.arange(6) * 0.04 + 1e5 + 1e-9
    ts[2] = np.nan
    t = make_tracks("halpe26", image_size=(640, 480), fps=24.976, timestamps=ts,
                    meta={"detector": "rtmpose-m", "nested": {"a": [1, 2.5, None]},
                          "threshold": np.float64(0.3)})
    path = write_tracks(t, _path(tmp_path, fmt), format=fmt)
    assert detect_format(path) == fmt
    r = read_tracks(path)
    assert_same_detections(t, r)
    np.testing.assert_array_equal(r.timestamps, ts)
    assert (r.camera, r.skeleton, r.image_size, r.fps) == ("cam0", t.skeleton, (640, 480),
                                                           24.976)
    assert r.meta == {"detector": "rtmpose-m", "nested": {"a": [1, 2.5, None]},
                      "threshold": 0.3}
    assert r.source == str(path)


@pytest.mark.parametrize("fmt", ["native-json", "native-npz"])
def test_native_keeps_a_custom_skeleton_and_missing_optionals(tmp_path, fmt):
    sk = Skeleton("my_legs", ("lh", "rh", "la", "ra", "x"),
                  ("left_hip", "right_hip", "left_ankle", "right_ankle", None))
    t = make_tracks(sk, n_frames=4, n_persons=1, ids=False)
    r = read_tracks(write_tracks(t, _path(tmp_path, fmt), format=fmt))
    assert r.skeleton == sk and r.image_size is None and r.fps is None
    assert r.timestamps is None and r.track_ids is None and r.meta == {}
    assert_same_detections(t, r)


@pytest.mark.parametrize("fmt, skeleton", [("openpose", "body25"), ("openpose", "coco17"),
                                           ("mmpose", "halpe26"), ("mmpose", "coco17"),
                                           ("cascalib-ref", "coco17"), ("coco", "coco17")])
def test_detector_formats_keep_keypoints_and_track_ids(tmp_path, fmt, skeleton):
    t = make_tracks(skeleton, image_size=(640, 480), fps=30.0)
    path = write_tracks(t, _path(tmp_path, fmt), format=fmt)
    assert detect_format(path) == fmt
    r = read_tracks(path, camera="cam0", skeleton=skeleton, image_size=(640, 480))
    assert_same_detections(t, r)
    assert r.image_size == (640, 480) and r.skeleton.name == skeleton
    # mmpose keeps the frame rate in meta_info; the others do not store it
    assert r.fps == (30.0 if fmt == "mmpose" else None)


def test_mmpose_stores_image_size_itself(tmp_path):
    t = make_tracks("coco17", image_size=(800, 600))
    r = read_tracks(write_tracks(t, tmp_path / "a.json", format="mmpose"))
    assert r.image_size == (800, 600)


@pytest.mark.parametrize("fmt", ["cascalib-ref", "coco"])
def test_coco17_formats_convert_other_skeletons_through_canonical_joints(tmp_path, fmt):
    t = make_tracks("halpe26")
    r = read_tracks(write_tracks(t, _path(tmp_path, fmt), format=fmt))
    assert r.skeleton.name == "coco17"
    coco = [CANONICAL_INDEX[n] for n in SKELETONS["coco17"].canonical]
    np.testing.assert_array_equal(r.canonical()[..., coco, :], t.canonical()[..., coco, :])


def test_mediapipe_csv_round_trip_of_several_cameras(tmp_path):
    cams = []
    for port in (0, 3):
        t = make_tracks("blazepose33", n_persons=1, ids=False, seed=port, camera=f"port_{port}")
        kp = t.keypoints.copy()
        kp[..., 2] = np.where(np.isnan(kp[..., 2]), np.nan, 1.0)  # the CSV has no confidence
        ts = 47389.9 + port * 1e-3 + np.arange(6) / 29.97
        cams.append(t.with_(keypoints=kp, timestamps=ts))
    path = write_tracks(cams, tmp_path / "xy.csv")
    assert detect_format(path) == "mediapipe-csv"
    back = read_tracks_many(path)
    assert [b.camera for b in back] == ["port_0", "port_3"]
    for a, b in zip(cams, back, strict=True):
        assert_same_detections(a, b)
        # frame 2 has no landmark row, so its time is unknown
        np.testing.assert_array_equal(b.timestamps, np.where(np.arange(6) == 2, np.nan,
                                                             a.timestamps))


def test_mediapipe_csv_uses_fps_for_frame_time_and_converts_skeletons(tmp_path):
    t = make_tracks("coco17", n_persons=1, ids=False, fps=25.0)
    b = read_tracks(write_tracks(t, tmp_path / "a.csv"))
    assert b.skeleton.name == "blazepose33" and b.camera == "a"  # one port: named after the file
    np.testing.assert_allclose(b.timestamps[[0, 1, 3]], np.array([0, 1, 3]) / 25.0)
    ankle = CANONICAL_INDEX["left_ankle"]
    np.testing.assert_array_equal(b.canonical()[..., ankle, :2], t.canonical()[..., ankle, :2])


def test_mediapipe_csv_refuses_two_persons(tmp_path):
    with pytest.raises(InputError, match="one person per camera") as info:
        write_tracks(make_tracks("blazepose33"), tmp_path / "a.csv")
    assert info.value.frame == 0 and info.value.camera == "cam0"


def test_single_camera_formats_refuse_several_cameras(tmp_path):
    two = [make_tracks(camera="a"), make_tracks(camera="b")]
    with pytest.raises(InputError, match="one camera per file"):
        write_tracks(two, tmp_path / "x.json", format="coco")


def test_every_format_has_a_round_trip_test():
    tested = {"native-json", "native-npz", "openpose", "mmpose", "cascalib-ref", "coco",
              "mediapipe-csv"}
    assert tested == set(FORMATS)


def test_wholebody_133_is_recognised_from_mmpose_meta_and_from_the_count(tmp_path):
    t = make_tracks("coco_wholebody133", image_size=(640, 480))
    path = write_tracks(t, tmp_path / "wb.json", format="mmpose")
    r = read_tracks(path)
    assert r.skeleton.name == "coco_wholebody133"
    assert_same_detections(t, r)
    heel = CANONICAL_INDEX["left_heel"]
    np.testing.assert_array_equal(r.canonical()[..., heel, :], t.keypoints[..., 19, :])
    # without the meta: 133 joints can only be COCO-WholeBody
    plain = read_tracks(write_tracks(t, tmp_path / "wb", format="openpose"))
    assert plain.skeleton.name == "coco_wholebody133"
