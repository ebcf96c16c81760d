"""``cascalib simulate`` end to end: files written, plot, presets list, bad input."""

from __future__ import annotations

import json

import numpy as np

from cascalib.cli import main


def test_simulate_writes_tracks_truth_and_plot(tmp_path, capsys):
    out = tmp_path / "scene"
    rc = main(["simulate", "--preset", "terrace", "--seed", "0", "-o", str(out), "--format",
               "native-npz", "--plot", "--duration", "6", "--persons", "2"])
    assert rc == 0
    report = json.loads(capsys.readouterr().out)
    assert [c["name"] for c in report["cameras"]] == ["cam0", "cam1", "cam2", "cam3"]
    assert sorted(p.name for p in (out / "tracks").iterdir()) == [
        "cam0.npz", "cam1.npz", "cam2.npz", "cam3.npz"]
    truth = np.load(out / "truth.npz")
    assert truth["heights"].shape == (2,)
    assert truth["cam1/joints3d"].shape[1:] == (2, 26, 3)
    png = (out / "scene.png").read_bytes()
    assert png[:8] == b"\x89PNG\r\n\x1a\n" and len(png) > 20_000
    assert json.loads((out / "scene.json").read_text())["seed"] == 0


def test_simulate_list_and_errors(tmp_path, capsys):
    assert main(["simulate", "--list"]) == 0
    listing = capsys.readouterr().out
    assert "periodic" in listing and "crowd" in listing
    assert main(["simulate", "--preset", "nope", "-o", str(tmp_path)]) == 2
    assert "unknown simulation preset 'nope'" in capsys.readouterr().err
    assert main(["simulate", "--preset", "terrace"]) == 2
    bad = tmp_path / "bad.json"
    bad.write_text('{"people": {"n_persons": 0}}')
    assert main(["simulate", "--config", str(bad), "-o", str(tmp_path / "x")]) == 2
    assert "invalid scene configuration" in capsys.readouterr().err
