"""COLMAP and EasyMocap keep the rig's clocks in ``cascalib_time.json`` beside the model; without
it (or with one for other cameras) a read says so and gives the neutral values."""

from __future__ import annotations

import json

import pytest
from test_calibration_files import assert_cameras_equal, random_rig

from cascalib.cli import main
from cascalib.errors import CalibrationFileError
from cascalib.formats import load_calibration, save_calibration
from cascalib.formats.calibration import TIME_SIDECAR

FOLDER_FORMATS = ["colmap", "easymocap"]


def _neutral(calib):
    return all((c.fps, c.time_offset, c.time_rate) == (None, 0.0, 1.0) for c in calib.cameras)


@pytest.mark.parametrize("fmt", FOLDER_FORMATS)
def test_the_sidecar_gives_the_clocks_back(tmp_path, fmt):
    rig = random_rig()
    written = save_calibration(rig.subset(["cam1", "cam2", "cam3"]), tmp_path, format=fmt)
    assert written[-1] == tmp_path / TIME_SIDECAR
    back = load_calibration(tmp_path)
    assert back.reference_camera == "cam1"  # subset re-expressed the clocks in cam1's frames
    for a, b in zip(back.cameras, rig.subset(["cam1", "cam2", "cam3"]).cameras, strict=True):
        assert_cameras_equal(a, b)


@pytest.mark.parametrize("fmt", FOLDER_FORMATS)
def test_without_the_sidecar_the_read_says_what_is_missing(tmp_path, fmt, caplog):
    save_calibration(random_rig(), tmp_path, format=fmt)
    (tmp_path / TIME_SIDECAR).unlink()
    back = load_calibration(tmp_path)
    assert _neutral(back) and back.reference_camera == "cam0"
    assert f"there is no {TIME_SIDECAR} beside it: fps unknown, time offsets 0" in caplog.text


@pytest.mark.parametrize("fmt", FOLDER_FORMATS)
def test_a_sidecar_for_other_cameras_is_not_used(tmp_path, fmt, caplog):
    save_calibration(random_rig(), tmp_path, format=fmt)
    data = json.loads((tmp_path / TIME_SIDECAR).read_text())
    data["cameras"]["cam9"] = data["cameras"].pop("cam3")
    (tmp_path / TIME_SIDECAR).write_text(json.dumps(data))
    assert _neutral(load_calibration(tmp_path))
    assert "its clocks are not used" in caplog.text


@pytest.mark.parametrize("text, message", [
    ("{", "not valid JSON"), ('{"schema": "x"}', "expected an object with schema"),
    ('{"schema": "cascalib/time@1", "cameras": []}', "'cameras' must be an object"),
])
def test_a_broken_sidecar_is_an_error(tmp_path, text, message):
    save_calibration(random_rig(), tmp_path, format="colmap")
    (tmp_path / TIME_SIDECAR).write_text(text)
    with pytest.raises(CalibrationFileError, match=message):
        load_calibration(tmp_path)


def test_a_bad_value_in_the_sidecar_names_the_camera(tmp_path):
    save_calibration(random_rig(), tmp_path, format="colmap")
    data = json.loads((tmp_path / TIME_SIDECAR).read_text())
    data["cameras"]["cam1"]["time_rate"] = -1
    (tmp_path / TIME_SIDECAR).write_text(json.dumps(data))
    with pytest.raises(CalibrationFileError) as err:
        load_calibration(tmp_path)
    assert err.value.camera == "cam1" and err.value.field == "time_rate"


@pytest.mark.parametrize("fmt", FOLDER_FORMATS)
def test_convert_round_trip_keeps_time_and_says_where(tmp_path, capsys, fmt):
    rig = random_rig()
    save_calibration(rig, tmp_path / "c.json")
    assert main(["convert", str(tmp_path / "c.json"), str(tmp_path / "model"), "--to", fmt]) == 0
    out = capsys.readouterr().out
    assert f"warning: {fmt} has no place for frame rates" in out and TIME_SIDECAR in out
    assert main(["convert", str(tmp_path / "model"), str(tmp_path / "back.json")]) == 0
    for a, b in zip(load_calibration(tmp_path / "back.json").cameras, rig.cameras, strict=True):
        assert_cameras_equal(a, b)
