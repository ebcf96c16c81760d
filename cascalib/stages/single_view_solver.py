"""Focal length and ground plane of one camera from upright people: model, DLT, RANSAC, refinement.

Geometry (camera coordinates, OpenCV axes, metres). A standing person's ankle point ``A`` lies on
the *ankle plane* ``n . A = -d`` (``n`` the unit ground normal pointing up, ``d`` > 0 the distance
from the camera centre to that plane); an upper body point ``k`` (shoulder centre, neck, head
top) lies straight above it, ``U_k = A + delta_k n``, with ``delta_k`` its vertical distance from
the ankle in metres. With ``K = [[f, 0, cx], [0, f, cy], [0, 0, 1]]`` the pixels are
``a ~ K A`` and ``u_k ~ K U_k``.

The linear solve is the DLT of the CasCalib supplement (Eq. "cross_prod"/"DLT"): the cross
product ``u_k x (w a + delta_k m) = 0`` with ``m ~ K n`` (the vertical vanishing point) and
``w`` the ankle depth, generalised to any number of upper points per person. The per-person
depths are eliminated in closed form, so the solve is a 3x3 eigenproblem whatever the number of
detections, and pixels are Hartley-normalised (centred on the principal point, isotropically
scaled) first. The focal length then follows from the ankles being coplanar (supplement, "Ground
normal extraction"), as a least-squares solve over all ankles instead of one ankle pair.

References
----------
CasCalib paper, section "Single View Geometric Calibration" and supplement "Camera Calibration
Derivation - Details". R. Hartley, "In defense of the eight-point algorithm", PAMI 1997.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from cascalib.geometry import skew

__all__ = [
    "GroundModel",
    "Observations",
    "hartley_scale",
    "vanishing_point",
    "dlt_estimate",
    "grid_estimate",
    "inlier_errors",
]

F64 = NDArray[np.float64]


@dataclass(frozen=True)
class Observations:
    """Ankle/upper-point pixel pairs of upright persons.

    Parameters
    ----------
    ankle : ndarray, shape (N, 2)
        Ankle-centre pixel of each detection.
    upper : ndarray, shape (N, K, 2)
        Upper points (e.g. shoulder centre, neck, head top) in pixels; NaN where missing.
    offset : ndarray, shape (N, K)
        Vertical distance (m) of each upper point above the ankle point; NaN where missing.
    group : ndarray of int, shape (N,)
        Person (track) of each detection, for shared heights and clustered uncertainty;
        every detection its own group when persons are not tracked.
    motion : ndarray, shape (N, 2, 2), optional
        Ankle-centre pixels of the same person about ``motion_dt / 2`` before and after (NaN
        where not found): the walking velocity, for the forward lean of walkers.
    motion_dt : ndarray, shape (N,), optional
        Time (s) between the two pixels of ``motion``.
    """

    ankle: F64
    upper: F64
    offset: F64
    group: NDArray[np.int64]
    motion: F64 | None = None
    motion_dt: F64 | None = None

    @property
    def n(self) -> int:
        return int(self.ankle.shape[0])

    @property
    def valid(self) -> NDArray[np.bool_]:
        """(N, K): upper point present."""
        return np.isfinite(self.upper[..., 0]) & np.isfinite(self.offset)

    def take(self, idx: NDArray[np.int64] | NDArray[np.bool_]) -> Observations:
        """Subset of detections."""
        return Observations(self.ankle[idx], self.upper[idx], self.offset[idx], self.group[idx],
                            None if self.motion is None else self.motion[idx],
                            None if self.motion_dt is None else self.motion_dt[idx])

    def pixel_height(self) -> F64:
        """(N,) pixel height of each person: distance from the ankle to the highest upper point.

        Used to normalise the paper's pixel inlier test (5 % of the person's pixel height).
        """
        dist = np.linalg.norm(self.upper - self.ankle[:, None, :], axis=-1)
        with np.errstate(invalid="ignore", divide="ignore"):
            k = np.nanargmax(np.where(self.valid, self.offset, -np.inf), axis=1)
            rows = np.arange(self.n)
            # the ankle-to-highest-point length: with the paper's ankle-shoulder pairs this is
            # the pixel height the paper normalises by (slightly conservative for head tops)
            return dist[rows, k]


@dataclass(frozen=True)
class GroundModel:
    """Pinhole intrinsics (square pixels, no skew) and the ankle plane in camera coordinates.

    Parameters
    ----------
    f : float
        Focal length (px).
    c : ndarray, shape (2,)
        Principal point (px).
    n : ndarray, shape (3,)
        Unit ground normal in camera coordinates, pointing up (away from the ground).
    d : float
        Distance (m) from the camera centre to the ankle plane.
    """

    f: float
    c: F64
    n: F64
    d: float

    def ankle_points(self, ankle: F64) -> F64:
        """Back-project ankle pixels (..., 2) onto the ankle plane: camera points (..., 3).

        NaN where the ray misses the plane (above the horizon).
        """
        r = np.concatenate([(ankle - self.c) / self.f, np.ones(ankle.shape[:-1] + (1,))], -1)
        with np.errstate(invalid="ignore", divide="ignore"):
            s = -self.d / (r @ self.n)
        s = np.where(s > 0, s, np.nan)
        return s[..., None] * r

    def predict_upper(self, ankle: F64, offset: F64, lean: F64 | None = None) -> F64:
        """Predicted upper pixels (N, K, 2) for ankles (N, 2) and vertical offsets (N, K) in m;
        ``lean`` (N, K, 3) adds a horizontal displacement (m, camera coordinates)."""
        A = self.ankle_points(ankle)
        U = A[:, None, :] + offset[..., None] * self.n
        if lean is not None:
            U = U + lean
        with np.errstate(invalid="ignore", divide="ignore"):
            z = np.where(U[..., 2] > 1e-9, U[..., 2], np.nan)
            return self.f * U[..., :2] / z[..., None] + self.c

    def residuals(self, obs: Observations) -> F64:
        """(N, K, 2) predicted minus observed upper pixels (NaN where missing)."""
        return self.predict_upper(obs.ankle, obs.offset) - obs.upper

    def corrected_ankles(self, obs: Observations, offset: F64 | None = None,
                         eps: float = 0.5, sideways: float = 1.0,
                         along_weight: F64 | None = None, lean: F64 | None = None) -> F64:
        """Ankle pixels (N, 2) that best explain ankle *and* upper detections under this model.

        The ankle is as noisy as the upper points; predicting the uppers from the raw ankle
        biases the focal length (errors in variables: near the horizon a pixel of ankle noise
        moves the person far). One Gauss-Newton step per detection on its ankle pixel, minimising
        ``|a - a_obs|^2 + sum_k |u_k(a) - u_k_obs|^2``, vectorised, with the 2x2 Jacobians of
        ``u_k(a)`` by central differences of ``eps`` px. ``sideways`` < 1 down-weights the
        ankle's position across the body axis (see :func:`ankle_weights`); ``along_weight``
        (N, K) scales the upper residuals' components along the body axis; ``lean`` is passed
        to :meth:`predict_upper`.
        """
        off = obs.offset if offset is None else offset
        valid = obs.valid
        base = self.predict_upper(obs.ankle, off, lean)
        r = np.where(valid[..., None], base - obs.upper, 0.0)                   # (N, K, 2)
        D = np.empty(r.shape + (2,))                                           # (N, K, 2, 2)
        for j in range(2):
            step = np.zeros(2)
            step[j] = eps
            D[..., j] = (self.predict_upper(obs.ankle + step, off, lean)
                         - self.predict_upper(obs.ankle - step, off, lean)) / (2 * eps)
        D = np.where(valid[..., None, None] & np.isfinite(D), D, 0.0)
        r = np.where(np.isfinite(r), r, 0.0)
        if along_weight is not None:
            along, across = body_axes(obs)
            r = weigh_along(r, along, across, along_weight)
            D = np.stack([weigh_along(D[..., j], along, across, along_weight)
                          for j in range(2)], -1)
        H = ankle_weights(obs, sideways) + np.einsum("nkij,nkil->njl", D, D)
        g = np.einsum("nkij,nki->nj", D, r)
        delta = -np.linalg.solve(H, g[..., None])[..., 0]
        return obs.ankle + delta

    def velocities(self, obs: Observations) -> F64:
        """Walking velocity (N, 3) on the ankle plane (m/s, camera coordinates) from
        ``obs.motion`` (one-sided, from the detection's own ankle, where one end is missing);
        0 where unknown."""
        if obs.motion is None or obs.motion_dt is None:
            return np.zeros((obs.n, 3))
        P = self.ankle_points(obs.motion)                                      # (N, 2, 3)
        me = self.ankle_points(obs.ankle)
        before, after = P[:, 0], P[:, 1]
        no_b, no_a = ~np.isfinite(before[:, 0]), ~np.isfinite(after[:, 0])
        before = np.where(no_b[:, None], me, before)
        after = np.where(no_a[:, None], me, after)
        dt = np.where(no_b ^ no_a, 0.5 * obs.motion_dt, obs.motion_dt)
        with np.errstate(invalid="ignore", divide="ignore"):
            v = (after - before) / dt[:, None]
        v = v - (v @ self.n)[:, None] * self.n  # on the plane (the points are, up to rounding)
        return np.where(np.isfinite(v), v, 0.0)

    def flipped(self) -> GroundModel:
        return replace(self, n=-self.n)


def body_axes(obs: Observations) -> tuple[F64, F64]:
    """Unit image directions (N, 2) along (ankle to highest upper point) and across the body."""
    k = np.nanargmax(np.where(obs.valid, obs.offset, -np.inf), axis=1)
    v = obs.upper[np.arange(obs.n), k] - obs.ankle
    with np.errstate(invalid="ignore", divide="ignore"):
        along = v / np.linalg.norm(v, axis=1, keepdims=True)
    along = np.where(np.isfinite(along), along, [0.0, -1.0])
    return along, np.stack([-along[:, 1], along[:, 0]], 1)


def weigh_along(v: F64, along: F64, across: F64, w: F64) -> F64:
    """Vectors (N, K, 2) in body-axis components ``(w * along, across)``."""
    return np.stack([w * np.einsum("nki,ni->nk", v, along),
                     np.einsum("nki,ni->nk", v, across)], -1)


def ankle_weights(obs: Observations, sideways: float) -> F64:
    """(N, 2, 2) information matrices of the ankle pixel: 1 along the body axis, ``sideways^2``
    across it. A walking person's ankle centre swings sideways of the vertical through the
    shoulders by several cm (gait, lean); treated as pixel noise of the same size as the upper
    points' it tilts the body axes at random, which pulls the vertical vanishing point towards
    the image and biases the focal length low (by 8-12 % on simulated walkers)."""
    along, across = body_axes(obs)
    return (along[:, :, None] * along[:, None, :]
            + sideways ** 2 * across[:, :, None] * across[:, None, :])


def hartley_scale(points: F64, centre: F64) -> float:
    """Isotropic scale that brings points to mean distance sqrt(2) from ``centre`` (Hartley 1997).

    Only the scale is free: the translation must be the principal point to keep K's structure.
    """
    dist = np.linalg.norm(points.reshape(-1, 2) - centre, axis=1)
    mean = float(np.nanmean(dist)) if np.isfinite(dist).any() else 1.0
    return float(np.sqrt(2.0) / max(mean, 1e-9))


def _homog(p: F64) -> F64:
    return np.concatenate([p, np.ones(p.shape[:-1] + (1,))], -1)


def vanishing_point(obs: Observations, c: F64, scale: float) -> tuple[F64, F64]:
    """Vertical vanishing point ``m ~ K' n`` (normalised pixels) with per-detection depths ``w``.

    Solves the supplement's DLT ``u_k x (w a + delta_k m) = 0`` with ``w`` eliminated: for fixed
    ``m`` the best ``w_i`` is a 1-D least squares, which leaves the 3x3 problem
    ``min |m|=1  m^T (sum_i C_i^T P_i C_i) m``.

    Returns
    -------
    m : ndarray, shape (3,)
        Unit vector, the vertical vanishing point in Hartley-normalised homogeneous pixels.
    w : ndarray, shape (N,)
        Ankle depths up to the common scale of ``m``.
    """
    valid = obs.valid
    a = _homog((obs.ankle - c) * scale)                       # (N, 3)
    u = _homog((np.where(valid[..., None], obs.upper, 0.0) - c) * scale)  # (N, K, 3)
    S = skew(u) * valid[..., None, None]                       # (N, K, 3, 3)
    delta = np.where(valid, obs.offset, 0.0)
    # stacked over k: b_i = [u_k]x a_i (N, K, 3), C_i = delta_k [u_k]x (N, K, 3, 3)
    b = np.einsum("nkij,nj->nki", S, a)
    C = S * delta[..., None, None]
    bb = np.einsum("nki,nki->n", b, b)
    bC = np.einsum("nki,nkij->nj", b, C)                        # (N, 3)
    CC = np.einsum("nkij,nkil->njl", C, C)                      # (N, 3, 3)
    M = (CC - bC[:, :, None] * bC[:, None, :] / np.maximum(bb, 1e-300)[:, None, None]).sum(0)
    _, vecs = np.linalg.eigh(M)
    m = vecs[:, 0]
    w = -(bC @ m) / np.maximum(bb, 1e-300)
    return m, w


def _model_from_vp(m: F64, w: F64, a_n: F64, c: F64, scale: float, f_n: float
                   ) -> GroundModel | str:
    """Ground model from the vanishing point, depths and a normalised focal length ``f_n``."""
    n = np.array([m[0] / f_n, m[1] / f_n, m[2]])
    lam = np.linalg.norm(n) * np.sign(np.median(w))
    if not np.isfinite(lam) or lam == 0:
        return "vanishing point at infinity in every direction"
    n = n / lam
    z = w / lam                                                  # ankle depths (m)
    A = z[:, None] * np.c_[a_n / f_n, np.ones(len(z))]
    d = -float(np.median(A @ n))
    if not d > 0:
        return "ankles and upper points imply the camera is below the ground"
    return GroundModel(float(f_n / scale), c.copy(), n, d)


def dlt_estimate(obs: Observations, c: F64, f_range: tuple[float, float], *,
                 focal: float | None = None) -> GroundModel | str:
    """Closed-form focal length and ankle plane (supplement DLT), or a message saying why not.

    Parameters
    ----------
    obs : Observations
        At least 3 detections at distinct places (2 with a known ``focal``).
    c : ndarray, shape (2,)
        Principal point (px), held fixed as in the paper.
    f_range : (float, float)
        Plausible focal lengths (px); solutions outside are rejected.
    focal : float, optional
        Known focal length (px): only the plane is solved for (the normal is ``K^-1 m``) and
        ``f_range`` is ignored.

    Returns
    -------
    GroundModel or str
        The model, or a message when the system has no valid solution (e.g. negative ``1/f^2``).

    Examples
    --------
    >>> import numpy as np
    >>> obs = Observations(np.array([[0., 500.], [10., 500.], [20., 500.]]),
    ...                    np.array([[[0., 400.]], [[10., 400.]], [[20., 400.]]]),
    ...                    np.ones((3, 1)), np.arange(3))
    >>> dlt_estimate(obs, np.array([960., 540.]), (100., 10000.))  # doctest: +ELLIPSIS
    'focal length ... px outside the plausible range ...'
    """
    scale = hartley_scale(np.concatenate([obs.ankle, obs.upper.reshape(-1, 2)]), c)
    m, w = vanishing_point(obs, c, scale)
    a_n = (obs.ankle - c) * scale
    if focal is not None:
        return _model_from_vp(m, w, a_n, c, scale, focal * scale)
    # coplanar ankles: w_i (g (m_x a_x + m_y a_y) + m_z) = c0 for all i, linear in g = 1/f'^2, c0
    q = a_n @ m[:2]
    Amat = np.c_[w * q, -np.ones(obs.n)]
    rhs = -w * m[2]
    sol, *_ = np.linalg.lstsq(Amat, rhs, rcond=None)
    g = float(sol[0])
    f_lo, f_hi = f_range
    if not (g > 0 and f_lo * scale <= 1 / np.sqrt(g) <= f_hi * scale):
        if not g > 0:
            return f"no real focal length fits these detections (1/f^2 = {g:.3g} < 0)"
        return (f"focal length {1 / np.sqrt(g) / scale:.0f} px outside the plausible range "
                f"[{f_lo:.0f}, {f_hi:.0f}]")
    return _model_from_vp(m, w, a_n, c, scale, 1.0 / np.sqrt(g))


def grid_estimate(obs: Observations, c: F64, f_range: tuple[float, float],
                  n_grid: int = 60) -> GroundModel | str:
    """Focal by a 1-D search: for each candidate ``f`` the normal is ``K^-1 m`` (``m`` the vertical
    vanishing point, which does not depend on ``f``) and the plane distance a median; keep the
    ``f`` with the least median squared reprojection error. No inlier threshold and no sign
    condition on ``1/f^2``, so it rescues noisy few-person scenes where the DLT fails.

    All candidates (both normal signs) are evaluated at once, shape (S=2*n_grid, N, K).
    """
    scale = hartley_scale(np.concatenate([obs.ankle, obs.upper.reshape(-1, 2)]), c)
    m, _ = vanishing_point(obs, c, scale)
    fs = np.geomspace(f_range[0], f_range[1], n_grid)
    n = np.stack([m[0] / (fs * scale), m[1] / (fs * scale), np.full(n_grid, m[2])], -1)
    n /= np.linalg.norm(n, axis=1, keepdims=True)
    fs, n = np.r_[fs, fs], np.r_[n, -n]                                   # (S,), (S, 3)
    valid = obs.valid
    ra = _homog((obs.ankle - c)[None] / fs[:, None, None])                # (S, N, 3)
    up = np.where(valid[..., None], obs.upper, 0.0) - c
    ru = _homog(up[None] / fs[:, None, None, None])                      # (S, N, K, 3)
    ca = np.cross(ru, ra[:, :, None, :])
    cn = np.cross(ru, n[:, None, None, :])
    # s ra + delta n parallel to ru  ->  s (ru x ra) = -delta (ru x n); plane distance -n.(s ra)
    with np.errstate(invalid="ignore", divide="ignore"):
        s_ = -np.einsum("gnki,gnki->gnk", ca, cn) * obs.offset / np.einsum("gnki,gnki->gnk",
                                                                             ca, ca)
        na = np.einsum("gni,gi->gn", ra, n)
        d_all = np.where(valid, -s_ * na[:, :, None], np.nan)
        d_all = np.where(d_all > 0, d_all, np.nan)
        with warnings.catch_warnings():  # candidates with no valid distance: NaN, dropped
            warnings.simplefilter("ignore", RuntimeWarning)
            d = np.nanmedian(d_all.reshape(len(fs), -1), axis=1)         # (S,)
        depth = -d[:, None] / na                                          # ankle ray scale
        U = (depth[..., None] * ra)[:, :, None, :] + obs.offset[None, ..., None] * n[:, None,
                                                                                   None, :]
        pred = fs[:, None, None, None] * U[..., :2] / U[..., 2:3]
        err = np.sum((pred - up[None]) ** 2, -1)
        err = np.where((depth[:, :, None] > 0) & (U[..., 2] > 0), err, np.inf)
        cost = np.where(np.isfinite(d), np.median(np.where(valid, err, np.nan)[:, valid],
                                                  axis=1), np.inf)
    cost = np.where(np.isnan(cost), np.inf, cost)
    best = int(np.argmin(cost))
    if not np.isfinite(cost[best]):
        return "no focal length in range explains the detections"
    return GroundModel(float(fs[best]), c.copy(), n[best], float(d[best]))


def inlier_errors(model: GroundModel, obs: Observations) -> tuple[F64, F64]:
    """The paper's two inlier tests per detection (worst over its upper points).

    Returns
    -------
    rel : ndarray, shape (N,)
        Predicted-minus-observed upper pixel distance over the person's pixel height.
    angle_deg : ndarray, shape (N,)
        Angle (deg) at the ankle between the observed and predicted ankle-to-upper directions.
        Both are ``inf`` where the model cannot predict (ankle above the horizon).
    """
    pred = model.predict_upper(obs.ankle, obs.offset)
    err = np.linalg.norm(pred - obs.upper, axis=-1)
    v_obs = obs.upper - obs.ankle[:, None, :]
    v_pred = pred - obs.ankle[:, None, :]
    with np.errstate(invalid="ignore", divide="ignore"):
        cosang = np.einsum("nki,nki->nk", v_obs, v_pred) / (
            np.linalg.norm(v_obs, axis=-1) * np.linalg.norm(v_pred, axis=-1))
        ang = np.degrees(np.arccos(np.clip(cosang, -1.0, 1.0)))
        rel = err / obs.pixel_height()[:, None]
    valid = obs.valid
    bad = valid & ~np.isfinite(rel)
    rel = np.where(bad, np.inf, rel)
    ang = np.where(bad | (valid & ~np.isfinite(ang)), np.inf, ang)
    rel = np.max(np.where(valid, rel, -np.inf), axis=1)
    ang = np.max(np.where(valid, ang, -np.inf), axis=1)
    return rel, ang
