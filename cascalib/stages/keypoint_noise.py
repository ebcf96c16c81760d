"""How keypoint noise grows with the person's size in the image.

A pose detector's error scales with the person it sees: COCO's keypoint similarity (OKS) is
defined relative to the object's scale for that reason, and a person close to the camera is
located to several pixels where a distant one is located to one or two. A reprojection graph that
weighs every keypoint by one pixel noise level trusts the large, near persons too much, and that
is not only inefficient: a near camera dominates the triangulation of its persons, their noise
passes into the 3D points and so into the other cameras, and with the principal point free it
moved every camera the same way. Measured on the simulated crowd (15 people, 640 x 480 cameras,
noise ``1 px + 0.008 x person height``), refining from the true rig: principal points 2-9 px off,
all upwards, and relative rotations 0.75 / 1.10 deg (median / max); 0.94 / 1.32 with 8000
person-frames instead of 2400, so a bias, not noise. With this model: 0.17 / 0.23 and
0.15 / 0.19.

The model is ``sigma(h)^2 = a + b h^2`` for a person ``h`` pixels tall, fitted to the
triangulation residuals of the person-frames in the graph (no detector is assumed). The fit has
to undo what the triangulation does: the view that dominates a point has a small residual
whatever its noise (on that scene the raw residuals *fell* from 1.4 px for persons 53 px tall
to 0.7 px at 260 px), so each residual is compared with its expectation through the hat matrix
(:func:`residual_gains`). The graph uses the model as a *relative* weight per view, so that its
overall noise level stays what the graduated solve sets.
"""

from __future__ import annotations

import logging

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import nnls

from cascalib.camera import Camera
from cascalib.stages.triangulation import huber_weight

__all__ = ["fit_size_noise", "person_pixel_height", "residual_gains", "size_noise_scale",
           "triangulation_weights"]

log = logging.getLogger(__name__)

#: Most joints the fit uses (an even subset beyond).
_MAX_POINTS = 12000
#: The relative weights are clipped to this range: the fit extrapolates at the extremes.
_SCALE_RANGE = (0.25, 4.0)


def person_pixel_height(points: NDArray[np.float64], cameras: list[Camera], height: float
                        ) -> NDArray[np.float64]:
    """Height (px) of each person-frame in each camera, ``f * height / depth``.

    Parameters
    ----------
    points : ndarray, shape (S, J, 3)
        Triangulated joints (world, metres); NaN joints are skipped.
    cameras : list of Camera
    height : float
        Person height (m).

    Returns
    -------
    ndarray, shape (S, C)
        NaN where the person-frame has no joint or is behind the camera.
    """
    with np.errstate(invalid="ignore"):  # all-NaN person-frames
        centre = np.nanmedian(points, axis=1)  # (S, 3)
    out = np.full((points.shape[0], len(cameras)), np.nan)
    for c, cam in enumerate(cameras):
        depth = (centre @ cam.R.T + cam.t)[:, 2]
        with np.errstate(invalid="ignore", divide="ignore"):
            out[:, c] = np.where(depth > 0, cam.focal * height / depth, np.nan)
    return out


def triangulation_weights(errors: NDArray[np.float64], confidence: NDArray[np.float64],
                          huber_px: float) -> NDArray[np.float64]:
    """Weights of the squared pixel residuals in :func:`cascalib.stages.triangulation.triangulate`
    at its solution: squared confidence, times Huber's weight beyond ``huber_px``; 0 where the
    error is not finite (unobserved)."""
    w = np.nan_to_num(confidence) ** 2 * huber_weight(errors, huber_px)
    return np.where(np.isfinite(errors), w, 0.0)


def residual_gains(points: NDArray[np.float64], cameras: list[Camera],
                   weights: NDArray[np.float64]) -> NDArray[np.float64]:
    """How each view's noise reaches each view's triangulation residual.

    For a point triangulated by weighted least squares from views with noise ``n_d``
    (isotropic, s.d. ``sigma_d``), the residual of view ``c`` is ``r_c = sum_d A_cd n_d`` with
    ``A = I - H`` and ``H`` the hat matrix of the linearised projections, so
    ``E|r_c|^2 = sum_d G_cd sigma_d^2`` with ``G_cd = ||A_cd||_F^2``. A view that dominates the
    point (a near camera: more pixels per metre) has a small residual whatever its noise; this
    is what lets a fit recover the noise of such views.

    Parameters
    ----------
    points : ndarray, shape (N, 3)
        Triangulated points (world).
    cameras : list of Camera, length C
    weights : ndarray, shape (C, N)
        Weights of the squared pixel residuals in the triangulation; 0 where unobserved.

    Returns
    -------
    ndarray, shape (N, C, C)
        ``G``; NaN rows for points with fewer than two weighted views or behind a camera.
    """
    n, n_c = points.shape[0], len(cameras)
    jac = np.zeros((n, n_c, 2, 3))
    for c, cam in enumerate(cameras):
        p = points @ cam.R.T + cam.t
        z = p[:, 2]
        with np.errstate(invalid="ignore", divide="ignore"):
            d = np.zeros((n, 2, 3))
            d[:, 0, 0] = d[:, 1, 1] = 1.0 / z
            d[:, 0, 2], d[:, 1, 2] = -p[:, 0] / z**2, -p[:, 1] / z**2
        jac[:, c] = cam.focal * d @ cam.R  # pixels per metre, pinhole
    w = np.nan_to_num(weights.T)  # (N, C)
    jac = np.where((w > 0)[..., None, None], jac, 0.0)
    info = np.einsum("nc,ncki,nckj->nij", w, jac, jac)
    good = np.isfinite(info).all((1, 2)) & ((w > 0).sum(1) >= 2)
    good[good] &= np.linalg.cond(info[good]) < 1e12
    cov = np.full(info.shape, np.nan)
    cov[good] = np.linalg.inv(info[good])
    # H_cd = J_c cov J_d^T w_d, as (N, 2C, 2C) matrix products
    flat = jac.reshape(n, 2 * n_c, 3)
    hat = flat @ cov @ flat.transpose(0, 2, 1) * np.repeat(w, 2, axis=1)[:, None, :]
    a = np.eye(2 * n_c) - hat
    return (a**2).reshape(n, n_c, 2, n_c, 2).sum(axis=(2, 4))


def fit_size_noise(errors: NDArray[np.float64], gains: NDArray[np.float64],
                   size_px: NDArray[np.float64], *, n_iter: int = 4
                   ) -> tuple[float, float] | None:
    """Fit ``sigma(h)^2 = a + b h^2`` (px^2) to triangulation residuals.

    Parameters
    ----------
    errors : ndarray, shape (N, C)
        Reprojection error (px) of each observation, NaN where unobserved.
    gains : ndarray, shape (N, C, C)
        :func:`residual_gains` of the points.
    size_px : ndarray, shape (N, C)
        Person height in each view (px).
    n_iter : int
        Reweighting rounds: each drops observations beyond the 99 % point of their predicted
        error (outliers, wrong associations) and weighs the rest by the inverse of their
        predicted spread.

    Returns
    -------
    (a, b) or None
        None when fewer than 100 observations can be used.
    """
    h2 = np.where(np.isfinite(size_px), size_px, 0.0) ** 2
    f1 = np.nansum(gains, axis=2)
    f2 = np.nansum(gains * h2[:, None, :], axis=2)
    y = errors**2
    ok = np.isfinite(y) & np.isfinite(gains).all(2) & (f1 > 1e-6)
    if ok.sum() < 100:
        return None
    A, y = np.column_stack([f1[ok], f2[ok]]), y[ok]
    keep, pred = np.ones(len(y), dtype=bool), np.ones(len(y))
    coef = np.zeros(2)
    for _ in range(n_iter):
        wt = 1.0 / np.maximum(pred[keep], 1e-9)
        coef, _ = nnls(A[keep] * wt[:, None], y[keep] * wt)
        pred = A @ coef
        if not np.any(pred > 0):
            return None
        keep = y <= -np.log(0.01) * pred  # |r|^2 / E|r|^2 is about Exp(1) for a 2D residual
    return float(coef[0]), float(coef[1])


def size_noise_scale(errors: NDArray[np.float64], points: NDArray[np.float64],
                     cameras: list[Camera], weights: NDArray[np.float64], height: float
                     ) -> NDArray[np.float64]:
    """Relative keypoint noise of each view of each person-frame.

    Parameters
    ----------
    errors : ndarray, shape (S, C, J)
        Reprojection errors (px) of a triangulation of the person-frames, NaN where unobserved.
    points : ndarray, shape (S, J, 3)
        The triangulated joints.
    cameras : list of Camera, length C
    weights : ndarray, shape (S, C, J)
        Weights of the squared pixel residuals in that triangulation (0 where unobserved).
    height : float
        Person height (m), for the sizes (:func:`person_pixel_height`).

    Returns
    -------
    ndarray, shape (S, C)
        ``sigma(h) / median sigma`` over the observed views, clipped to [0.25, 4]; 1 everywhere
        when the fit has too few observations.
    """
    size = person_pixel_height(points, cameras, height)  # (S, C)
    n_s, n_c, n_j = errors.shape
    pts = points.reshape(-1, 3)
    w = weights.transpose(1, 0, 2).reshape(n_c, -1)
    err = errors.transpose(0, 2, 1).reshape(-1, n_c)  # (S*J, C)
    per_point = np.repeat(size, n_j, axis=0)  # (S*J, C): the group's size for each joint
    ok = np.flatnonzero(np.isfinite(pts).all(1))
    # two parameters: an even subset of the joints fits them as well and costs far less
    ok = ok[np.linspace(0, ok.size - 1, min(ok.size, _MAX_POINTS)).astype(int)] if ok.size else ok
    scale = np.ones((n_s, n_c))
    fit = None
    if ok.size >= 50:
        gains = residual_gains(pts[ok], cameras, w[:, ok])
        fit = fit_size_noise(err[ok], gains, per_point[ok])
    if fit is None:
        return scale
    a, b = fit
    sigma = np.sqrt(a + b * np.where(np.isfinite(size), size, 0.0) ** 2)
    seen = np.isfinite(size) & np.isfinite(errors).any(2)
    ref = float(np.median(sigma[seen])) if seen.any() else 0.0
    if not ref > 0:
        return scale
    log.info("keypoint noise: sigma^2 = %.2f + (%.4f h)^2 px^2", a, np.sqrt(b))
    return np.where(np.isfinite(size), np.clip(sigma / ref, *_SCALE_RANGE), 1.0)
