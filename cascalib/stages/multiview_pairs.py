"""The people's joints as point matches between two cameras, and the two-view geometry they fit.

The multi-view start (:mod:`~cascalib.stages.multiview_start`) needs no ground plane: the same
joint of the same person at the same instant, seen by two cameras, is a point correspondence.
Once the clocks are known, each camera's detections are resampled at common instants; which
person of camera A is which person of camera B is not known, so every person pair of an instant
is a candidate, a fundamental matrix is fitted robustly to all candidates' joints (OpenCV's USAC
MAGSAC++), and the person pairs whose joints fit it are kept (one-to-one per instant).

References
----------
Hartley, R. & Zisserman, A. *Multiple View Geometry*, 2nd ed.: sec. 11.2 (8-point algorithm),
sec. 11.4.3 (Sampson distance). Barath, D. et al. MAGSAC++, CVPR 2020.
"""

from __future__ import annotations

from dataclasses import dataclass

import cv2
import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment
from scipy.spatial import cKDTree

from cascalib.nanstats import nanmedian_last
from cascalib.stages.epipolar_sync import fit_fundamental, sampson_distance

__all__ = ["PairMatches", "match_pair", "MIN_CONFIDENCE"]

#: Least detector confidence of a joint used as a correspondence.
MIN_CONFIDENCE = 0.3
#: Least joints two views of a person must share for the person pair to count.
MIN_SHARED_JOINTS = 6
#: RANSAC inlier threshold as a fraction of the image diagonal: real detections sit about
#: 0.5 % of the diagonal from any consistent geometry, so 1 % keeps them and drops swaps.
RANSAC_THRESHOLD = 0.01
#: A person pair is accepted when its joints' median Sampson distance is below this many
#: RANSAC thresholds.
GROUP_GATE = 1.5
#: Most candidate correspondences fed to RANSAC (instants are subsampled beyond it).
MAX_CANDIDATES = 20000
#: A detection whose joints sit within this many pixels (median) of an earlier instant's is a
#: repeat: the robust fit leaves it out, since copies of a figure that never moves (mannequin,
#: poster, composited figure) would outvote the people who move. Detector jitter of a person
#: holding still is about a pixel.
STATIC_PX = 0.5
#: Earlier detections (nearest by centroid) each detection is compared with.
STATIC_NEIGHBOURS = 8
#: Detections compared at once by :func:`repeats` (bounds its memory).
REPEAT_BLOCK = 2000


@dataclass(frozen=True)
class PairMatches:
    """Joint correspondences of cameras ``i`` and ``j`` and their fundamental matrix.

    Attributes
    ----------
    i, j : int
        Camera indices.
    F : ndarray, shape (3, 3)
        ``x_i^T F x_j = 0`` in pixels.
    times : ndarray of int, shape (G,)
        Instant index of each matched person pair (a group).
    persons : ndarray of int, shape (G, 2)
        Person slot in camera ``i`` and in camera ``j``.
    joints : ndarray of bool, shape (G, J)
        Joints both cameras see confidently in the group.
    xi, xj : ndarray, shape (N, 2)
        The correspondences (pixels), grouped; ``group`` gives each row's group.
    group : ndarray of int, shape (N,)
    distances : ndarray, shape (N,)
        Sampson distances (px) to ``F``.
    """

    i: int
    j: int
    F: NDArray[np.float64]
    times: NDArray[np.int64]
    persons: NDArray[np.int64]
    joints: NDArray[np.bool_]
    xi: NDArray[np.float64]
    xj: NDArray[np.float64]
    group: NDArray[np.int64]
    distances: NDArray[np.float64]

    @property
    def n_groups(self) -> int:
        return int(self.times.size)

    @property
    def inlier_share(self) -> float:
        """Share of correspondences within the RANSAC threshold's scale of ``F`` (for ranking)."""
        return float(np.mean(self.distances < np.median(self.distances) * 3 + 1e-9))


@dataclass(frozen=True)
class _Candidates:
    t: NDArray[np.int64]  # (G,)
    pa: NDArray[np.int64]
    pb: NDArray[np.int64]
    ok: NDArray[np.bool_]  # (G, J)


def repeats(v: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Detections that repeat an earlier instant's to within :data:`STATIC_PX`, shape (T, P).

    Parameters
    ----------
    v : ndarray, shape (T, P, J, 3)
        One camera's detections (x, y, confidence; NaN missing).
    """
    seen = np.nan_to_num(v[..., 2]) >= MIN_CONFIDENCE
    xy = np.where(seen[..., None], v[..., :2], np.nan)
    t, p = np.nonzero(seen.sum(-1) >= MIN_SHARED_JOINTS)
    out = np.zeros(seen.shape[:2], dtype=bool)
    if t.size < 2:
        return out
    with np.errstate(invalid="ignore"):
        centre = np.nanmean(xy[t, p], axis=1)
    k = min(STATIC_NEIGHBOURS + 1, t.size)
    _, near = cKDTree(centre).query(centre, k=k, distance_upper_bound=4 * STATIC_PX)
    near = near.reshape(t.size, -1)
    # the rows whose centre has an earlier neighbour, compared in blocks (one nanmedian per
    # block: a call per detection made this the clock scans' slowest step)
    cols = np.minimum(near, t.size - 1)
    earlier = (near < t.size) & (t[cols] < t[:, None])
    rows = np.flatnonzero(earlier.any(axis=1))
    for block in np.array_split(rows, max(1, rows.size // REPEAT_BLOCK)):
        c = cols[block]
        d = np.linalg.norm(xy[t[c], p[c]] - xy[t[block], p[block]][:, None], axis=-1)
        still = nanmedian_last(d) < STATIC_PX
        out[t[block], p[block]] = np.any(still & earlier[block], axis=1)
    return out


def _candidates(va: NDArray[np.float64], vb: NDArray[np.float64], rng: np.random.Generator
                ) -> _Candidates | None:
    """Every person pair of every common instant that shares enough confident joints."""
    ca = np.nan_to_num(va[..., 2]) >= MIN_CONFIDENCE  # (T, Pa, J)
    cb = np.nan_to_num(vb[..., 2]) >= MIN_CONFIDENCE
    ok = ca[:, :, None, :] & cb[:, None, :, :]  # (T, Pa, Pb, J)
    t, pa, pb = np.nonzero(ok.sum(-1) >= MIN_SHARED_JOINTS)
    if t.size == 0:
        return None
    joints = ok[t, pa, pb]
    n_points = joints.sum()
    if n_points > MAX_CANDIDATES:
        keep = np.sort(rng.choice(t.size, int(t.size * MAX_CANDIDATES / n_points),
                                  replace=False))
        t, pa, pb, joints = t[keep], pa[keep], pb[keep], joints[keep]
    return _Candidates(t, pa, pb, joints)


def _points(va: NDArray[np.float64], vb: NDArray[np.float64], c: _Candidates
            ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.int64]]:
    g, j = np.nonzero(c.ok)
    return va[c.t[g], c.pa[g], j, :2], vb[c.t[g], c.pb[g], j, :2], g


def _one_to_one(c: _Candidates, score: NDArray[np.float64], gate: float) -> NDArray[np.int64]:
    """Candidate groups kept: per instant, a one-to-one assignment of persons by score."""
    keep: list[int] = []
    for t in np.unique(c.t):
        rows = np.flatnonzero(c.t == t)
        ua, ia = np.unique(c.pa[rows], return_inverse=True)
        ub, ib = np.unique(c.pb[rows], return_inverse=True)
        cost = np.full((ua.size, ub.size), 1e9)
        cost[ia, ib] = score[rows]
        r, k = linear_sum_assignment(cost)
        for a, b in zip(r, k, strict=True):
            hit = rows[(ia == a) & (ib == b)]
            if hit.size and score[hit[0]] < gate:
                keep.append(int(hit[0]))
    return np.asarray(keep, dtype=np.int64)


def _group_median(d: NDArray[np.float64], g: NDArray[np.int64], n: int) -> NDArray[np.float64]:
    order = np.argsort(g, kind="stable")
    starts = np.searchsorted(g[order], np.arange(n))
    ends = np.searchsorted(g[order], np.arange(n), side="right")
    ds = d[order]
    return np.array([np.median(ds[s:e]) if e > s else np.inf
                     for s, e in zip(starts, ends, strict=True)])


def match_pair(i: int, j: int, va: NDArray[np.float64], vb: NDArray[np.float64],
               diagonal: float, rng: np.random.Generator, *, min_groups: int = 10
               ) -> PairMatches | None:
    """Match the persons of two cameras at common instants and fit their two-view geometry.

    Parameters
    ----------
    i, j : int
        Camera indices (kept on the result).
    va, vb : ndarray, shape (T, P, J, 3)
        The two cameras' detections at the same T instants (x, y, confidence; NaN missing).
    diagonal : float
        Image diagonal (px) of the larger of the two images: sets the RANSAC threshold.
    rng : numpy.random.Generator
    min_groups : int
        Fewest matched person pairs for a result.

    Returns
    -------
    PairMatches or None
        None when the cameras share too few instants of one person, or no geometry fits.
    """
    cand = _candidates(va, vb, rng)
    if cand is None or cand.t.size < min_groups:
        return None
    xa, xb, g = _points(va, vb, cand)
    thr = RANSAC_THRESHOLD * diagonal
    fresh = ~(repeats(va)[cand.t, cand.pa] & repeats(vb)[cand.t, cand.pb])[g]
    if fresh.sum() < MIN_SHARED_JOINTS * min_groups:  # a still scene: every copy counts
        fresh[:] = True
    F, _ = cv2.findFundamentalMat(xa[fresh], xb[fresh], cv2.USAC_MAGSAC, thr, 0.9999, 20000)
    if F is None or F.shape != (3, 3):
        return None
    # OpenCV's F has x_b^T F x_a = 0: transposed, x_a^T F x_b = 0
    F = np.asarray(F, dtype=np.float64).T
    score = _group_median(sampson_distance(F, xa, xb), g, cand.t.size)
    kept = _one_to_one(cand, score, GROUP_GATE * thr)
    if kept.size < min_groups:
        return None
    sub = _Candidates(cand.t[kept], cand.pa[kept], cand.pb[kept], cand.ok[kept])
    xa, xb, g = _points(va, vb, sub)
    F, d = fit_fundamental(xa, xb, scale_px=thr / 4)
    return PairMatches(i, j, F, sub.t, np.c_[sub.pa, sub.pb], sub.ok, xa, xb, g, d)
