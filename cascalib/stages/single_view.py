"""Stage I: focal length, principal point and ground plane of one camera from upright people.

Per camera, without synchronisation (CasCalib, "Single View Geometric Calibration"):

1. keep upright, untruncated, confident poses (:mod:`cascalib.stages.upright`);
2. RANSAC over minimal 3-person DLT solves with the paper's inlier tests (predicted upper point
   within 5 % of the person's pixel height, direction within 2.86 deg);
3. DLT refit on the inliers, then a robust nonlinear refinement of ``(f, normal, height
   [, cx, cy], lean)`` on *all* inliers (every upright frame of every person; shoulder centre,
   neck and head top), with one height per tracked person and the neck/head ratios refined
   under priors, re-classifying the inliers with a noise-adaptive threshold;
4. the focal length's confidence interval from the Jacobian, and a refusal
   (:class:`~cascalib.errors.EstimationFailed`) when the geometry cannot determine it.

Beyond the paper: the upper points are not at the stature ``h``: the shoulder centre is at
0.818 h, the head top at h and the ankle joint itself 0.039 h above the floor (Drillis & Contini
1966, in Winter, "Biomechanics and Motor Control of Human Movement", Fig. 4.1). The paper's DLT
puts the shoulder at ``h`` above the ankle, which overstates the ankle-shoulder distance by
22 %; this only rescales the scene (the focal length and normal do not depend on a common height
scale), but it biases the camera height, and mixing points at different heights needs the
right ratios.

Walkers are not upright: normal gait leans the body above the hips forward by 2-5 deg, so the
shoulders and head are 2-5 cm ahead of the vertical through the feet, along the walking
direction. Taken as upright, those people tilt the estimated verticals and bias the focal
length (simulated terrace, principal point at the centre: median focal error 2.04 % upright,
1.28 % with the lean). The refinement models the lean as proportional to the walking velocity,
which the ankle centre's motion over 0.4 s gives (the nearest detection then, no track ids
needed), with one lean per camera.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Mapping, Sequence
from typing import Literal

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from cascalib.blas import one_blas_thread
from cascalib.camera import Camera
from cascalib.errors import EstimationFailed, InputError
from cascalib.stages.single_view_fit import SingleViewFit, fit_observations
from cascalib.stages.single_view_result import SingleViewResult
from cascalib.stages.upright import extract_observations, upright_mask
from cascalib.tracks import Tracks

__all__ = ["SingleViewConfig", "SingleViewResult", "calibrate_single_view"]

logger = logging.getLogger(__name__)


class SingleViewConfig(BaseModel):
    """Settings of Stage I (single-view focal length and ground plane)."""

    model_config = ConfigDict(extra="forbid")

    # -- people ---------------------------------------------------------------------------
    default_height: float = Field(
        1.70, gt=0.5, lt=2.5,
        description="Assumed stature (m) of every person whose height is not given "
                    "(paper: 1.7 m in the simulations).")
    height_sd: float = Field(
        0.07, ge=0.0,
        description="Prior s.d. (m) of a tracked person's stature around the assumed one, used "
                    "when each tracked person gets their own height (adult stature s.d. is "
                    "about 7 cm within a sex, NCD-RisC 2016).")
    track_heights: bool = Field(
        True, description="Estimate one height per tracked person (needs track ids and at "
                          "least `min_track_detections` upright frames); the paper uses one "
                          "fixed height for everyone.")
    min_track_detections: int = Field(
        5, ge=2, description="Upright frames a track needs to get its own height.")
    upper_points: list[Literal["shoulder", "hip", "neck", "head_top"]] = Field(
        default_factory=lambda: ["shoulder", "hip", "neck", "head_top"],  # type: ignore[arg-type]
        description="Points above the ankle centre to use (the paper uses the shoulder centre "
                    "only). The hip centre lengthens the lever that fixes each body's vertical "
                    "axis; neck and head top are used only when the skeleton has them.")
    joint_height_ratios: dict[str, float] = Field(
        default_factory=lambda: {"ankle": 0.039, "hip": 0.530, "shoulder": 0.818,
                                 "neck": 0.818, "head_top": 1.0},
        description="Height above the floor as a fraction of stature (Drillis & Contini 1966: "
                    "ankle 0.039, shoulder 0.818, head top 1.0; the neck keypoint of "
                    "COCO-derived detectors is the shoulder midpoint, others place it higher, "
                    "hence `refine_upper_ratios`).")
    refine_upper_ratios: bool = Field(
        True, description="Refine the ratios of the neck and head top (not the shoulder, which "
                          "anchors the scale) under a prior of s.d. `upper_ratio_sd`.")
    upper_ratio_sd: float = Field(
        0.05, gt=0.0, description="Relative prior s.d. of the refined neck/head-top ratios.")
    walking_lean_sd: float = Field(
        0.05, ge=0.0,
        description="Prior s.d. (s/m) of the forward lean of walking people per unit walking "
                    "speed. Walkers lean forward about the hips (2-5 deg of trunk lean in normal "
                    "gait at 1.3 m/s: 0.03-0.07 s/m), so their shoulders and head are 2-5 cm "
                    "ahead of the vertical through the feet. One value per camera is estimated "
                    "from the tracked persons' ankle motion; 0 keeps everyone upright (the "
                    "paper's model). Untracked detections are treated as upright.")
    ankle_sideways_weight: float = Field(
        0.25, gt=0.0, le=1.0,
        description="Weight of the ankle centre's image position across the body axis relative "
                    "to along it (1: as reliable as the upper points). Walking feet swing "
                    "sideways of the vertical through the shoulders; trusting them fully tilts "
                    "the body axes at random and biases the focal length low.")
    # -- upright filter -------------------------------------------------------------------
    max_bend_deg: float = Field(
        25.0, gt=0.0,
        description="Largest (180 - knee angle) + (180 - centre-line hip angle) of the "
                    "straighter side for "
                    "a pose to count as upright (supplement Eq. supp_angle_filter; the paper "
                    "gives no threshold).")
    min_confidence: float = Field(
        0.3, ge=0.0, description="Smallest detector confidence of the legs, hips and shoulders.")
    border_px: float = Field(
        3.0, ge=0.0, description="Poses with a required joint this close to the image edge "
                                 "are treated as truncated.")
    leg_torso_ratio: tuple[float, float] = Field(
        (1.2, 2.8), description="Accepted image ratio ankle-hip / hip-shoulder (standing: "
                                "about 1.7); rejects sitting or crouching people seen "
                                "from the front.")
    min_pixel_height: float = Field(
        30.0, ge=0.0, description="Smallest ankle-to-shoulder length (px) of a usable person.")
    # -- RANSAC ---------------------------------------------------------------------------
    inlier_rel_error: float = Field(
        0.05, gt=0.0, description="RANSAC inlier test: predicted-minus-detected upper point "
                                  "distance over the person's pixel height (paper: 5 %).")
    inlier_angle_deg: float = Field(
        2.86, gt=0.0, description="RANSAC inlier test: angle at the ankle between detected "
                                  "and predicted upper point (paper: 2.86 deg).")
    adaptive_inlier_sigmas: float = Field(
        3.0, gt=0.0,
        description="After the refinement, a detection is an inlier if its error is within "
                    "the paper's thresholds or within this many robust s.d. of the residuals "
                    "(keeps good data when the detector noise exceeds 5 % of small persons).")
    ransac_max_iterations: int = Field(
        300, ge=1, description="RANSAC iteration cap (the grid-search start backs it up).")
    ransac_confidence: float = Field(
        0.999, gt=0.0, lt=1.0, description="RANSAC stops when an all-inlier sample has been "
                                           "drawn with this probability.")
    min_sample_spread: float = Field(
        0.02, ge=0.0, description="Minimal samples whose ankles are closer than this fraction "
                                  "of the image diagonal are rejected unsolved.")
    max_detections: int = Field(
        600, ge=10,
        description="Upright detections used for the fit, picked spread over the image "
                    "(consecutive frames add little); all are classified in the end.")
    # -- model ----------------------------------------------------------------------------
    principal_point: Literal["center", "estimate", "auto"] = Field(
        "center", description="'center' holds it at the image centre (paper); 'estimate' always "
                            "fits it; 'auto' fits it and keeps it when well determined and "
                            "significantly better.")
    principal_point_max_sd: float = Field(
        0.01, gt=0.0, description="'auto' keeps the estimated principal point only if its "
                                  "1-s.d. is below this fraction of the image diagonal.")
    fov_range_deg: tuple[float, float] = Field(
        (5.0, 160.0), description="Plausible horizontal field of view; focal lengths outside "
                                  "are rejected.")
    loss: Literal["linear", "huber", "soft_l1", "cauchy"] = Field(
        "huber", description="Robust loss of the refinement (scipy.optimize.least_squares).")
    # -- refusal --------------------------------------------------------------------------
    confidence_level: float = Field(
        0.95, gt=0.0, lt=1.0, description="Level of the reported focal interval.")
    max_focal_uncertainty: float = Field(
        0.25, gt=0.0,
        description="Refuse (EstimationFailed) when the focal interval's half-width exceeds "
                    "this fraction of the focal length.")
    min_ankle_spread: float = Field(
        0.05, ge=0.0,
        description="Refuse when the upright ankles span less than this fraction of the image "
                    "diagonal (everyone in one spot).")
    min_detections: int = Field(
        3, ge=3, description="Fewest upright detections to attempt a fit (3: the minimal DLT).")
    max_normal_sd_deg: float = Field(
        2.0, gt=0.0,
        description="With known intrinsics (no focal interval to judge): refuse when the "
                    "ground normal's 1-s.d. exceeds this (deg), e.g. all vertical lines on one "
                    "image line.")


@one_blas_thread
def calibrate_single_view(tracks: Tracks, config: SingleViewConfig | None = None, *,
                          height: float | Mapping[int, float] | Sequence[float] | None = None,
                          rng: np.random.Generator | int | None = None,
                          known_intrinsics: tuple[NDArray[np.float64], NDArray[np.float64]]
                          | None = None) -> SingleViewResult:
    """Estimate focal length, principal point and ground plane of one camera.

    With ``known_intrinsics`` (e.g. from a checkerboard) only the ground plane (normal and
    camera height) is estimated: the keypoints are undistorted first and mapped to an ideal
    pinhole with square pixels of focal ``fx`` (the y pixels scaled by ``fx / fy`` about
    ``cy``), the focal length and principal point are held fixed throughout, and no focal
    interval can cause a refusal.

    Parameters
    ----------
    tracks : Tracks
        The camera's 2D detections; the image size must be known.
    config : SingleViewConfig, optional
    height : float, mapping or sequence, optional
        Stature (m) of everyone, or per track id (a {id: height} mapping or a list indexed by
        id); default ``config.default_height``.
    rng : Generator, int or None
        Randomness of RANSAC and the subsampling.
    known_intrinsics : (ndarray (3, 3), ndarray (5,)), optional
        Known ``K`` and OpenCV distortion ``(k1, k2, p1, p2, k3)``. The result then reports
        ``focal = K[0, 0]``, the interval ``(focal, focal)``, ``principal_point = K[:2, 2]``
        (not estimated) and its ``ankle``/``upper`` pixels are the ideal square pixels; its
        :meth:`~SingleViewResult.to_camera` carries ``K`` and the distortion unchanged.

    Returns
    -------
    SingleViewResult

    Raises
    ------
    EstimationFailed
        Too few upright people, everyone in one spot, a camera looking straight down or
        horizontally, or a focal interval wider than ``config.max_focal_uncertainty``. The
        exception's ``partial`` attribute holds the best (untrustworthy) result when there is
        one. With ``known_intrinsics``: too few upright people, everyone in one spot, or a
        ground normal more uncertain than ``config.max_normal_sd_deg``.
    InputError
        ``known_intrinsics`` of the wrong shape or with a non-positive focal length.
    """
    cfg = config or SingleViewConfig()
    rng = np.random.default_rng(rng)
    t0 = time.perf_counter()
    size = tracks.require_image_size()
    raw = tracks
    known = None
    if known_intrinsics is not None:
        known = _check_intrinsics(known_intrinsics, tracks)
        tracks = _ideal_tracks(tracks, *known)
    mask = _upright(tracks, raw, cfg)
    n_det = tracks.n_detections
    logger.info("camera %s: %d of %d detections upright", tracks.camera, int(mask.sum()), n_det)
    ex = extract_observations(
        tracks, mask, ratios=cfg.joint_height_ratios, upper_points=cfg.upper_points,
        height=cfg.default_height if height is None else height,
        default_height=cfg.default_height, min_confidence=cfg.min_confidence)
    focal, c = (None, None) if known is None else (float(known[0][0, 0]), known[0][:2, 2])
    try:
        fit = fit_observations(ex.obs, size, cfg, rng=rng, focal=focal, principal_point=c)
    except EstimationFailed as err:
        partial = getattr(err, "partial", None)
        new = EstimationFailed(
            f"{err.message} ({int(mask.sum())} upright of {n_det} detections)",
            file=tracks.source, camera=tracks.camera, field="keypoints")
        if isinstance(partial, SingleViewFit):
            new.partial = _result(tracks, ex, partial, mask, t0,  # type: ignore[attr-defined]
                                  known)
        raise new from None
    return _result(tracks, ex, fit, mask, t0, known)


def _check_intrinsics(known: tuple[NDArray[np.float64], NDArray[np.float64]], tracks: Tracks
                      ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Validated ``(K (3, 3), dist (5,))`` copies; InputError naming the camera otherwise."""
    K = np.asarray(known[0], dtype=np.float64)
    dist = np.zeros(5)
    given = np.asarray(known[1] if known[1] is not None else [], dtype=np.float64).ravel()
    if K.shape != (3, 3) or given.size > 5 or not np.all(np.isfinite(K)) or not np.all(
            np.isfinite(given)) or not (K[0, 0] > 0 and K[1, 1] > 0):
        raise InputError(f"known intrinsics need a finite (3, 3) K with positive fx, fy and "
                         f"at most 5 distortion coefficients, got K {K.shape}, dist "
                         f"{given.shape}", file=tracks.source, camera=tracks.camera,
                         field="known_intrinsics")
    dist[:given.size] = given
    return K.copy(), dist


def _ideal_tracks(tracks: Tracks, K: NDArray[np.float64], dist: NDArray[np.float64]) -> Tracks:
    """The tracks with keypoints undistorted to an ideal pinhole of focal ``fx``, square pixels.

    Scaling y by ``fx / fy`` about ``cy`` (rather than averaging fx and fy) keeps the model's
    focal exactly the known ``fx`` and is exact for any ``fy``; skew is dropped with the
    distortion (the normalised coordinates are mapped back with ``[[fx, 0, cx], [0, fx, cy]]``).
    """
    cam = Camera(tracks.camera, tracks.require_image_size(), K, dist, np.eye(3), np.zeros(3))
    kp = tracks.keypoints.copy()
    xy = cam.undistort(kp[..., :2])
    kp[..., :2] = K[0, 0] * xy + K[:2, 2]
    return tracks.with_(keypoints=kp)


def _upright(tracks: Tracks, raw: Tracks, cfg: SingleViewConfig) -> NDArray[np.bool_]:
    """Upright mask of ``tracks``, with truncation judged on the ``raw`` (image) pixels.

    Undistorted pixels can leave the image rectangle, so the border test runs on the raw
    keypoints and the shape tests (angles, proportions, size) on the undistorted ones.
    """
    size = tracks.require_image_size()
    kw = dict(max_bend_deg=cfg.max_bend_deg, min_confidence=cfg.min_confidence,
              leg_torso_ratio=cfg.leg_torso_ratio, min_pixel_height=cfg.min_pixel_height)
    mask = upright_mask(tracks.canonical(), size, border_px=cfg.border_px, **kw)  # type: ignore[arg-type]
    if raw is not tracks:
        inside = upright_mask(raw.canonical(), size, border_px=cfg.border_px,
                              **{**kw, "max_bend_deg": np.inf, "leg_torso_ratio": (0.0, np.inf),  # type: ignore[arg-type]
                                 "min_pixel_height": 0.0})
        shape = upright_mask(tracks.canonical(), size, border_px=-np.inf, **kw)  # type: ignore[arg-type]
        mask = inside & shape
    return mask


def _result(tracks: Tracks, ex, fit: SingleViewFit, mask: np.ndarray,  # type: ignore[no-untyped-def]
            t0: float, known: tuple[NDArray[np.float64], NDArray[np.float64]] | None = None
            ) -> SingleViewResult:
    size = tracks.require_image_size()
    diag = dict(fit.diagnostics)
    diag.update(n_detections=tracks.n_detections, n_upright=int(mask.sum()),
                time_s=time.perf_counter() - t0)
    return SingleViewResult(
        camera=tracks.camera, image_size=size, focal=fit.model.f,
        focal_interval=fit.focal_interval, focal_sd_rel=fit.refined.log_f_sd,
        principal_point=fit.model.c.copy(), principal_point_estimated=fit.principal_point_fitted,
        normal_cam=fit.model.n.copy(), normal_sd_deg=fit.refined.normal_sd_deg,
        camera_height=fit.model.d + float(fit.diagnostics["ankle_height_m"]),
        upper_points=ex.names, frames=ex.frame, persons=ex.person, ankle=ex.obs.ankle,
        upper=ex.obs.upper, offset=fit.offsets, inliers=fit.inliers, residuals=fit.rel_error,
        residuals_px=fit.px_error, upright_mask=mask, diagnostics=diag,
        dist=np.zeros(5) if known is None else known[1].copy(),
        known_K=None if known is None else known[0].copy())
