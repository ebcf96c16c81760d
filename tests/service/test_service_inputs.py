"""Safe handling of uploaded files: zip folders, zip-shaped keypoint files, hostile archives."""

from __future__ import annotations

import io
import stat
import zipfile
from pathlib import Path

import numpy as np
import pytest
from service_helpers import camera_zip, zip_bytes

from cascalib.errors import InputError
from service.inputs import ZipLimits, is_zip, safe_extract
from service.uploads import camera_name

LIMITS = ZipLimits(max_members=100, max_total_bytes=10 * 2**20, max_ratio=200)


def test_npz_is_a_file_not_a_folder(tmp_path: Path) -> None:
    np.savez(tmp_path / "cam0.npz", keypoints=np.zeros((2, 1, 17, 3)))
    (tmp_path / "noext").write_bytes((tmp_path / "cam0.npz").read_bytes())
    (tmp_path / "cam1.zip").write_bytes(camera_zip())
    (tmp_path / "cam2.json").write_bytes(b'{"people": []}')
    assert [is_zip(tmp_path / n) for n in ("cam0.npz", "noext", "cam1.zip", "cam2.json")] == [
        False, False, True, False]


def test_extract_flattens_and_skips_metadata(tmp_path: Path) -> None:
    data = zip_bytes({"cam/a_000000000000_keypoints.json": b"{}", "__MACOSX/cam/._a": b"x",
                      "cam/.DS_Store": b"x", "cam/b_000000000001_keypoints.json": b"{}"})
    (tmp_path / "in.zip").write_bytes(data)
    out = safe_extract(tmp_path / "in.zip", tmp_path / "out", LIMITS, file="cam0.zip")
    assert sorted(p.name for p in out.iterdir()) == ["a_000000000000_keypoints.json",
                                                     "b_000000000001_keypoints.json"]


def _symlink_zip() -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w") as zf:
        info = zipfile.ZipInfo("link.json")
        info.external_attr = (stat.S_IFLNK | 0o777) << 16
        zf.writestr(info, "/etc/passwd")
    return buf.getvalue()


@pytest.mark.parametrize(("members", "message"), [
    ({"../x.json": b"{}"}, "absolute or parent path"),
    ({"a/../../x.json": b"{}"}, "absolute or parent path"),
    ({"/abs/x.json": b"{}"}, "absolute or parent path"),
    ({"C:/x.json": b"{}"}, "absolute or parent path"),
    ({"a/x.json": b"{}", "b/x.json": b"{}"}, "two members named 'x.json'"),
    ({"we ird;name.json": b"{}"}, "characters other than"),
    ({"big.json": b" " * (5 * 2**20)}, "zip bomb"),
    ({f"{i}.json": b"{}" for i in range(101)}, "at most 100 allowed"),
    ({"__MACOSX/x": b""}, "holds no files"),
])
def test_hostile_zips_rejected(tmp_path: Path, members: dict[str, bytes], message: str) -> None:
    (tmp_path / "in.zip").write_bytes(zip_bytes(members))
    with pytest.raises(InputError, match=message) as err:
        safe_extract(tmp_path / "in.zip", tmp_path / "out", LIMITS, file="cam0.zip")
    assert err.value.file == "cam0.zip" and err.value.field == "files"
    assert not list(tmp_path.glob("x.json")) and not (tmp_path.parent / "x.json").exists()


def test_symlink_member_rejected(tmp_path: Path) -> None:
    (tmp_path / "in.zip").write_bytes(_symlink_zip())
    with pytest.raises(InputError, match="symbolic link"):
        safe_extract(tmp_path / "in.zip", tmp_path / "out", LIMITS, file="cam0.zip")


def test_lying_sizes_still_bounded(tmp_path: Path) -> None:
    """A member whose header understates its size is cut off by the bytes actually written."""
    raw = bytearray(zip_bytes({"a.json": b" " * (4 * 2**20)}))
    # Patch the declared uncompressed size (central directory) down to 10 bytes.
    cd = raw.rfind(b"PK\x01\x02")
    raw[cd + 24:cd + 28] = (10).to_bytes(4, "little")
    (tmp_path / "in.zip").write_bytes(bytes(raw))
    small = ZipLimits(max_members=10, max_total_bytes=2**20, max_ratio=10_000)
    with pytest.raises(InputError):
        safe_extract(tmp_path / "in.zip", tmp_path / "out", small, file="cam0.zip")
    assert sum(p.stat().st_size for p in (tmp_path / "out").iterdir()) <= 2**20


@pytest.mark.parametrize(("name", "camera"), [
    ("cam0.json", ("cam0", "json")), ("side.left.CSV", ("side.left", "csv")),
    ("cam3", ("cam3", "")), ("cam_4.tar.gz", ("cam_4.tar", "gz"))])
def test_camera_names(name: str, camera: tuple[str, str]) -> None:
    assert camera_name(name) == camera


@pytest.mark.parametrize("name", ["../cam0.json", "a/b.json", "a\\b.json", ".hidden", "",
                                  "cam 0.json", "x" * 70 + ".json", "caméra.json"])
def test_bad_camera_names(name: str) -> None:
    from service.core.problems import ProblemError

    with pytest.raises(ProblemError) as err:
        camera_name(name)
    assert err.value.status == 422 and err.value.errors[0].field == "files"


def test_npz_unpacking_past_the_limit_refused_before_unpacking(tmp_path: Path) -> None:
    """A compressed NPZ of zeros is a zip bomb for np.load: its declared size is checked
    first."""
    from api_schemas import JobOptions
    from cascalib.formats.keypoints import LimitExceeded
    from service.inputs import read_camera

    path = tmp_path / "cam0.npz"
    np.savez_compressed(path, header=np.array('{"schema": "cascalib/tracks@1"}'),
                        keypoints=np.zeros((40_000, 4, 17, 3)))
    assert path.stat().st_size < 2**20
    limits = ZipLimits(100, 2**30, 200, max_keypoint_bytes=16 * 2**20)
    with pytest.raises(LimitExceeded, match="unpack to") as info:
        read_camera(path, "cam0", JobOptions(), limits)
    assert (info.value.camera, info.value.field) == ("cam0", "keypoints")


def test_given_values_follow_the_command_lines_rule(tmp_path: Path) -> None:
    """The service fills in fps and image size with the CLI's function: this camera's fps
    beats the file's, one for every camera loses to it, and both say so; a size the file
    contradicts is refused, naming the option."""
    from api_schemas import JobOptions
    from cascalib import Tracks
    from cascalib.formats import write_tracks
    from cascalib.session import GivenValues
    from service.inputs import read_camera

    kp = np.random.default_rng(0).uniform(10, 400, (6, 1, 17, 3))
    path = write_tracks(Tracks("cam0", kp, "coco17", image_size=(800, 600), fps=50.0),
                        tmp_path / "cam0.json", format="native-json")
    raw = Tracks("cam0", kp, "coco17", image_size=(800, 600), fps=50.0)
    for options in ({"fps": {"cam0": 25}}, {"fps": 25}, {"fps": 50, "image_size": "800x600"},
                    {}):
        tracks, notes = read_camera(path, "cam0", JobOptions.model_validate(options), LIMITS)
        expected = GivenValues.parse(options.get("image_size"), options.get("fps")).apply(raw)
        assert (tracks.fps, tracks.image_size, notes) == (expected[0].fps,
                                                          expected[0].image_size, expected[1])
    tracks, notes = read_camera(path, "cam0", JobOptions(fps={"cam0": 25}), LIMITS)
    assert tracks.fps == 25.0 and notes == [
        "camera cam0: the given 25 fps replaces the 50 fps its file records"]
    tracks, notes = read_camera(path, "cam0", JobOptions(fps=25), LIMITS)
    assert tracks.fps == 50.0 and "not used" in notes[0]
    with pytest.raises(InputError) as err:
        read_camera(path, "cam0", JobOptions(image_size={"cam0": "1024x768"}), LIMITS)
    assert err.value.field == "options.image_size" and err.value.camera == "cam0"
