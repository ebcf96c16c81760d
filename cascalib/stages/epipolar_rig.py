"""Stage IV's last step: the rig from the epipolar geometry of the people's joints.

Stages II-IV place every camera with a similarity on the ground plane, from stage I's focal
length and ground plane. A focal length a few per cent off stretches a camera's ground view
unevenly, and the principal point is taken at the image centre, where real ones lie 1-2 % of
the width away (a 20 px offset at f = 700 px turns the camera by 1.6 deg). The similarity
cannot absorb either.

Once the clocks are right, the joints two cameras see of one person at one instant obey the
epipolar constraint ``x_i^T F_ij x_j = 0``, and ``F_ij`` is a function of the two cameras' focal
lengths, principal points, rotations and centres. This step adjusts all of them together so that
the Sampson distances of every camera pair's joint correspondences are small (a Cauchy loss,
its scale lowered in steps from the starting distances), with no 3D points: ten unknowns per
camera (a radial term stands for lens distortion, see :func:`_radial_directions`), solved by
Levenberg-Marquardt with a Jacobian made pair by pair (each pair depends on two cameras only).
No gtsam factor expresses a Sampson distance of two unknown calibrations, and a Python factor
would cost more than the whole step.

The epipolar geometry says nothing about the ground, the heading of the rig or its size. Priors
hold them where stage IV put them: each camera's tilt around stage I's (stage I measures it from
the people's verticals), the reference camera's heading and ground position fixed, each camera's
height above the ground around stage I's, and the spread of the camera centres (the metric scale
from the people's height) fixed. Focal lengths have a loose prior around stage I's and principal
points one around the image centre (as in Stage V's principal-point pass).

Measured on 24 whole-cascade scenes (terrace, lab ring, crowd, periodic; seeds 0-5; 40 s; real
stage I), the worst value per scene before -> after this step:

=====================================  ===========  ===========
                                       before       after
=====================================  ===========  ===========
relative rotation (deg)                1.07-4.86    0.38-2.38
  scenes above 3 deg                   8            0
centre after similarity alignment (m)  0.10-0.49    0.006-0.13
  scenes above 0.3 m                   8            0
focal length (%)                       1.7-14.9     0.2-2.6
=====================================  ===========  ===========

Stage V from there, on the same 24 scenes: the mean over the scenes of the median rotation
error 0.222 -> 0.219 deg and of the worst 0.354 -> 0.348 deg (11 scenes better, 13 worse; scenes
with median <= 0.3 and worst <= 1 deg 19 -> 21), the worst focal error 0.33 -> 0.29 % and the
worst centre 1.49 -> 1.32 cm on average, and 21 % less CPU time (42.7 -> 33.7 s per scene).

Two scenes got a worse rotation here (crowd seed 1: 1.32 -> 2.38 deg). There the data cost at the
true rig equals the refined rig's: a camera's turn trades against its principal point, and the
priors decide. The principal points are what limits the rotations: with them held at the image
centre the same step left 1-2.5 deg on a periodic scene (0.1-0.6 deg with them free).

References
----------
Hartley, R. & Zisserman, A. *Multiple View Geometry*, 2nd ed.: sec. 9.2 (F of two cameras),
sec. 11.4.3 (Sampson distance).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from functools import partial

import numpy as np
from numpy.typing import NDArray

from cascalib.calibration import Calibration
from cascalib.camera import Camera
from cascalib.geometry import rodrigues_to_matrix, skew
from cascalib.stages.epipolar_sync import (
    EPIPOLAR_JOINTS,
    cauchy_cost,
    first_association,
    pinhole_pixels,
    shared_groups,
)
from cascalib.stages.reconstruct import SessionData, clock_check_times, views_at

__all__ = ["RigRefinement", "fundamental_of", "refine_rig", "signed_sampson"]

log = logging.getLogger(__name__)

#: Unknowns per camera: rotation (3, about the world axes), centre (3, m), log focal,
#: principal point (2, px), radial term.
_N = 10
_ROT, _CENTRE, _FOCAL, _PP, _RADIAL = slice(0, 3), slice(3, 6), 6, slice(7, 9), 9
#: Forward-difference steps of the unknowns (rad, m, log, px; the radial term's derivatives are
#: in closed form).
_STEP = np.array([1e-7, 1e-7, 1e-7, 1e-6, 1e-6, 1e-6, 1e-7, 1e-3, 1e-3, 0.0])


@dataclass(frozen=True)
class RigRefinement:
    """Outcome of :func:`refine_rig`.

    Attributes
    ----------
    calibration : Calibration
        The refined rig (the input's when ``kept`` is False); clocks unchanged.
    kept : bool
        Whether the refinement was taken.
    reason : str
        Why not, when ``kept`` is False.
    cost_before, cost_after : float
        Mean Cauchy loss (px^2) of the Sampson distances over all pairs, at the last scale.
    n_points : dict of str to int
        Joint correspondences per camera pair ("cam0-cam1").
    rotation_change_deg, focal_change : dict of str to float
        Per camera: the angle between the refined and the input rotation, and the focal
        length's relative change.
    radial : dict of str to float
        Per camera: the radial term (0 where the radial terms were not kept).
    """

    calibration: Calibration
    kept: bool
    reason: str
    cost_before: float
    cost_after: float
    n_points: dict[str, int]
    rotation_change_deg: dict[str, float]
    focal_change: dict[str, float]
    radial: dict[str, float]


def fundamental_of(cam_i: Camera, cam_j: Camera) -> NDArray[np.float64]:
    """The fundamental matrix of two pinhole cameras, ``x_i^T F x_j = 0`` (H&Z 9.2)."""
    return _fundamental((cam_i.R, cam_i.center, np.linalg.inv(cam_i.K).astype(np.float64)),
                        (cam_j.R, cam_j.center, np.linalg.inv(cam_j.K).astype(np.float64)))


def _fundamental(a: tuple[NDArray[np.float64], ...], b: tuple[NDArray[np.float64], ...]
                 ) -> NDArray[np.float64]:
    """F of cameras given as (R, centre, K^-1): the rays ``R^T K^-1 x`` from the two centres
    and the baseline are coplanar."""
    (Ri, Ci, Ki_inv), (Rj, Cj, Kj_inv) = a, b
    return Ki_inv.T @ (Ri @ skew(Cj - Ci) @ Rj.T) @ Kj_inv


def signed_sampson(F: NDArray[np.float64], ha: NDArray[np.float64], hb: NDArray[np.float64]
                   ) -> NDArray[np.float64]:
    """Sampson distance (px) of homogeneous pixels ``ha``, ``hb`` (N, 3) to ``x_a^T F x_b = 0``,
    with the sign of the algebraic residual (a least-squares residual needs one)."""
    num, g, _, _ = _sampson_terms(F, ha, hb)
    return num / g


def _sampson_terms(F: NDArray[np.float64], ha: NDArray[np.float64], hb: NDArray[np.float64]
                   ) -> tuple[NDArray[np.float64], ...]:
    """``x_a^T F x_b`` (N,), its gradient norm over the four pixel coordinates (N,), and the
    epipolar lines ``F x_b`` and ``F^T x_a`` (N, 3)."""
    fb = hb @ F.T
    fa = ha @ F
    num = np.einsum("ij,ij->i", ha, fb)
    return num, np.sqrt(fb[:, 0] ** 2 + fb[:, 1] ** 2 + fa[:, 0] ** 2 + fa[:, 1] ** 2), fb, fa


@dataclass(frozen=True)
class _Pair:
    """A pair's correspondences: homogeneous pixels of cameras ``i`` and ``j`` (N, 3), and the
    directions (N, 3) in which their radial terms move them (see :func:`_radial_directions`)."""

    i: int
    j: int
    ha: NDArray[np.float64]
    hb: NDArray[np.float64]
    ra: NDArray[np.float64]
    rb: NDArray[np.float64]

    def points(self, P: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        """The pixels with the radial terms of the changes ``P`` (C, 10) applied."""
        return self.ha + P[self.i, _RADIAL] * self.ra, self.hb + P[self.j, _RADIAL] * self.rb


def _radial_directions(x: NDArray[np.float64], cam: Camera) -> NDArray[np.float64]:
    """``(x - c) r^2`` (N, 3; third column 0) of pixels ``x`` (N, 2), with ``c`` the camera's
    principal point and ``r`` their distance from it in focal lengths: a radial term ``k``
    moves a pixel to ``x + k (x - c) r^2``, a first-order lens undistortion. Wide lenses bend
    the joints off their epipolar lines (barrel distortion 0.15 at 60-100 deg of field of view
    turned a refined security camera by 1.4 deg more than stage IV had it)."""
    d = x - cam.principal_point
    r2 = np.sum(d * d, 1) / cam.focal**2
    return np.c_[d * r2[:, None], np.zeros(len(x))]


def _pairs(data: SessionData, cams: list[Camera], height: float, usable: Sequence[bool],
           max_points: int, rng: np.random.Generator) -> list[_Pair]:
    """The joint correspondences of every pair of usable cameras at the current clocks, persons
    matched as in the epipolar clock step."""
    assoc = first_association(views_at(data, cams), cams, data.times, height,
                              reference=data.reference)
    obs = assoc.obs[:, :, EPIPOLAR_JOINTS]
    out = []
    for i in range(len(cams)):
        for j in range(i + 1, len(cams)):
            shared = shared_groups(obs[:, i], obs[:, j], max_points, rng) \
                if usable[i] and usable[j] else None
            if shared is None:
                continue
            groups, ok = shared
            sel = ok[groups]
            xa = pinhole_pixels(cams[i], obs[groups, i, :, :2])[sel]
            xb = pinhole_pixels(cams[j], obs[groups, j, :, :2])[sel]
            out.append(_Pair(i, j, np.c_[xa, np.ones(len(xa))], np.c_[xb, np.ones(len(xb))],
                             _radial_directions(xa, cams[i]), _radial_directions(xb, cams[j])))
    return out


class _Rig:
    """The rig as a function of the unknowns: ``P`` (C, 10) changes from the start."""

    def __init__(self, cams: list[Camera]) -> None:
        self.R0 = [c.R for c in cams]
        self.C0 = np.array([c.center for c in cams])
        self.f0 = np.array([c.focal for c in cams])
        self.pp0 = np.array([c.principal_point for c in cams])
        self.spread0 = _spread(self.C0)

    def camera(self, c: int, p: NDArray[np.float64]) -> tuple[NDArray[np.float64], ...]:
        """Camera ``c`` at the changes ``p`` (10,): R, centre and K^-1."""
        # the rotation's change is about the world axes: its x, y parts tilt the camera, its z
        # part turns it about the vertical
        R = self.R0[c] @ rodrigues_to_matrix(p[_ROT])
        f = self.f0[c] * np.exp(p[_FOCAL])
        pp = self.pp0[c] + p[_PP]
        K_inv = np.array([[1 / f, 0.0, -pp[0] / f], [0.0, 1 / f, -pp[1] / f], [0.0, 0.0, 1.0]])
        return R, self.C0[c] + p[_CENTRE], K_inv

    def cameras(self, cams: list[Camera], P: NDArray[np.float64]) -> list[Camera]:
        """``cams`` changed by ``P`` (C, 10) (distortion and clocks kept)."""
        out = []
        for c, cam in enumerate(cams):
            R, C, K_inv = self.camera(c, P[c])
            out.append(cam.with_(R=R, t=-R @ C, K=np.linalg.inv(K_inv)))
        return out


def _distances(rig: _Rig, P: NDArray[np.float64], pair: _Pair) -> NDArray[np.float64]:
    """Signed Sampson distances (px) of a pair's correspondences at the changes ``P``."""
    F = _fundamental(rig.camera(pair.i, P[pair.i]), rig.camera(pair.j, P[pair.j]))
    return signed_sampson(F, *pair.points(P))


@dataclass(frozen=True)
class _Priors:
    """Prior sds: tilt (rad), log focal, radial term, principal point (px per camera), height
    (m per camera); ``anchor`` is the camera whose heading and ground position are fixed."""

    tilt: float
    focal: float
    radial: float
    pp: NDArray[np.float64]
    height: NDArray[np.float64]
    anchor: int


def _spread(C: NDArray[np.float64]) -> float:
    """RMS distance (m) of camera centres ``C`` (C, 3) from their mean: the rig's size."""
    return float(np.sqrt(np.mean(np.sum((C - C.mean(0)) ** 2, 1))))


def _prior_residuals(P: NDArray[np.float64], rig: _Rig, pri: _Priors) -> NDArray[np.float64]:
    """Prior residuals (in sds) of the changes ``P`` (C, 10); the anchor's heading and ground
    position, and the spread of the centres, as near-hard constraints (sd 1e-3)."""
    size = np.log(_spread(rig.C0 + P[:, _CENTRE]) / rig.spread0)
    a = pri.anchor
    return np.concatenate([P[:, 0] / pri.tilt, P[:, 1] / pri.tilt, P[:, _FOCAL] / pri.focal,
                           P[:, _RADIAL] / pri.radial,
                           (P[:, _PP] / pri.pp[:, None]).ravel(), P[:, 5] / pri.height,
                           1e3 * np.array([P[a, 2], P[a, 3], P[a, 4], size])])


def _cauchy_residual(d: NDArray[np.float64], k: float) -> NDArray[np.float64]:
    """A residual whose square is twice the Cauchy loss of ``d`` at scale ``k``."""
    return np.sign(d) * k * np.sqrt(np.log1p((d / k) ** 2))


def _cauchy_slope(d: NDArray[np.float64], k: float) -> NDArray[np.float64]:
    """Derivative of :func:`_cauchy_residual` by ``d`` (1 at 0)."""
    u = np.abs(d) / k
    root = np.sqrt(np.log1p(u * u))
    return np.where(u > 1e-6, u / ((1 + u * u) * np.maximum(root, 1e-300)), 1.0)


def _sampson_gradient(F: NDArray[np.float64], ha: NDArray[np.float64], hb: NDArray[np.float64]
                      ) -> tuple[NDArray[np.float64], ...]:
    """:func:`signed_sampson` (N,), its derivatives by the entries of ``F`` (N, 9), row by
    row, and by the points ``ha`` and ``hb`` (N, 3 each; 0 in the third column): ``d = num /
    g`` with ``num = ha^T F hb`` and ``g`` the gradient norm."""
    num, g, fb, fa = _sampson_terms(F, ha, hb)
    # d g / d ha_k = (fa_0 F_k0 + fa_1 F_k1) / g; d g / d hb_l = (fb_0 F_0l + fb_1 F_1l) / g
    q = num / g**3
    d_ha = fb / g[:, None] - q[:, None] * (fa[:, :2] @ F[:, :2].T)
    d_hb = fa / g[:, None] - q[:, None] * (fb[:, :2] @ F[:2, :])
    d_ha[:, 2] = 0.0
    d_hb[:, 2] = 0.0
    # d num / d F_kl = ha_k hb_l; d g / d F_kl = (fb_k hb_l [k < 2] + ha_k fa_l [l < 2]) / g
    outer = ha[:, :, None] * hb[:, None, :]
    fb[:, 2] = 0.0  # only the lines' first two coordinates enter g
    fa[:, 2] = 0.0
    dg = (fb[:, :, None] * hb[:, None, :] + ha[:, :, None] * fa[:, None, :]) / g[:, None, None]
    d = num / g
    return d, ((outer - d[:, None, None] * dg) / g[:, None, None]).reshape(len(d), 9), d_ha, d_hb


def _solve(pairs: list[_Pair], rig: _Rig, pri: _Priors, free: NDArray[np.bool_],
           scales: list[float], weight: NDArray[np.float64], start: NDArray[np.float64]
           ) -> tuple[NDArray[np.float64], Callable[[NDArray[np.float64], float], float]]:
    """The changes (C, 10) that minimise the pairs' Cauchy losses plus the priors, the loss
    lowered through ``scales`` (px), from the changes ``start``; and the data cost (mean
    loss) of any changes at a scale. ``weight`` (per pair) makes each pair count as a fixed
    number of points."""
    n = len(rig.f0)
    cols = np.flatnonzero(free.ravel())

    def full(x: NDArray[np.float64]) -> NDArray[np.float64]:
        P = np.zeros(n * _N)
        P[cols] = x
        return P.reshape(n, _N)

    def residuals(x: NDArray[np.float64], k: float) -> NDArray[np.float64]:
        P = full(x)
        data = [w * _cauchy_residual(_distances(rig, P, p), k)
                for p, w in zip(pairs, weight, strict=True)]
        return np.concatenate([*data, _prior_residuals(P, rig, pri)])

    def normal_equations(x: NDArray[np.float64], k: float
                         ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
        # J^T J and J^T r pair by pair: a pair moves with its two cameras' unknowns only. The
        # distances' derivatives by F's entries are in closed form, F's by the unknowns are
        # forward differences
        P = full(x)
        geo = [rig.camera(c, P[c]) for c in range(n)]
        owner = cols // _N
        steps = _STEP[cols % _N]
        stepped = []
        for flat, h in zip(cols, steps, strict=True):
            p = P[flat // _N].copy()
            p[flat % _N] += h
            stepped.append(rig.camera(int(flat) // _N, p))
        A = np.zeros((len(cols), len(cols)))
        g = np.zeros(len(cols))
        radial = cols % _N == _RADIAL
        for pair, w in zip(pairs, weight, strict=True):
            F = _fundamental(geo[pair.i], geo[pair.j])
            d, dd_dF, d_ha, d_hb = _sampson_gradient(F, *pair.points(P))
            mine = np.flatnonzero(((owner == pair.i) | (owner == pair.j)) & ~radial)
            dF = np.empty((9, len(mine)))
            for m, col in enumerate(mine):
                a, b = (stepped[col], geo[pair.j]) if owner[col] == pair.i else \
                    (geo[pair.i], stepped[col])
                dF[:, m] = (_fundamental(a, b) - F).ravel() / steps[col]
            # the radial terms move the points: their derivatives in closed form
            bent = [c for c in np.flatnonzero(radial) if owner[c] in (pair.i, pair.j)]
            mine = np.r_[mine, bent].astype(int)
            moved = [np.einsum("ij,ij->i", d_ha, pair.ra) if owner[c] == pair.i else
                     np.einsum("ij,ij->i", d_hb, pair.rb) for c in bent]
            B = (w * _cauchy_slope(d, k))[:, None] * np.column_stack([dd_dF @ dF, *moved])
            A[np.ix_(mine, mine)] += B.T @ B
            g[mine] += B.T @ (w * _cauchy_residual(d, k))
        r0 = _prior_residuals(P, rig, pri)
        Jp = np.empty((len(r0), len(cols)))
        for u, unknown in enumerate(cols):
            Ph = P.copy()
            Ph.flat[unknown] += 1e-7
            Jp[:, u] = (_prior_residuals(Ph, rig, pri) - r0) / 1e-7
        return A + Jp.T @ Jp, g + Jp.T @ r0

    def cost(P: NDArray[np.float64], k: float) -> float:
        return cauchy_cost(np.concatenate([_distances(rig, P, p) for p in pairs]), k)

    x = start.ravel()[cols]
    for k in scales:
        x = _levenberg_marquardt(partial(_sum_of_squares, residuals, k=k),
                                 partial(normal_equations, k=k), x)
    return full(x), cost


def _sum_of_squares(residuals: Callable[[NDArray[np.float64], float], NDArray[np.float64]],
                    x: NDArray[np.float64], k: float) -> float:
    return float(np.sum(residuals(x, k) ** 2))


def _levenberg_marquardt(cost: Callable[[NDArray[np.float64]], float],
                         normal: Callable[[NDArray[np.float64]],
                                          tuple[NDArray[np.float64], NDArray[np.float64]]],
                         x: NDArray[np.float64], *, max_iter: int = 30, ftol: float = 1e-6
                         ) -> NDArray[np.float64]:
    """Levenberg-Marquardt on the normal equations ``normal(x) = (J^T J, J^T r)`` of the sum
    of squares ``cost(x)``, damped along their diagonal (Marquardt).

    Written here because scipy's ``least_squares`` factorises the whole Jacobian at every
    step (thousands of rows, tens of columns), and most of its entries are zeros: each pair's
    rows depend on two cameras. Summed pair by pair, the normal equations cost a fraction.
    """
    current = cost(x)
    lam = 1e-4
    for _ in range(max_iter):
        A, g = normal(x)
        scale = np.maximum(np.diag(A), 1e-12)
        for _ in range(12):
            step = np.linalg.solve(A + lam * np.diag(scale), -g)
            new = cost(x + step)
            if new < current:
                break
            lam *= 10.0
        else:
            return x  # no step lowers the cost: a minimum
        x = x + step
        lam = max(lam / 10.0, 1e-9)
        done = current - new <= ftol * current
        current = new
        if done:
            break
    return x


def _radial_terms(pairs: list[_Pair], rig: _Rig, pri: _Priors, free: NDArray[np.bool_],
                  weight: NDArray[np.float64], P: NDArray[np.float64],
                  cost: Callable[[NDArray[np.float64], float], float], scale_px: float,
                  gain: float) -> tuple[NDArray[np.float64], bool]:
    """The changes ``P`` solved again with the radial terms free where the focal lengths are,
    and True, if that lowers the cost by the fraction ``gain``; else ``P`` and False. The
    later rounds keep them free (their association made at the bent rig).

    Free from the start, the radial terms trade against the focal lengths, principal points and
    rotations where the lenses have no distortion: on the 24 distortion-free scenes they left
    the worst rotation per scene up to 1.6 deg further off (periodic seed 1: 0.47 -> 2.08 deg,
    lab ring seed 5: 1.31 -> 2.66 deg); on five of them they lowered the cost by -0.3 to 1 %.
    On the simulated security cameras (60-100 deg field of view, barrel distortion k1 up to
    -0.15) they lowered it by 17 and 27 % (seeds 0 and 1) and took the worst relative rotation
    from 6.1 to 1.5 and 1.4 deg.
    """
    bent = free.copy()
    bent[:, _RADIAL] = free[:, _FOCAL]
    radial, _ = _solve(pairs, rig, pri, bent, [scale_px], weight, P)
    before, after = cost(P, scale_px), cost(radial, scale_px)
    kept = after < (1 - gain) * before
    log.info("radial terms %s: cost %.3f -> %.3f px^2", "kept" if kept else "not kept",
             before, after)
    return (radial, True) if kept else (P, False)


def _scales(d: NDArray[np.float64], final: float) -> list[float]:
    """Cauchy scales from the starting distances' spread down to ``final`` by factors of 3:
    started at its final scale, the loss ignores the correspondences a poor start puts far
    off."""
    k = max(final, 1.5 * float(np.median(np.abs(d))))
    out = []
    while k > final * 1.5:
        out.append(k)
        k /= 3.0
    return [*out, final]


def refine_rig(data: SessionData, calibration: Calibration, *, height: float = 1.70,
               fixed_intrinsics: Sequence[str] = (), held: Sequence[str] = (),
               n_times: int = 300, max_points: int = 3000, scale_px: float = 2.0,
               pair_points: float = 3600.0, tilt_sigma_deg: float = 1.0,
               focal_sigma: float = 0.1, principal_point_sigma: float = 0.02,
               radial_sigma: float = 0.2, radial_gain: float | None = 0.05,
               height_sigma: float = 0.05, max_rotation_deg: float = 10.0,
               max_focal_change: float = 0.4, rounds: int = 2,
               rng: np.random.Generator | int | None = None) -> RigRefinement:
    """Refine every camera's focal length, principal point, rotation and centre so that the
    joints two cameras see of the same persons fit their epipolar geometry.

    Parameters
    ----------
    data : SessionData
        The tracks as :func:`~cascalib.stages.reconstruct.prepare` makes them for
        ``calibration``.
    calibration : Calibration
        Stage IV's rig with its clocks (after the epipolar clock step).
    height : float
        Mean person height (m), for matching persons across cameras by ground position.
    fixed_intrinsics : sequence of str
        Cameras whose focal length and principal point are known: held.
    held : sequence of str
        Cameras not refined at all (not placed by stage IV).
    n_times : int
        Reference times whose persons are matched (evenly spread).
    max_points : int
        Joint correspondences per camera pair (a random subset of the persons beyond).
    scale_px : float
        Final scale (px) of the Cauchy loss of the Sampson distances.
    pair_points : float
        Every pair weighs as much as this many correspondences at ``scale_px`` of noise
        against the priors, whatever its number of correspondences (they are correlated over
        time, and a pair with many should not steer the others).
    tilt_sigma_deg, focal_sigma, principal_point_sigma, radial_sigma, height_sigma : float
        Prior sds: tilt (deg) around stage I's, log focal length, principal point (fraction
        of the image width) around stage I's (the image centre), the radial term that stands
        for lens distortion (around 0; it is not reported: Stage V's lens pass estimates the
        distortion), camera height (fraction of it).
    radial_gain : float, optional
        The radial terms are kept only if they lower the cost by this fraction; None: not
        tried.
    rounds : int
        Associations and solves: the persons are matched again at the refined rig.
    max_rotation_deg, max_focal_change : float
        A refinement that turns a camera farther, or changes a focal length by more (relative),
        is not kept: the correspondences were not what they seemed.
    rng : Generator or int, optional
        For the subsets of correspondences.

    Returns
    -------
    RigRefinement
    """
    rng = np.random.default_rng(rng)
    cams = list(calibration.cameras)
    names = calibration.names
    usable = [c.name not in held for c in cams]
    data = clock_check_times(data, n_times)
    rig = _Rig(cams)
    P = np.zeros((len(cams), _N))
    counts: dict[str, int] = {}

    def unchanged(reason: str) -> RigRefinement:
        log.info("rig not refined: %s", reason)
        zero = dict.fromkeys(names, 0.0)
        return RigRefinement(calibration, False, reason, np.nan, np.nan, counts, zero, zero,
                             zero)

    bend = False  # whether the radial terms are free (decided after the first round)
    for r in range(rounds):
        # persons matched again at the refined rig: in a crowd stage IV's rig mismatches some
        pairs = _pairs(data, rig.cameras(cams, P), height, usable, max_points, rng)
        counts = {f"{names[p.i]}-{names[p.j]}": len(p.ha) for p in pairs}
        if not pairs:
            return unchanged("no camera pair shares enough joints")
        seen = {c for p in pairs for c in (p.i, p.j)}
        free = np.zeros((len(cams), _N), dtype=bool)
        for c in seen:
            free[c] = True
            free[c, _RADIAL] = bend
            if cams[c].name in fixed_intrinsics:
                free[c, _FOCAL] = False
                free[c, _PP] = False
                free[c, _RADIAL] = False
        anchor = data.reference if data.reference in seen else min(seen)
        pri = _Priors(np.radians(tilt_sigma_deg), focal_sigma, radial_sigma,
                      np.array([principal_point_sigma * c.image_size[0] for c in cams]),
                      np.maximum(height_sigma * rig.C0[:, 2], 0.05), anchor)
        weight = np.array([np.sqrt(pair_points / len(p.ha)) / scale_px for p in pairs])
        start = np.concatenate([_distances(rig, P, p) for p in pairs])
        try:
            P, cost = _solve(pairs, rig, pri, free, _scales(start, scale_px), weight, P)
        except (ValueError, np.linalg.LinAlgError) as exc:
            return unchanged(f"the solver failed ({exc})")
        if r == 0 and radial_gain is not None and free[:, _FOCAL].any():
            P, bend = _radial_terms(pairs, rig, pri, free, weight, P, cost, scale_px,
                                    radial_gain)
    P0 = np.zeros_like(P)
    out = rig.cameras(cams, P)
    turned = {c.name: float(np.degrees(np.linalg.norm(P[k, _ROT]))) for k, c in enumerate(cams)}
    stretched = {c.name: float(np.expm1(P[k, _FOCAL])) for k, c in enumerate(cams)}
    before, after = cost(P0, scale_px), cost(P, scale_px)
    worst = max(turned, key=lambda n: turned[n])
    if turned[worst] > max_rotation_deg:
        return unchanged(f"it turned camera {worst} by {turned[worst]:.1f} deg")
    worst = max(stretched, key=lambda n: abs(stretched[n]))
    if abs(stretched[worst]) > max_focal_change:
        return unchanged(f"it changed camera {worst}'s focal length by "
                         f"{100 * stretched[worst]:+.0f} %")
    radial = {n: float(v) for n, v in zip(names, P[:, _RADIAL], strict=True)}
    log.info("rig from the epipolar geometry: cost %.2f -> %.2f px^2; turned %s; focal %s; "
             "radial terms %s", before, after,
             ", ".join(f"{n} {v:.2f} deg" for n, v in turned.items()),
             ", ".join(f"{n} {100 * v:+.1f} %" for n, v in stretched.items()),
             ", ".join(f"{n} {v:+.3f}" for n, v in radial.items()))
    refined = Calibration(out, reference_camera=calibration.reference_camera,
                          quality=calibration.quality, world=calibration.world)
    return RigRefinement(refined, True, "", before, after, counts, turned, stretched, radial)
