"""``cascalib tracks-info`` on real and sample keypoint files."""

from __future__ import annotations

import json
from pathlib import Path

from cascalib.cli import main

DATA = Path(__file__).resolve().parents[1] / "data" / "keypoints"


def test_tracks_info_table(shared_data, capsys):
    folder = shared_data / "pose2sim_demo" / "single_person" / "pose" / "cam02_json"
    assert main(["tracks-info", str(folder), str(DATA / "caliscope.csv"),
                 str(DATA / "native.json")]) == 0
    lines = capsys.readouterr().out.splitlines()
    assert lines[0].split() == ["camera", "format", "skeleton", "frames", "persons",
                                "detections", "image", "fps", "timestamps"]
    assert lines[1].split() == ["cam02", "openpose", "body25b", "100", "2", "200", "?", "?",
                                "no"]
    assert lines[2].split() == ["port_0", "mediapipe-csv", "blazepose33", "2", "1", "2", "?",
                                "?", "yes"]
    assert lines[4].split() == ["side", "native-json", "coco17", "2", "1", "1", "640x480",
                                "25", "yes"]


def test_tracks_info_json_and_bad_input(tmp_path, capsys):
    assert main(["tracks-info", "--json", "--image-size", "640x480", "--fps", "30",
                 str(DATA / "mmpose_video.json")]) == 0
    out = json.loads(capsys.readouterr().out)
    cam = out["cameras"][0]
    assert (cam["format"], cam["frames"], cam["persons"], cam["detections"]) == ("mmpose", 3,
                                                                                 2, 3)
    assert cam["image_size"] == [640, 480] and cam["fps"] == 30.0 and cam["track_ids"]
    bad = tmp_path / "bad.json"
    bad.write_text("{")
    assert main(["tracks-info", str(bad)]) == 2
    assert "not valid JSON" in capsys.readouterr().err
