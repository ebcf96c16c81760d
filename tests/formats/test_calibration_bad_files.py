"""Each kind of bad calibration file raises CalibrationFileError naming file, camera, field."""

from __future__ import annotations

import copy
import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from cascalib import Calibration, CalibrationFileError, Camera
from cascalib.formats import load_calibration, save_calibration

DATA = Path(__file__).resolve().parents[1] / "data" / "calibration"
SAMPLE = json.loads((DATA / "rig.json").read_text())


def _set(path: list, value):
    def change(d):
        for key in path[:-1]:
            d = d[key]
        d[path[-1]] = value
    return change


def _delete(path: list):
    def change(d):
        for key in path[:-1]:
            d = d[key]
        del d[path[-1]]
    return change


_EAST = ["cameras", "east"]
#: (id, change to the sample dict, camera, field, message regex)
NATIVE_BAD = [
    ("schema", _set(["schema"], "cascalib/calibration@2"), None, "schema", "unsupported schema"),
    ("missing-schema", _delete(["schema"]), None, "schema", "missing key 'schema'"),
    ("units", _set(["units"], "mm"), None, "units", "units must be 'm'"),
    ("missing-cameras", _delete(["cameras"]), None, "cameras", "missing key"),
    ("empty-cameras", _set(["cameras"], {}), None, "cameras", "non-empty"),
    ("missing-K", _delete([*_EAST, "K"]), "east", "K", "missing key 'K'"),
    ("missing-time-rate", _delete([*_EAST, "time_rate"]), "east", "time_rate", "missing key"),
    ("R-scaled", _set([*_EAST, "R"], (2 * np.eye(3)).tolist()), "east", "R",
     "not a rotation matrix: max"),
    ("R-reflection", _set([*_EAST, "R"], np.diag([1.0, 1, -1]).tolist()), "east", "R",
     "determinant is negative"),
    ("R-shape", _set([*_EAST, "R"], [1.0, 0.0, 0.0]), "east", "R", "expected shape 3x3"),
    ("t-nan", _set([*_EAST, "t"], [0.0, float("nan"), 4.0]), "east", "t", "non-finite"),
    ("K-inf", _set([*_EAST, "K"], [[800, 0, float("inf")], [0, 800, 360], [0, 0, 1]]), "east",
     "K", "non-finite"),
    ("K-negative-focal", _set([*_EAST, "K"], [[-800, 0, 640], [0, 800, 360], [0, 0, 1]]),
     "east", "K", "focal lengths must be positive"),
    ("K-zero-focal", _set([*_EAST, "K"], [[800, 0, 640], [0, 0, 360], [0, 0, 1]]), "east", "K",
     "focal lengths must be positive"),
    ("K-last-row", _set([*_EAST, "K"], [[800, 0, 640], [0, 800, 360], [0, 0, 2]]), "east", "K",
     "upper-triangular"),
    ("size-negative", _set([*_EAST, "image_size"], [-1280, 720]), "east", "image_size",
     "two positive integers"),
    ("size-fraction", _set([*_EAST, "image_size"], [1280.5, 720]), "east", "image_size",
     "two positive integers"),
    ("size-length", _set([*_EAST, "image_size"], [1280]), "east", "image_size",
     "expected shape 2"),
    ("dist-length", _set([*_EAST, "dist"], [0.1, 0.2, 0.3]), "east", "dist",
     "4 or 5 distortion"),
    ("dist-text", _set([*_EAST, "dist"], ["a", 0, 0, 0, 0]), "east", "dist",
     "not a numeric array"),
    ("rate-zero", _set([*_EAST, "time_rate"], 0.0), "east", "time_rate", "must be positive"),
    ("offset-text", _set([*_EAST, "time_offset"], "soon"), "east", "time_offset",
     "expected a number"),
    ("fps-negative", _set([*_EAST, "fps"], -30), "east", "fps", "must be positive"),
    ("reference-unknown", _set(["reference_camera"], "west"), None, "reference_camera",
     "'west' is not one of"),
]


@pytest.mark.parametrize("change, camera, field, message",
                         [case[1:] for case in NATIVE_BAD], ids=[case[0] for case in NATIVE_BAD])
def test_bad_native_json(tmp_path, change, camera, field, message):
    data = copy.deepcopy(SAMPLE)
    change(data)
    path = tmp_path / "calibration.json"
    path.write_text(json.dumps(data))
    with pytest.raises(CalibrationFileError, match=message) as info:
        load_calibration(path)
    err = info.value
    assert (err.file, err.camera, err.field) == (str(path), camera, field)


def test_not_json_at_all(tmp_path):
    path = tmp_path / "calibration.json"
    path.write_text("{'cameras': ")
    with pytest.raises(CalibrationFileError, match="not valid JSON") as info:
        load_calibration(path)
    assert info.value.file == str(path)


def _edit(src: str, old: str, new: str):
    def make(tmp_path: Path) -> Path:
        source = DATA / src
        if source.is_dir():
            target = tmp_path / source.name
            shutil.copytree(source, target)
            victim = next(p for p in target.iterdir() if old in p.read_text())
        else:
            target = victim = tmp_path / source.name
            shutil.copy(source, target)
        text = victim.read_text()
        assert old in text, old
        victim.write_text(text.replace(old, new, 1))
        return target
    return make


#: (id, file maker, camera, field, message regex)
OTHER_BAD = [
    ("toml-missing-translation", _edit("rig_aniposelib.toml", "translation = [0.0, 1.5, 4.0]\n"
                                       "fisheye", "fisheye"), "north", "translation",
     "missing key"),
    ("toml-fisheye", _edit("rig_aniposelib.toml", "fisheye = false", "fisheye = true"), "north",
     "fisheye", "fisheye cameras are not supported"),
    ("toml-rodrigues-length", _edit("rig_aniposelib.toml", "rotation = [1.5707963267948966, "
                                    "0.0, 0.0]", "rotation = [1.5, 0.0]"), "north", "rotation",
     "expected shape 3"),
    ("toml-matrix-not-rotation", _edit("rig_caliscope.toml", "[0.0, 0.0, -1.0], [-1.0",
                                       "[0.0, 0.0, -1.0], [-2.0"), "cam_1", "rotation",
     "not a rotation"),
    ("toml-distortions", _edit("rig_aniposelib.toml", "[-0.1, 0.01, 0.001, -0.002]", "[-0.1]"),
     "north", "distortions", "4 or 5 distortion"),
    ("toml-syntax", _edit("rig_aniposelib.toml", "[cam_1]", "[cam_1"), None, None,
     "not valid TOML"),
    ("toml-duplicate-names", _edit("rig_aniposelib.toml", 'name = "east"', 'name = "north"'),
     None, "cameras", "duplicate camera names"),
    ("opencv-syntax", _edit("rig_opencv.yml", "K_east: !!opencv-matrix", "K_east: [[[ !!x"),
     None, None, "OpenCV cannot parse this file: line [0-9]+: Missing ,"),
    ("colmap-model", _edit("colmap_rig", "7 SIMPLE_RADIAL", "7 THIN_PRISM_FISHEYE"), "east",
     "model", "unsupported COLMAP camera model"),
    ("colmap-params", _edit("colmap_rig", "800.0 640.5 360.5 0.0", "800.0 640.5"), "east",
     "params", "expected shape 4"),
    ("colmap-quaternion", _edit("colmap_rig", "2 0.5 0.5", "2 0.9 0.5"), "east", "QW QX QY QZ",
     "not unit length"),
    ("colmap-camera-id", _edit("colmap_rig", "4.0 7 east", "4.0 8 east"), "east", "CAMERA_ID",
     "unknown CAMERA_ID 8"),
    ("colmap-short-line", _edit("colmap_rig", "1 0.7071067811865476", "1 0.70710x"), None,
     None, "line 5: expected 'IMAGE_ID"),
    ("opencv-missing-T", _edit("rig_opencv.yml", "T_east", "X_east"), "east", "T_east",
     "missing key 'T_east'"),
    ("opencv-Rot-not-rotation", _edit("rig_opencv.yml", "data: [ 0., 1., 0., 0., 0., -1., -1.",
                                      "data: [ 0., 1., 0., 0., 0., -1., -1.5"), "east",
     "Rot_east", "not a rotation"),
    ("colmap-negative-focal", _edit("colmap_rig", "7 SIMPLE_RADIAL 1280 720 800.0",
                                    "7 SIMPLE_RADIAL 1280 720 -800.0"), "east", "params",
     "focal lengths must be positive"),
    ("colmap-size", _edit("colmap_rig", "7 SIMPLE_RADIAL 1280 720", "7 SIMPLE_RADIAL 1280 0"),
     "east", "WIDTH HEIGHT", "two positive integers"),
    ("opencv-missing-names", _edit("rig_opencv.yml", "names:", "nombres:"), None, "names",
     "missing key 'names'"),
    ("easymocap-missing-R", _edit("easymocap_rig", "R_east", "Q_east"), "east", "R_east",
     "missing key 'R_east'"),
    ("easymocap-K", _edit("easymocap_rig", "800., 0., 640., 0., 800.", "800., 0., 640., 0., "
                          "-800."), "east", "K_east", "focal lengths must be positive"),
]


@pytest.mark.parametrize("make, camera, field, message", [c[1:] for c in OTHER_BAD],
                         ids=[c[0] for c in OTHER_BAD])
def test_bad_files_of_other_formats(tmp_path, make, camera, field, message):
    path = make(tmp_path)
    with pytest.raises(CalibrationFileError, match=message) as info:
        load_calibration(path)
    err = info.value
    assert err.file is not None and Path(err.file).is_relative_to(tmp_path)
    assert (err.camera, err.field) == (camera, field)


@pytest.mark.parametrize("old, new, camera, field, message", [
    ('r11="0.5536380477336265" ', "", "cam_01", "transform.r11", "missing attribute 'r11'"),
    ('focalLengthU="107599.671875"', 'focalLengthU="big"', "cam_01", "intrinsic.focalLengthU",
     "not a number"),
    ('serial="cam_02" viewrotation="0"', 'serial="cam_02" viewrotation="90"', "cam_02",
     "viewrotation", "viewrotation=90 is not supported"),
    ('r21="-0.4345300743838753"', 'r21="0.4345300743838753"', "cam_01", "transform",
     "not a rotation"),
])
def test_bad_qualisys_files(shared_data, tmp_path, old, new, camera, field, message):
    text = (shared_data / "pose2sim_demo" / "Calib.qca.txt").read_text()
    assert old in text
    path = tmp_path / "Calib.qca.txt"
    path.write_text(text.replace(old, new, 1))
    with pytest.raises(CalibrationFileError, match=message) as info:
        load_calibration(path)
    assert (info.value.file, info.value.camera, info.value.field) == (str(path), camera, field)


def _two_cameras(name: str = "a", skew: float = 0.0) -> Calibration:
    K = np.array([[800.0, skew, 320], [0, 800, 240], [0, 0, 1]])
    return Calibration([Camera(name, (640, 480), K, None, np.eye(3), [0, 0, 1]),
                        Camera("b", (640, 480), K, None, np.eye(3), [1, 0, 1])])


@pytest.mark.parametrize("calib, fmt, camera, field, message", [
    (_two_cameras("a b"), "opencv", "a b", "name", "node names allow only"),
    (_two_cameras("a/b"), "easymocap", "a/b", "name", "node names allow only"),
    (_two_cameras("a b"), "colmap", "a b", "name", "cannot contain whitespace"),
    (_two_cameras(skew=1.5), "colmap", "a", "K", "no skew"),
    (_two_cameras(), "qualisys", None, "format", "can be read but not written"),
    (_two_cameras(), "obj", None, "format", "unknown calibration format 'obj'"),
])
def test_what_a_writer_cannot_write_is_refused(tmp_path, calib, fmt, camera, field, message):
    with pytest.raises(CalibrationFileError, match=message) as info:
        save_calibration(calib, tmp_path / "out", format=fmt)
    assert (info.value.camera, info.value.field) == (camera, field)


def test_missing_and_unrecognised_paths(tmp_path):
    with pytest.raises(CalibrationFileError, match="file not found"):
        load_calibration(tmp_path / "nope.json")
    (tmp_path / "notes.txt").write_text("hello")
    with pytest.raises(CalibrationFileError, match="cannot tell the calibration format"):
        load_calibration(tmp_path / "notes.txt")
    (tmp_path / "empty").mkdir()
    with pytest.raises(CalibrationFileError, match="folder holds no known calibration"):
        load_calibration(tmp_path / "empty")
