"""Stage IV's rig refinement from the epipolar geometry of the people's joints: the
fundamental matrix of two cameras, the Sampson distance's derivatives, and the refinement of a
simulated rig with the errors stage IV leaves."""

from __future__ import annotations

import numpy as np
import pytest
from align_scene import stage1_like

from cascalib.calibration import Calibration
from cascalib.camera import Camera, look_at
from cascalib.geometry import rodrigues_to_matrix, rotation_angle_deg
from cascalib.metrics import compare_calibrations
from cascalib.simulate import simulate
from cascalib.stages.align import AlignConfig, align_cameras
from cascalib.stages.epipolar_rig import (
    _sampson_gradient,
    fundamental_of,
    refine_rig,
    signed_sampson,
)
from cascalib.stages.reconstruct import prepare


def _camera(name: str, eye: list[float], focal: float, pp: tuple[float, float]) -> Camera:
    R, t = look_at(eye, [0, 0, 1])
    K = np.array([[focal, 0, pp[0]], [0, focal, pp[1]], [0, 0, 1.0]])
    return Camera(name, (1280, 720), K, np.zeros(5), R, t)


def test_fundamental_matrix_relates_the_two_projections() -> None:
    rng = np.random.default_rng(0)
    X = rng.uniform([-2, -2, 0], [2, 2, 1.8], size=(50, 3))
    a = _camera("a", [8, 0, 3], 800, (630, 370))
    b = _camera("b", [0, 9, 2.5], 600, (650, 350))
    F = fundamental_of(a, b)
    ha, hb = np.c_[a.project(X), np.ones(50)], np.c_[b.project(X), np.ones(50)]
    np.testing.assert_allclose(signed_sampson(F, ha, hb), 0, atol=1e-9)
    # a point slid along its epipolar line still fits; moved across it, it does not
    line = F @ hb[0]
    along = np.r_[-line[1], line[0], 0] / np.linalg.norm(line[:2])
    across = np.r_[line[:2], 0] / np.linalg.norm(line[:2])
    assert abs(signed_sampson(F, (ha[0] + 40 * along)[None], hb[:1])[0]) < 1e-6
    assert abs(signed_sampson(F, (ha[0] + 5 * across)[None], hb[:1])[0]) > 2.0
    # camera b tilted down by 2 deg: its F no longer fits
    turned = b.with_(R=rodrigues_to_matrix([np.radians(2.0), 0, 0]) @ b.R)
    turned = turned.with_(t=-turned.R @ b.center)
    assert np.median(np.abs(signed_sampson(fundamental_of(a, turned), ha, hb))) > 5


def test_sampson_derivatives_match_differences() -> None:
    rng = np.random.default_rng(1)
    F = rng.normal(size=(3, 3))
    ha = np.c_[rng.uniform(0, 1280, (20, 2)), np.ones(20)]
    hb = np.c_[rng.uniform(0, 1280, (20, 2)), np.ones(20)]
    d, J, d_ha, d_hb = _sampson_gradient(F, ha, hb)
    np.testing.assert_allclose(d, signed_sampson(F, ha, hb))
    for q in range(9):
        h = 1e-6 * np.abs(F).max()
        Fh = F.copy()
        Fh.flat[q] += h
        numeric = (signed_sampson(Fh, ha, hb) - d) / h
        np.testing.assert_allclose(J[:, q], numeric, rtol=1e-4, atol=1e-6 * np.abs(J).max())
    # by the points (what the radial terms move)
    for k in range(2):
        step = np.zeros(3)
        step[k] = 1e-4
        np.testing.assert_allclose(d_ha[:, k], (signed_sampson(F, ha + step, hb) - d) / 1e-4,
                                   rtol=1e-4, atol=1e-6 * np.abs(d_ha).max())
        np.testing.assert_allclose(d_hb[:, k], (signed_sampson(F, ha, hb + step) - d) / 1e-4,
                                   rtol=1e-4, atol=1e-6 * np.abs(d_hb).max())
    assert not d_ha[:, 2].any() and not d_hb[:, 2].any()


@pytest.fixture(scope="module")
def terrace() -> tuple[list, Calibration]:
    sc = simulate("terrace", seed=0, duration_s=24.0)
    return sc.tracks, sc.truth


def _stage_iv_errors(truth: Calibration) -> Calibration:
    """The true rig with errors like stage IV's: principal points at the image centre, focal
    lengths 4-10 % off, cameras turned 1-3 deg (tilt about 1 deg) and moved 0.2-0.3 m; the
    reference camera is turned and its focal length is off too."""
    rng = np.random.default_rng(7)
    cams = []
    for k, cam in enumerate(truth.cameras):
        yaw = rodrigues_to_matrix([0, 0, np.radians(rng.uniform(1.0, 3.0) * rng.choice([-1, 1]))])
        axis = np.r_[rng.normal(size=2), 0.0]
        tilt = rodrigues_to_matrix(axis / np.linalg.norm(axis) * np.radians(1.0))
        R = cam.R @ (tilt @ yaw if k else tilt).T
        move = np.r_[rng.normal(size=2), 0.0]
        C = cam.center + (0.25 * move / np.linalg.norm(move) if k else 0.0)
        f = cam.focal * (1 + rng.uniform(0.04, 0.10) * rng.choice([-1, 1]))
        w, h = cam.image_size
        K = np.array([[f, 0, (w - 1) / 2], [0, f, (h - 1) / 2], [0, 0, 1.0]])
        cams.append(cam.with_(R=R, t=-R @ C, K=K, dist=np.zeros(5)))
    return Calibration(cams, reference_camera=truth.reference_camera, world=truth.world)


def _worst_relative_rotation(est: Calibration, truth: Calibration) -> float:
    n = len(truth.cameras)
    e, t = est.cameras, truth.cameras
    return max(rotation_angle_deg((e[j].R @ e[i].R.T) @ (t[j].R @ t[i].R.T).T)
               for i in range(n) for j in range(i + 1, n))


def _worst_focal(est: Calibration, truth: Calibration) -> float:
    return max(abs(e.focal / t.focal - 1) for e, t in zip(est, truth, strict=True))


def test_the_rig_is_refined_from_stage_iv_errors(terrace: tuple[list, Calibration]) -> None:
    tracks, truth = terrace
    start = _stage_iv_errors(truth)
    assert _worst_relative_rotation(start, truth) > 2.5 and _worst_focal(start, truth) > 0.06
    res = refine_rig(prepare(tracks, start), start, rng=0)
    assert res.kept, res.reason
    out = res.calibration
    # measured 1.8 deg, 1.6 % and 0.07 m; 4.7 deg, 9.5 % and 0.22 m before. The rotations
    # keep a part of the principal points' error (12 px at f = 387 px is 1.8 deg of pan)
    assert _worst_relative_rotation(out, truth) < 2.5
    assert _worst_focal(out, truth) < 0.025
    assert compare_calibrations(out, truth).summary.center_error_similarity_max < 0.1
    assert res.cost_after < 0.7 * res.cost_before
    assert min(res.n_points.values()) > 1000
    # the principal points move towards the truth (the simulator puts them off the centre)
    before = [np.linalg.norm(s.principal_point - t.principal_point) for s, t in
              zip(start, truth, strict=True)]
    after = [np.linalg.norm(o.principal_point - t.principal_point) for o, t in
             zip(out, truth, strict=True)]
    assert np.mean(after) < 0.7 * np.mean(before), (before, after)  # measured 0.49
    # the priors hold the frame: the reference camera's heading and ground position, the
    # cameras' heights and the rig's size
    ref = out[truth.reference_camera]
    np.testing.assert_allclose(ref.center[:2], start[truth.reference_camera].center[:2],
                               atol=0.01)
    spread = [np.linalg.norm(c.center - np.mean([d.center for d in cal], 0)) for cal in
              (start, out) for c in cal]
    assert np.mean(spread[len(out.cameras):]) == pytest.approx(
        np.mean(spread[:len(out.cameras)]), rel=0.02)
    for o, s in zip(out, start, strict=True):
        assert o.center[2] == pytest.approx(s.center[2], rel=0.1)
        assert o.time_offset == s.time_offset and o.time_rate == s.time_rate


def test_known_intrinsics_and_unplaced_cameras_are_held(terrace: tuple[list, Calibration]
                                                        ) -> None:
    tracks, truth = terrace
    start = _stage_iv_errors(truth)
    names = start.names
    res = refine_rig(prepare(tracks, start), start, fixed_intrinsics=[names[1]],
                     held=[names[3]], rng=0)
    assert res.kept, res.reason
    out = res.calibration
    np.testing.assert_array_equal(out[names[1]].K, start[names[1]].K)
    assert not np.allclose(out[names[1]].R, start[names[1]].R)
    held = out[names[3]]
    np.testing.assert_array_equal(held.K, start[names[3]].K)
    np.testing.assert_array_equal(held.R, start[names[3]].R)
    assert all(names[3] not in pair for pair in res.n_points)
    assert not np.allclose(out[names[2]].K, start[names[2]].K)


def test_an_implausible_refinement_is_not_kept(terrace: tuple[list, Calibration]) -> None:
    tracks, truth = terrace
    start = _stage_iv_errors(truth)
    res = refine_rig(prepare(tracks, start), start, max_rotation_deg=0.5, rng=0)
    assert not res.kept and "turned camera" in res.reason
    assert res.calibration is start
    # one camera left to refine: no pair
    res = refine_rig(prepare(tracks, start), start, held=start.names[1:], rng=0)
    assert not res.kept and "no camera pair" in res.reason


def test_stage_iv_ends_with_the_rig_refinement(terrace: tuple[list, Calibration]) -> None:
    """align_cameras from stage-I-like cameras (focal 3 %, tilt 1 deg, scale 5 %, principal
    points at the image centre): the refinement is its last step and improves the rig."""
    tracks, truth = terrace
    rng = np.random.default_rng(5)
    plane = [stage1_like(c, rng, errors=True).with_centred_principal_point()
             for c in truth.cameras]
    with_rig = align_cameras(tracks, plane, rng=0)
    without = align_cameras(tracks, plane, AlignConfig(epipolar_rig=False), rng=0)
    assert without.rig is None and with_rig.rig is not None and with_rig.rig.kept
    before = compare_calibrations(without.calibration, truth).summary
    after = compare_calibrations(with_rig.calibration, truth).summary
    # measured: centres 0.29 -> 0.08 m, focal 3.4 -> 1.5 %, rotation 2.0 -> 1.76 deg (the
    # 640 x 480 cameras' principal points, 19 px off at f = 387 px, keep most of it)
    assert after.center_error_similarity_max < 0.5 * before.center_error_similarity_max
    assert after.focal_error_pct_max < 0.6 * before.focal_error_pct_max
    assert after.pairwise_rotation_error_deg_max < 0.95 * before.pairwise_rotation_error_deg_max
    # the clocks are the epipolar clock step's
    for a, b in zip(with_rig.calibration, without.calibration, strict=True):
        assert a.time_offset == b.time_offset and a.time_rate == b.time_rate


def test_radial_terms_are_kept_only_for_distorted_lenses(terrace: tuple[list, Calibration]
                                                         ) -> None:
    """Security cameras (60-100 deg field of view, barrel distortion): the radial terms keep
    the distortion from bending the rig; on the terrace's distortion-free lenses they stay
    out (free, they trade against the focal lengths and rotations)."""
    sc = simulate("security", seed=1, duration_s=20.0)
    assert max(abs(c.dist[0]) for c in sc.truth) > 0.05
    start = _stage_iv_errors(sc.truth)
    data = prepare(sc.tracks, start)
    bent = refine_rig(data, start, rng=0)
    straight = refine_rig(data, start, radial_gain=None, rng=0)
    assert bent.kept and straight.kept
    assert sum(abs(v) > 0.02 for v in bent.radial.values()) >= 2, bent.radial
    assert not any(straight.radial.values())
    rot_bent = _worst_relative_rotation(bent.calibration, sc.truth)
    rot_straight = _worst_relative_rotation(straight.calibration, sc.truth)
    assert rot_bent < 0.6 * rot_straight, (rot_bent, rot_straight)  # measured 2.8 and 6.8 deg
    # the terms approach the lenses' -k1 (measured 0.03-0.19 for k1 -0.06 to -0.14)
    for cam in sc.truth:
        assert 0 < bent.radial[cam.name] < 3 * abs(cam.dist[0])
    # no lens distortion: not kept
    tracks, truth = terrace
    res = refine_rig(prepare(tracks, _stage_iv_errors(truth)), _stage_iv_errors(truth), rng=0)
    assert res.kept and not any(res.radial.values())
