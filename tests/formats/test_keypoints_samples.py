"""Every keypoint reader on small hand-written samples (tests/data/keypoints/), value by value."""

from __future__ import annotations

import logging
from pathlib import Path

import numpy as np
import pytest

from cascalib.formats import read_tracks, read_tracks_many
from cascalib.formats.keypoints import detect_format
from cascalib.formats.keypoints.openpose import read_openpose

DATA = Path(__file__).resolve().parents[1] / "data" / "keypoints"


@pytest.mark.parametrize("name, fmt", [
    ("openpose_cam1", "openpose"),
    ("openpose_cam1/cam1_000000000002_keypoints.json", "openpose"),
    ("mmpose_video.json", "mmpose"),
    ("rtmlib_list.json", "mmpose"),
    ("cascalib_ref.json", "cascalib-ref"),
    ("coco_results.json", "coco"),
    ("coco_annotations.json", "coco"),
    ("caliscope.csv", "mediapipe-csv"),
    ("native.json", "native-json"),
])
def test_format_is_detected_from_content(name, fmt):
    assert detect_format(DATA / name) == fmt


def test_openpose_folder(caplog):
    with caplog.at_level(logging.WARNING):
        t = read_tracks(DATA / "openpose_cam1", fps=30)
    # the stray del_* file is skipped, and said so
    assert "del_cam1_000000000001_keypoints.json" in caplog.text
    assert t.camera == "openpose_cam1" and t.skeleton.name == "body25"
    assert (t.n_frames, t.n_persons) == (3, 2) and t.fps == 30.0
    assert np.isnan(t.keypoints[1]).all()  # no file for frame 1: an empty row
    np.testing.assert_array_equal(t.keypoints[0, 0, 0], [300.0, 380.0, 0.9])  # nose
    assert np.isnan(t.keypoints[0, 0, 4]).all()  # 0,0,0 = missing (RWrist)
    np.testing.assert_array_equal(t.keypoints[0, 1, 11], [876.0, 650.0, 0.8])  # RAnkle
    # frame 2: the second person has an empty keypoint list: not a detection
    assert np.isnan(t.keypoints[2, 1]).all() and np.isfinite(t.keypoints[2, 0, :, 0]).all()
    assert t.track_ids is None and t.image_size is None and t.timestamps is None


def test_openpose_single_frame_file_takes_frame_from_name():
    t = read_openpose(DATA / "openpose_cam1" / "cam1_000000000002_keypoints.json",
                      skeleton="body25")
    assert t.n_frames == 3 and np.isnan(t.keypoints[:2]).all()
    assert t.keypoints[2, 0, 0, 0] == 310.0


def test_mmpose_wrapper_with_meta_and_track_ids():
    t = read_tracks(DATA / "mmpose_video.json")
    assert t.skeleton.name == "coco17" and t.image_size == (640, 480)
    assert (t.n_frames, t.n_persons) == (3, 2)
    np.testing.assert_array_equal(t.track_ids, [[4, -1], [-1, -1], [7, 4]])
    np.testing.assert_array_equal(t.keypoints[0, 0, 16], [88, 230, 0.75])
    np.testing.assert_array_equal(t.keypoints[2, 1, 5], [122, 82, 0.95])
    assert np.isnan(t.keypoints[2, 0, 15]).all()  # [0, 0] with score 0: missing
    assert np.isnan(t.keypoints[1]).all()


def test_rtmlib_list_with_scores_inside_keypoints():
    t = read_tracks(DATA / "rtmlib_list.json", image_size="640x480", camera="front")
    assert (t.camera, t.n_frames, t.n_persons) == ("front", 4, 1)
    np.testing.assert_array_equal(t.keypoints[3, 0, 15], [112, 230, 1.4])  # SimCC score > 1
    assert t.track_ids is None and t.image_size == (640, 480)


def test_cascalib_reference_layout():
    t = read_tracks(DATA / "cascalib_ref.json")
    assert (t.n_frames, t.n_persons, t.skeleton.name) == (5, 2, "coco17")
    np.testing.assert_array_equal(t.track_ids[[0, 4]], [[1, 2], [1, -1]])
    np.testing.assert_array_equal(t.keypoints[4, 0, 0], [102, 52, 0.9])
    assert np.isnan(t.keypoints[0, 1, 16]).all() and np.isnan(t.keypoints[1:4]).all()


def test_coco_results_use_v_as_confidence():
    t = read_tracks(DATA / "coco_results.json")
    assert (t.n_frames, t.n_persons) == (2, 1)
    np.testing.assert_array_equal(t.keypoints[1, 0, 16], [88, 230, 0.65])
    np.testing.assert_array_equal(t.keypoints[0, 0, 16], [288, 240, 0.6])
    assert np.isnan(t.keypoints[0, 0, 15]).all()


def test_coco_annotation_flags_use_the_instance_score():
    t = read_tracks(DATA / "coco_annotations.json")
    np.testing.assert_array_equal(t.keypoints[2, 0, 3], [110, 48, 0.8])  # v = 1 -> score
    np.testing.assert_array_equal(t.keypoints[2, 0, 0], [100, 50, 0.8])  # v = 2 -> score
    assert np.isnan(t.keypoints[2, 0, 16]).all()


def test_caliscope_csv_one_tracks_per_port():
    cams = read_tracks_many(DATA / "caliscope.csv", image_size={"port_0": "1280x720"})
    assert [t.camera for t in cams] == ["port_0", "port_2"]
    p0, p2 = cams
    assert p0.skeleton.name == "blazepose33" and p0.image_size == (1280, 720)
    assert p2.image_size is None
    assert p0.n_frames == 2 and p2.n_frames == 3
    np.testing.assert_array_equal(p0.timestamps, [100.50, 100.53])
    np.testing.assert_array_equal(p2.timestamps, [100.49, np.nan, 100.56])
    np.testing.assert_array_equal(p0.keypoints[0, 0, [0, 11, 12, 27], :2],
                                  [[520, 193], [600, 300], [450, 300], [590, 650]])
    np.testing.assert_array_equal(p2.keypoints[0, 0, 28], [812.5, 640.25, 1.0])
    assert np.isfinite(p0.keypoints[0, 0, :, 0]).sum() == 4  # hand point 101 not read
    assert np.isnan(p2.keypoints[1]).all()


def test_caliscope_csv_camera_names():
    named = read_tracks_many(DATA / "caliscope.csv", camera={0: "left", 2: "right"})
    assert [t.camera for t in named] == ["left", "right"]
    templ = read_tracks_many(DATA / "caliscope.csv", camera="cam_{port}")
    assert [t.camera for t in templ] == ["cam_0", "cam_2"]


def test_native_json_sample():
    t = read_tracks(DATA / "native.json")
    assert (t.camera, t.skeleton.name, t.image_size, t.fps) == ("side", "coco17", (640, 480),
                                                               25.0)
    np.testing.assert_array_equal(t.timestamps, [12.0, np.nan])
    np.testing.assert_array_equal(t.track_ids, [[5], [-1]])
    assert t.meta == {"detector": "hand-written sample", "threshold": 0.3}
    assert np.isnan(t.keypoints[0, 0, 16]).all() and np.isnan(t.keypoints[1]).all()
    np.testing.assert_array_equal(t.keypoints[0, 0, 15], [112, 230, 0.7])


def test_caller_camera_name_overrides_the_file_stem():
    assert read_tracks(DATA / "coco_results.json", camera="c7").camera == "c7"
    assert read_tracks(DATA / "native.json", camera="c8").camera == "c8"


def test_caliscope_csv_empty_frame_time_means_unknown(tmp_path):
    path = tmp_path / "one.csv"
    path.write_text("sync_index,port,frame_index,frame_time,point_id,img_loc_x,img_loc_y,"
                    "obj_loc_x,obj_loc_y\n0,4,0,,0,10,20,,\n1,4,1,,0,11.5,20,,\n")
    t = read_tracks(path)
    assert t.camera == "one" and t.timestamps is None  # a single port: named after the file
    np.testing.assert_array_equal(t.keypoints[:, 0, 0], [[10, 20, 1], [11.5, 20, 1]])
