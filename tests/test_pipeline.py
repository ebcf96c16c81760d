"""End to end: the whole cascade on a simulated session, through the API and the command line."""

from __future__ import annotations

import json

import numpy as np
import pytest

import cascalib
from cascalib.cli import main
from cascalib.config import CalibrationConfig
from cascalib.errors import InputError
from cascalib.formats import load_calibration, write_tracks
from cascalib.metrics import compare_calibrations
from cascalib.simulate import simulate

SHORT = {"duration_s": 40.0, "people.n_persons": 4}


@pytest.fixture(scope="module")
def scene():
    return simulate("terrace", seed=3, **SHORT)


@pytest.fixture(scope="module")
def result(scene):
    stages = []
    res = cascalib.calibrate(scene.tracks, CalibrationConfig(seed=1),
                             progress=lambda s, f: stages.append((s, f)))
    res.progress_seen = stages  # type: ignore[attr-defined]
    return res


def test_cascade_recovers_the_rig(result, scene):
    err = compare_calibrations(result.calibration, scene.truth)
    s = err.summary
    # tolerances a broken stage cannot meet: stage I alone is off by ~5 % focal and ~2 deg
    assert s.focal_error_pct_median < 2.0 and s.focal_error_pct_max < 4.0, err.table()
    assert s.rotation_error_deg_median < 1.0 and s.rotation_error_deg_max < 2.0, err.table()
    assert s.center_error_similarity_max < 0.15, err.table()
    assert abs(s.scale_error_pct) < 6.0, err.table()
    assert s.time_offset_error_frames_max < 0.5, err.table()


def test_progress_reports_every_stage_in_order(result):
    stages = [s for s, _ in result.progress_seen]
    order = [s for i, s in enumerate(stages) if i == 0 or stages[i - 1] != s]
    assert order == ["single_view", "sync", "refine", "triangulate"]
    assert all(0.0 <= f <= 1.0 for _, f in result.progress_seen)
    for stage in order:  # within a stage the fraction never goes back, and it ends at 1
        seen = [f for s, f in result.progress_seen if s == stage]
        assert seen == sorted(seen) and seen[-1] == 1.0, (stage, seen)
    # the long stages report in between, not only their start and end
    for stage in ("sync", "refine"):
        inner = {f for s, f in result.progress_seen if s == stage and 0.0 < f < 1.0}
        assert len(inner) >= 3, (stage, inner)


def test_estimated_principal_points_carry_a_split_half_uncertainty(result):
    for cam in result.calibration:
        q = result.refinement.quality[cam.name]
        centre = (np.array(cam.image_size) - 1) / 2
        if result.refinement.distortion:  # a lens model: as uncertain as the prior
            assert q.sigma_principal_point_px >= 0.02 * cam.image_size[0] - 1e-9, q
        elif np.allclose(cam.principal_point, centre):  # the pass was not kept: assumed
            assert q.sigma_principal_point_px == pytest.approx(0.02 * cam.image_size[0]), q
        else:  # estimated: its split-half spread is part of the rotation uncertainty
            assert 0 < q.sigma_principal_point_px < 30, q
            pp_deg = np.degrees(np.arctan(q.sigma_principal_point_px / cam.focal))
            assert q.sigma_rotation_deg >= pp_deg - 1e-9, q


def test_time_offsets_carry_an_uncertainty_that_covers_their_error(result, scene):
    ref = result.calibration.reference_camera
    summary = {c["name"]: c for c in result.summary()["cameras"]}
    for cam in result.calibration:
        sd = result.refinement.quality[cam.name].sigma_time_offset_frames
        assert summary[cam.name]["time_offset_sd_frames"] == sd
        assert result.calibration.quality[cam.name]["sigma_time_offset_frames"] == sd
        if cam.name == ref:
            assert sd == 0.0
            continue
        # at least the calibrated floor, and far below a frame on this well-observed scene
        assert 0.025 <= sd < 0.3, sd
        error = abs(cam.time_offset - scene.truth[cam.name].time_offset)
        assert error < 3 * sd, (cam.name, error, sd)


def test_result_keeps_every_stage_and_poses(result, scene):
    assert set(result.single_view) == set(scene.truth.names)
    assert result.alignment.calibration.names == result.calibration.names
    joints = result.poses.joints
    assert joints.shape[2:] == (26, 3) and np.isfinite(joints).any()
    feet = joints[..., cascalib.skeletons.CANONICAL_INDEX["left_ankle"], 2]
    assert abs(np.nanmedian(feet)) < 0.15  # feet on the ground, z up


def test_save_writes_contract_files(result, tmp_path):
    written = result.save(tmp_path, formats=("json", "toml", "colmap"))
    data = json.loads((tmp_path / "calibration.json").read_text())
    assert data["schema"] == "cascalib/calibration@1" and data["world"] == "z-up, ground z=0"
    assert data["reference_camera"] == result.calibration.reference_camera
    cam = next(iter(data["cameras"].values()))
    assert set(cam) >= {"image_size", "K", "dist", "R", "t", "fps", "time_offset", "time_rate"}
    back = load_calibration(tmp_path / "calibration.toml")
    np.testing.assert_allclose(back.cameras[1].R, result.calibration.cameras[1].R, atol=1e-9)
    assert (tmp_path / "report.html").stat().st_size > 10_000
    page = (tmp_path / "report.html").read_text(encoding="utf-8")
    sd = result.refinement.quality["cam1"].sigma_time_offset_frames
    assert f"{result.calibration['cam1'].time_offset:.2f} &plusmn; {sd:.2f}" in page
    assert all(np.isfinite(data["quality"][n]["sigma_time_offset_frames"]) for n in data["cameras"])
    assert "report" in written and (tmp_path / "poses" / "poses.npz").exists()
    assert list((tmp_path / "poses").glob("*.trc"))


def test_cli_calibrate_json_summary(scene, tmp_path, capsys):
    inputs = []
    for t in scene.tracks:
        inputs.append(str(write_tracks(t.with_(image_size=None, fps=None),
                                       tmp_path / f"{t.camera}.json", format="mmpose")))
    sizes = [f"--image-size={t.camera}={t.image_size[0]}x{t.image_size[1]}" for t in scene.tracks]
    code = main(["calibrate", *inputs, "-o", str(tmp_path / "out"), "--fps", "25", *sizes,
                 "--json", "--no-report", "--seed", "1"])
    out = json.loads(capsys.readouterr().out)
    assert code in (0, 1)  # 1 only if the quality check rejected a camera
    assert out["ok"] == (code == 0)
    assert [c["name"] for c in out["cameras"]] == [t.camera for t in scene.tracks]
    assert (tmp_path / "out" / "calibration.json").exists()
    assert set(out["input_timings_s"]) == {"imports", "configuration", "reading", "checks"}


def test_cli_reports_missing_image_size_clearly(scene, tmp_path, capsys):
    paths = [str(write_tracks(t.with_(image_size=None), tmp_path / f"{t.camera}.json",
                              format="coco")) for t in scene.tracks[:2]]
    code = main(["calibrate", *paths, "-o", str(tmp_path / "out"), "--fps", "25"])
    assert code == 2
    err = capsys.readouterr().err
    assert "image size unknown" in err and "cam0" in err


def test_one_camera_is_rejected():
    t = simulate("clean", seed=0, duration_s=5.0).tracks[:1]
    with pytest.raises(InputError, match="at least two cameras"):
        cascalib.calibrate(t)


@pytest.mark.slow  # about 35 s on 2 cores
def test_wide_lenses_are_found_before_the_principal_points():
    """Security cameras (barrel distortion, k1 -0.06 .. -0.14), the whole cascade: stage V finds
    the lenses after its first rounds and holds them in the principal-point pass. Measured on
    this scene: relative rotations 0.50 deg median (stage IV left 1.20); with the lens pass only
    at the end, 2.64 deg, worse than stage IV."""
    scene = simulate("security", seed=0, duration_s=40.0)
    res = cascalib.calibrate(scene.tracks, CalibrationConfig(seed=0))
    assert res.refinement.distortion
    for est, true in zip(res.calibration, scene.truth, strict=True):
        assert abs(est.dist[0] - true.dist[0]) < 0.04, (est.name, est.dist, true.dist)
    summary = compare_calibrations(res.calibration, scene.truth).summary
    assert summary.pairwise_rotation_error_deg_median < 1.0, summary


def test_save_writes_a_trc_per_person_and_times_itself(result, tmp_path):
    written = result.save(tmp_path, report=False)
    trc = [p for k, p in written.items() if k.endswith(".trc")]
    n_persons = len(result.poses.persons())
    assert 1 <= len(trc) == n_persons <= 1.5 * SHORT["people.n_persons"]
    assert {"calibration", "poses"} <= set(result.save_timings)


def test_report_histograms_from_a_spread_of_person_frames(result):
    from cascalib.report import reprojection_errors

    every = reprojection_errors(result, max_groups=None)
    some = reprojection_errors(result, max_groups=200)
    for name, errors in some.items():
        assert errors.size == 200 * result.refinement.association.obs.shape[2]
        assert np.nanmedian(errors) == pytest.approx(np.nanmedian(every[name]), rel=0.15)

