"""3D pose record and its writers."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from test_linking import FPS, walkers

from cascalib.poses import Poses3D, load_poses
from cascalib.skeletons import CANONICAL_INDEX, CANONICAL_JOINTS

TRC_KEYS = ["DataRate", "CameraRate", "NumFrames", "NumMarkers", "Units", "OrigDataRate",
            "OrigDataStartFrame", "OrigNumFrames"]


def _poses(never_seen=("head_top",)):
    """Two persons for 4 s; person 1 leaves after 2 s; person 0's right heel missing at
    t = 1 s (the last marker column)."""
    joints, times = walkers([1.7, 1.8], [(0, 0), (0, 4)], [(1.0, 0), (1.0, 0)], seconds=4.0)
    ids = np.tile([0, 1], (len(times), 1))
    joints[times >= 2.0, 1] = np.nan
    ids[times >= 2.0, 1] = -1
    joints[:, :, [CANONICAL_INDEX[n] for n in never_seen]] = np.nan
    joints[int(FPS), 0, CANONICAL_INDEX["right_heel"]] = np.nan
    return Poses3D(joints, np.arange(len(times), dtype=float), FPS, ids)


def _opensim_tokens(line):
    """OpenSim 4.6 FileAdapter::tokenize on tabs: every tab ends a field, an empty last one is
    dropped."""
    fields = line.rstrip("\r\n").split("\t")
    return fields[:-1] if fields and fields[-1] == "" else fields


def read_trc_strictly(path: Path):
    """Read a TRC file by OpenSim's TRCFileAdapter rules; raise AssertionError where it would
    refuse. Returns (marker names, times, markers (N, M, 3) with NaN where empty)."""
    lines = path.read_text().split("\n")
    assert lines[0].split("\t")[0] == "PathFileType"
    assert [k for k in lines[1].split("\t") if k] == TRC_KEYS
    meta = dict(zip(TRC_KEYS, [v for v in lines[2].split("\t") if v], strict=True))
    n_markers, n_frames = int(meta["NumMarkers"]), int(meta["NumFrames"])
    labels = [v for v in lines[3].split("\t") if v]
    assert labels[:2] == ["Frame#", "Time"] and len(labels) == n_markers + 2
    xyz = [v for v in lines[4].split("\t") if v]
    assert xyz == [f"{a}{i}" for i in range(1, n_markers + 1) for a in "XYZ"]
    rows = lines[5:]
    while rows and rows[0].strip() == "":
        rows = rows[1:]
    data = rows[:rows.index("")] if "" in rows else rows
    times, markers = [], []
    for k, line in enumerate(data):
        tok = _opensim_tokens(line)
        assert len(tok) == 2 + 3 * n_markers, f"row {k}: {len(tok)} columns"
        times.append(float(tok[1]))
        markers.append([float(v) if v else np.nan for v in tok[2:]])
    assert len(data) == n_frames
    return labels[2:], np.array(times), np.array(markers).reshape(len(data), n_markers, 3)


def test_npz_round_trip_is_lossless(tmp_path):
    p = _poses()
    p.save(tmp_path, formats=("npz",))
    q = load_poses(tmp_path / "poses.npz")
    np.testing.assert_array_equal(q.joints, p.joints)
    np.testing.assert_array_equal(q.person_ids, p.person_ids)
    np.testing.assert_array_equal(q.linked_ids, p.linked_ids)
    assert q.fps == FPS


def test_trc_files_open_by_opensims_rules(tmp_path):
    p = _poses()
    files = p.save(tmp_path, formats=("trc",))
    assert sorted(f.name for f in files) == ["poses_person0.trc", "poses_person1.trc"]
    names, times, markers = read_trc_strictly(tmp_path / "poses_person0.trc")
    assert "head_top" not in names and len(names) == len(CANONICAL_JOINTS) - 1
    assert np.isnan(markers[int(FPS), names.index("right_heel")]).all()
    wx, wy, wz = p.joints[3, 0, 0]
    assert markers[3, 0] == pytest.approx((wx, wz, -wy), abs=1e-6)  # y-up: (x, z, -y)
    assert times[3] == pytest.approx(3 / FPS, abs=1e-6)


def test_a_persons_trc_holds_the_frames_it_is_seen(tmp_path):
    p = _poses()
    p.save(tmp_path, formats=("trc",))
    _, times, _ = read_trc_strictly(tmp_path / "poses_person1.trc")
    np.testing.assert_allclose(times, p.times[p.times < 2.0], atol=1e-6)


def test_trc_opens_in_opensim(tmp_path):
    opensim = pytest.importorskip("opensim")
    p = _poses()
    p.save(tmp_path, formats=("trc",))
    table = opensim.TimeSeriesTableVec3(str(tmp_path / "poses_person0.trc"))
    assert table.getNumRows() == len(p.times) and table.getNumColumns() == 25


def test_json_has_null_for_missing_and_both_ids(tmp_path):
    p = _poses()
    p.save(tmp_path, formats=("json",))
    data = json.loads((tmp_path / "poses.json").read_text())
    assert data["schema"] == "cascalib/poses@1" and len(data["frames"]) == len(p.times)
    late = data["frames"][-1]["persons"]
    assert len(late) == 1 and late[0]["id"] == 0 and late[0]["person"] == p.linked_ids[-1, 0]
    heel = data["frames"][int(FPS)]["persons"][0]["joints"][CANONICAL_INDEX["right_heel"]]
    assert heel == [None, None, None]
    np.testing.assert_allclose(np.array(data["frames"][3]["persons"][1]["joints"], float),
                               p.joints[3, 1], atol=1e-5)
