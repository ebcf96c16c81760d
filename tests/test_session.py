"""Session loading: per-camera image sizes and frame rates, manifests, clear errors."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cascalib import InputError, Tracks
from cascalib.formats import write_tracks
from cascalib.session import (
    apply_overrides,
    load_session,
    parse_camera_values,
    resolve_session,
)


def _write(tmp_path, name, fmt="coco", **kw):
    kp = np.random.default_rng(0).uniform(10, 400, (6, 1, 17, 3))
    kp[..., 2] = 0.9
    t = Tracks(name, kp, "coco17", **kw)
    return write_tracks(t, tmp_path / f"{name}.json", format=fmt)


def test_global_and_per_camera_values_with_precedence(tmp_path):
    a = _write(tmp_path, "cam0")
    b = _write(tmp_path, "cam1")
    tracks = load_session([a, b], image_size=["1920x1080", "cam1=1280x720"],
                          fps=["30", "cam1=25"])
    assert [t.camera for t in tracks] == ["cam0", "cam1"]
    assert tracks[0].image_size == (1920, 1080) and tracks[1].image_size == (1280, 720)
    assert tracks[0].fps == 30.0 and tracks[1].fps == 25.0


def test_frame_rate_in_file_wins_over_global_but_not_over_per_camera(tmp_path):
    a = _write(tmp_path, "cam0", fmt="native-json", image_size=(800, 600), fps=50.0)
    t = load_session([a], image_size="800x600", fps=30)[0]
    assert t.image_size == (800, 600) and t.fps == 50.0
    t = load_session([a], image_size={"cam0": "800x600"}, fps={"cam0": 25})[0]
    assert t.image_size == (800, 600) and t.fps == 25.0


def test_a_given_frame_rate_the_file_contradicts_is_a_warning(tmp_path, caplog):
    """Either way the rule goes, the caller hears of it: in the warnings, not only a log."""
    a = _write(tmp_path, "cam0", fmt="native-json", image_size=(800, 600), fps=50.0)
    b = _write(tmp_path, "cam1", fmt="native-json", image_size=(800, 600), fps=30.0)
    tracks, warnings = resolve_session([a, b], fps=["30", "cam0=25"])
    assert [t.fps for t in tracks] == [25.0, 30.0]
    assert warnings == ["camera cam0: the given 25 fps replaces the 50 fps its file records"]
    tracks, warnings = resolve_session([a, b], fps=25)
    assert [t.fps for t in tracks] == [50.0, 30.0]
    assert len(warnings) == 2 and "the 25 fps given for every camera is not used" in warnings[0]
    assert resolve_session([a, b], fps={"cam0": 50, "cam1": 30})[1] == []
    caplog.set_level("WARNING")
    load_session([a], fps={"cam0": 25})  # the plain loader logs what it cannot return
    assert "replaces the 50 fps" in caplog.text


@pytest.mark.parametrize("given", ["1920x1080", {"cam0": "1024x768"}, {"cam0": "1x1"}])
def test_given_image_size_other_than_the_files_is_refused(tmp_path, given):
    a = _write(tmp_path, "cam0", fmt="native-json", image_size=(800, 600))
    with pytest.raises(InputError, match="differs from the 800x600 the file records") as info:
        load_session([a], image_size=given)
    assert info.value.camera == "cam0" and info.value.field == "image_size"
    assert info.value.file == str(a)


@pytest.mark.parametrize("kw, message", [
    (dict(image_size=["camX=640x480"]), "no camera named 'camX'"),
    (dict(image_size=["640by480"]), "image size must look like 1920x1080"),
    (dict(fps=["cam0=-3"]), "frame rate must be positive"),
    (dict(fps=["30", "25"]), "given twice"),
])
def test_bad_overrides_name_field_and_camera(tmp_path, kw, message):
    a = _write(tmp_path, "cam0")
    with pytest.raises(InputError, match=message) as info:
        load_session([a], **kw)
    assert info.value.field in ("image_size", "fps")


def test_manifest_names_cameras_and_sets_values(tmp_path):
    _write(tmp_path, "left")
    _write(tmp_path, "right")
    manifest = tmp_path / "session.toml"
    manifest.write_text('fps = 30\nimage_size = "640x480"\n'
                        '[cameras.A]\nfile = "left.json"\n'
                        '[cameras.B]\nfile = "right.json"\nfps = 60\n')
    tracks = load_session([manifest])
    assert [t.camera for t in tracks] == ["A", "B"]
    assert [t.fps for t in tracks] == [30.0, 60.0]
    assert tracks[1].image_size == (640, 480)
    # command-line values still win over the manifest's
    assert load_session([manifest], fps={"B": 25})[1].fps == 25.0


def test_manifest_json_and_missing_file(tmp_path):
    manifest = tmp_path / "session.json"
    manifest.write_text(json.dumps({"cameras": {"A": {"file": "nope.json"}}}))
    with pytest.raises(InputError, match="no such file") as info:
        load_session([manifest])
    assert info.value.camera == "A"


def test_duplicate_camera_names_are_rejected(tmp_path):
    a = _write(tmp_path, "cam0")
    (tmp_path / "other").mkdir()
    b = _write(tmp_path / "other", "cam0")
    with pytest.raises(InputError, match="duplicate camera name"):
        load_session([a, b])


def test_parse_camera_values_forms():
    assert parse_camera_values(None, float, field="fps") == (None, {})
    assert parse_camera_values({"a": 25}, float, field="fps") == (None, {"a": 25.0})
    assert parse_camera_values(["30", "b=60"], float, field="fps") == (30.0, {"b": 60.0})
    t = Tracks("a", np.ones((2, 1, 17, 3)), "coco17")
    assert apply_overrides([t], fps=12)[0].fps == 12.0
