"""``cascalib tracks-info`` on real and sample keypoint files."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import pytest

from cascalib import InputError
from cascalib.cli import COMMANDS, tracks_info


def main(argv: list[str]) -> int:
    """The sub-command alone (the full ``cascalib`` parser imports every other sub-command)."""
    parser = argparse.ArgumentParser(prog="cascalib")
    tracks_info.add_parser(parser.add_subparsers(dest="command", required=True))
    args = parser.parse_args(argv)
    return args.run(args)


def test_tracks_info_is_a_registered_command():
    assert "tracks_info" in COMMANDS

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
    # the mmpose file stores its image size (640x480): a given size that differs is refused
    # (docs/decisions/image-size-precedence.md), so the other cameras get theirs by name
    files = [str(DATA / "mmpose_video.json"), str(DATA / "caliscope.csv")]
    with pytest.raises(InputError, match="1280x720 differs from the 640x480 the file records"):
        main(["tracks-info", "--image-size", "1280x720", *files])
    assert main(["tracks-info", "--json", "--image-size", "port_0=1280x720", "--fps", "30",
                 "--fps", "port_2=25", "--image-size", "port_2=1920x1080", *files]) == 0
    out = json.loads(capsys.readouterr().out)
    port0, port2 = out["cameras"][1:]
    assert (port0["fps"], port0["image_size"]) == (30.0, [1280, 720])
    assert (port2["fps"], port2["image_size"]) == (25.0, [1920, 1080])
    cam = out["cameras"][0]
    assert (cam["format"], cam["frames"], cam["persons"], cam["detections"]) == ("mmpose", 3,
                                                                                 2, 3)
    assert cam["image_size"] == [640, 480] and cam["fps"] == 30.0 and cam["track_ids"]
    bad = tmp_path / "bad.json"
    bad.write_text("{")
    with pytest.raises(InputError, match="not valid JSON"):  # cli.main maps it to exit code 2
        main(["tracks-info", str(bad)])
