"""Stage I (single-view focal length and ground plane) on seeded synthetic scenes.

The scenes are built here (not with cascalib.simulate) so that the model is exact: rigid people
standing straight, body points at the Drillis-Contini heights the stage assumes, so that zero
noise must give the truth to rounding error.
"""

from __future__ import annotations

import doctest

import numpy as np
import pytest

from cascalib.camera import Camera, look_at
from cascalib.errors import EstimationFailed
from cascalib.skeletons import CANONICAL_INDEX as CI
from cascalib.stages import single_view_solver
from cascalib.stages.single_view import SingleViewConfig, calibrate_single_view
from cascalib.stages.upright import bend_angle, upright_mask
from cascalib.tracks import Tracks

SIZE = (1280, 720)


def _standing(ground: np.ndarray, h: float, yaw: float, width: float = 1.0) -> np.ndarray:
    """Canonical 3D joints (26, 3) of a person standing straight at ``ground`` (x, y).

    ``width`` scales the left-right spread; 0 puts left and right joints on the body axis (the
    image midpoint of two joints is not the image of their 3D midpoint, an effect of ~0.01 px
    that would spoil exact-recovery tests).
    """
    fwd = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    left = width * np.array([-np.sin(yaw), np.cos(yaw), 0.0])
    up = np.array([0.0, 0.0, 1.0])
    g = np.array([ground[0], ground[1], 0.0])
    J = np.full((26, 3), np.nan)
    for side, s in (("left", 1.0), ("right", -1.0)):
        J[CI[f"{side}_ankle"]] = g + 0.039 * h * up + s * 0.05 * h * left
        J[CI[f"{side}_knee"]] = g + 0.285 * h * up + s * 0.05 * h * left
        J[CI[f"{side}_hip"]] = g + 0.530 * h * up + s * 0.06 * h * left
        J[CI[f"{side}_shoulder"]] = g + 0.818 * h * up + s * 0.11 * h * left
        J[CI[f"{side}_elbow"]] = g + 0.63 * h * up + s * 0.13 * h * left
        J[CI[f"{side}_wrist"]] = g + 0.485 * h * up + s * 0.13 * h * left
        J[CI[f"{side}_eye"]] = g + 0.936 * h * up + s * 0.02 * h * left + 0.05 * h * fwd
        J[CI[f"{side}_ear"]] = g + 0.92 * h * up + s * 0.05 * h * left
        J[CI[f"{side}_heel"]] = g + 0.01 * h * up + s * 0.05 * h * left - 0.03 * h * fwd
        J[CI[f"{side}_big_toe"]] = g + 0.01 * h * up + s * 0.05 * h * left + 0.1 * h * fwd
        J[CI[f"{side}_small_toe"]] = g + 0.01 * h * up + s * 0.07 * h * left + 0.09 * h * fwd
    J[CI["nose"]] = g + 0.92 * h * up + 0.06 * h * fwd
    J[CI["neck"]] = g + 0.818 * h * up
    J[CI["head_top"]] = g + 1.0 * h * up
    J[CI["mid_hip"]] = g + 0.530 * h * up
    return J


def _sitting(ground: np.ndarray, h: float, yaw: float) -> np.ndarray:
    """A person sitting on a chair: thighs horizontal, shanks vertical, trunk upright."""
    J = _standing(ground, h, yaw)
    fwd = np.array([np.cos(yaw), np.sin(yaw), 0.0])
    drop = (0.530 - 0.285) * h
    for name in ("hip", "shoulder", "elbow", "wrist", "eye", "ear"):
        for side in ("left", "right"):
            J[CI[f"{side}_{name}"], 2] -= drop
    for name in ("nose", "neck", "head_top", "mid_hip"):
        J[CI[name], 2] -= drop
    for side in ("left", "right"):  # knees forward at hip height, feet below the knees
        J[CI[f"{side}_knee"]] = J[CI[f"{side}_hip"]] + 0.245 * h * fwd
        J[CI[f"{side}_ankle"]] = J[CI[f"{side}_knee"]] - np.array([0, 0, 0.245 * h])
    return J


def make_scene(*, n_persons: int = 6, n_frames: int = 40, noise: float = 0.0,
               f: float = 900.0, eye=(0.0, -9.0, 4.0), target=(0.0, 5.0, 0.0),
               c: tuple[float, float] | None = None, area: float = 7.0,
               heights: np.ndarray | None = None, seed: int = 0,
               track_ids: bool = False, width: float = 1.0) -> tuple[Tracks, Camera, np.ndarray]:
    """People standing at random places (a new place every frame) seen by one camera."""
    rng = np.random.default_rng(seed)
    R, t = look_at(eye, target)
    cam = Camera.from_params("cam", SIZE, f, R, t, c=c)
    hts = 1.70 + 0.0 * np.arange(n_persons) if heights is None else heights
    J = np.empty((n_frames, n_persons, 26, 3))
    for k in range(n_frames):
        for p in range(n_persons):
            g = np.array(target[:2]) + rng.uniform(-area, area, 2)
            J[k, p] = _standing(g, hts[p], rng.uniform(0, 2 * np.pi), width)
    uv = cam.project(J) + noise * rng.standard_normal(J.shape[:-1] + (2,))
    kp = np.concatenate([uv, np.ones(uv.shape[:-1] + (1,))], -1)
    inside = (uv[..., 0] >= 0) & (uv[..., 0] < SIZE[0]) & (uv[..., 1] >= 0) & (uv[..., 1] < SIZE[1])
    kp[~inside] = np.nan
    ids = np.tile(np.arange(n_persons), (n_frames, 1)) if track_ids else None
    return Tracks("cam", kp, "halpe26", image_size=SIZE, track_ids=ids), cam, hts


def normal_error_deg(result, cam: Camera) -> float:
    return float(np.degrees(np.arccos(np.clip(result.normal_cam @ cam.R[:, 2], -1, 1))))


def test_exact_recovery_at_zero_noise():
    tracks, cam, _ = make_scene(width=0.0)
    res = calibrate_single_view(tracks, SingleViewConfig(principal_point="center"), rng=0)
    assert res.focal == pytest.approx(cam.focal, rel=1e-6)
    assert normal_error_deg(res, cam) < 1e-5
    assert res.camera_height == pytest.approx(cam.center[2], rel=1e-6)
    assert res.n_inliers == len(res.inliers) > 100
    lo, hi = res.focal_interval
    assert lo <= res.focal <= hi and hi - lo < 1e-3 * res.focal


@pytest.mark.parametrize("noise, f_tol, n_tol_deg", [(0.5, 0.02, 0.5), (1.0, 0.04, 1.0)])
def test_noise_tolerance(noise, f_tol, n_tol_deg):
    errors = []
    for seed in range(3):
        tracks, cam, _ = make_scene(noise=noise, seed=seed)
        res = calibrate_single_view(tracks, SingleViewConfig(principal_point="center"), rng=seed)
        errors.append(abs(res.focal / cam.focal - 1))
        assert normal_error_deg(res, cam) < n_tol_deg
        assert abs(res.camera_height / cam.center[2] - 1) < 2 * f_tol
        lo, hi = res.focal_interval  # the interval is honest: it covers the truth (loosely)
        assert lo * (1 - f_tol) < cam.focal < hi * (1 + f_tol)
    assert max(errors) < f_tol


def test_robust_to_outlier_detections():
    tracks, cam, _ = make_scene(noise=0.5, seed=3)
    kp = tracks.keypoints.copy()
    rng = np.random.default_rng(1)
    bad = rng.random(kp.shape[:2]) < 0.3  # 30 % of persons: the shoulders pushed sideways
    for j in ("left_shoulder", "right_shoulder", "neck", "head_top"):
        kp[bad, CI[j], 0] += rng.choice([-1, 1], bad.sum()) * rng.uniform(15, 40, bad.sum())
    res = calibrate_single_view(tracks.with_(keypoints=kp),
                                SingleViewConfig(principal_point="center"), rng=0)
    assert abs(res.focal / cam.focal - 1) < 0.03
    outlier_slots = bad[res.frames, res.persons]
    assert (~res.inliers[outlier_slots]).mean() > 0.8
    assert res.inliers[~outlier_slots].mean() > 0.9


def test_upright_filter_standing_vs_sitting():
    R, t = look_at((0.0, -6.0, 1.5), (0.0, 0.0, 0.8))
    cam = Camera.from_params("cam", SIZE, 900.0, R, t)
    poses = [_standing(np.zeros(2), 1.7, yaw) for yaw in (0.0, 1.0, 2.0)]
    poses += [_sitting(np.zeros(2), 1.7, yaw) for yaw in (0.3, 1.2, -np.pi / 2)]
    uv = cam.project(np.array(poses))
    kp = np.concatenate([uv, np.ones(uv.shape[:-1] + (1,))], -1)[None]
    bend = bend_angle(kp[0])
    assert np.all(bend[:3] < 5.0)
    assert np.all(bend[3:5] > 40.0)
    ok = upright_mask(kp, SIZE, max_bend_deg=25, min_confidence=0.3, border_px=3,
                      leg_torso_ratio=(1.2, 2.8), min_pixel_height=30)[0]
    # the last sitting person faces the camera: straight in the image, caught by proportions
    assert ok.tolist() == [True, True, True, False, False, False]
    low = kp.copy()
    low[0, 0, CI["left_knee"], 2] = 0.1  # a low-confidence joint rejects the person
    truncated = kp.copy()
    truncated[0, 1, :, 1] += SIZE[1] - truncated[0, 1, CI["left_ankle"], 1] - 1.0
    for arr in (low, truncated):
        ok = upright_mask(arr, SIZE, max_bend_deg=25, min_confidence=0.3, border_px=3,
                          leg_torso_ratio=(1.2, 2.8), min_pixel_height=30)[0]
        assert not ok[:2].all()


def test_everyone_in_one_spot_is_refused():
    tracks, _, _ = make_scene(noise=0.5, area=0.05)
    with pytest.raises(EstimationFailed, match="one spot") as info:
        calibrate_single_view(tracks, rng=0)
    assert info.value.camera == "cam"


def test_camera_looking_straight_down_is_refused():
    tracks, _, _ = make_scene(noise=0.5, f=800.0, eye=(0.0, 0.0, 6.0), target=(0.01, 0.0, 0.0),
                              area=2.5)
    cfg = SingleViewConfig(min_pixel_height=10.0, leg_torso_ratio=(0.5, 5.0), max_bend_deg=60)
    with pytest.raises(EstimationFailed, match="straight down") as info:
        calibrate_single_view(tracks, cfg, rng=0)
    partial = info.value.partial
    lo, hi = partial.focal_interval
    assert (hi - lo) / partial.focal > 0.5


def test_too_few_upright_people_is_refused():
    tracks, _, _ = make_scene(n_persons=1, n_frames=2)
    with pytest.raises(EstimationFailed, match="only 2 upright"):
        calibrate_single_view(tracks, rng=0)


def _walkers(*, lean: float, n_persons: int = 8, n_frames: int = 75, fps: float = 25.0,
             noise: float = 0.3, seed: int = 0) -> tuple[Tracks, Camera]:
    """People walking straight lines at 0.9-1.6 m/s whose body above the hips leans forward
    by ``atan(lean * speed)`` (``lean`` in s/m), seen by one camera at 25 fps."""
    rng = np.random.default_rng(seed)
    R, t = look_at((0.0, -9.0, 4.0), (0.0, 5.0, 0.0))
    cam = Camera.from_params("cam", SIZE, 900.0, R, t)
    J = np.empty((n_frames, n_persons, 26, 3))
    for p in range(n_persons):
        start = np.array([0.0, 5.0]) + rng.uniform(-6, 6, 2)
        yaw, speed = rng.uniform(0, 2 * np.pi), rng.uniform(0.9, 1.6)
        fwd = np.array([np.cos(yaw), np.sin(yaw), 0.0])
        for k in range(n_frames):
            pose = _standing(start + speed * k / fps * fwd[:2], 1.7, yaw)
            above = np.clip(pose[:, 2] - 0.530 * 1.7, 0.0, None)
            J[k, p] = pose + (lean * speed * above)[:, None] * fwd
    uv = cam.project(J) + noise * rng.standard_normal(J.shape[:-1] + (2,))
    kp = np.concatenate([uv, np.ones(uv.shape[:-1] + (1,))], -1)
    inside = (uv[..., 0] >= 0) & (uv[..., 0] < SIZE[0]) & (uv[..., 1] >= 0) & (uv[..., 1] < SIZE[1])
    kp[~inside] = np.nan
    return Tracks("cam", kp, "halpe26", image_size=SIZE, fps=fps), cam


def test_walkers_forward_lean_is_estimated():
    # a 3.4 deg lean at 1.3 m/s: the shoulders 2.2 cm and the head top 3.4 cm ahead of the
    # feet. Ignored, it tilts every body axis towards the walking direction and biases the
    # focal length; estimated from the ankles' motion (no track ids), it is recovered
    tracks, cam = _walkers(lean=0.046)
    upright = calibrate_single_view(tracks, SingleViewConfig(walking_lean_sd=0.0), rng=0)
    leaning = calibrate_single_view(tracks, rng=0)
    assert abs(upright.focal / cam.focal - 1) > 0.03
    assert abs(leaning.focal / cam.focal - 1) < 0.01
    assert leaning.diagnostics["walking_lean"] == pytest.approx(0.046, abs=0.01)
    assert normal_error_deg(leaning, cam) < 0.3
    # upright walkers: the lean stays near 0 and costs little
    still, cam = _walkers(lean=0.0, seed=1)
    res = calibrate_single_view(still, rng=0)
    assert abs(res.diagnostics["walking_lean"]) < 0.01
    assert abs(res.focal / cam.focal - 1) < 0.01


def test_principal_point_estimated_on_rich_scene():
    # the component of the principal point along the horizon is observable; the other trades
    # off against the focal length and stays at the image centre
    c = (SIZE[0] / 2 + 45.0, SIZE[1] / 2 - 0.5)
    tracks, cam, _ = make_scene(noise=0.3, c=c, n_persons=10, n_frames=60, area=9.0, f=700.0,
                                eye=(0.0, -7.0, 5.0), seed=5)
    fixed = calibrate_single_view(tracks, SingleViewConfig(principal_point="center"), rng=0)
    auto = calibrate_single_view(tracks, SingleViewConfig(principal_point="auto"), rng=0)
    assert auto.principal_point_estimated and not fixed.principal_point_estimated
    assert abs(auto.principal_point[0] - c[0]) < 10.0
    assert abs(auto.focal / cam.focal - 1) < 0.02
    assert normal_error_deg(auto, cam) < 0.5
    # a principal point off along the horizon acts like a pan: it barely moves the normal but
    # leaves residuals the fitted principal point removes
    assert auto.diagnostics["sigma_px"] < 0.8 * fixed.diagnostics["sigma_px"]


def test_track_heights_with_known_heights():
    heights = np.array([1.60, 1.66, 1.72, 1.78, 1.84, 1.63])
    tracks, cam, _ = make_scene(noise=0.3, heights=heights, track_ids=True, seed=7)
    given = calibrate_single_view(tracks, SingleViewConfig(principal_point="center"),
                                  height={i: float(h) for i, h in enumerate(heights)}, rng=0)
    assert given.focal == pytest.approx(cam.focal, rel=0.01)
    assert given.camera_height == pytest.approx(cam.center[2], rel=0.01)
    fitted = calibrate_single_view(tracks, SingleViewConfig(principal_point="center"), rng=0)
    assert fitted.focal == pytest.approx(cam.focal, rel=0.02)
    scale = fitted.diagnostics["height_scale"]
    have = [i for i in range(len(heights)) if i in scale]
    assert len(have) >= 5
    est = np.array([scale[i] for i in have])
    # relative heights are recovered up to the common scale the prior pins to 1.70 m
    assert np.corrcoef(est, heights[have])[0, 1] > 0.95


def test_plane_frame_camera():
    tracks, cam, _ = make_scene(noise=0.0, seed=2, width=0.0)
    res = calibrate_single_view(tracks, SingleViewConfig(principal_point="center"), rng=0)
    pc = res.to_camera()
    assert np.allclose(pc.center, [0.0, 0.0, res.camera_height], atol=1e-9)
    axis = pc.R.T @ np.array([0.0, 0.0, 1.0])  # optical axis in the plane frame
    assert abs(axis[1]) < 1e-9 and axis[0] > 0
    kp = tracks.canonical()[res.frames, res.persons]
    ankle_px = 0.5 * (kp[:, CI["left_ankle"], :2] + kp[:, CI["right_ankle"], :2])
    ankle_h = 0.039 * 1.70
    ground = pc.backproject_to_plane(ankle_px, z=ankle_h)
    foot = ground.copy()
    foot[:, 2] = 0.0  # the floor under the ankle projects below it (z = 0 is the ground)
    assert np.all(pc.project(foot)[:, 1] > ankle_px[:, 1])
    for joint, ratio in (("neck", 0.818), ("head_top", 1.0)):
        top = ground.copy()
        top[:, 2] = ratio * 1.70
        seen = np.isfinite(kp[:, CI[joint], 0])
        assert seen.mean() > 0.5
        assert np.allclose(pc.project(top)[seen], kp[seen, CI[joint], :2], atol=1e-4)


def test_solver_doctests():
    assert doctest.testmod(single_view_solver).failed == 0


def test_config_rejects_unknown_fields():
    with pytest.raises(ValueError, match="extra"):
        SingleViewConfig(focal_guess=3)


def test_plot_writes_png(tmp_path):
    import matplotlib.image as mpimg

    from cascalib.stages.single_view_plot import plot_single_view

    tracks, _, _ = make_scene(noise=0.5, n_frames=10)
    res = calibrate_single_view(tracks, rng=0)
    out = tmp_path / "single_view.png"
    fig = plot_single_view(res, path=out)
    img = mpimg.imread(out)
    assert img.shape[:2] == (450, 800)  # 8 x 4.5 in at 100 dpi for a 16:9 image
    # green inlier segments and blue grid lines are drawn
    assert len(fig.axes[0].collections) == 3
    assert img[..., 1].std() > 0.01
