"""Simulated scenes: exact projections, determinism, clocks, detector effects, presets, output."""

from __future__ import annotations

import numpy as np
import pytest

from cascalib.errors import InputError
from cascalib.simulate import PRESETS, DetectorConfig, SceneConfig, simulate
from cascalib.simulate.detector import JOINT_SIGMA, detect
from cascalib.skeletons import CANONICAL_INDEX, LEFT_RIGHT_PAIRS

J = CANONICAL_INDEX


@pytest.fixture(scope="module")
def clean():
    return simulate("clean", seed=1, duration_s=12)


def _projected(scene, name):
    return scene.truth[name].project(scene.joints3d(name))


def test_clean_detections_are_the_projected_truth(clean):
    for tr in clean.tracks:
        uv = _projected(clean, tr.camera)
        kp = tr.keypoints
        seen = np.isfinite(kp[..., 0])
        assert seen.mean() > 0.3
        np.testing.assert_array_equal(kp[..., :2][seen], uv[seen])
        assert np.all(kp[..., 2][seen] == 1.0)
        np.testing.assert_array_equal(clean.slot_to_person(tr.camera)[:, :4],
                                      np.where(seen.any(-1), np.arange(4), -2))
        # What was dropped lies outside the image (truncation), nothing else.
        w, h = tr.image_size
        u, v = uv[..., 0][~seen], uv[..., 1][~seen]
        outside = ~((u >= 0) & (u <= w - 1) & (v >= 0) & (v <= h - 1))
        assert outside.all()


def test_written_detections_reproduce_the_truth(clean, tmp_path):
    from cascalib.formats import load_calibration, read_tracks

    clean.save(tmp_path, "native-json")
    calib = load_calibration(tmp_path / "calibration.json")
    truth = np.load(tmp_path / "truth.npz")
    np.testing.assert_allclose(truth["heights"], clean.heights)
    for tr in clean.tracks:
        back = read_tracks(tmp_path / "tracks" / f"{tr.camera}.json")
        cam = calib[tr.camera]
        uv = cam.project(truth[f"{tr.camera}/joints3d"])
        seen = np.isfinite(back.keypoints[..., 0])
        assert seen.sum() == np.isfinite(tr.keypoints[..., 0]).sum()
        np.testing.assert_allclose(back.keypoints[..., :2][seen], uv[seen], atol=1e-6)
        assert cam.time_offset == pytest.approx(clean.truth[tr.camera].time_offset)
        assert back.fps == pytest.approx(tr.fps)


def test_same_seed_same_scene_other_seed_other_scene():
    a = simulate("lab_ring", seed=7, duration_s=6)
    b = simulate("lab_ring", seed=7, duration_s=6)
    c = simulate("lab_ring", seed=8, duration_s=6)
    for ta, tb in zip(a.tracks, b.tracks, strict=True):
        np.testing.assert_array_equal(ta.keypoints, tb.keypoints)
    np.testing.assert_array_equal(a.truth["cam1"].R, b.truth["cam1"].R)
    assert not np.allclose(a.truth["cam1"].R, c.truth["cam1"].R)
    # The detector stream is separate: changing the detector keeps people and cameras.
    d = simulate("lab_ring", seed=7, duration_s=6, detector=DetectorConfig.clean())
    np.testing.assert_array_equal(a.heights, d.heights)
    np.testing.assert_array_equal(a.joints3d("cam2"), d.joints3d("cam2"))


def test_time_offsets_match_the_frame_times():
    scene = simulate("phones", seed=2, duration_s=30)
    ref = scene.truth.cameras[0]
    t_ref = scene.frame_times(ref.name)
    assert ref.time_offset == 0.0 and ref.time_rate == 1.0
    rates = set()
    for cam, tr in zip(scene.truth, scene.tracks, strict=True):
        k = np.arange(tr.n_frames)
        t = scene.frame_times(cam.name)
        # TIME CONVENTION: frame k shows reference frame time_rate * k + time_offset
        np.testing.assert_allclose(t, t_ref[0] + cam.reference_frame(k) / ref.fps, atol=1e-9)
        np.testing.assert_allclose(scene.reference_times(cam.reference_frame(k)), t, atol=1e-9)
        np.testing.assert_allclose(tr.frame_times(), k / cam.fps)
        assert cam.fps == tr.fps
        rates.add(round(cam.time_rate, 2))
        # The 3D joints of this camera are the scene at those times.
        np.testing.assert_array_equal(scene.joints3d(cam.name)[::50], scene.joints_at(t[::50]))
    assert len(rates) > 1  # mixed frame rates


def _single_camera_joints(seed=0):
    scene = simulate("clean", seed=seed, duration_s=10)
    cam = scene.truth.cameras[0]
    return scene, cam, scene.joints3d(cam.name)


def test_noise_grows_with_person_size():
    scene, cam, x = _single_camera_joints()
    cfg = DetectorConfig(noise_px=0.0, noise_rel=0.01, confidence=True)
    det = detect(cam, x, scene.heights, cfg, np.random.default_rng(0))
    uv = cam.project(x)
    err = det.keypoints[..., :2] - uv
    seen = np.isfinite(err[..., 0])
    depth = cam.world_to_cam(x)[..., J["mid_hip"], 2]
    ph = cam.focal * scene.heights / depth
    z = err / (0.01 * ph[..., None, None] * JOINT_SIGMA[:, None])
    assert np.std(z[seen]) == pytest.approx(1.0, rel=0.05)
    # confidence falls with the error
    e = np.linalg.norm(err, axis=-1)[seen] / np.broadcast_to(ph[..., None], seen.shape)[seen]
    c = det.keypoints[..., 2][seen]
    assert np.corrcoef(e, c)[0, 1] < -0.3


def test_detector_effects():
    scene, cam, x = _single_camera_joints(1)
    uv = cam.project(x)
    rng = np.random.default_rng(0)
    base = detect(cam, x, scene.heights, DetectorConfig.clean(), rng)
    n_base = np.isfinite(base.keypoints[..., 0]).sum()
    miss = detect(cam, x, scene.heights, DetectorConfig.clean().model_copy(
        update={"miss_rate": 0.2}), rng)
    assert np.isfinite(miss.keypoints[..., 0]).sum() / n_base == pytest.approx(0.8, abs=0.03)
    swap = detect(cam, x, scene.heights, DetectorConfig.clean().model_copy(
        update={"swap_rate": 1.0}), rng)
    la, ra = LEFT_RIGHT_PAIRS[0]
    seen = np.isfinite(swap.keypoints[..., la, 0])
    np.testing.assert_array_equal(swap.keypoints[..., la, :2][seen], uv[..., ra, :][seen])
    fp = detect(cam, x, scene.heights, DetectorConfig.clean().model_copy(
        update={"false_positive_rate": 0.5}), rng)
    s2p = fp.slot_to_person
    n_fp = (s2p == -1).sum()
    assert n_fp == pytest.approx(0.5 * x.shape[0], rel=0.3)
    assert np.isfinite(fp.keypoints[s2p == -1][..., 0]).any(-1).all()


def test_occlusion_hides_the_farther_person():
    scene = simulate("crowd", seed=0, duration_s=8)
    cam = scene.truth.cameras[0]
    x = scene.joints3d(cam.name)
    cfg = DetectorConfig.clean().model_copy(update={"occlusion": 1.0})
    det = detect(cam, x, scene.heights, cfg, np.random.default_rng(0))
    base = detect(cam, x, scene.heights, DetectorConfig.clean(), np.random.default_rng(0))
    lost = np.isfinite(base.keypoints[..., 0]) & ~np.isfinite(det.keypoints[..., 0])
    assert lost.any()
    depth = cam.world_to_cam(x)[..., J["mid_hip"], 2]
    f, p, _ = np.nonzero(lost)
    nearest = depth.min(axis=1)
    assert np.all(depth[f, p] > nearest[f])  # the nearest person is never occluded


def test_track_ids_and_slot_shuffling():
    scene, cam, x = _single_camera_joints(2)
    cfg = DetectorConfig.clean().model_copy(update={"track_ids": "global",
                                                     "shuffle_slots": True})
    det = detect(cam, x, scene.heights, cfg, np.random.default_rng(0))
    s2p, ids = det.slot_to_person, det.track_ids
    np.testing.assert_array_equal(ids[s2p >= 0], s2p[s2p >= 0])
    uv = cam.project(x)
    f, s = np.nonzero(s2p >= 0)
    kp = det.keypoints[f, s]
    seen = np.isfinite(kp[..., 0])
    np.testing.assert_array_equal(kp[..., :2][seen], uv[f, s2p[f, s]][seen])
    assert np.any(s2p[:, 0] != 0)  # really shuffled
    per = detect(cam, x, scene.heights, cfg.model_copy(update={"track_ids": "per_camera"}),
                 np.random.default_rng(0))
    # one id per person, the same in every frame
    for p in range(x.shape[1]):
        assert len(np.unique(per.track_ids[per.slot_to_person == p])) <= 1


def test_id_switches_when_people_cross():
    scene = simulate("crowd", seed=1, duration_s=20)
    cam = scene.truth.cameras[1]
    cfg = DetectorConfig.clean().model_copy(update={"track_ids": "global", "id_switch": 1.0})
    det = detect(cam, scene.joints3d(cam.name), scene.heights, cfg, np.random.default_rng(0))
    ok = det.slot_to_person >= 0
    wrong = det.track_ids[ok] != det.slot_to_person[ok]
    assert 0 < wrong.mean() < 1


def test_output_skeleton_and_config_overrides():
    scene = simulate("clean", seed=0, duration_s=5, skeleton="coco17",
                     **{"people.n_persons": 2, "rig.n_cameras": 2})
    assert len(scene.tracks) == 2 and scene.heights.shape == (2,)
    tr = scene.tracks[0]
    assert tr.skeleton.name == "coco17" and tr.n_joints == 17
    uv = _projected(scene, tr.camera)[..., :17, :]
    seen = np.isfinite(tr.keypoints[..., 0])
    np.testing.assert_array_equal(tr.keypoints[..., :2][seen], uv[seen])


def test_unknown_preset_is_a_clear_error():
    with pytest.raises(InputError, match="unknown simulation preset 'nope'; presets: "):
        simulate("nope")


@pytest.mark.parametrize("name", sorted(PRESETS))
def test_every_preset_runs(name):
    cfg = PRESETS[name]
    assert cfg.description
    scene = simulate(name, seed=0, duration_s=6)
    assert [t.camera for t in scene.tracks] == scene.truth.names
    for tr in scene.tracks:
        assert tr.n_detections > 0
        assert tr.image_size == scene.truth[tr.camera].image_size
        f = scene.joints3d(tr.camera)
        assert f.shape == (tr.n_frames, cfg.people.n_persons, 26, 3)
        assert scene.slot_to_person(tr.camera).shape == tr.keypoints.shape[:2]


def test_phones_have_portrait_landscape_and_distortion():
    scenes = [simulate("phones", seed=s, duration_s=4) for s in range(4)]
    cams = [c for sc in scenes for c in sc.truth]
    assert any(c.image_size[0] < c.image_size[1] for c in cams)
    assert any(c.image_size[0] > c.image_size[1] for c in cams)
    assert all(c.has_distortion for c in cams)


def test_scene_config_rejects_unknown_fields():
    with pytest.raises(ValueError):
        SceneConfig(people={"n_persons": 3, "legs": 3})


def test_plane_camera_is_the_camera_in_its_own_ground_frame(clean):
    for name in clean.camera_names:
        pc, R, t = clean.plane_camera(name)
        cam = clean.truth[name]
        np.testing.assert_allclose(pc.center[:2], 0.0, atol=1e-9)
        assert pc.center[2] == pytest.approx(cam.center[2])
        axis = pc.R[2]
        assert abs(axis[1]) < 1e-9 and axis[0] > 0  # optical axis projects onto +x
        x = clean.joints3d(name)[::40]
        np.testing.assert_allclose(pc.project((x - t) @ R), cam.project(x), atol=1e-6)


def test_correlated_noise_keeps_its_spread():
    scene, cam, x = _single_camera_joints(3)
    cfg = DetectorConfig(noise_px=2.0, noise_rel=0.0, noise_corr=0.8, confidence=False)
    det = detect(cam, x, scene.heights, cfg, np.random.default_rng(0))
    err = (det.keypoints[..., :2] - cam.project(x)) / (2.0 * JOINT_SIGMA[:, None])
    both = np.isfinite(err[1:, ..., 0]) & np.isfinite(err[:-1, ..., 0])
    a, b = err[1:][both], err[:-1][both]
    assert np.std(a) == pytest.approx(1.0, rel=0.1)
    assert np.corrcoef(a[:, 0], b[:, 0])[0, 1] == pytest.approx(0.8, abs=0.05)


def test_strong_distortion_never_folds_points_into_the_image():
    scene = simulate("security", seed=0, duration_s=8, detector=DetectorConfig.clean(),
                     **{"rig.radial_distortion": 0.3, "rig.fov_range_deg": (90, 100)})
    for tr in scene.tracks:
        cam = scene.truth[tr.camera]
        assert cam.dist[0] < -0.05
        xc = cam.world_to_cam(scene.joints3d(tr.camera))
        seen = np.isfinite(tr.keypoints[..., 0])
        ideal = xc[..., :2][seen] / xc[..., 2:][seen]
        np.testing.assert_allclose(cam.undistort(tr.keypoints[..., :2][seen]), ideal, atol=1e-9)


def test_camera_names():
    scene = simulate("clean", seed=0, duration_s=4,
                     **{"rig.n_cameras": 2, "camera_names": ["left", "right"]})
    assert scene.truth.names == ["left", "right"] == [t.camera for t in scene.tracks]
    with pytest.raises(ValueError, match="camera_names must be 2 unique names"):
        SceneConfig(rig={"n_cameras": 2}, camera_names=["a", "a"])
