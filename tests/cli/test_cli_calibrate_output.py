"""``cascalib calibrate``'s last line names every file the run wrote, and nothing else."""

from __future__ import annotations

import os

import pytest

from cascalib.cli import main
from cascalib.cli.calibrate import file_stamps, files_line, written_since
from cascalib.formats import load_calibration, write_tracks
from cascalib.simulate import simulate


def test_written_since_sees_new_and_rewritten_files_only(tmp_path):
    (tmp_path / "old.json").write_text("{}")
    (tmp_path / "kept.txt").write_text("x")
    os.utime(tmp_path / "old.json", ns=(1, 1))
    os.utime(tmp_path / "kept.txt", ns=(1, 1))
    before = file_stamps(tmp_path)
    (tmp_path / "old.json").write_text("{}")  # rewritten
    (tmp_path / "poses").mkdir()
    (tmp_path / "poses" / "poses.npz").write_bytes(b"")
    assert written_since(tmp_path, before) == [tmp_path / "old.json",
                                               tmp_path / "poses" / "poses.npz"]
    assert file_stamps(tmp_path / "missing") == {}


def test_files_line_groups_by_subfolder(tmp_path):
    files = [tmp_path / "calibration.json", tmp_path / "colmap" / "cameras.txt",
             tmp_path / "colmap" / "images.txt", tmp_path / "report.html",
             tmp_path / "poses" / "poses.npz"]
    assert files_line(tmp_path, sorted(files)) == (
        "calibration.json, report.html, colmap/ (cameras.txt, images.txt), poses/ (poses.npz)")


@pytest.mark.slow  # one whole calibration, about 35 s on 2 cores
def test_the_last_line_lists_every_file_written(tmp_path, capsys):
    scene = simulate("terrace", seed=3, duration_s=40.0, **{"people.n_persons": 4})
    inputs = [str(write_tracks(t, tmp_path / f"{t.camera}.json", format="mmpose"))
              for t in scene.tracks]
    out = tmp_path / "out"
    code = main(["calibrate", *inputs, "-o", str(out), "--fps", "25", "--seed", "1",
                 "--formats", "json,caliscope,colmap"])
    assert code in (0, 1)  # 1 only if the quality check rejected a camera
    last = capsys.readouterr().out.strip().splitlines()[-1]
    everything = sorted(p for p in out.rglob("*") if p.is_file())
    assert last == f"written to {out}/: {files_line(out, everything)}"
    for name in ("calibration.json", "camera_array.toml", "cascalib_time.json", "report.html"):
        assert name in last
    assert load_calibration(out / "camera_array.toml").names == [t.camera for t in scene.tracks]
