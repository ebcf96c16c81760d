"""3D poses from an existing calibration: the API and ``cascalib triangulate``."""

from __future__ import annotations

import json
from dataclasses import replace

import numpy as np
import pytest

from cascalib.cli import main
from cascalib.errors import InputError
from cascalib.formats import save_calibration, write_tracks
from cascalib.metrics import match_persons
from cascalib.poses import load_poses
from cascalib.skeletons import CANONICAL_INDEX
from cascalib.stages.reconstruct import triangulate_poses
from cascalib.stages.refine_config import DEFAULT_JOINTS
from cascalib.stages.resync import resynchronize

BODY = [CANONICAL_INDEX[n] for n in DEFAULT_JOINTS]


@pytest.fixture(scope="module")
def scene():
    from cascalib.simulate import simulate

    return simulate("terrace", seed=2, duration_s=15.0, **{"people.n_persons": 3})


def joint_errors(poses, scene, reference: str | None = None) -> tuple[np.ndarray, int]:
    """Distance (m) of every reconstructed body joint to the nearest true person's same joint,
    and the number of reconstructed person-frames (poses on the frames of ``reference``,
    default the true rig's reference camera)."""
    truth = scene.joints3d(reference or scene.truth.reference_camera)  # (F, P, 26, 3)
    frames = poses.reference_frames.astype(int)
    errors, _, present = match_persons(poses.joints, truth[frames], BODY)
    return errors[present], int(present.sum())


def test_true_calibration_reconstructs_the_people(scene):
    poses = triangulate_poses(scene.tracks, scene.truth)
    err, n = joint_errors(poses, scene)
    # detector noise of a few pixels at 5-15 m: centimetres; a wrong clock or camera is decimetres
    assert n > 0.5 * poses.joints.shape[0] * 3
    assert np.nanmedian(err) < 0.04, np.nanmedian(err)  # measured 0.026
    assert np.nanpercentile(err, 90) < 0.10  # measured 0.049
    assert np.nanmedian(poses.residuals) < 3.0
    feet = poses.joints[..., CANONICAL_INDEX["left_ankle"], 2]
    assert abs(np.nanmedian(feet) - 0.07) < 0.05  # ankles just above the ground z = 0


def test_wrong_clocks_are_visible_in_the_poses(scene):
    """The calibration's time offsets are used: shifting them by 5 frames makes poses worse."""
    shifted = replace(scene.truth, cameras=[
        c if c.name == scene.truth.reference_camera else c.with_(time_offset=c.time_offset + 5)
        for c in scene.truth])
    good, _ = joint_errors(triangulate_poses(scene.tracks, scene.truth), scene)
    bad, _ = joint_errors(triangulate_poses(scene.tracks, shifted), scene)
    assert np.nanmedian(bad) > 2 * np.nanmedian(good)


def test_cli_writes_pose_files(scene, tmp_path, capsys):
    calib = tmp_path / "rig.json"
    save_calibration(scene.truth, calib, "json")
    # no image size in COCO results: taken from the calibration
    inputs = [str(write_tracks(t.with_(image_size=None), tmp_path / f"{t.camera}.json",
                               format="coco")) for t in scene.tracks]
    code = main(["triangulate", "--calibration", str(calib), *inputs, "-o",
                 str(tmp_path / "poses"), "--fps", "25", "--formats", "npz,trc", "--json"])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert out["frames_with_persons"] > 0.5 * out["frames"]
    assert out["median_reprojection_px"] < 3.0
    back = load_poses(tmp_path / "poses" / "poses.npz")
    err, _ = joint_errors(back, scene)
    assert np.nanmedian(err) < 0.05
    assert list((tmp_path / "poses").glob("poses_person*.trc"))


def test_part_of_the_rig_without_the_reference_camera(scene, tmp_path, capsys):
    """A recording by two of the four cameras, the reference camera not among them: the clocks
    are re-based on the first camera present and the poses are as good."""
    calib = tmp_path / "rig.json"
    save_calibration(scene.truth, calib, "json")
    two = [t for t in scene.tracks if t.camera != scene.truth.reference_camera][:2]
    inputs = [str(write_tracks(t, tmp_path / f"{t.camera}.json", format="native")) for t in two]
    code = main(["triangulate", "--calibration", str(calib), *inputs, "-o",
                 str(tmp_path / "poses"), "--formats", "npz", "--json"])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert list(out["time_offsets"]) == [t.camera for t in two]
    assert out["time_offsets"][two[0].camera] == 0.0
    poses = load_poses(tmp_path / "poses" / "poses.npz")
    err, n = joint_errors(poses, scene, reference=two[0].camera)  # on the new reference's frames
    assert n > 100 and np.nanmedian(err) < 0.05


def test_unknown_camera_is_named(scene):
    extra = [*scene.tracks[:2], scene.tracks[2].with_(camera="cam9")]
    with pytest.raises(InputError, match="cam9"):
        triangulate_poses(extra, scene.truth)


def test_cameras_must_match_by_name(scene):
    renamed = [t.with_(camera=f"other{i}") for i, t in enumerate(scene.tracks)]
    with pytest.raises(InputError, match="camera names must match"):
        triangulate_poses(renamed, scene.truth)


def test_resync_recovers_the_clocks_of_a_new_recording(scene, tmp_path, capsys):
    """A rig calibrated in another session (its clocks zeroed here) and this recording: the
    geometry is kept, the offsets and rates are found again to a fraction of a frame."""
    stale = replace(scene.truth, cameras=[c.with_(time_offset=0.0, time_rate=1.0)
                                          for c in scene.truth])
    synced = resynchronize(scene.tracks, stale)
    dt = [abs(e.time_offset - t.time_offset) for e, t in zip(synced, scene.truth, strict=True)]
    # measured 0.067 / 0.074 / 0.084 frames on this 15 s, 3-person scene (0.26 / 0.002 / 0.03
    # before the clock search spread its times over frame fractions; over 7 such scenes the
    # worst error fell on 5); stale clocks: 1.7-13
    assert max(dt) < 0.3 and np.median(dt) < 0.15, dt
    for est, true in zip(synced, scene.truth, strict=True):
        assert abs(est.time_rate - true.time_rate) < 1e-3
        np.testing.assert_array_equal(est.R, true.R)  # geometry kept exactly
        np.testing.assert_array_equal(est.K, true.K)
    calib = tmp_path / "stale.json"
    save_calibration(stale, calib, "json")
    inputs = [str(write_tracks(t, tmp_path / f"{t.camera}.json", format="native"))
              for t in scene.tracks]
    code = main(["triangulate", "--calibration", str(calib), *inputs, "-o",
                 str(tmp_path / "poses"), "--resync", "--formats", "npz", "--json"])
    assert code == 0
    out = json.loads(capsys.readouterr().out)
    assert (tmp_path / "poses" / "calibration_resync.json").exists()
    err, _ = joint_errors(load_poses(tmp_path / "poses" / "poses.npz"), scene)
    assert np.nanmedian(err) < 0.04
    assert set(out["time_offsets"]) == set(scene.truth.names)
