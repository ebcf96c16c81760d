"""Calibration files: hand-written samples, round trips of every writer, real files, bad files."""

from __future__ import annotations

import json
import shutil
from pathlib import Path

import numpy as np
import pytest

from cascalib import Calibration, Camera
from cascalib.camera import look_at
from cascalib.formats import load_calibration, save_calibration
from cascalib.formats.calibration import (
    anipose_toml,
    caliscope_toml,
    colmap_text,
    detect_format,
    easymocap_yaml,
    native_json,
    opencv_yaml,
)
from cascalib.geometry import rotation_angle_deg

DATA = Path(__file__).resolve().parents[1] / "data" / "calibration"
R_NORTH = np.array([[1.0, 0, 0], [0, 0, -1], [0, 1, 0]])
R_EAST = np.array([[0.0, 1, 0], [0, 0, -1], [-1, 0, 0]])
K_NORTH = np.array([[1000.0, 0, 959.5], [0, 1002.0, 539.5], [0, 0, 1]])
K_EAST = np.array([[800.0, 0, 640.0], [0, 800.0, 360.0], [0, 0, 1]])
DIST_NORTH = np.array([-0.1, 0.01, 0.001, -0.002, 0.0])


def assert_cameras_equal(a: Camera, b: Camera, *, atol: float = 1e-9, time: bool = True) -> None:
    assert a.name == b.name
    assert a.image_size == b.image_size
    for field in ("K", "dist", "R", "t"):
        np.testing.assert_allclose(getattr(a, field), getattr(b, field), atol=atol, rtol=0,
                                   err_msg=f"{a.name}.{field}")
    if time:
        assert a.fps == b.fps
        assert a.time_offset == pytest.approx(b.time_offset, abs=atol)
        assert a.time_rate == pytest.approx(b.time_rate, abs=atol)


def random_rig(seed: int = 0, n: int = 4) -> Calibration:
    """A rig with distortion, skew-free K, time offsets/rates and one unknown frame rate."""
    rng = np.random.default_rng(seed)
    cams = []
    for i in range(n):
        eye = [6 * np.cos(2 * np.pi * i / n), 6 * np.sin(2 * np.pi * i / n), rng.uniform(1, 3)]
        R, t = look_at(eye, rng.uniform(-0.5, 0.5, 3) + [0, 0, 1])
        cams.append(Camera.from_params(
            f"cam{i}", (1920, 1080), tuple(rng.uniform(900, 1500, 2)), R, t,
            c=tuple(rng.uniform(900, 1000, 2)), dist=rng.normal(0, 0.05, 5),
            fps=None if i == 2 else 29.97, time_offset=0.0 if i == 0 else rng.uniform(-40, 40),
            time_rate=1.0 if i == 0 else rng.uniform(0.99, 1.01)))
    return Calibration(cams, reference_camera="cam0", quality={"median_px": 1.5})


# -- hand-written samples -------------------------------------------------------------------------

def test_native_json_sample_keeps_everything():
    calib = load_calibration(DATA / "rig.json")
    assert calib.names == ["north", "east"] and calib.reference_camera == "north"
    assert calib.world == "z-up, ground z=0"
    assert calib.quality == {"reprojection_median_px": 1.25, "verdict": "good"}
    north, east = calib.cameras
    assert_cameras_equal(north, Camera("north", (1920, 1080), K_NORTH, DIST_NORTH, R_NORTH,
                                       [0, 1.5, 4], fps=30.0), atol=0)
    assert_cameras_equal(east, Camera("east", (1280, 720), K_EAST, None, R_EAST, [0, 1.5, 4],
                                      fps=None, time_offset=12.5, time_rate=1.001), atol=0)
    np.testing.assert_allclose(east.center, [4, 0, 1.5], atol=1e-15)


@pytest.mark.parametrize("sample", ["rig_aniposelib.toml", "colmap_rig", "easymocap_rig",
                                    "rig_opencv.yml"])
def test_other_samples_describe_the_same_rig(sample):
    calib = load_calibration(DATA / sample)
    assert calib.names == ["north", "east"]
    north, east = calib.cameras
    expect_north = Camera("north", (1920, 1080), K_NORTH, DIST_NORTH, R_NORTH, [0, 1.5, 4])
    expect_east = Camera("east", (1280, 720), K_EAST, None, R_EAST, [0, 1.5, 4])
    assert_cameras_equal(north, expect_north, atol=1e-12, time=False)
    assert_cameras_equal(east, expect_east, atol=1e-12, time=False)


def test_caliscope_sample_keeps_table_order_and_names_the_camera_world():
    calib = load_calibration(DATA / "rig_caliscope.toml")
    assert calib.names == ["cam_2", "cam_1"]  # file order, never sorted
    assert "camera 'cam_2' frame" in calib.world and "not the ground" in calib.world
    np.testing.assert_array_equal(calib["cam_1"].R, R_EAST)
    np.testing.assert_allclose(calib["cam_1"].center, [4, 0, 1.5], atol=1e-15)


def test_colmap_reader_shifts_the_pixel_origin_and_skips_points_lines():
    calib = load_calibration(DATA / "colmap_rig" / "images.txt")
    # COLMAP's (960, 540) is the pixel centre (959.5, 539.5) in OpenCV's convention
    np.testing.assert_array_equal(calib["north"].principal_point, [959.5, 539.5])
    np.testing.assert_array_equal(calib["east"].dist, np.zeros(5))  # SIMPLE_RADIAL k = 0


@pytest.mark.parametrize("sample, fmt", [
    ("rig.json", "json"), ("rig_aniposelib.toml", "toml"), ("rig_caliscope.toml", "toml"),
    ("camera_array_caliscope.toml", "caliscope"),
    ("rig_opencv.yml", "opencv"), ("colmap_rig", "colmap"), ("colmap_rig/cameras.txt", "colmap"),
    ("easymocap_rig", "easymocap"), ("easymocap_rig/extri.yml", "easymocap"),
])
def test_format_detection(sample, fmt):
    assert detect_format(DATA / sample) == fmt


def test_format_detection_by_content(tmp_path):
    shutil.copy(DATA / "rig.json", tmp_path / "calib.dat")
    assert detect_format(tmp_path / "calib.dat") == "json"
    shutil.copy(DATA / "rig_aniposelib.toml", tmp_path / "calib")
    assert load_calibration(tmp_path / "calib").names == ["north", "east"]


# -- round trips ----------------------------------------------------------------------------------

#: format, target (file or folder), whether it keeps fps / time offset / rate (COLMAP and
#: EasyMocap in their cascalib_time.json)
ROUND_TRIPS = [("json", "c.json", True), ("toml", "c.toml", True), ("opencv", "c.yml", True),
               ("opencv", "c.xml", True), ("colmap", "model", True), ("easymocap", "emc", True),
               ("caliscope", "camera_array.toml", True)]


@pytest.mark.parametrize("fmt, target, keeps_time", ROUND_TRIPS)
def test_round_trip_through_files(tmp_path, fmt, target, keeps_time):
    rig = random_rig()
    written = save_calibration(rig, tmp_path / target, format=fmt)
    assert written and all(p.is_file() for p in written)
    back = load_calibration(tmp_path / target)  # format detected
    assert back.names == rig.names
    for a, b in zip(back.cameras, rig.cameras, strict=True):
        assert_cameras_equal(a, b, time=keeps_time)
        if not keeps_time:  # what the format cannot hold comes back as the neutral values
            assert (a.fps, a.time_offset, a.time_rate) == (None, 0.0, 1.0)
    assert back.reference_camera == "cam0"
    if fmt in ("json", "toml", "opencv", "caliscope"):
        assert back.world == rig.world
    assert back.quality == (rig.quality if fmt == "json" else {})


@pytest.mark.parametrize("module", [native_json, anipose_toml, opencv_yaml, colmap_text,
                                    easymocap_yaml, caliscope_toml])
def test_plain_dict_round_trip(module):
    rig = random_rig(seed=3, n=3)
    back = module.from_dict(module.to_dict(rig))
    for a, b in zip(back.cameras, rig.cameras, strict=True):
        assert_cameras_equal(a, b, time=module not in (colmap_text, easymocap_yaml))


def test_reference_camera_other_than_first_survives(tmp_path):
    rig = random_rig()
    rig = Calibration(rig.cameras, reference_camera="cam3")
    for fmt, target, _ in ROUND_TRIPS:
        save_calibration(rig, tmp_path / target, format=fmt)
        assert load_calibration(tmp_path / target).reference_camera == "cam3"


def test_toml_is_readable_in_aniposelib_layout(tmp_path):
    """Sorted table names keep the rig order (aniposelib sorts them) and rotations are
    Rodrigues vectors."""
    cams = random_rig(n=4).cameras
    rig = Calibration([c.with_(name=n) for c, n in zip(cams, ["z", "b", "y", "a"], strict=True)])
    save_calibration(rig, tmp_path / "c.toml", format="toml")
    import tomllib

    data = tomllib.loads((tmp_path / "c.toml").read_text())
    tables = sorted(k for k in data if k.startswith("cam_"))
    assert [data[k]["name"] for k in tables] == ["z", "b", "y", "a"]
    assert np.asarray(data[tables[0]]["rotation"]).shape == (3,)


# -- real files -----------------------------------------------------------------------------------

def test_qualisys_reader_agrees_with_the_pose2sim_conversion(shared_data):
    qca = load_calibration(shared_data / "pose2sim_demo" / "Calib.qca.txt")
    toml = load_calibration(
        shared_data / "pose2sim_demo" / "Calib_qualisys_converted_by_pose2sim.toml")
    assert qca.names == toml.names == ["cam_01", "cam_02", "cam_03", "cam_04"]
    assert qca.world.startswith("z-up, ground z=0")
    for a, b in zip(qca.cameras, toml.cameras, strict=True):
        assert a.image_size == b.image_size == (1088, 1920)  # portrait
        assert rotation_angle_deg(a.R @ b.R.T) < 0.1
        assert np.linalg.norm(a.center - b.center) < 0.01
        assert abs(a.focal / b.focal - 1) < 0.005
        np.testing.assert_allclose(a.principal_point, b.principal_point, atol=0.01)
        assert 1.6 < a.center[2] < 2.2  # cameras about 2 m above the lab floor (z up)


def test_caliscope_reference_calibration(shared_data):
    calib = load_calibration(shared_data / "caliscope_4cam" / "config.toml")
    assert calib.names == ["cam_0", "cam_1", "cam_2", "cam_3"]
    assert calib["cam_0"].dist[0] == pytest.approx(-0.3383569013465177)
    assert calib["cam_0"].dist[4] == pytest.approx(-0.0037489346582201062)
    assert calib["cam_1"].image_size == (1280, 720)
    assert "camera 'cam_1' frame" in calib.world


def test_real_files_survive_every_writer(shared_data, tmp_path):
    calib = load_calibration(shared_data / "caliscope_4cam" / "config.toml")
    for fmt, target, _ in ROUND_TRIPS:
        save_calibration(calib, tmp_path / target, format=fmt)
        for a, b in zip(load_calibration(tmp_path / target).cameras, calib.cameras, strict=True):
            assert_cameras_equal(a, b, time=False)


def test_reference_camera_with_a_time_offset_is_read_with_a_warning(tmp_path, caplog):
    data = json.loads((DATA / "rig.json").read_text())
    data["cameras"]["north"]["time_offset"] = 3.0
    (tmp_path / "c.json").write_text(json.dumps(data))
    calib = load_calibration(tmp_path / "c.json")
    assert calib["north"].time_offset == 3.0
    assert "the schema expects 0 and 1" in caplog.text


def test_a_folder_with_calibration_json_is_read(tmp_path):
    shutil.copy(DATA / "rig.json", tmp_path / "calibration.json")
    assert load_calibration(tmp_path).names == ["north", "east"]
