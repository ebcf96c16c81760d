"""RANSAC over minimal DLT samples and the nonlinear refinement of focal length and ground plane.

The refinement minimises the pixel distance between observed and predicted upper points
(shoulder centre, neck, head top) over ``(log f, normal (2 dof), log d [, cx, cy] [, lean])``
plus, when persons are tracked, one log-height per person tied to the assumed height by a
Gaussian prior. ``lean`` is the walkers' forward lean per unit walking speed: the body above
the hips tilts forward by ``atan(lean * speed)`` along the ankles' motion (Gaussian prior
around 0).
Its Jacobian gives the focal length's confidence interval: the usual ``s^2 (J^T J)^-1`` and a
cluster-robust sandwich (clusters = persons, or image cells when persons are not tracked, since
repeated frames of one person at one spot are not independent), whichever is wider.

References
----------
CasCalib paper, "Single View Geometric Calibration" (RANSAC, inlier tests 5 % / 2.86 deg).
Fischler & Bolles, "Random sample consensus", CACM 1981. Torr & Zisserman, "MLESAC", CVIU 2000
(the truncated-quadratic score used here).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix

from cascalib.stages.single_view_solver import (
    GroundModel,
    Observations,
    body_axes,
    dlt_estimate,
    inlier_errors,
    weigh_along,
)

__all__ = ["RansacResult", "RefineResult", "ransac", "refine", "spatial_cells"]

logger = logging.getLogger(__name__)
F64 = NDArray[np.float64]

#: Residual (px) given to an upper point whose ankle ray misses the ground plane, so that the
#: least-squares problem stays finite; such points are gross outliers for any sensible model.
_MISS_PX = 1000.0


@dataclass(frozen=True)
class RansacResult:
    model: GroundModel
    inliers: NDArray[np.bool_]
    n_iterations: int


def _inliers(model: GroundModel, obs: Observations, rel_thr: float, ang_thr: float
             ) -> tuple[NDArray[np.bool_], float]:
    rel, ang = inlier_errors(model, obs)
    ok = (rel < rel_thr) & (ang < ang_thr)
    # truncated quadratic (MSAC): prefers tight consensus sets among equally large ones
    score = float(np.sum(1.0 - np.minimum((rel[ok] / rel_thr) ** 2, 1.0)))
    return ok, score


def ransac(obs: Observations, c: F64, *, f_range: tuple[float, float], rel_thr: float,
           ang_thr: float, max_iterations: int, min_sample_px: float,
           rng: np.random.Generator, confidence: float = 0.999,
           focal: float | None = None) -> RansacResult | str:
    """Largest consensus set over minimal 3-detection DLT solves.

    Samples whose ankles lie closer than ``min_sample_px`` to each other are rejected before
    solving (three people in one spot do not determine the focal length). With a known
    ``focal`` the samples have 2 detections (two vertical lines give the vanishing point,
    hence the normal) and only the plane is solved for.

    Returns
    -------
    RansacResult or str
        The best model refit (DLT) on its inliers, or a message when no sample gave a model.
    """
    n = obs.n
    best: tuple[float, GroundModel | None, NDArray[np.bool_]] = (-1.0, None,
                                                                 np.zeros(n, bool))
    needed, it = max_iterations, 0
    tries = 0
    k = 3 if focal is None else 2
    while it < min(needed, max_iterations) and tries < 20 * max_iterations:
        tries += 1
        idx = rng.choice(n, k, replace=False) if n > k else np.arange(n)
        a = obs.ankle[idx]
        gaps = np.linalg.norm(a[:, None] - a[None], axis=-1)[np.triu_indices(len(idx), 1)]
        if n > k and gaps.min() < min_sample_px:
            continue
        it += 1
        model = dlt_estimate(obs.take(idx), c, f_range, focal=focal)
        if isinstance(model, str):
            if n <= k:
                break
            continue
        ok, score = _inliers(model, obs, rel_thr, ang_thr)
        if score > best[0]:
            best = (score, model, ok)
            p_good = min(float(ok.mean()) ** k, 1.0 - 1e-12)
            needed = (max_iterations if p_good < 1e-9 else
                      int(np.ceil(np.log(1 - confidence) / np.log1p(-p_good))))
        if n <= k:
            break
    if best[1] is None:
        return f"no {k}-person sample gave a valid focal length and ground plane"
    model, ok = best[1], best[2]
    if ok.sum() >= k:
        refit = dlt_estimate(obs.take(ok), c, f_range, focal=focal)
        if not isinstance(refit, str):
            ok2, _ = _inliers(refit, obs, rel_thr, ang_thr)
            if ok2.sum() >= ok.sum():
                model, ok = refit, ok2
    return RansacResult(model, ok, it)


def spatial_cells(points: F64, size: tuple[int, int], n_cells: int) -> NDArray[np.int64]:
    """Index of the ``n_cells x n_cells`` image cell holding each point (N, 2)."""
    w, h = size
    ix = np.clip((points[:, 0] / w * n_cells).astype(int), 0, n_cells - 1)
    iy = np.clip((points[:, 1] / h * n_cells).astype(int), 0, n_cells - 1)
    return (iy * n_cells + ix).astype(np.int64)


@dataclass(frozen=True)
class RefineResult:
    """Refined model with its uncertainty.

    Attributes
    ----------
    model : GroundModel
    log_f_sd : float
        1-sigma of ``log f`` (relative focal uncertainty).
    c_sd : ndarray, shape (2,)
        1-sigma of the principal point (px) along x and y (it moves along the horizon only);
        zeros when it was held fixed.
    normal_sd_deg : float
        1-sigma of the normal direction (deg, root of the two tangent variances).
    sigma_px : float
        Robust scale of the pixel residuals.
    cost : float
        Sum of squared residuals (px^2) over valid upper points, robust-loss-free.
    height_scale : dict of int to float
        Estimated height multiplier per tracked person (1 = the assumed height).
    ratio_scale : ndarray, shape (K,)
        Estimated multiplier of each upper point's offset (column 0 fixed at 1).
    lean : float
        Estimated forward lean of walkers (s/m: lean angle per unit walking speed); 0 when not
        estimated.
    """

    model: GroundModel
    log_f_sd: float
    c_sd: F64
    normal_sd_deg: float
    sigma_px: float
    cost: float
    height_scale: dict[int, float]
    ratio_scale: F64
    lean: float = 0.0


def _tangent_basis(n: F64) -> tuple[F64, F64]:
    e1 = np.cross(n, [1.0, 0.0, 0.0] if abs(n[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    return e1, np.cross(n, e1)


class _Problem:
    """Parameter packing and residuals of the refinement (one instance per solve)."""

    def __init__(self, obs: Observations, model: GroundModel, fit_c: bool,
                 height_groups: NDArray[np.int64], n_heights: int, prior_w: float,
                 n_ratios: int, ratio_w: float, c_scale: float, sideways: float,
                 lean_w: float = 0.0, lean_pivot: float = 0.0) -> None:
        self.obs, self.n0, self.fit_c = obs, model.n, fit_c
        self.e1, self.e2 = _tangent_basis(model.n)
        self.c0, self.c_scale = model.c, c_scale
        # only the principal point's component along the horizon is observable: people on one
        # plane give the vertical vanishing point and the horizon (4 dof + scale) for 5 unknowns
        # (f, c, tilt, roll); moving c towards the vanishing point trades off against f
        h = np.array([-model.n[1], model.n[0]])
        self.c_dir = h / np.linalg.norm(h) if np.linalg.norm(h) > 1e-9 else np.array([1.0, 0.0])
        self.hg, self.n_h, self.prior_w = height_groups, n_heights, prior_w
        self.n_r, self.ratio_w = n_ratios, ratio_w
        self.valid = obs.valid
        # walkers lean forward (about the hips): one lean per unit walking speed, where the
        # ankles' motion is known
        self.fit_lean = lean_w > 0 and obs.motion is not None
        self.lean_w, self.lean_pivot = lean_w, lean_pivot
        self.i_lean = 5 if fit_c else 4
        self.n_base = self.i_lean + (1 if self.fit_lean else 0)
        self.sideways = sideways
        self.along, self.across = body_axes(obs)
        self.w_along = np.ones(obs.upper.shape[:2])

    def x0(self, model: GroundModel) -> F64:
        base = [np.log(model.f), 0.0, 0.0, np.log(model.d)]
        if self.fit_c:
            base += [0.0]
        if self.fit_lean:
            base += [0.0]
        return np.r_[base, np.zeros(self.n_r + self.n_h)]

    def model(self, x: F64) -> GroundModel:
        n = self.n0 + x[1] * self.e1 + x[2] * self.e2
        c = self.c0 + (x[4] * self.c_scale * self.c_dir if self.fit_c else 0.0)
        return GroundModel(float(np.exp(x[0])), np.asarray(c, float), n / np.linalg.norm(n),
                           float(np.exp(x[3])))

    def offsets(self, x: F64) -> F64:
        off = self.obs.offset
        if self.n_r:
            # column 0 (shoulder centre) anchors the scale; the others' ratios are refined
            off = off * np.exp(np.r_[0.0, x[self.n_base:self.n_base + self.n_r]])[None, :]
        if self.n_h:
            eta = np.r_[x[self.n_base + self.n_r:], 0.0]  # index -1 -> no height parameter
            off = off * np.exp(eta[self.hg])[:, None]
        return off

    def pixel_residuals(self, x: F64) -> F64:
        """Ankle corrections (N, 2) then upper-point residuals (valid, 2), flattened (px).

        The ankle pixels are re-estimated for every evaluation (variable projection): the
        residual is that of the best ankle, so ankle noise is treated like upper-point noise.
        """
        model, off = self.model(x), self.offsets(x)
        lean = self.lean(x, model, off)
        ankle = model.corrected_ankles(self.obs, off, sideways=self.sideways,
                                       along_weight=self.w_along, lean=lean)
        pred = model.predict_upper(ankle, off, lean)
        da = ankle - self.obs.ankle
        ra = np.stack([np.sum(da * self.along, 1), self.sideways * np.sum(da * self.across, 1)],
                      1)
        ru = weigh_along(pred - self.obs.upper, self.along, self.across, self.w_along)
        r = np.r_[ra.ravel(), ru[self.valid].ravel()]
        return np.where(np.isfinite(r), r, _MISS_PX)

    def lean(self, x: F64, model: GroundModel, off: F64) -> F64 | None:
        """Forward displacement (N, K, 3) of the upper points: the lean per unit speed times
        the walking velocity times each point's height above the hips (none below them)."""
        if not self.fit_lean:
            return None
        lever = np.clip(off - self.lean_pivot * off[:, :1], 0.0, None)
        lever = np.where(np.isfinite(lever), lever, 0.0)
        return x[self.i_lean] * lever[..., None] * model.velocities(self.obs)[:, None, :]

    def __call__(self, x: F64) -> F64:
        b, r = self.n_base, self.n_r
        out = [self.pixel_residuals(x), self.ratio_w * x[b:b + r], self.prior_w * x[b + r:]]
        if self.fit_lean:
            out.append([self.lean_w * x[self.i_lean]])  # type: ignore[arg-type]
        return np.concatenate(out)

    def row_detections(self) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
        """Detection and upper column (-1: ankle) of every pixel-residual row."""
        n = self.obs.n
        det, col = (np.repeat(v, 2) for v in np.nonzero(self.valid))
        return (np.r_[np.repeat(np.arange(n), 2), det].astype(np.int64),
                np.r_[np.full(2 * n, -1), col].astype(np.int64))

    def sparsity(self) -> lil_matrix:
        det, col = self.row_detections()
        n_res = len(det)
        n_extra = self.n_r + self.n_h
        n_lean = 1 if self.fit_lean else 0
        S = lil_matrix((n_res + n_extra + n_lean, self.n_base + n_extra), dtype=int)
        S[:n_res, : self.n_base] = 1
        rows = np.arange(n_res)
        ratio_rows = col > 0
        if self.n_r:
            S[rows[ratio_rows], self.n_base + col[ratio_rows] - 1] = 1
            # the corrected ankle depends on every upper point of its detection
            S[rows[col < 0], self.n_base:self.n_base + self.n_r] = 1
        has = self.hg[det] >= 0
        S[rows[has], self.n_base + self.n_r + self.hg[det][has]] = 1
        S[n_res + np.arange(n_extra), self.n_base + np.arange(n_extra)] = 1
        if n_lean:
            S[n_res + n_extra, self.i_lean] = 1
        return S


def _robust_sigma(r: F64) -> float:
    r = r[np.abs(r) < _MISS_PX]
    return float(1.4826 * np.median(np.abs(r))) if r.size else 1.0


def _covariance(J: F64, r: F64, clusters: NDArray[np.int64], n_params: int,
                per_cluster: float = 1.0, key: slice = slice(0, 1)) -> F64:
    """Classic or cluster-sandwich covariance, whichever gives the ``key`` parameters (default
    ``log f``) the larger total variance."""
    H = J.T @ J
    # a (near-)singular normal matrix means an unobservable parameter: infinite variance, not
    # the pseudo-inverse's silent zero
    d = np.sqrt(np.maximum(np.diag(H), 1e-300))
    Hn = H / d[:, None] / d[None, :]
    if not np.all(np.isfinite(Hn)) or np.linalg.cond(Hn) > 1e12:
        return np.full_like(H, np.inf)
    Hinv = np.linalg.inv(Hn) / d[:, None] / d[None, :]
    dof = max(len(r) - n_params, 1)
    classic = Hinv * float(r @ r) / dof
    scores = J * r[:, None]
    uniq, inv = np.unique(clusters, return_inverse=True)
    if len(uniq) < 5:
        # too few clusters for the sandwich: count each cluster as one observation (frames of
        # a person at one spot repeat the same information)
        return classic * max(per_cluster, 1.0)
    S = np.zeros((len(uniq), J.shape[1]))
    np.add.at(S, inv, scores)
    sandwich = Hinv @ (S.T @ S) @ Hinv * len(uniq) / (len(uniq) - 1)
    # the focal length (parameter 0) is what the interval is reported for
    return sandwich if np.trace(sandwich[key, key]) > np.trace(classic[key, key]) else classic


def _solve(prob: _Problem, model: GroundModel, fit_focal: bool, sparse: bool, *, loss: str,
           f_scale: float, max_nfev: int) -> tuple[F64, F64, Any]:
    """Run the least squares, optionally with ``log f`` (parameter 0) held at ``model.f``.

    Returns
    -------
    x : ndarray
        All parameters (``log f`` included).
    J : ndarray, shape (n_residuals, n_free)
        Dense Jacobian of the free parameters (``log f`` column dropped when held).
    res : OptimizeResult
    """
    x0 = prob.x0(model)
    free = slice(0, None) if fit_focal else slice(1, None)

    def fun(y: F64) -> F64:
        return prob(np.r_[x0[:free.start], y])

    # grouped (sparse) differencing pays off only with many per-person height columns
    kw = dict(jac_sparsity=prob.sparsity()[:, free]) if sparse else {}
    res = least_squares(fun, x0[free], loss=loss, f_scale=f_scale, x_scale="jac",
                        max_nfev=max_nfev, ftol=1e-8, xtol=1e-10, **kw)
    logger.debug("refine: %d residuals, %d params, %d evaluations, status %d", len(res.fun),
                 len(res.x), res.nfev, res.status)
    # dense for the covariance: 3-6 columns + one per refined ratio and tracked person
    J = res.jac.toarray() if hasattr(res.jac, "toarray") else np.asarray(res.jac)
    return np.r_[x0[:free.start], res.x], J, res


def refine(obs: Observations, model: GroundModel, *, fit_principal_point: bool,
           track_heights: bool, height_sd_rel: float, min_track_detections: int,
           fit_ratios: bool, ratio_sd_rel: float,
           clusters: NDArray[np.int64], image_diag: float, loss: str = "huber",
           f_scale: float = 2.0, max_nfev: int = 100, ankle_sideways: float = 1.0,
           height_nuisance: bool = False, fit_focal: bool = True, lean_sd: float = 0.0,
           lean_pivot: float = 0.0) -> RefineResult:
    """Nonlinear least squares on all inliers (see module docstring).

    Parameters
    ----------
    obs : Observations
        Inlier detections (N).
    model : GroundModel
        Starting point (DLT on the inliers).
    fit_principal_point : bool
        Also estimate the principal point's component along the horizon (the other component
        is not observable from people on a plane: it trades off against the focal length).
    track_heights : bool
        One height multiplier per person (``obs.group`` >= 0 with at least
        ``min_track_detections`` detections), with prior sd ``height_sd_rel`` (relative).
    fit_ratios : bool
        Refine the height ratio of every upper point but the first (shoulder centre), with
        prior sd ``ratio_sd_rel`` (relative): detectors place the neck differently.
    clusters : ndarray of int, shape (N,)
        Independence clusters for the sandwich covariance.
    image_diag : float
        Image diagonal (px), scales the principal-point parameters.
    loss, f_scale : str, float
        Robust loss and its scale in robust residual s.d. of the starting model.
    ankle_sideways : float
        Weight of the ankle's position across the body axis relative to along it.
    height_nuisance : bool
        Treat the height of persons without their own height parameter as uncertain (relative
        s.d. ``height_sd_rel``): down-weights residuals along their body axis accordingly.
    fit_focal : bool
        False holds the focal length at ``model.f`` (known intrinsics): ``log_f_sd`` is then 0
        and only the plane (and heights, ratios) is estimated.
    lean_sd : float
        Prior s.d. (s/m) of the walkers' forward lean per unit walking speed, estimated when
        positive and ``obs.motion`` is given; 0 keeps everyone upright (the paper's model).
    lean_pivot : float
        Height of the lean's pivot (the hips) as a fraction of the first upper point's offset.
    """
    hg = np.full(obs.n, -1, dtype=np.int64)
    ids: NDArray[np.int64] = np.zeros(0, dtype=np.int64)
    if track_heights:
        g, counts = np.unique(obs.group[obs.group >= 0], return_counts=True)
        ids = g[counts >= min_track_detections]
        hg = np.where(np.isin(obs.group, ids), np.searchsorted(ids, obs.group), -1)
    along, across = body_axes(obs)
    r0 = weigh_along(model.residuals(obs), along, across, np.ones(obs.upper.shape[:2]))
    # pixel noise from the residuals across the body axis, which unknown heights do not touch
    sigma0 = _robust_sigma(r0[..., 1][obs.valid])
    prior_w = max(sigma0, 0.05) / height_sd_rel
    n_r = obs.upper.shape[1] - 1 if fit_ratios else 0
    prob = _Problem(obs, model, fit_principal_point, hg, len(ids), prior_w,
                    n_r, max(sigma0, 0.05) / ratio_sd_rel, image_diag, ankle_sideways,
                    lean_w=max(sigma0, 0.05) / lean_sd if lean_sd > 0 else 0.0,
                    lean_pivot=lean_pivot)
    if height_nuisance:
        # persons without a height of their own: their unknown height error (relative s.d.
        # height_sd_rel) stretches the residual along the body axis by height_sd_rel * length;
        # marginalised, it divides that component by sqrt(1 + (height_sd_rel L / sigma)^2)
        length = np.linalg.norm(obs.upper - obs.ankle[:, None, :], axis=-1)
        w = 1.0 / np.sqrt(1.0 + (height_sd_rel * length / max(sigma0, 0.05)) ** 2)
        prob.w_along = np.where(np.isfinite(w) & (hg[:, None] < 0), w, 1.0)
    x, J, res = _solve(prob, model, fit_focal, len(ids) > 8, loss=loss,
                       f_scale=max(f_scale * sigma0, 0.05), max_nfev=max_nfev)
    fitted = prob.model(x)
    if not fit_focal:
        fitted = replace(fitted, f=model.f)  # exactly, not exp(log f)
    r_px = prob.pixel_residuals(x)
    det, _ = prob.row_detections()
    clus = np.r_[clusters[det], -1 - np.arange(n_r + len(ids) + int(prob.fit_lean))]
    r_all = np.r_[r_px, res.fun[len(r_px):]]
    n_clusters = len(np.unique(clusters)) if len(clusters) else 1
    # with the focal held, the interval that matters is the normal's (reduced columns 0, 1)
    cov = _covariance(J, r_all, clus, J.shape[1], per_cluster=obs.n / n_clusters,
                      key=slice(0, 1) if fit_focal else slice(0, 2))
    sd = np.sqrt(np.maximum(np.diag(cov), 0.0))
    if not fit_focal:
        sd = np.r_[0.0, sd]  # log f is exact
    c_sd = np.abs(sd[4] * image_diag * prob.c_dir) if fit_principal_point else np.zeros(2)
    b = prob.n_base
    heights = {int(i): float(np.exp(v)) for i, v in zip(ids, x[b + n_r:], strict=True)}
    ratios = np.exp(np.r_[0.0, x[b:b + n_r], np.zeros(obs.upper.shape[1] - 1 - n_r)])
    return RefineResult(fitted, float(sd[0]), c_sd, float(np.degrees(np.hypot(sd[1], sd[2]))),
                        _robust_sigma(r_px), float(np.sum(r_px[np.abs(r_px) < _MISS_PX] ** 2)),
                        heights, ratios, float(x[prob.i_lean]) if prob.fit_lean else 0.0)
