"""Stage I on observations: RANSAC, refinement rounds, principal point choice, interval, refusal.

Separate from :mod:`cascalib.stages.single_view` (which reads :class:`~cascalib.tracks.Tracks`)
so that benchmarks can feed bare ankle/upper pixel pairs, e.g. the paper's simulation protocol.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import numpy as np
from numpy.typing import NDArray
from scipy.stats import chi2, norm

from cascalib.errors import EstimationFailed
from cascalib.stages.single_view_refine import RefineResult, ransac, refine, spatial_cells
from cascalib.stages.single_view_solver import (
    GroundModel,
    Observations,
    dlt_estimate,
    grid_estimate,
    inlier_errors,
)

if TYPE_CHECKING:
    from cascalib.stages.single_view import SingleViewConfig

__all__ = ["SingleViewFit", "fit_observations", "focal_range"]

logger = logging.getLogger(__name__)
F64 = NDArray[np.float64]

#: Below this many detections RANSAC cannot tell outliers from noise: every detection is used.
_MIN_RANSAC = 6
#: Image cells per side for spatial subsampling and for the independence clusters.
_CELLS = 12
#: Detections RANSAC scores its hypotheses on, and the starting models are compared on.
_RANSAC_SCORE = 300
_START_SET = 250
#: Image cells per side of the independence clusters when persons are not tracked: coarse,
#: because a walker's gait and lean errors persist over metres of their path.
_CLUSTER_CELLS = 4


@dataclass(frozen=True)
class SingleViewFit:
    """Outcome of :func:`fit_observations` (all arrays over the N input detections)."""

    model: GroundModel
    refined: RefineResult
    focal_interval: tuple[float, float]
    principal_point_fitted: bool
    inliers: NDArray[np.bool_]
    rel_error: F64
    px_error: F64
    offsets: F64
    ankle_ratio: float
    diagnostics: dict[str, Any] = field(default_factory=dict)


def focal_range(image_size: tuple[int, int], fov_deg: tuple[float, float]) -> tuple[float, float]:
    """Focal lengths (px) of the widest and narrowest horizontal field of view."""
    half_w = image_size[0] / 2.0
    return (float(half_w / np.tan(np.radians(fov_deg[1]) / 2)),
            float(half_w / np.tan(np.radians(fov_deg[0]) / 2)))


def _subsample(obs: Observations, size: tuple[int, int], max_n: int,
               rng: np.random.Generator) -> NDArray[np.int64]:
    """Indices of at most ``max_n`` detections, spread evenly over image cells."""
    if obs.n <= max_n:
        return np.arange(obs.n)
    order = rng.permutation(obs.n)
    cell = spatial_cells(obs.ankle[order], size, _CELLS)
    by_cell = np.argsort(cell, kind="stable")
    starts = np.searchsorted(cell[by_cell], cell[by_cell])
    rank = np.empty(obs.n, dtype=np.int64)
    rank[by_cell] = np.arange(obs.n) - starts
    # round robin over cells: every cell's first detection, then every cell's second, ...
    pick = order[np.lexsort((rng.random(obs.n), rank))[:max_n]]
    return np.sort(pick)


def _clusters(obs: Observations, size: tuple[int, int]) -> NDArray[np.int64]:
    """Independence clusters: the track id when known, else the image cell of the ankle."""
    cells = spatial_cells(obs.ankle, size, _CLUSTER_CELLS) + 1 + int(max(obs.group.max(
        initial=0), 0))
    return np.where(obs.group >= 0, obs.group, cells)


def _offsets(obs: Observations, ref: RefineResult, max_rel: float = 0.0) -> F64:
    """Offsets with the refined upper-point ratios and per-person heights applied.

    With ``max_rel`` > 0, tracked persons the refinement has no height for (e.g. tall people
    RANSAC rejected at the assumed height) get one from the median ratio of their observed to
    predicted ankle-to-shoulder lengths, if within ``1 +- max_rel``; they can then rejoin.
    """
    heights = dict(ref.height_scale)
    missing = np.setdiff1d(obs.group[obs.group >= 0], list(heights))
    if max_rel > 0 and len(missing):
        base = obs.offset * ref.ratio_scale[None, :]
        pred = ref.model.predict_upper(obs.ankle, base)[:, 0]
        with np.errstate(invalid="ignore", divide="ignore"):
            ratio = (np.linalg.norm(obs.upper[:, 0] - obs.ankle, axis=1)
                     / np.linalg.norm(pred - obs.ankle, axis=1))
        for g in missing:
            r = ratio[(obs.group == g) & np.isfinite(ratio)]
            if r.size and abs(np.median(r) - 1) < max_rel:
                heights[int(g)] = float(np.median(r))
    scale = np.array([heights.get(int(g), 1.0) for g in obs.group])
    return obs.offset * ref.ratio_scale[None, :] * scale[:, None]


def _classify(model: GroundModel, obs: Observations, offsets: F64, adaptive: bool,
              cfg: SingleViewConfig) -> tuple[NDArray[np.bool_], F64, F64]:
    """Paper inlier test, widened to ``adaptive_inlier_sigmas`` residual s.d. for small people.

    The s.d. is the median absolute deviation of the upper points predicted from the raw
    ankles (robust to outliers below one half).
    """
    o = Observations(obs.ankle, obs.upper, offsets, obs.group)
    rel, ang = inlier_errors(model, o)
    ph = o.pixel_height()
    sigma_px = 0.0
    if adaptive:
        r = model.residuals(o)[o.valid].ravel()
        r = r[np.isfinite(r)]
        sigma_px = float(1.4826 * np.median(np.abs(r))) if r.size else 0.0
    with np.errstate(invalid="ignore", divide="ignore"):
        adapt = cfg.adaptive_inlier_sigmas * sigma_px / ph
        ok = (rel < np.maximum(cfg.inlier_rel_error, adapt)) & (
            ang < np.maximum(cfg.inlier_angle_deg, np.degrees(adapt)))
    return ok, rel, rel * ph


def _max_height_rel(cfg: SingleViewConfig) -> float:
    """Largest relative height deviation a tracked person may be given (3 prior s.d.)."""
    return 3.0 * cfg.height_sd / cfg.default_height if cfg.track_heights else 0.0


def _refine(obs: Observations, model: GroundModel, cfg: SingleViewConfig, fit_c: bool,
            size: tuple[int, int], fit_focal: bool = True) -> RefineResult:
    return refine(obs, model, fit_principal_point=fit_c, track_heights=cfg.track_heights,
                  height_sd_rel=max(cfg.height_sd, 1e-3) / cfg.default_height,
                  min_track_detections=cfg.min_track_detections,
                  fit_ratios=cfg.refine_upper_ratios, ratio_sd_rel=cfg.upper_ratio_sd,
                  clusters=_clusters(obs, size), image_diag=float(np.hypot(*size)),
                  loss=cfg.loss, ankle_sideways=cfg.ankle_sideways_weight,
                  height_nuisance=cfg.height_sd > 0, fit_focal=fit_focal,
                  lean_sd=cfg.walking_lean_sd, lean_pivot=_lean_pivot(cfg))


def _lean_pivot(cfg: SingleViewConfig) -> float:
    """Height of the hips above the ankles as a fraction of the shoulders' (column 0)."""
    r = cfg.joint_height_ratios
    return (r["hip"] - r["ankle"]) / (r["shoulder"] - r["ankle"])


def _initial(o: Observations, c0: F64, f_rng: tuple[float, float], cfg: SingleViewConfig,
             rng: np.random.Generator, diag: dict[str, Any], focal: float | None = None
             ) -> tuple[list[GroundModel], NDArray[np.bool_]]:
    """Starting models (RANSAC+DLT and the focal grid search) and the RANSAC inliers.

    With a known ``focal`` RANSAC draws 2-person samples and the grid has that one focal.
    """
    inl = np.ones(o.n, dtype=bool)
    starts: list[GroundModel] = []
    if o.n >= _MIN_RANSAC:
        # scoring hypotheses on a few hundred detections is as selective and much cheaper
        score_set = o.take(np.sort(rng.permutation(o.n)[:_RANSAC_SCORE]))
        rr = ransac(score_set, c0, f_range=f_rng, rel_thr=cfg.inlier_rel_error,
                    ang_thr=cfg.inlier_angle_deg, max_iterations=cfg.ransac_max_iterations,
                    min_sample_px=cfg.min_sample_spread * float(np.hypot(*c0 * 2)),
                    rng=rng, confidence=cfg.ransac_confidence, focal=focal)
        if not isinstance(rr, str):
            diag["ransac_iterations"] = rr.n_iterations
            inl, _, _ = _classify(rr.model, o, o.offset, False, cfg)
            diag["ransac_inliers"] = int(inl.sum())
            starts.append(rr.model)
            if inl.sum() < 3:
                inl = np.ones(o.n, dtype=bool)
    else:
        m = dlt_estimate(o, c0, f_rng, focal=focal)
        if not isinstance(m, str):
            starts.append(m)
    # the 1-D focal search with a least-median score needs no inlier threshold: it rescues
    # scenes whose noise exceeds the paper's 5 % test (few, small or noisy persons)
    for subset in (inl, np.ones(o.n, dtype=bool)) if not inl.all() else (inl,):
        g = grid_estimate(o.take(subset), c0, f_rng, n_grid=60 if focal is None else 1)
        if not isinstance(g, str):
            starts.append(g)
    return starts, inl


def _robust_start(o: Observations, starts: list[GroundModel], cfg: SingleViewConfig,
                  size: tuple[int, int], fit_focal: bool = True) -> RefineResult:
    """Refine every start on all detections with a redescending loss; keep the least median
    relative error (scale-free, so starts with different noise estimates compare fairly)."""
    best: tuple[float, RefineResult | None] = (np.inf, None)
    for m in starts:
        r = refine(o, m, fit_principal_point=False, track_heights=False, height_sd_rel=1.0,
                   min_track_detections=cfg.min_track_detections,
                   fit_ratios=cfg.refine_upper_ratios, ratio_sd_rel=cfg.upper_ratio_sd,
                   clusters=_clusters(o, size), image_diag=float(np.hypot(*size)),
                   loss="cauchy", f_scale=2.0, ankle_sideways=cfg.ankle_sideways_weight,
                   fit_focal=fit_focal)
        rel, _ = inlier_errors(r.model, Observations(o.ankle, o.upper, _offsets(o, r), o.group))
        score = float(np.median(rel))
        if score < best[0]:
            best = (score, r)
    assert best[1] is not None
    return best[1]


def fit_observations(obs: Observations, image_size: tuple[int, int], cfg: SingleViewConfig, *,
                     rng: np.random.Generator | int | None = None, focal: float | None = None,
                     principal_point: F64 | None = None) -> SingleViewFit:
    """Focal length, principal point and ankle plane from upright ankle/upper-point pairs.

    Parameters
    ----------
    obs : Observations
        Upright detections (N).
    image_size : (int, int)
    cfg : SingleViewConfig
    focal : float, optional
        Known focal length (px, square pixels): held fixed everywhere (RANSAC, grid start,
        refinement); only the plane is estimated and the focal interval is ``(focal, focal)``.
    principal_point : ndarray, shape (2,), optional
        Known principal point (px), held fixed; default the image centre (then fitted per
        ``cfg.principal_point`` unless ``focal`` is given).

    Returns
    -------
    SingleViewFit

    Raises
    ------
    EstimationFailed
        With ``partial`` (a SingleViewFit) attached when a model was found but is not trusted.
    """
    rng = np.random.default_rng(rng)
    w, h = image_size
    img_diag = float(np.hypot(w, h))
    known = focal is not None
    c0 = (np.array([(w - 1) / 2.0, (h - 1) / 2.0]) if principal_point is None
          else np.asarray(principal_point, dtype=np.float64).copy())
    f_rng = (float(focal), float(focal)) if known else focal_range(image_size,  # type: ignore[arg-type]
                                                                     cfg.fov_range_deg)
    diag = _check_spread(obs, img_diag, cfg, known)
    o = obs.take(_subsample(obs, image_size, cfg.max_detections, rng))
    starts, inl = _initial(o, c0, f_rng, cfg, rng, diag, focal)
    if not starts:
        raise EstimationFailed("no focal length in the plausible range explains the "
                               "upright persons (check the image size and the skeleton)"
                               if not known else "no ground plane explains the upright "
                               "persons with the known intrinsics (check K and the skeleton)")
    # choosing among starts needs few detections; the rounds below use all of ``o``
    best = _robust_start(o.take(np.sort(rng.permutation(o.n)[:_START_SET])), starts, cfg,
                         image_size, fit_focal=not known)
    for _ in range(2 if o.n >= _MIN_RANSAC else 0):
        # re-classify with the noise level of the refined model, refit
        inl, _, _ = _classify(best.model, o, _offsets(o, best, _max_height_rel(cfg)), True, cfg)
        if inl.sum() < 3:
            break
        best = _refine(o.take(inl), best.model, cfg, False, image_size, fit_focal=not known)
    fitted_c = False
    if cfg.principal_point != "center" and not known and inl.sum() >= 6:
        with_c = _refine(o.take(inl), best.model, cfg, True, image_size)
        gain = (best.cost - with_c.cost) / max(with_c.sigma_px, 1e-6) ** 2
        diag.update(principal_point_sd=with_c.c_sd.tolist(), principal_point_gain=gain)
        good = (float(np.hypot(*with_c.c_sd)) < cfg.principal_point_max_sd * img_diag
                and gain > chi2.ppf(0.999, 1))
        if cfg.principal_point == "estimate" or good:
            best, fitted_c = with_c, True
    return _finish(obs, best, fitted_c, image_size, cfg, diag, known)


def _check_spread(obs: Observations, img_diag: float, cfg: SingleViewConfig,
                  known: bool) -> dict[str, Any]:
    """Refuse too few detections or everyone in one spot; the diagnostics started here."""
    if obs.n < cfg.min_detections:
        raise EstimationFailed(
            f"only {obs.n} upright, fully visible persons found; at least "
            f"{cfg.min_detections} are needed (people standing or walking upright, feet and "
            "shoulders in view)")
    ext = np.percentile(obs.ankle, 95, axis=0) - np.percentile(obs.ankle, 5, axis=0)
    spread = float(np.hypot(*ext)) / img_diag
    if spread < cfg.min_ankle_spread:
        # with a known focal one spot still leaves the normal free about one axis
        what = "the ground plane" if known else "the focal length"
        raise EstimationFailed(
            f"all upright persons stand in one spot (their feet span {100 * spread:.1f} % of "
            f"the image diagonal, need {100 * cfg.min_ankle_spread:.0f} %): {what} "
            "is not observable; record people standing or walking at several places spread "
            "over the floor")
    return {"ankle_spread": spread, "n_used": obs.n}


def _finish(obs: Observations, best: RefineResult, fitted_c: bool, size: tuple[int, int],
            cfg: SingleViewConfig, diag: dict[str, Any], known: bool = False) -> SingleViewFit:
    """Classify every detection, build the interval and refuse untrustworthy results."""
    model = best.model
    offsets = _offsets(obs, best, _max_height_rel(cfg))
    inliers, rel, px = _classify(model, obs, offsets, True, cfg)
    z = float(norm.ppf(0.5 + cfg.confidence_level / 2))
    sd = best.log_f_sd if np.isfinite(best.log_f_sd) and best.log_f_sd < 5 else np.inf
    with np.errstate(over="ignore"):
        lo, hi = model.f * np.exp(-z * sd), model.f * np.exp(z * sd)
    if known:
        lo = hi = model.f  # exact: exp(+-0) could still round
    pitch = float(np.degrees(np.arcsin(np.clip(-model.n[2], -1, 1))))
    ankle_ratio = cfg.joint_height_ratios["ankle"]
    diag.update(pitch_deg=pitch, sigma_px=best.sigma_px, confidence_level=cfg.confidence_level,
                n_inliers=int(inliers.sum()), ratio_scale=best.ratio_scale.tolist(),
                height_scale=best.height_scale, principal_point_fitted=fitted_c,
                focal_known=known, walking_lean=best.lean,
                ankle_height_m=float(ankle_ratio * np.median(offsets[:, 0] / max(
                    cfg.joint_height_ratios["shoulder"] - ankle_ratio, 1e-9))))
    fit = SingleViewFit(model, best, (float(lo), float(hi)), fitted_c, inliers, rel, px,
                        offsets, ankle_ratio, diag)
    half = (hi - lo) / (2 * model.f)
    if not half <= cfg.max_focal_uncertainty:
        err = EstimationFailed(
            f"focal length not determined: {100 * cfg.confidence_level:.0f} % interval "
            f"[{lo:.0f}, {hi:.0f}] px around {model.f:.0f} px (+-{100 * half:.0f} %, limit "
            f"{100 * cfg.max_focal_uncertainty:.0f} %): {_reason(pitch, diag['ankle_spread'])}")
        err.partial = fit  # type: ignore[attr-defined]
        raise err
    if known and not best.normal_sd_deg <= cfg.max_normal_sd_deg:
        err = EstimationFailed(
            f"ground plane not determined with the known intrinsics: normal 1-s.d. "
            f"{best.normal_sd_deg:.2f} deg (limit {cfg.max_normal_sd_deg:.2f} deg); the upright "
            "persons' vertical lines nearly coincide: record people at several places "
            "spread over the floor")
        err.partial = fit  # type: ignore[attr-defined]
        raise err
    if obs.n < _MIN_RANSAC:  # too few to tell outliers from noise: all are used
        inliers = np.ones(obs.n, dtype=bool)
        fit = SingleViewFit(model, best, (float(lo), float(hi)), fitted_c, inliers, rel, px,
                            offsets, ankle_ratio, diag)
    if inliers.sum() < cfg.min_detections:
        err = EstimationFailed(f"only {int(inliers.sum())} detections agree with the best model")
        err.partial = fit  # type: ignore[attr-defined]
        raise err
    return fit


def _reason(pitch: float, spread: float) -> str:
    if pitch > 80:
        return (f"the camera looks nearly straight down (pitch {pitch:.0f} deg): people's image "
                "heights then do not depend on the focal length")
    if abs(pitch) < 4:
        return (f"the camera is nearly horizontal (pitch {pitch:.1f} deg): the vertical "
                "vanishing point is at infinity and the focal length cancels out")
    if spread < 0.15:
        return (f"the upright persons cover only {100 * spread:.0f} % of the image diagonal; "
                "record people at several places spread over the floor")
    return "too few or too noisy upright detections"
