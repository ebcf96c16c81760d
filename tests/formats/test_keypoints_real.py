"""Keypoint readers on the real data in ../shared/data (Pose2Sim OpenPose, caliscope CSV)."""

from __future__ import annotations

import csv
import json
import logging
import shutil

import numpy as np
import pytest

from cascalib.formats import read_session, read_tracks, read_tracks_many
from cascalib.formats.keypoints import detect_format


@pytest.fixture(scope="module")
def caliscope(shared_data):
    path = shared_data / "caliscope_4cam" / "xy_HOLISTIC.csv"
    return path, read_tracks_many(path, image_size="1280x720")


@pytest.mark.parametrize("scene", ["single_person", "multi_person"])
@pytest.mark.parametrize("cam", [1, 2, 3, 4])
def test_pose2sim_openpose_folders_are_body25b(shared_data, scene, cam):
    folder = shared_data / "pose2sim_demo" / scene / "pose" / f"cam0{cam}_json"
    assert detect_format(folder) == "openpose"
    t = read_tracks(folder, image_size="1088x1920", fps=60)
    assert t.camera == f"cam0{cam}" and t.skeleton.name == "body25b"
    assert t.n_frames == 100 and t.image_size == (1088, 1920)
    assert t.n_detections >= 100  # at least the participant in every frame
    # the values are the file's, with 0,0,0 turned into NaN
    raw = json.loads((folder / f"cam0{cam}.0042.json").read_text())["people"]
    first = np.array(next(p for p in raw if p["pose_keypoints_2d"])["pose_keypoints_2d"],
                     float).reshape(25, 3)
    first[(first == 0).all(1)] = np.nan
    np.testing.assert_array_equal(t.keypoints[42, 0], first)


def test_pose2sim_session_and_duplicate_names(shared_data):
    pose = shared_data / "pose2sim_demo" / "single_person" / "pose"
    cams = read_session(sorted(pose.glob("cam0*_json")))
    assert [t.camera for t in cams] == ["cam01", "cam02", "cam03", "cam04"]
    other = shared_data / "pose2sim_demo" / "multi_person" / "pose" / "cam02_json"
    with pytest.raises(Exception, match="duplicate camera name") as info:
        read_session([pose / "cam02_json", other])
    assert info.value.camera == "cam02" and info.value.field == "camera"
    assert str(other) in str(info.value) and str(pose / "cam02_json") in str(info.value)


def test_stray_non_frame_files_are_skipped_with_a_warning(shared_data, tmp_path, caplog):
    src = shared_data / "pose2sim_demo" / "single_person" / "pose" / "cam03_json"
    dst = tmp_path / "cam03_json"
    dst.mkdir()
    for k in range(5):
        shutil.copy(src / f"cam03.{k:04d}.json", dst)
    shutil.copy(src / "cam03.0002.json", dst / "del_cam03.0002.json")
    (dst / "del_notes.json").write_text("not even JSON")
    with caplog.at_level(logging.WARNING):
        t = read_tracks(dst)
    assert t.n_frames == 5 and t.skeleton.name == "body25b"
    assert "del_cam03.0002.json" in caplog.text and "del_notes.json" in caplog.text
    full = read_tracks(src)
    np.testing.assert_array_equal(t.keypoints, full.keypoints[:5, :t.n_persons])


def test_caliscope_csv_four_ports_with_timestamps(caliscope):
    _, cams = caliscope
    assert [t.camera for t in cams] == ["port_0", "port_1", "port_2", "port_3"]
    assert [t.n_frames for t in cams] == [267, 262, 267, 266]
    for t in cams:
        assert t.skeleton.name == "blazepose33" and t.n_persons == 1
        assert t.timestamps is not None and np.isfinite(t.timestamps).all()
        assert 25 < 1 / np.median(np.diff(t.timestamps)) < 35  # about 30 fps webcams
        assert t.image_size == (1280, 720)


def test_caliscope_csv_values_match_the_rows(caliscope):
    path, cams = caliscope
    with open(path, newline="") as fh:
        rows = [r for _, r in zip(range(3000), csv.DictReader(fh), strict=False)]
    checked = 0
    for r in rows:
        port, frame, pid = int(r["port"]), int(r["frame_index"]), int(r["point_id"])
        t = cams[port]
        if pid < 33:
            np.testing.assert_array_equal(
                t.keypoints[frame, 0, pid], [float(r["img_loc_x"]), float(r["img_loc_y"]), 1])
            assert t.timestamps[frame] == float(r["frame_time"])
            checked += 1
    assert checked > 1000


def test_caliscope_csv_is_several_cameras_for_read_tracks(caliscope):
    path, _ = caliscope
    with pytest.raises(Exception, match="holds 4 cameras.*read_tracks_many"):
        read_tracks(path)
