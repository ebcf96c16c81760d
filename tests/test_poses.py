"""3D pose record and its writers."""

from __future__ import annotations

import json

import numpy as np
import pytest

from cascalib.poses import Poses3D, load_poses


def _poses():
    rng = np.random.default_rng(0)
    joints = rng.normal(size=(4, 2, 26, 3))
    joints[1, 1] = np.nan
    ids = np.array([[0, 1], [0, -1], [1, 0], [0, 1]])
    return Poses3D(joints, np.arange(4) * 2.0, 30.0, ids)


def test_npz_round_trip_is_lossless(tmp_path):
    p = _poses()
    p.save(tmp_path, formats=("npz",))
    q = load_poses(tmp_path / "poses.npz")
    np.testing.assert_array_equal(q.joints, p.joints)
    np.testing.assert_array_equal(q.person_ids, p.person_ids)
    assert q.fps == 30.0


def test_person_tracks_follow_ids_across_slots():
    p = _poses()
    tracks = p.person_tracks()
    np.testing.assert_array_equal(tracks[1][2], p.joints[2, 0])
    np.testing.assert_array_equal(tracks[1][0], p.joints[0, 1])
    assert np.isnan(tracks[1][1]).all()


def test_trc_is_y_up_with_one_row_per_sample(tmp_path):
    p = _poses()
    files = p.save(tmp_path, formats=("trc",))
    assert sorted(f.name for f in files) == ["poses_person0.trc", "poses_person1.trc"]
    lines = (tmp_path / "poses_person0.trc").read_text().splitlines()
    assert lines[2].split("\t")[2:5] == ["4", "26", "m"]
    first = lines[6].split("\t")
    x, y, z = (float(v) for v in first[2:5])
    wx, wy, wz = p.joints[0, 0, 0]
    assert (x, y, z) == pytest.approx((wx, wz, -wy), abs=1e-6)
    assert float(first[1]) == pytest.approx(0.0)
    assert float(lines[7].split("\t")[1]) == pytest.approx(2.0 / 30.0, abs=1e-6)


def test_json_has_null_for_missing(tmp_path):
    p = _poses()
    p.save(tmp_path, formats=("json",))
    data = json.loads((tmp_path / "poses.json").read_text())
    assert data["schema"] == "cascalib/poses@1" and len(data["frames"]) == 4
    assert len(data["frames"][1]["persons"]) == 1
