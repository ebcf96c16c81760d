"""Robust, confidence-weighted multi-view triangulation of many points at once.

Used by stage V three times: to initialise the 3D joints of the factor graph, to check the
consistency of a cross-view association, and to reconstruct every frame with the refined cameras.
The linear (DLT) solution is computed on undistorted, normalised image coordinates so lens
distortion is handled by :meth:`cascalib.camera.Camera.undistort`; iteratively reweighted least
squares with Huber weights on the pixel reprojection error then suppresses outliers
(Hartley & Zisserman, *Multiple View Geometry*, sec. 12.2, with robust reweighting).
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numpy.typing import NDArray

from cascalib.camera import Camera, distort_normalized
from cascalib.geometry import norm_xy

__all__ = ["cauchy_weight", "huber_weight", "reprojection_errors", "triangulate"]

# Points per block of :func:`triangulate`. Measured on 380k points x 4 cameras (one BLAS
# thread, 2 cores), one thread: one block 0.73-0.85 s, blocks of 10k / 25k / 50k / 100k 0.52 /
# 0.54 / 0.64 / 0.76 s (a block's dozen (C, N) temporaries stay in cache); blocks on two threads
# 0.34 s (numpy releases the GIL in the elementwise work and the GEMM that dominate).
BLOCK_POINTS = 16384


def _normal_coefficients(P: NDArray[np.float64]) -> NDArray[np.float64]:
    """Camera part of the DLT normal equations, shape (4, C, 16).

    The rows of view ``c`` are ``x p - a`` and ``y p - b`` (``a, b, p`` the rows of ``P[c]``), so
    their contribution ``w^2 (r1 r1^T + r2 r2^T)`` to the 4x4 normal matrix is linear in four
    per-observation scalars ``(w^2, w^2 x, w^2 y, w^2 (x^2 + y^2))`` with coefficients that
    depend on the camera only: ``aa^T + bb^T``, ``-(pa^T + ap^T)``, ``-(pb^T + bp^T)``, ``pp^T``.
    """
    a, b, p = P[:, 0, :], P[:, 1, :], P[:, 2, :]

    def outer(u: NDArray[np.float64], v: NDArray[np.float64]) -> NDArray[np.float64]:
        return (u[:, :, None] * v[:, None, :]).reshape(len(P), 16)

    return np.stack([outer(a, a) + outer(b, b), -(outer(p, a) + outer(a, p)),
                     -(outer(p, b) + outer(b, p)), outer(p, p)])


def _weighted_dlt(P: NDArray[np.float64], xy: NDArray[np.float64], w: NDArray[np.float64]
                  ) -> NDArray[np.float64]:
    """Batched weighted DLT.

    Parameters
    ----------
    P : ndarray, shape (C, 3, 4)
        Normalised projection matrices ``[R | t]``.
    xy : ndarray, shape (C, N, 2)
        Normalised coordinates (NaN where missing).
    w : ndarray, shape (C, N)
        Weights (0 where missing).

    Returns
    -------
    X : ndarray, shape (N, 3)
        NaN where fewer than two views have weight or the views are degenerate.
    """
    n_cams, n = w.shape
    x, y = np.nan_to_num(xy[..., 0]), np.nan_to_num(xy[..., 1])  # (C, N)
    # the four scalars per observation as contiguous (C, N) rows: 7x faster to fill than (N, 4, C)
    S = np.empty((4, n_cams, n))
    np.multiply(w, w, out=S[0])
    np.multiply(S[0], x, out=S[1])
    np.multiply(S[0], y, out=S[2])
    S[3] = S[1] * x + S[2] * y
    # the normal equations of every point in one GEMM: (16, 4C) @ (4C, N), 4x faster than
    # accumulating batched (4, C) @ (C, 4) products
    m = _normal_coefficients(P).reshape(-1, 16).T @ S.reshape(4 * n_cams, n)  # (16, N)
    # inhomogeneous form (X, 1): A X = b with A = M[:3, :3] (symmetric), b = -M[:3, 3],
    # solved by the adjugate (Cramer), vectorised over the points
    a00, a01, a02, a11, a12, a22 = m[0], m[1], m[2], m[5], m[6], m[10]
    b0, b1, b2 = -m[3], -m[7], -m[11]
    c00, c01, c02 = a11 * a22 - a12 * a12, a02 * a12 - a01 * a22, a01 * a12 - a02 * a11
    c11, c12, c22 = a00 * a22 - a02 * a02, a01 * a02 - a00 * a12, a00 * a11 - a01 * a01
    det = a00 * c00 + a01 * c01 + a02 * c02
    scale = np.maximum.reduce([np.abs(v) for v in (a00, a01, a02, a11, a12, a22)])
    good = ((w > 0).sum(0) >= 2) & (np.abs(det) > 1e-12 * scale**3)
    with np.errstate(invalid="ignore", divide="ignore"):
        inv = np.where(good, 1.0 / det, np.nan)
    return np.stack([(c00 * b0 + c01 * b1 + c02 * b2) * inv,
                     (c01 * b0 + c11 * b1 + c12 * b2) * inv,
                     (c02 * b0 + c12 * b1 + c22 * b2) * inv], axis=-1)


def huber_weight(errors: NDArray[np.float64], k: float) -> NDArray[np.float64]:
    """Huber's weight of a squared residual of norm ``errors``: 1 up to ``k``, ``k / errors``
    beyond (``k > 0``; NaN stays NaN)."""
    return k / np.maximum(errors, k)


def cauchy_weight(errors: NDArray[np.float64], k: float) -> NDArray[np.float64]:
    """Cauchy's weight of a squared residual of norm ``errors``: ``1 / (1 + (errors / k)^2)``
    (``k > 0``; NaN stays NaN). Unlike Huber's, it falls with the square of the distance, so
    that far outliers (wrong persons, swapped joints) lose their pull instead of keeping one
    that grows with their distance."""
    return 1.0 / (1.0 + (errors / k) ** 2)


def reprojection_errors(cameras: list[Camera], X: NDArray[np.float64], uv: NDArray[np.float64]
                        ) -> NDArray[np.float64]:
    """Pixel distance between observations and reprojected points.

    Parameters
    ----------
    cameras : list of Camera, length C
    X : ndarray, shape (N, 3)
    uv : ndarray, shape (C, N, 2)

    Returns
    -------
    ndarray, shape (C, N)
        NaN where the observation or the point is missing (or behind the camera).
    """
    rows = np.ascontiguousarray(X.T)  # once for all cameras
    proj = np.stack([_project(cam, rows) for cam in cameras])
    return norm_xy(proj - uv)


def _project(cam: Camera, rows: NDArray[np.float64]) -> NDArray[np.float64]:
    """:meth:`Camera.project` of points given as contiguous coordinate rows (3, N), returning
    (N, 2): einsum and the divisions on rows are 5x faster than on the columns of (N, 3), and
    BLAS matmul of tall (N, 3) arrays is slower still on a busy machine."""
    Xc = np.einsum("ij,jn->in", cam.R, rows)
    Xc += cam.t[:, None]
    z = Xc[2]
    with np.errstate(invalid="ignore", divide="ignore"):
        front = z > 0
        x = np.where(front, Xc[0] / z, np.nan)
        y = np.where(front, Xc[1] / z, np.nan)
    if cam.has_distortion:
        xy = distort_normalized(np.stack([x, y], axis=-1), cam.dist)
        x, y = xy[:, 0], xy[:, 1]
    K = cam.K
    return np.stack([K[0, 0] * x + K[0, 1] * y + K[0, 2], K[1, 1] * y + K[1, 2]], axis=-1)


def triangulate(cameras: list[Camera], uv: NDArray[np.float64], conf: NDArray[np.float64] | None
                = None, *, huber_px: float = 4.0, n_iter: int = 3, min_views: int = 2,
                workers: int = 2) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Triangulate N points seen by up to C cameras, robustly.

    Parameters
    ----------
    cameras : list of Camera, length C
    uv : ndarray, shape (C, N, 2)
        Pixel observations, NaN where not seen.
    conf : ndarray, shape (C, N), optional
        Detection confidences (weights of the first solve); default 1.
    huber_px : float
        Huber threshold of the reprojection error (pixels) for the reweighting.
    n_iter : int
        Reweighting iterations after the first linear solve.
    min_views : int
        Points seen by fewer views are NaN.
    workers : int
        Threads over blocks of :data:`BLOCK_POINTS` points (1: in this thread); the points are
        independent, so the result does not depend on it.

    Returns
    -------
    X : ndarray, shape (N, 3)
        World points (NaN where not triangulable or behind a camera).
    errors : ndarray, shape (C, N)
        Reprojection error of each observation (px), NaN where unobserved.
    """
    uv = np.asarray(uv, dtype=np.float64)
    n_cams, n = uv.shape[:2]
    if n == 0:
        return np.zeros((0, 3)), np.zeros((n_cams, 0))
    if conf is not None:
        conf = np.asarray(conf, dtype=np.float64)
    kw = dict(huber_px=huber_px, n_iter=n_iter, min_views=min_views)
    if n <= BLOCK_POINTS:
        return _triangulate_block(cameras, uv, conf, **kw)  # type: ignore[arg-type]
    blocks = [slice(i, i + BLOCK_POINTS) for i in range(0, n, BLOCK_POINTS)]

    def one(b: slice) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        return _triangulate_block(cameras, uv[:, b], None if conf is None else conf[:, b], **kw)  # type: ignore[arg-type]

    if workers > 1:
        with ThreadPoolExecutor(max_workers=min(workers, len(blocks))) as pool:
            parts = list(pool.map(one, blocks))
    else:
        parts = [one(b) for b in blocks]
    return (np.concatenate([p[0] for p in parts]),
            np.concatenate([p[1] for p in parts], axis=1))


def _triangulate_block(cameras: list[Camera], uv: NDArray[np.float64],
                       conf: NDArray[np.float64] | None, *, huber_px: float, n_iter: int,
                       min_views: int) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """:func:`triangulate` of one block of points (``uv`` (C, N, 2), N >= 1)."""
    n_cams, n = uv.shape[:2]
    seen = np.isfinite(uv[..., 0]) & np.isfinite(uv[..., 1])  # not .all(-1): a slow reduce
    c0 = np.ones((n_cams, n)) if conf is None else np.nan_to_num(conf)  # float64: triangulate
    c0 = np.where(seen, np.clip(c0, 1e-3, None), 0.0)
    xy = np.stack([cam.undistort(uv[i]) for i, cam in enumerate(cameras)])
    seen &= np.isfinite(xy[..., 0]) & np.isfinite(xy[..., 1])
    c0 = np.where(seen, c0, 0.0)
    P = np.stack([np.hstack([cam.R, cam.t[:, None]]) for cam in cameras])
    # a DLT row is scaled by the depth: divide by it (from the previous solution) so weights
    # act on image-plane errors; focal converts normalised units to pixels
    focal = np.array([cam.focal for cam in cameras])[:, None]
    w = c0 * focal
    X = _weighted_dlt(P, xy, w)
    for _ in range(n_iter):
        depth = np.einsum("cj,jn->cn", P[:, 2, :3], np.nan_to_num(X).T.copy()) + P[:, 2, 3][:, None]
        err = reprojection_errors(cameras, X, uv)
        err = np.where(seen, np.nan_to_num(err, nan=1e6), 0.0)
        huber = huber_weight(err, huber_px)
        # weights on squared residuals: sqrt for the linear rows
        w = c0 * focal * np.sqrt(huber) / np.maximum(np.abs(depth), 1e-3)
        w = np.where(seen & (depth > 0), w, 0.0)
        X = _weighted_dlt(P, xy, w)
    n_views = seen.sum(0)
    X[n_views < min_views] = np.nan
    errors = np.where(seen, reprojection_errors(cameras, X, uv), np.nan)
    # an observation whose point lies behind its camera is an outlier, not a missing value
    behind = np.isnan(errors) & seen & np.isfinite(X).all(-1)[None]  # type: ignore[index]
    errors[behind] = np.inf
    return X, errors
