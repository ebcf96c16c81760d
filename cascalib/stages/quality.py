"""Reference-free quality report of the refined cameras.

For each camera: the reprojection error of all associated observations after the final
triangulation (median and 90th percentile of the inliers), the inlier rate, 1-sigma uncertainties
from gtsam's marginal covariances, and a verdict (accepted / suspicious / failed) with its reason.

The marginals describe the noise the model assumes, not the errors of the model itself (detector
bias, body-model error): they are first scaled by the a-posteriori standard deviation of unit
weight (the measured whitened residual spread, so a wrong ``sigma_px`` is corrected) and then by
``uncertainty_inflation``, calibrated on simulated rigs against the true errors.

The principal point trades against the camera's rotation to first order (only the perspective
across the image tells them apart), which the marginals of one solve understate. When it is
estimated, its spread between the two halves of the recording (a split-half standard error)
adds ``atan(se / f)`` to the rotation uncertainty; once a lens-distortion model is estimated,
the principal point (estimated without it) counts as uncertain as its prior.
"""

from __future__ import annotations

from dataclasses import asdict, dataclass

import numpy as np
from numpy.typing import NDArray

from cascalib.camera import Camera
from cascalib.stages.refine_config import RefineConfig

__all__ = ["CameraQuality", "assess_camera", "unit_weight_sigma"]

#: Median of the norm of a 2D standard normal vector (chi with 2 dof): sqrt(2 ln 2).
_CHI2_MEDIAN = float(np.sqrt(2 * np.log(2)))


@dataclass(frozen=True)
class CameraQuality:
    """Quality of one refined camera (pixels, metres, degrees)."""

    camera: str
    n_observations: int
    reprojection_median_px: float
    reprojection_p90_px: float
    inlier_rate: float
    sigma_focal_px: float
    sigma_focal_rel: float
    sigma_rotation_deg: float
    sigma_position_m: float
    time_offset: float
    verdict: str
    reason: str
    sigma_principal_point_px: float = float("nan")
    sigma_time_offset_frames: float = float("nan")

    def to_dict(self) -> dict[str, object]:
        return asdict(self)


def unit_weight_sigma(errors_px: NDArray[np.float64], sigma_px: NDArray[np.float64]) -> float:
    """Robust a-posteriori standard deviation of unit weight.

    Parameters
    ----------
    errors_px : ndarray, shape (N,)
        Reprojection error norms of inlier observations.
    sigma_px : ndarray, shape (N,)
        Their assumed standard deviation per axis.

    Returns
    -------
    float
        ``median(error / sigma) / sqrt(2 ln 2)``: 1 when the assumed noise is right.
    """
    ok = np.isfinite(errors_px) & np.isfinite(sigma_px)
    if not ok.any():
        return float("nan")
    return float(np.median(errors_px[ok] / sigma_px[ok]) / _CHI2_MEDIAN)


def _verdict(q: dict[str, float], n_obs: int, cfg: RefineConfig) -> tuple[str, str]:
    med, rate = q["median"], q["inlier_rate"]
    if n_obs < cfg.min_observations:
        return "failed", f"only {n_obs} associated observations (< {cfg.min_observations})"
    if not np.isfinite(med) or med > cfg.fail_median_px:
        return "failed", f"median reprojection error {med:.1f} px > {cfg.fail_median_px:g} px"
    if rate < cfg.fail_inlier_rate:
        return "failed", f"inlier rate {rate:.0%} < {cfg.fail_inlier_rate:.0%}"
    reasons = []
    if med > cfg.accept_median_px:
        reasons.append(f"median reprojection error {med:.1f} px > {cfg.accept_median_px:g} px")
    if rate < cfg.min_inlier_rate:
        reasons.append(f"inlier rate {rate:.0%} < {cfg.min_inlier_rate:.0%}")
    if q["rotation"] > cfg.max_sigma_rotation_deg:
        pp = q.get("principal_point", np.nan)
        reasons.append(f"rotation uncertainty {q['rotation']:.2f} deg > "
                       f"{cfg.max_sigma_rotation_deg:g} deg"
                       + (f" (principal point uncertain by {pp:.0f} px)" if np.isfinite(pp)
                          else ""))
    if q["position"] > cfg.max_sigma_position_m:
        reasons.append(f"position uncertainty {q['position']:.3f} m > "
                       f"{cfg.max_sigma_position_m:g} m")
    if q["focal_rel"] > cfg.max_sigma_focal_rel:
        reasons.append(f"focal uncertainty {q['focal_rel']:.1%} > {cfg.max_sigma_focal_rel:.0%}")
    if not np.all(np.isfinite([q["rotation"], q["position"], q["focal_rel"]])):
        reasons.append("uncertainty unavailable")
    if reasons:
        return "suspicious", "; ".join(reasons)
    return "accepted", (f"median reprojection {med:.1f} px, {rate:.0%} inliers, "
                        f"sigma {q['rotation']:.2f} deg / {q['position'] * 100:.1f} cm / "
                        f"{q['focal_rel']:.1%} focal")


def assess_camera(camera: Camera, errors_px: NDArray[np.float64], sigmas: dict[str, float],
                  scale: float, cfg: RefineConfig) -> CameraQuality:
    """Quality and verdict of one camera.

    Parameters
    ----------
    camera : Camera
        The refined camera.
    errors_px : ndarray, shape (N,)
        Reprojection errors of all its associated observations (inf for points behind it).
    sigmas : dict
        Marginal 1-sigma ``focal`` (px), ``rotation`` (deg), ``position`` (m); optionally
        ``principal_point`` (px, split-half standard error, or the prior's sd where a lens
        model was estimated; not scaled), added to the rotation,
        and ``time_offset`` (1-sigma of the time offset in reference frames, already calibrated:
        see ``RefineConfig.time_uncertainty_inflation``; not scaled).
    scale : float
        Factor on the sigmas (unit-weight sigma times the configured inflation).
    cfg : RefineConfig
        Thresholds of the verdict.
    """
    e = errors_px[~np.isnan(errors_px)]
    inl = e[e < cfg.inlier_px]
    n = int(e.size)
    q = dict(median=float(np.median(inl)) if inl.size else np.nan,
             p90=float(np.percentile(inl, 90)) if inl.size else np.nan,
             inlier_rate=float(inl.size / n) if n else 0.0,
             focal=sigmas["focal"] * scale, rotation=sigmas["rotation"] * scale,
             position=sigmas["position"] * scale)
    pp = q["principal_point"] = float(sigmas.get("principal_point", np.nan))
    if np.isfinite(pp):
        q["rotation"] = float(np.hypot(q["rotation"], np.degrees(np.arctan(pp / camera.focal))))
    q["focal_rel"] = q["focal"] / camera.focal
    verdict, reason = _verdict(q, n, cfg)
    sd_time = float(sigmas.get("time_offset", np.nan))
    return CameraQuality(camera.name, n, q["median"], q["p90"], q["inlier_rate"], q["focal"],
                         q["focal_rel"], q["rotation"], q["position"], camera.time_offset,
                         verdict, reason, pp, sd_time)
