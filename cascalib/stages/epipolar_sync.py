"""Stage IV's sub-frame clocks from the epipolar geometry of the people's joints (the step
before the last, which refines the rig from the same geometry: stages/epipolar_rig.py).

Stage III measures the clocks on ground trajectories (ankles back-projected onto each camera's
plane). In a crowd those carry decimetres of noise per point, so its offsets scatter by about
half a frame: on bench_sync.py's 24 scenes 76 of 84 cameras came within half a frame, the crowd's
median error was 0.34-0.36 frame and its worst 1.02 (the integer part wrong).

The joints of one person seen by two cameras at the same instant obey the epipolar constraint
``x_a^T F x_b = 0``; seen a fraction of a frame apart they do not, since the person moved. For
every camera pair, camera B's tracks are interpolated at a shifted clock and a fundamental matrix
is fitted afresh to all joint correspondences at each shift (variable projection): the shift at
which *some* two-view geometry explains the correspondences best is B's clock error relative to
A's. F has seven degrees of freedom, so neither stage IV's rotations nor stage I's focal lengths
bias the shift (stage V's clock search, which triangulates with the current rig, took good clocks
0.3 frame off when it was run at the stage-IV geometry); the stage-IV rig only matches the
persons across cameras by their ground positions, as stage V's first association does.

The pairwise shifts become per-camera corrections by a robust L1 fit over all pairs, so that one
bad pair is outvoted by the cycles through the other cameras. Rates stay at stage III's.

Measured (``python bench/bench_sync.py --only scenes``, 84 cameras of 24 scenes with offsets up to
half the recording, 25/30 fps, drift; with and without stage-I errors): integer part right
76 -> 84 of 84, median error per preset 0.10-0.36 -> 0.03-0.08 frame, worst 1.02 -> 0.27. On 24
whole-cascade scenes (real stage I; terrace, lab ring, crowd, periodic, seeds 0-5, 40 s): 67 -> 84
of 84, median 0.24 -> 0.04 frame, and Stage V's offsets worst 0.89 -> 0.13 frame.

The cost of a shift is the mean Cauchy loss of the Sampson distances (it was a Huber loss). On
table 1 the worst error per row went 0.13-0.24 -> 0.09-0.18 frame (sum over the 8 rows 1.31 ->
1.08; one row worse, the crowd without stage-I errors, 0.15 -> 0.18); on table 2b (the paper's
walker, 35 runs, swapped joints in the detections) the worst 0.53 -> 0.08 frame, mean 0.20 -> 0.04.

References
----------
Hartley, R. & Zisserman, A. *Multiple View Geometry*, 2nd ed.: sec. 11.2 (normalised 8-point
algorithm), sec. 11.4.3 (Sampson distance).
"""

from __future__ import annotations

import logging
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from cascalib.calibration import Calibration
from cascalib.camera import Camera
from cascalib.geometry import norm_xy
from cascalib.nanstats import joint_extent
from cascalib.skeletons import CANONICAL_INDEX
from cascalib.stages.association import Association, associate
from cascalib.stages.reconstruct import SessionData, clock_check_times, prepare, views_at
from cascalib.stages.refine_config import DEFAULT_JOINTS, RefineConfig
from cascalib.stages.single_view_solver import hartley_scale
from cascalib.stages.sync import irls_l1
from cascalib.stages.track_interpolation import interpolate_views, person_distances
from cascalib.stages.triangulation import cauchy_weight
from cascalib.tracks import Tracks

__all__ = ["EPIPOLAR_JOINTS", "EpipolarClocks", "PairShift", "cauchy_cost", "epipolar_clocks",
           "first_association", "fit_fundamental", "hartley_normalization", "pair_cost",
           "pinhole_pixels", "quadratic_minimum", "sampson_distance", "shared_groups"]

log = logging.getLogger(__name__)


@dataclass(frozen=True)
class PairShift:
    """The clock shift of camera ``j`` against camera ``i`` that the epipolar geometry favours.

    Attributes
    ----------
    i, j : int
        Camera indices; ``j``'s clock is shifted.
    shift : float
        Reference frames to add to ``j``'s time offset relative to ``i``'s.
    sd : float
        Approximate standard deviation (frames) from the cost curve's curvature; a relative
        weight (the correspondences are correlated over time).
    n_points : int
        Joint correspondences at the best shift.
    shifts, costs : ndarray, shape (n,)
        The evaluated shifts (sorted) and the robust Sampson cost at each (for plots).
    iteration : int
        The search it comes from (0 the first).
    base : float
        How far earlier iterations had already moved ``j``'s offset relative to ``i``'s: the
        shifts are relative to that (``base + shift`` is the change since stage III).
    """

    i: int
    j: int
    shift: float
    sd: float
    n_points: int
    shifts: NDArray[np.float64]
    costs: NDArray[np.float64]
    iteration: int = 0
    base: float = 0.0


@dataclass(frozen=True)
class EpipolarClocks:
    """Outcome of :func:`epipolar_clocks`.

    Attributes
    ----------
    calibration : Calibration
        The input with corrected time offsets (rates, geometry and quality unchanged).
    corrections : dict of str to float
        Total change of each camera's time offset (reference frames; 0 for the reference and
        for cameras that no usable pair reaches).
    pairs : list of PairShift
        The pairs that gave a shift, every iteration's (``PairShift.iteration``).
    accepted : dict of str to bool
        Whether the camera was corrected: agreeing pairs tied it to the reference in some
        iteration.
    """

    calibration: Calibration
    corrections: dict[str, float]
    pairs: list[PairShift]
    accepted: dict[str, bool]


def hartley_normalization(x: NDArray[np.float64]) -> tuple[NDArray[np.float64],
                                                            NDArray[np.float64]]:
    """Homogeneous points (N, 3) centred on their mean with mean distance sqrt(2), and the
    3x3 transform ``T`` that maps the input's homogeneous coordinates to them (H&Z 4.4.4)."""
    mean = x.mean(0)
    s = hartley_scale(x, mean)
    T = np.array([[s, 0.0, -s * mean[0]], [0.0, s, -s * mean[1]], [0.0, 0.0, 1.0]])
    return np.c_[(x - mean) * s, np.ones(len(x))], T


def _epipolar_terms(F: NDArray[np.float64], ha: NDArray[np.float64], hb: NDArray[np.float64]
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Algebraic residual ``|x_a^T F x_b|`` of homogeneous pixels ``ha``, ``hb`` (N, 3) and its
    gradient norm over the four pixel coordinates, each (N,)."""
    fb = hb @ F.T  # F x_b
    fa = ha @ F  # F^T x_a
    num = np.abs(np.einsum("ij,ij->i", ha, fb))
    return num, np.sqrt(fb[:, 0] ** 2 + fb[:, 1] ** 2 + fa[:, 0] ** 2 + fa[:, 1] ** 2)


def sampson_distance(F: NDArray[np.float64], xa: NDArray[np.float64],
                     xb: NDArray[np.float64]) -> NDArray[np.float64]:
    """First-order geometric distance (px) of correspondences ``xa`` (N, 2) and ``xb`` (N, 2)
    to ``x_a^T F x_b = 0`` (H&Z 11.9)."""
    num, grad = _epipolar_terms(F, np.c_[xa, np.ones(len(xa))], np.c_[xb, np.ones(len(xb))])
    with np.errstate(invalid="ignore", divide="ignore"):
        return num / grad


def fit_fundamental(xa: NDArray[np.float64], xb: NDArray[np.float64], *, scale_px: float = 2.0,
                    n_iter: int = 4) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Robust fundamental matrix of many correspondences, ``x_a^T F x_b = 0``.

    The normalised 8-point algorithm (H&Z 11.2), reweighted ``n_iter`` times so that the
    algebraic residuals stand for Sampson distances in a Cauchy kernel: the algebraic residual
    is the same in normalised and in pixel coordinates and equals the Sampson distance times
    the gradient norm, so each row is weighed by the kernel's weight of its distance over its
    squared gradient norm. The kernel's scale starts wide (1.5 x the median distance, which the
    first, unweighted fit leaves large when there are outliers) and shrinks with the fit to
    ``scale_px``: a Huber kernel at 2 px from the start still left the inliers 4-5 px
    off after four reweightings with 5 % of the points anywhere in the image and 10 % 10-40 px
    off (swapped joints), the shrinking Cauchy kernel 1.7 px (1 px noise).

    Parameters
    ----------
    xa, xb : ndarray, shape (N, 2)
        Pixels of the same points in two images (N >= 8, finite).

    Returns
    -------
    F : ndarray, shape (3, 3)
        Rank 2, in pixel coordinates.
    distances : ndarray, shape (N,)
        Sampson distances (px) of the correspondences to ``F``.

    Examples
    --------
    >>> rng = np.random.default_rng(0)
    >>> X = rng.uniform([-2, -1, 4], [2, 1, 8], size=(50, 3))
    >>> xa = 500 * X[:, :2] / X[:, 2:] + 320
    >>> Xb = X - [1.0, 0.0, 0.0]
    >>> xb = 500 * Xb[:, :2] / Xb[:, 2:] + 320
    >>> F, d = fit_fundamental(xa, xb)
    >>> bool(d.max() < 1e-6)
    True
    """
    return _fit_fundamental(_View.of(xa), _View.of(xb), scale_px, n_iter)


@dataclass(frozen=True)
class _View:
    """One image's side of the correspondences: homogeneous pixels ``h`` (N, 3), their Hartley
    normalisation ``p`` (N, 3) and its transform ``T`` (a pair search fits many F with the same
    first view: it is normalised once)."""

    h: NDArray[np.float64]
    p: NDArray[np.float64]
    T: NDArray[np.float64]

    @classmethod
    def of(cls, x: NDArray[np.float64]) -> _View:
        p, T = hartley_normalization(x)
        return cls(np.c_[x, np.ones(len(x))], p, T)


def _fit_fundamental(a: _View, b: _View, scale_px: float, n_iter: int
                     ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """:func:`fit_fundamental` of normalised views."""
    rows = (a.p[:, :, None] * b.p[:, None, :]).reshape(-1, 9)
    w = np.ones(len(a.h))
    for _ in range(n_iter + 1):
        _, vecs = np.linalg.eigh((rows.T * w) @ rows)
        U, S, Vt = np.linalg.svd(vecs[:, 0].reshape(3, 3))
        F = a.T.T @ (U @ np.diag([S[0], S[1], 0.0]) @ Vt) @ b.T
        num, grad = _epipolar_terms(F, a.h, b.h)
        d = num / np.maximum(grad, 1e-300)
        # the kernel's scale from every fourth distance: the median of thousands needs no more
        scale = max(scale_px, 1.5 * float(np.median(d[::4])))
        w = cauchy_weight(d, scale) / np.maximum(grad, 1e-150) ** 2
        w /= w.max()
    return F, d


def cauchy_cost(d: NDArray[np.float64], k: float) -> float:
    """Mean Cauchy loss of distances ``d`` at scale ``k`` (px^2: ``d^2 / 2`` for small ``d``).

    A Huber loss here let the outliers (swapped joints, wrong detections) count in proportion
    to their distance, which changes from shift to shift at random: on the paper's walker
    (bench_sync.py table 2b, 35 runs) the clocks came out up to 0.53 frame off (mean 0.20),
    with the Cauchy loss 0.08 at most (mean 0.04).
    """
    return float(np.mean(0.5 * k * k * np.log1p((d / k) ** 2)))


def pinhole_pixels(cam: Camera, uv: NDArray[np.float64]) -> NDArray[np.float64]:
    """Distortion-free pixels (an F relates pinhole images)."""
    return cam.undistort_pixels(uv) if cam.has_distortion else uv


def quadratic_minimum(x: NDArray[np.float64], y: NDArray[np.float64], centre: float,
                       half_width: float) -> tuple[float, float] | None:
    """Vertex and curvature (second derivative) of the least-squares parabola through the
    samples within ``half_width`` of ``centre``; None unless it opens upwards."""
    near = np.abs(x - centre) <= half_width + 1e-9
    if near.sum() < 3:
        return None
    c2, c1, _ = np.polyfit(x[near], y[near], 2)
    if c2 <= 0:
        return None
    return float(-c1 / (2 * c2)), float(2 * c2)


#: Canonical indices of the joints the fundamental matrices are fitted to (Stage V's).
EPIPOLAR_JOINTS = np.array([CANONICAL_INDEX[n] for n in DEFAULT_JOINTS])


def first_association(views: list[NDArray[np.float64]], cams: list[Camera],
                      times: NDArray[np.float64], height: float, *,
                      consistency: float | None = None, reference: int = 0) -> Association:
    """Persons matched across cameras as in Stage V's first round (gates sized for the errors
    stage IV leaves), without track links; ``consistency`` overrides its triangulation gate."""
    gates = RefineConfig().association_gates(refined=False)
    if consistency is not None:
        gates["consistency"] = consistency
    return associate(views, cams, times, height=height, reference=reference, link=False,
                     **gates)  # type: ignore[arg-type]


def shared_groups(obs_a: NDArray[np.float64], obs_b: NDArray[np.float64], max_points: int,
                  rng: np.random.Generator
                  ) -> tuple[NDArray[np.int64], NDArray[np.bool_]] | None:
    """Groups whose person two views share in at least 8 confident joints (confidence >=
    0.3; a random subset of about ``max_points`` joints beyond that), and the (G, J) mask of
    the joints both see; None with fewer than 10 such groups. ``obs_a``, ``obs_b``: (G, J, 3).
    """
    ok = (np.nan_to_num(obs_a[..., 2]) >= 0.3) & (np.nan_to_num(obs_b[..., 2]) >= 0.3)
    groups = np.flatnonzero(ok.sum(1) >= 8)
    if groups.size < 10:
        return None
    per_group = ok[groups].sum() / groups.size
    if groups.size * per_group > max_points:
        groups = np.sort(rng.choice(groups, int(max_points / per_group), replace=False))
    return groups, ok


def _pair_shift(i: int, j: int, obs: NDArray[np.float64], times: NDArray[np.float64],
                keypoints: NDArray[np.float64], links: NDArray[np.int64], cams: list[Camera],
                window: float, n_samples: int, max_points: int, huber_px: float,
                min_contrast: float, rng: np.random.Generator, *, widen: bool = False
                ) -> PairShift | None:
    """The best shift of camera ``j``'s clock against camera ``i`` (see the module docstring).

    ``obs`` (G, C, J, 3) are the associated keypoints at reference ``times`` (G,) and the
    current clocks, ``keypoints`` (F, P, J, 2) and ``links`` camera ``j``'s tracks. The cost is
    sampled at ``n_samples`` evenly spaced shifts over +-``window`` (:func:`_search`). With
    ``widen``, a lowest sample on the window's edge (a larger error) is searched again over
    twice the window. None when the pair shares too few joints or the search finds nothing.
    """
    shared = shared_groups(obs[:, i], obs[:, j], max_points, rng)
    if shared is None:
        return None
    groups, ok = shared
    pair = _PairData(pinhole_pixels(cams[i], obs[groups, i, :, :2]), obs[groups, j, :, :2],
                     (times[groups] - cams[j].time_offset) / cams[j].time_rate, ok[groups],
                     # the same person within a quarter of its size (or 20 px) of where it was
                     np.maximum(20.0, 0.25 * norm_xy(joint_extent(obs[groups, j]))),
                     keypoints, links, cams[j])
    found = _search(pair, window, n_samples, huber_px, min_contrast)
    if found == "edge" and widen:
        found = _search(pair, 2 * window, 2 * n_samples - 3, huber_px, min_contrast)
    if not isinstance(found, tuple):
        return None
    return PairShift(i, j, *found)


@dataclass(frozen=True)
class _PairData:
    """A pair's correspondences at the current clocks: camera A's pixels ``xa`` (G, J, 2),
    camera B's ``base`` (G, J, 2) at its fractional ``frames`` (G,), the usable joints ``ok``
    (G, J), the person gate (G,) in px, and B's tracks and camera."""

    xa: NDArray[np.float64]
    base: NDArray[np.float64]
    frames: NDArray[np.float64]
    ok: NDArray[np.bool_]
    gate: NDArray[np.float64]
    keypoints: NDArray[np.float64]
    links: NDArray[np.int64]
    cam_b: Camera


def _search(pair: _PairData, window: float, n_samples: int, huber_px: float,
            min_contrast: float) -> tuple | str | None:
    """Sample the cost at ``n_samples`` shifts over +-``window``, every sample on the same
    correspondences (those found at every shift: a set that changed with the shift made the
    curve bumpy), and fit a parabola through the samples within half the window of the
    lowest. Returns ``(shift, sd, n_points, shifts, costs)``; "edge" when the lowest sample is
    on the window's edge or only one end rises ``min_contrast`` above it; None when the curve
    is flat (its ends less than ``min_contrast`` above its lowest sample: the people barely
    move, or too few are shared for the noise of the fits) or too few correspondences stay.
    """
    # the person is found anew at every shift, as the detection nearest to the association's
    # (median joint distance): following it along the frame links instead caught the links'
    # identity switches in crowds, outliers that grow with the shift and pulled the minimum
    # towards no shift (0.07 frame found for a 0.51 frame error)
    g = np.arange(pair.frames.size)
    shifts = np.linspace(-window, window, n_samples)
    ok = pair.ok.copy()
    xb = []
    for shift in shifts:
        cand = interpolate_views(pair.keypoints, pair.links,
                                 pair.frames - shift / pair.cam_b.time_rate)
        dist = person_distances(cand, pair.base)
        p = np.argmin(dist, axis=1)
        xb.append(cand[g, p])
        ok &= np.isfinite(xb[-1][..., 0]) & (dist[g, p] < pair.gate)[:, None]
    n = int(ok.sum())
    if n < 50:
        return None
    view_a = _View.of(pair.xa[ok])
    costs = np.array([cauchy_cost(_fit_fundamental(view_a,
                                                   _View.of(pinhole_pixels(pair.cam_b, x[ok])),
                                                   huber_px, 4)[1], huber_px)
                      for x in xb])
    k = int(np.argmin(costs))
    if k in (0, shifts.size - 1):
        return "edge"
    low_ends = (costs[0] < min_contrast * costs[k]) + (costs[-1] < min_contrast * costs[k])
    if low_ends == 2:
        return None
    if low_ends == 1:
        # rising on one side only: the lowest cost may lie beyond the other end (the paper's
        # walker 1.37 frames off had its lowest sample at -1.1 of +-1.5 and -1.5 within 0.1 %)
        return "edge"
    fit = quadratic_minimum(shifts, costs, shifts[k], window / 2)
    if fit is None:
        return None
    best, curvature = fit
    step = shifts[1] - shifts[0]
    best = float(np.clip(best, shifts[k] - step, shifts[k] + step))
    return best, float(np.sqrt(2.0 * costs[k] / (n * curvature))), n, shifts, costs


def _solve_corrections(n_cams: int, reference: int, pairs: list[PairShift], tolerance: float
                       ) -> tuple[NDArray[np.float64], NDArray[np.bool_]]:
    """Per-camera corrections from pairwise shifts (``d_j - d_i = shift``), reference 0, by
    L1 weighted with 1 / sd; a camera keeps 0 unless some pair within ``tolerance`` frames of
    the solution reaches it."""
    d = np.zeros(n_cams)
    reached = np.zeros(n_cams, dtype=bool)
    if not pairs:
        return d, reached
    A = np.zeros((len(pairs), n_cams))
    for r, p in enumerate(pairs):
        A[r, p.j], A[r, p.i] = 1.0, -1.0
    y = np.array([p.shift for p in pairs])
    w = 1.0 / np.array([max(p.sd, 1e-3) for p in pairs])
    free = np.arange(n_cams) != reference
    d[free] = irls_l1(A[:, free], y, w, 20, 1e-3)
    good = np.abs(A @ d - y) <= tolerance
    # reached: connected to the reference through agreeing pairs
    reached[reference] = True
    for _ in range(n_cams):
        for p, g in zip(pairs, good, strict=True):
            if g and (reached[p.i] or reached[p.j]):
                reached[p.i] = reached[p.j] = True
    return np.where(reached, d, 0.0), reached


def _search_pairs(obs: NDArray[np.float64], times: NDArray[np.float64],
                  keypoints: list[NDArray[np.float64]], links: list[NDArray[np.int64]],
                  cams: list[Camera], search: tuple[float, int, bool], max_points: int,
                  huber_px: float, min_contrast: float, n_workers: int,
                  rng: np.random.Generator) -> list[PairShift]:
    """:func:`_pair_shift` of every camera pair (``search``: window, samples, widen)."""
    ij = [(i, j) for i in range(len(cams)) for j in range(i + 1, len(cams))]
    seeds = rng.integers(2**62, size=len(ij))  # one stream per pair: any order, same result

    def one(k: int) -> PairShift | None:
        i, j = ij[k]
        return _pair_shift(i, j, obs, times, keypoints[j], links[j], cams, *search[:2],
                           max_points, huber_px, min_contrast, np.random.default_rng(seeds[k]),
                           widen=search[2])

    # numpy's interpolation and products release the GIL: two pairs at a time
    with ThreadPoolExecutor(max_workers=n_workers) as pool:
        return [p for p in pool.map(one, range(len(ij))) if p is not None]


def pair_cost(keypoints: list[NDArray[np.float64]], links: list[NDArray[np.int64]],
              cams: list[Camera], times: NDArray[np.float64], *, height: float,
              huber_px: float = 2.0, max_points: int = 8000,
              rng: np.random.Generator | int | None = None) -> tuple[float, int] | None:
    """How well one two-view geometry explains two cameras' people at their clocks.

    Persons are matched by ground position alone (stage V's first-round gate, no triangulation
    check: with a wrong clock the check would keep just the coincidences that look right), a
    fundamental matrix is fitted robustly to their joints, and the cost is the mean Cauchy
    loss of the Sampson distances, as in the clock search. It compares *hypotheses* of one
    pair: each candidate offset of a periodic walk with its own ground alignment. One lap off,
    the ground paths of a walker coincide to decimetres, but the joints seen at different
    instants fit no epipolar geometry.

    Parameters
    ----------
    keypoints : list of ndarray, shape (F_c, P_c, 26, 3)
        The two cameras' canonical detections.
    links : list of ndarray, shape (F_c, P_c)
        Their frame links.
    cams : list of Camera
        The two cameras in one ground frame with the clocks to test.
    times : ndarray, shape (T,)
        Reference times compared.
    height : float
        Mean person height (m) for the ground positions.

    Returns
    -------
    (cost, n_points), or None with fewer than 10 shared person-frames.
    """
    views = [interpolate_views(k, lk, (times - c.time_offset) / c.time_rate)
             for k, lk, c in zip(keypoints, links, cams, strict=True)]
    assoc = first_association(views, cams, times, height, consistency=np.inf)
    obs = assoc.obs[:, :, EPIPOLAR_JOINTS]
    shared = shared_groups(obs[:, 0], obs[:, 1], max_points, np.random.default_rng(rng))
    if shared is None:
        return None
    groups, ok = shared
    sel = ok[groups]
    xa = pinhole_pixels(cams[0], obs[groups, 0, :, :2])[sel]
    xb = pinhole_pixels(cams[1], obs[groups, 1, :, :2])[sel]
    d = _fit_fundamental(_View.of(xa), _View.of(xb), huber_px, 4)[1]
    return cauchy_cost(d, huber_px), int(sel.sum())


def epipolar_clocks(tracks: list[Tracks], calibration: Calibration, *, height: float = 1.70,
                    window: float = 1.5, n_times: int = 300, max_points: int = 8000,
                    iterations: int = 2, huber_px: float = 2.0, tolerance: float = 0.3,
                    min_contrast: float = 1.05, settle: float = 0.15, n_workers: int = 2,
                    rng: np.random.Generator | int | None = None,
                    data: SessionData | None = None) -> EpipolarClocks:
    """Correct every camera's time offset by the epipolar consistency of the people's joints.

    Parameters
    ----------
    tracks : list of Tracks
        One per camera of ``calibration`` (matched by name).
    calibration : Calibration
        Stage IV's rig: one world frame, clocks good to a frame or so.
    height : float
        Mean person height (m), for the ground positions that match persons across cameras.
    window : float
        Correction searched in the first iteration (reference frames); a pair whose best
        shift lies on its edge is searched again over twice the window (stage IV left a
        periodic walk 2.5 frames off). Each later iteration searches half as far.
    n_times : int
        Reference times associated (evenly spread).
    max_points : int
        Joint correspondences per camera pair (a random subset of the groups beyond).
    iterations : int
        Most searches. Search, correct, re-associate: the association is made at the current
        clocks and holds each search a little towards them (a first search left a third of a
        0.5-0.7 frame error on simulated crowds), so a second search from the corrected clocks
        follows, unless no camera moved by ``settle`` frames or more.
    huber_px : float
        Scale (px) of the Cauchy loss of the Sampson distances in the cost (the name is from
        the Huber loss it once was), and the smallest scale of the fundamental matrix's
        robust kernel.
    tolerance : float
        Pairs farther than this (frames) from the global solution are outvoted.
    min_contrast : float
        A pair counts only if the cost at both ends of its window is at least this factor
        above its lowest sample (on a short recording of a crowd, the second search's curves
        varied by 2-3 % from sample to sample, as much as over its whole window).
    n_workers : int
        Threads searching camera pairs.
    rng : Generator or int, optional
        For the subsets of correspondences.
    data : SessionData, optional
        ``tracks`` as :func:`~cascalib.stages.reconstruct.prepare` makes them for
        ``calibration`` (its camera order and reference), if the caller has them already
        (stage IV does: about 0.4 s of 4 cameras x 3000 frames x 5 persons).

    Returns
    -------
    EpipolarClocks
    """
    rng = np.random.default_rng(rng)
    if data is None:
        data = prepare(list(tracks), calibration)
    data = clock_check_times(data, n_times)
    joints = EPIPOLAR_JOINTS
    kps = [np.ascontiguousarray(k[:, :, joints, :2]) for k in data.keypoints]
    cams = list(calibration.cameras)
    n_cams = len(cams)
    total = np.zeros(n_cams)
    pairs: list[PairShift] = []
    accepted = np.zeros(n_cams, dtype=bool)
    for it in range(iterations):
        assoc = first_association(views_at(data, cams), cams, data.times, height,
                                   reference=data.reference)
        # the first search spans the window (twice it for a pair whose best shift lies on its
        # edge); later ones start closer and look half as far
        search = (window, 9, True) if it == 0 else (window / 2**it, 7, False)
        found = [replace(p, iteration=it, base=float(total[p.j] - total[p.i]))
                 for p in _search_pairs(assoc.obs[:, :, joints], assoc.times, kps, data.links,
                                        cams, search, max_points, huber_px, min_contrast,
                                        n_workers, rng)]
        d, reached = _solve_corrections(n_cams, data.reference, found, tolerance)
        log.debug("pair shifts: %s", ", ".join(f"{p.i}-{p.j} {p.shift:+.3f}" for p in found))
        log.info("epipolar clocks, iteration %d: %s", it + 1, ", ".join(
            f"{c.name} {dk:+.3f}" for c, dk in zip(cams, d, strict=True)))
        cams = [c.with_(time_offset=c.time_offset + float(d[k])) for k, c in enumerate(cams)]
        total += d
        pairs += found
        accepted |= reached
        if np.abs(d).max() < settle:
            break  # the association barely moves: another search would find what this one did
    names = calibration.names
    out = Calibration(cams, reference_camera=calibration.reference_camera,
                      quality=calibration.quality, world=calibration.world)
    return EpipolarClocks(out, {n: float(v) for n, v in zip(names, total, strict=True)}, pairs,
                          {n: bool(r) for n, r in zip(names, accepted, strict=True)})
