"""caliscope's ``camera_array.toml``: a file caliscope wrote, our file under caliscope's reading
rules (``CameraArray.from_toml`` of caliscope 0.11.8) and, where installed, caliscope itself."""

from __future__ import annotations

import tomllib

import cv2
import numpy as np
import pytest
from test_calibration_files import DATA, assert_cameras_equal, random_rig

from cascalib import Calibration
from cascalib.cli import main
from cascalib.errors import CalibrationFileError
from cascalib.formats import load_calibration, save_calibration
from cascalib.formats.calibration import caliscope_toml, detect_format

WRITTEN_BY_CALISCOPE = DATA / "camera_array_caliscope.toml"


def test_a_file_caliscope_wrote_is_read():
    calib = load_calibration(WRITTEN_BY_CALISCOPE)
    rig = random_rig(seed=5, n=3)
    assert calib.names == ["cam_1", "cam_2", "cam_3"]
    for a, b, name in zip(calib.cameras, rig.cameras, calib.names, strict=True):
        assert_cameras_equal(a, b.with_(name=name), atol=1e-12, time=False)
        assert (a.fps, a.time_offset, a.time_rate) == (None, 0.0, 1.0)
    assert "not the ground" in calib.world


def test_convert_accepts_a_caliscope_camera_array(tmp_path, capsys):
    assert main(["convert", str(WRITTEN_BY_CALISCOPE), str(tmp_path / "c.json")]) == 0
    assert "3 cameras (cam_1, cam_2, cam_3) -> json" in capsys.readouterr().out
    assert main(["convert", str(tmp_path / "c.json"), str(tmp_path / "camera_array.toml")]) == 0
    assert detect_format(tmp_path / "camera_array.toml") == "caliscope"


def test_our_file_follows_caliscopes_reading_rules(tmp_path):
    """What CameraArray.from_toml needs: [cameras.<int>] tables with cam_id, size, matrix,
    distortions, a Rodrigues rotation and a translation (cam_from_world, as cv2.projectPoints's
    rvec/tvec), no null values."""
    rig = random_rig(seed=1, n=4)
    save_calibration(rig, tmp_path / "camera_array.toml", format="caliscope")
    data = tomllib.loads((tmp_path / "camera_array.toml").read_text())
    tables = data["cameras"]
    assert [int(k) for k in tables] == [0, 1, 2, 3]  # cam0..cam3: their own digits
    points = np.array([[0.3, -0.2, 1.1], [1.0, 0.5, 0.2], [-0.7, 0.1, 1.7]])
    for key, cam in zip(tables, rig.cameras, strict=True):
        entry = tables[key]
        assert entry["cam_id"] == int(key) and entry["fisheye"] is False
        assert entry["size"] == [1920, 1080] and entry["rotation_count"] == 0
        assert np.shape(entry["matrix"]) == (3, 3) and len(entry["distortions"]) == 5
        assert np.shape(entry["rotation"]) == (3,)
        R = cv2.Rodrigues(np.asarray(entry["rotation"]))[0]
        np.testing.assert_allclose(R, cam.R, atol=1e-12)
        uv, _ = cv2.projectPoints(points, np.asarray(entry["rotation"]),
                                  np.asarray(entry["translation"]), np.asarray(entry["matrix"]),
                                  np.asarray(entry["distortions"]))
        np.testing.assert_allclose(uv.reshape(-1, 2), cam.project(points), atol=1e-9)


@pytest.mark.parametrize("names, ids", [
    (["cam0", "cam1"], [0, 1]), (["cam_3", "cam_7"], [3, 7]), (["A", "B"], [0, 1]),
    (["cam1", "left1"], [0, 1]), (["cam2", "B"], [0, 1]),
])
def test_camera_ids(names, ids):
    assert caliscope_toml.camera_ids(names) == ids


def _one_camera_file(tmp_path, **change):
    save_calibration(random_rig(n=2), tmp_path / "camera_array.toml", format="caliscope")
    text = (tmp_path / "camera_array.toml").read_text()
    data = tomllib.loads(text)
    for key, value in change.items():
        if value is None:
            del data["cameras"]["1"][key]
        else:
            data["cameras"]["1"][key] = value
    import tomli_w

    (tmp_path / "camera_array.toml").write_text(tomli_w.dumps(data))
    return tmp_path / "camera_array.toml"


@pytest.mark.parametrize("change, message", [
    ({"rotation": None}, "caliscope has not posed this camera"),
    ({"translation": None}, "caliscope has not posed this camera"),
    ({"fisheye": True}, "fisheye cameras are not supported"),
    ({"rotation": [1.0, 2.0]}, "expected shape 3, got [2]"),
])
def test_bad_camera_tables_are_refused(tmp_path, change, message):
    path = _one_camera_file(tmp_path, **change)
    with pytest.raises(CalibrationFileError) as err:
        load_calibration(path)
    assert message in str(err.value) and err.value.camera == "cam1"


def test_a_legacy_3x3_rotation_is_read(tmp_path):
    rig = random_rig(n=2)
    path = _one_camera_file(tmp_path, rotation=rig["cam1"].R.tolist())
    np.testing.assert_allclose(load_calibration(path)["cam1"].R, rig["cam1"].R, atol=1e-12)


def test_reading_it_as_aniposelib_toml_points_to_the_caliscope_format():
    with pytest.raises(CalibrationFileError, match="read it as format 'caliscope'"):
        load_calibration(WRITTEN_BY_CALISCOPE, format="toml")


def test_the_older_caliscope_layout_is_read_as_caliscope_too():
    calib = load_calibration(DATA / "rig_caliscope.toml", format="caliscope")
    assert calib.names == ["cam_2", "cam_1"]


def test_real_caliscope_loads_our_file(tmp_path):
    camera_array = pytest.importorskip(
        "caliscope.cameras.camera_array",
        reason="caliscope not installed (not in the dev extra: it needs opencv-python, which "
               "collides with opencv-python-headless; pip install caliscope==0.11.8)")
    rig = random_rig(seed=2, n=3)
    rig = Calibration([c.with_(name=n) for c, n in zip(rig.cameras, ["left", "top", "right"],
                                                        strict=True)])
    save_calibration(rig, tmp_path / "camera_array.toml", format="caliscope")
    array = camera_array.CameraArray.from_toml(tmp_path / "camera_array.toml")
    assert sorted(array.cameras) == [0, 1, 2] and len(array.posed_cameras) == 3
    for cam_id, cam in zip([0, 1, 2], rig.cameras, strict=True):
        data = array.cameras[cam_id]
        assert tuple(data.size) == cam.image_size
        np.testing.assert_allclose(data.matrix, cam.K, atol=1e-12)
        np.testing.assert_allclose(data.distortions, cam.dist, atol=1e-15)
        np.testing.assert_allclose(data.rotation, cam.R, atol=1e-12)
        np.testing.assert_allclose(data.translation, cam.t, atol=1e-15)
