"""``cascalib convert`` and ``cascalib evaluate``."""

from __future__ import annotations

import json
from pathlib import Path

import pytest

from cascalib.cli import EXIT_USAGE, main
from cascalib.formats import load_calibration

DATA = Path(__file__).resolve().parents[1] / "data" / "calibration"


@pytest.mark.parametrize("out, to, fmt_written", [
    ("c.toml", None, "toml"), ("c.yml", None, "opencv"), ("model", "colmap", "colmap"),
    ("emc", "easymocap", "easymocap"), ("c.json", None, "json"),
])
def test_convert_writes_the_requested_format(tmp_path, capsys, out, to, fmt_written):
    argv = ["convert", str(DATA / "rig.json"), str(tmp_path / out)]
    if to:
        argv += ["--to", to]
    assert main(argv) == 0
    assert f"2 cameras (north, east) -> {fmt_written}" in capsys.readouterr().out
    back = load_calibration(tmp_path / out)
    assert back.names == ["north", "east"]
    assert back["east"].focal == 800.0


def test_convert_needs_a_format_it_can_tell(tmp_path, capsys):
    assert main(["convert", str(DATA / "rig.json"), str(tmp_path / "out")]) == EXIT_USAGE
    assert "pass --to" in capsys.readouterr().err
    assert main(["convert", str(DATA / "rig.json"), str(tmp_path / "x.json"), "--from",
                 "toml"]) == EXIT_USAGE  # a JSON file read as TOML fails cleanly


def test_evaluate_prints_a_table_and_json(tmp_path, capsys):
    assert main(["evaluate", str(DATA / "rig.json"), "--truth",
                 str(DATA / "rig_aniposelib.toml")]) == 0
    out = capsys.readouterr().out
    assert "north" in out and "rotation vs reference" in out
    assert main(["evaluate", str(DATA / "rig_caliscope.toml"), "--truth", str(DATA / "rig.json"),
                 "--map", "cam_2=north", "--map", "cam_1=east", "--json"]) == 0
    data = json.loads(capsys.readouterr().out)
    assert data["ok"] is True
    assert [r["truth_camera"] for r in data["cameras"]] == ["north", "east"]
    # same intrinsics and the same relative pose, in another world frame
    assert abs(data["cameras"][1]["focal_error_pct"]) < 1e-12
    assert data["summary"]["rotation_error_deg_max"] > 1  # cam_2 at identity != north


def test_evaluate_bad_mapping_is_a_usage_error(capsys):
    code = main(["evaluate", str(DATA / "rig.json"), "--truth", str(DATA / "rig.json"),
                 "--map", "north"])
    assert code == EXIT_USAGE
    assert "expected EST=GT" in capsys.readouterr().err


def test_evaluate_ground_flag(capsys):
    argv = ["evaluate", str(DATA / "rig_aniposelib.toml"), "--truth", str(DATA / "rig.json"),
            "--json"]
    assert main(argv) == 0  # the TOML's world is unknown: no ground alignment by default
    assert json.loads(capsys.readouterr().out)["summary"]["center_error_ground_max"] is None
    assert main([*argv, "--ground"]) == 0
    assert json.loads(capsys.readouterr().out)["summary"]["center_error_ground_max"] < 1e-9
