"""Stage II: time synchronisation of two cameras from their ground-plane trajectories.

The paper (sec. "1D Temporal Search") compares the distance of each ground point from the
centroid between two cameras over integer offsets. That signal discards the direction of
motion, so a person walking in a circle gives a periodic cost with near-equal minima one period
apart (paper, "Failure Case: Periodic Motion"). Here the comparison keeps the full 2D shape:

* every tracklet of camera A is cut into chunks of a few seconds; for every chunk, every
  tracklet of camera B and **every** integer offset at once, the closed-form 2D Procrustes fit
  (rotation, translation and, optionally, scale: the stage-I metric error) and its residual are
  computed with FFT cross-correlations of the masked complex trajectories ``z = x + iy``;
* a chunk votes, at each offset, for its best-fitting B tracklet with weight
  ``n * exp(-rms^2 / 2 sigma^2)`` into a histogram over (offset, rotation angle): the yaw between
  two cameras is one number for all people and all times, so at a wrong offset the chunks'
  rotations scatter while at the right one they pile up in one bin. Walking one period of a
  loop too far fits each chunk but only as well as two different laps agree, which is far worse
  than the detection noise at the true offset;
* the best few peaks (offset, angle) are returned as candidates for the ICP verification
  (:mod:`cascalib.stages.icp`), which picks the winner and refines to sub-frame offset and rate.

Time is measured on a common grid: reference-camera frames, using the frame-rate prior
``rho = fps_ref / fps_cam`` (grid time of native frame ``k`` is ``rho * k``). The residual rate
is estimated later.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy import fft as sfft
from scipy.ndimage import gaussian_filter1d

from cascalib.stages.ground import GroundTracks

__all__ = ["GridTrack", "SyncCandidate", "SyncCurve", "irls_l1", "resample_tracks",
           "search_offsets", "solve_time"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class GridTrack:
    """Tracklets of one camera resampled on a regular grid of reference-frame time.

    Parameters
    ----------
    camera : str
    step : float
        Grid spacing in reference frames.
    start : ndarray of int, shape (n_tracklets,)
        Grid index of each tracklet's first sample (grid time ``start * step``).
    xy : list of ndarray, each shape (n_i, 2)
        Positions, NaN where the tracklet had a gap.
    length : int
        Number of grid samples covering the camera's whole video.
    """

    camera: str
    step: float
    start: NDArray[np.int64]
    xy: list[NDArray[np.float64]]
    length: int


@dataclass(frozen=True)
class SyncCandidate:
    """One peak of the pairwise offset search.

    ``offset`` (reference frames): grid time ``u_a`` of camera A shows the same instant as grid
    time ``u_a - offset`` of camera B. ``angle`` (radians) rotates B's ground frame into A's.
    """

    offset: float
    angle: float
    score: float


@dataclass(frozen=True)
class SyncCurve:
    """Result of :func:`search_offsets` for one camera pair.

    Parameters
    ----------
    offsets : ndarray, shape (n,)
        Candidate offsets (reference frames).
    score : ndarray, shape (n,)
        Vote mass at each offset (higher is better); the plot shows ``-score`` as a cost.
    candidates : list of SyncCandidate
        Best peaks, best first.
    peak_ratio : float
        Second-best peak score over the best (1 = ambiguous, 0 = unique).
    angles : ndarray, shape (n,), optional
        The rotation (radians, B -> A) of the strongest histogram bin at each offset: a start
        for ICP at offsets that are not among the candidates.
    """

    offsets: NDArray[np.float64]
    score: NDArray[np.float64]
    candidates: list[SyncCandidate]
    peak_ratio: float
    angles: NDArray[np.float64] | None = None


def _smooth(frames: NDArray[np.int64], xy: NDArray[np.float64], sigma: float
            ) -> NDArray[np.float64]:
    """Gaussian smoothing over native frames with gaps (normalised convolution)."""
    if sigma <= 0:
        return xy
    idx = frames - frames[0]
    m = np.zeros(idx[-1] + 1)
    v = np.zeros((idx[-1] + 1, 2))
    m[idx] = 1.0
    v[idx] = xy
    ms = gaussian_filter1d(m, sigma, mode="constant")
    vs = gaussian_filter1d(v, sigma, axis=0, mode="constant")
    return vs[idx] / ms[idx, None]


def resample_tracks(ground: GroundTracks, rho: float, step: float, *, max_gap: int = 3,
                    min_samples: int = 5, smooth: float = 0.0) -> GridTrack:
    """Resample tracklets at grid times ``g * step`` (reference frames) by linear interpolation.

    Parameters
    ----------
    ground : GroundTracks
    rho : float
        Reference frames per native frame (frame-rate prior).
    step : float
        Grid spacing in reference frames.
    max_gap : int
        Native frames across which interpolation is allowed.
    smooth : float
        Gaussian smoothing s.d. in native frames before resampling. Interpolating white noise
        halfway between samples halves its variance, which biases a sub-frame offset fit
        towards half frames; smoothing first makes the noise correlated and removes the bias.
    """
    starts, xys = [], []
    for tl in ground.tracklets:
        u = rho * tl.frames.astype(np.float64)
        g = np.arange(int(np.ceil(u[0] / step)), int(np.floor(u[-1] / step)) + 1)
        if g.size < min_samples:
            continue
        ug = g * step
        src = _smooth(tl.frames, tl.xy, smooth)
        xy = np.stack([np.interp(ug, u, src[:, k]) for k in (0, 1)], axis=1)
        right = np.clip(np.searchsorted(u, ug), 1, u.size - 1)
        gap = tl.frames[right] - tl.frames[right - 1]
        exact = np.isclose(u[np.clip(np.searchsorted(u, ug), 0, u.size - 1)], ug)
        xy[(gap > max_gap) & ~exact] = np.nan
        starts.append(int(g[0]))
        xys.append(xy)
    length = int(np.floor(rho * (ground.n_frames - 1) / step)) + 1
    return GridTrack(ground.camera, step, np.asarray(starts, np.int64), xys, length)


def _chunks(track: GridTrack, chunk: int, min_samples: int, min_spread: float
            ) -> list[tuple[int, NDArray[np.float64]]]:
    """Cut tracklets into chunks of at most ``chunk`` samples that move by ``min_spread`` m."""
    out = []
    for s0, xy in zip(track.start, track.xy, strict=True):
        n = len(xy)
        n_parts = max(1, int(np.ceil(n / chunk)))
        edges = np.linspace(0, n, n_parts + 1).astype(int)
        for a, b in zip(edges[:-1], edges[1:], strict=True):
            part = xy[a:b]
            ok = np.isfinite(part[:, 0])
            if ok.sum() < min_samples:
                continue
            if np.sqrt(np.nanvar(part[:, 0]) + np.nanvar(part[:, 1])) < min_spread:
                continue  # a person standing still says nothing about time
            out.append((int(s0 + a), part))
    return out


def _lanes(track: GridTrack, min_gap: int) -> list[list[int]]:
    """Pack tracklets into lanes whose members are at least ``min_gap`` samples apart.

    A chunk's overlap window is shorter than ``min_gap``, so it never spans two tracklets of
    one lane: fitting a chunk against a lane is fitting it against one tracklet, and there are
    about as many lanes as people seen at once instead of one per tracklet.
    """
    ends: list[int] = []
    lanes: list[list[int]] = []
    for i in np.argsort(track.start, kind="stable"):
        s0 = int(track.start[i])
        free = [k for k, e in enumerate(ends) if e + min_gap <= s0]
        if free:
            k = free[0]
        else:
            k = len(ends)
            ends.append(0)
            lanes.append([])
        ends[k] = s0 + len(track.xy[i])
        lanes[k].append(int(i))
    return lanes


def _dense(track: GridTrack, n_fft: int, min_gap: int) -> tuple[NDArray[np.complex128], ...]:
    """FFTs of mask, mask*z and mask*|z|^2 of every lane on the full grid, (n_lanes, n_fft)."""
    lanes = _lanes(track, min_gap)
    m = np.zeros((len(lanes), n_fft))
    z = np.zeros((len(lanes), n_fft), np.complex128)
    for k, members in enumerate(lanes):
        for i in members:
            xy = track.xy[i]
            ok = np.isfinite(xy[:, 0])
            idx = track.start[i] + np.arange(len(xy))
            m[k, idx[ok]] = 1.0
            z[k, idx[ok]] = xy[ok, 0] + 1j * xy[ok, 1]
    return (sfft.fft(m, axis=1), sfft.fft(z, axis=1),
            sfft.fft(m * np.abs(z) ** 2, axis=1))


def _chunk_fit(parts: list[NDArray[np.float64]], G: tuple[NDArray[np.complex128], ...],
               n_fft: int, lags: NDArray[np.int64], min_samples: int, scale_range: float,
               sigma: float) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Procrustes fit of each chunk against every B tracklet at every lag.

    Returns the vote ``n * exp(-rms^2 / 2 sigma^2)`` of the best-fitting B tracklet at each lag
    and that fit's rotation angle (A -> B), each shape (n_chunks, n_lags). The chunks go
    through the FFTs together: one at a time, the many small numpy calls held the GIL, so that
    camera pairs in threads ran no faster than one after another (4 x 3000 x 5: 2.15 s for the
    six searches serially, 2.28 s in two threads; blocked, 1.28 s in two threads).
    """
    m = np.zeros((len(parts), n_fft))
    za = np.zeros((len(parts), n_fft), np.complex128)
    for k, part in enumerate(parts):
        ok = np.isfinite(part[:, 0])
        m[k, : len(part)] = ok
        za[k, : len(part)] = np.where(ok, part[:, 0] + 1j * part[:, 1], 0)
    F1 = np.conj(sfft.fft(m, axis=1))[:, None]
    F2 = np.conj(sfft.fft(za, axis=1))[:, None]
    F3 = np.conj(sfft.fft(m * np.abs(za) ** 2, axis=1))[:, None]
    G1, G2, G3 = G

    def corr(F: NDArray[np.complex128], Gk: NDArray[np.complex128]) -> NDArray[np.complex128]:
        return sfft.ifft(F * Gk, axis=-1)  # (chunks, lanes, n_fft)

    X1 = corr(F1, G1 + 1j * G3)
    n = np.round(X1.real[..., lags])
    good = n >= min_samples
    # a chunk overlaps a lane at about a third of the lags: the fit only there, on the
    # flattened (chunks, lanes, n_fft) positions of those correlations
    b_l, j = np.nonzero(good.reshape(-1, lags.size))
    at = b_l * n_fft + lags[j]

    def pick(v: NDArray[np.complex128]) -> NDArray[np.complex128]:
        return v.reshape(-1)[at]

    nn, qb = n[good], pick(X1).imag
    sb, c = pick(corr(F1, G2)), pick(corr(F2, G2))
    sa = np.conj(pick(corr(F2, G1)))
    qa = pick(corr(F3, G1)).real
    va = np.maximum(qa - (sa.real**2 + sa.imag**2) / nn, 1e-12)
    vb = np.maximum(qb - (sb.real**2 + sb.imag**2) / nn, 0.0)
    x = c - sb * np.conj(sa) / nn
    ax = np.abs(x)
    s = np.clip(ax / va, 1.0 / scale_range, scale_range)  # b ~ s R a, stage-I scale
    res = np.maximum(vb - 2 * s * ax + s * s * va, 0.0) / nn
    support, angle = np.zeros(good.shape), np.zeros(good.shape)
    support[good] = nn * np.exp(-0.5 * res / sigma**2)
    angle[good] = np.angle(x)
    best = np.argmax(support, axis=1)[:, None]
    return (np.take_along_axis(support, best, 1)[:, 0],
            np.take_along_axis(angle, best, 1)[:, 0])


def search_offsets(a: GridTrack, b: GridTrack, *, max_offset: float | None = None,
                   chunk_seconds_frames: int = 150, min_overlap: int = 20,
                   min_spread: float = 0.3, sigma: float = 0.2, scale_range: float = 1.0,
                   angle_bins: int = 36, n_candidates: int = 3,
                   nms_frames: float = 15.0) -> SyncCurve:
    """Score every integer (grid) offset between cameras A and B; see the module docstring.

    Parameters
    ----------
    a, b : GridTrack
        Both on the same grid step.
    max_offset : float, optional
        Largest |offset| searched (reference frames); default: every offset with overlap.
    chunk_seconds_frames : int
        Chunk length of A's tracklets in reference frames.
    min_overlap : int
        Least number of overlapping grid samples for a chunk to vote.
    min_spread : float
        Chunks whose positions spread less (m, RMS) are skipped.
    sigma : float
        Residual scale of the vote kernel (m).
    scale_range : float
        Allowed relative scale between the two ground frames (1 = rigid).
    angle_bins : int
        Rotation histogram bins over 360 degrees.

    Returns
    -------
    SyncCurve
    """
    step = a.step
    chunk = max(min_overlap, int(round(chunk_seconds_frames / step)))
    n_fft = sfft.next_fast_len(b.length + chunk + 1)
    lag_min, lag_max = -(chunk - 1), b.length - 1
    lags = np.arange(lag_min, lag_max + 1)
    lag_idx = lags % n_fft
    n_off = a.length + b.length - 1  # offset index: (p - lag) + b.length - 1
    hist = np.zeros((n_off + chunk, angle_bins))
    chunks = _chunks(a, chunk, min_overlap, min_spread)
    if not chunks or not b.xy:  # nobody walking in one of the views: nothing to compare
        offsets = (np.arange(n_off) - (b.length - 1)) * step
        logger.warning("sync %s-%s: no moving person in one of the views", a.camera, b.camera)
        return SyncCurve(offsets, np.zeros(n_off), [], 1.0)  # type: ignore[arg-type]
    G = _dense(b, n_fft, chunk + 1)
    # blocks of chunks: each (chunks, lanes, n_fft) correlation stays about 8 MB
    block = max(1, int(2**19 // (G[0].shape[0] * n_fft)))
    for k0 in range(0, len(chunks), block):
        sup, th = _chunk_fit([part for _, part in chunks[k0:k0 + block]], G, n_fft, lag_idx,
                             min_overlap, scale_range, sigma)
        for (p, _), sup_p, th_p in zip(chunks[k0:k0 + block], sup, th, strict=True):
            off_idx = p - lags + b.length - 1
            keep = (sup_p > 1e-3) & (off_idx >= 0) & (off_idx < n_off)
            bins = np.floor((-th_p[keep] % (2 * np.pi)) / (2 * np.pi) * angle_bins).astype(int)
            np.add.at(hist, (off_idx[keep], bins % angle_bins), sup_p[keep])
    hist = hist[:n_off]
    smooth = 0.5 * hist + 0.25 * (np.roll(hist, 1, axis=1) + np.roll(hist, -1, axis=1))
    offsets = (np.arange(n_off) - (b.length - 1)) * step
    score = smooth.max(axis=1)
    if max_offset is not None:
        score = np.where(np.abs(offsets) <= max_offset, score, 0.0)
    cands = _peaks(offsets, score, smooth, angle_bins, n_candidates - n_candidates // 2,  # type: ignore[arg-type]
                   nms_frames)
    # Large offsets overlap little and collect few votes: also take the best peaks of the
    # vote per sqrt(overlap), so a short true overlap can beat a long periodic near-fit in
    # the (per-frame) ICP verification.
    overlap = _overlap(a, b, n_off)
    norm = score / np.sqrt(np.maximum(overlap, 4 * min_overlap))
    for c in _peaks(offsets, norm, smooth, angle_bins, n_candidates, nms_frames):  # type: ignore[arg-type]
        if len(cands) >= n_candidates:
            break
        if all(abs(c.offset - d.offset) >= nms_frames for d in cands):
            i = int(np.argmin(np.abs(offsets - c.offset)))
            cands.append(SyncCandidate(c.offset, c.angle, float(score[i])))
    ratio = cands[1].score / cands[0].score if len(cands) > 1 and cands[0].score > 0 else 0.0
    logger.debug("sync %s-%s: %d chunks, best offset %.1f (ratio %.2f)", a.camera, b.camera,
                 len(chunks), cands[0].offset if cands else np.nan, ratio)
    angles = (np.argmax(smooth, axis=1) + 0.5) * 2 * np.pi / angle_bins
    return SyncCurve(offsets, score, cands, float(ratio), np.angle(np.exp(1j * angles)))  # type: ignore[arg-type]


def _overlap(a: GridTrack, b: GridTrack, n_off: int) -> NDArray[np.float64]:
    """Grid samples where both cameras see someone, per offset index (as in the vote)."""
    def present(t: GridTrack) -> NDArray[np.float64]:
        m = np.zeros(t.length + max((s + len(x) for s, x in zip(t.start, t.xy, strict=True)),
                                    default=0))
        for s0, xy in zip(t.start, t.xy, strict=True):
            m[s0 + np.flatnonzero(np.isfinite(xy[:, 0]))] = 1.0
        return m
    ma, mb = present(a), present(b)
    n_fft = sfft.next_fast_len(ma.size + mb.size)
    corr = sfft.irfft(sfft.rfft(ma, n_fft) * np.conj(sfft.rfft(mb, n_fft)), n_fft)
    # offset index k <-> a index = b index + (k - (b.length - 1))
    d = np.arange(n_off) - (b.length - 1)
    return np.maximum(np.round(corr[d % n_fft]), 0.0)


def _peaks(offsets: NDArray[np.float64], score: NDArray[np.float64], hist: NDArray[np.float64],
           angle_bins: int, k: int, nms: float) -> list[SyncCandidate]:
    """Top ``k`` local maxima of ``score`` at least ``nms`` frames apart."""
    order = np.argsort(-score)
    out: list[SyncCandidate] = []
    for i in order:
        if score[i] <= 0 or len(out) >= k:
            break
        if any(abs(offsets[i] - c.offset) < nms for c in out):
            continue
        j = int(np.argmax(hist[i]))
        # sub-bin angle from the histogram's neighbours (circular mean of three bins)
        nb = np.array([j - 1, j, j + 1]) % angle_bins
        ang = (nb + 0.5) * 2 * np.pi / angle_bins
        w = hist[i, nb]
        angle = float(np.angle(np.sum(w * np.exp(1j * ang))))
        out.append(SyncCandidate(float(offsets[i]), angle, float(score[i])))
    return out


def solve_time(n_cams: int, edges: list[tuple[float, ...]], reference: int, *,
               tolerance: float = 2.0, rate_tolerance: float = 3.0, n_iter: int = 20
               ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Globally consistent clock models from pairwise estimates.

    Each edge ``(i, j, offset, log_rate, weight[, offset_sd, log_rate_sd])`` says grid time
    ``u_i = exp(log_rate) * u_j + offset``. Unknowns per camera: ``ref = a_c * u_c + b_c``
    (``a_ref = 1, b_ref = 0``). Log-rates then offsets are solved by iteratively reweighted L1
    with the edge weights (so that a single wrong pair, e.g. a period-off peak, is outvoted by
    the cycles through the other cameras); edges whose offset residual exceeds ``tolerance``
    frames are rejected and the rest are averaged by least squares weighted by their standard
    deviations (when given; else by ``weight``). An accepted edge whose log-rate is more than
    ``rate_tolerance`` of its s.d. from the L1 solution is left out of that average (but stays
    accepted), unless leaving it out would disconnect a camera: its offset at ``u = 0`` is tied
    to the rate it found.

    Returns
    -------
    a, b : ndarray, shape (n_cams,)
    accepted : ndarray of bool, shape (n_edges,)
    """
    if not edges:
        return np.ones(n_cams), np.zeros(n_cams), np.zeros(0, bool)
    E = np.array([tuple(e) + (np.nan, np.nan)[: 7 - len(e)] for e in edges], dtype=np.float64)
    i, j = E[:, 0].astype(int), E[:, 1].astype(int)
    w0 = np.maximum(E[:, 4], 1e-6)
    A = np.zeros((len(E), n_cams))
    A[np.arange(len(E)), j] = 1.0
    A[np.arange(len(E)), i] -= 1.0
    free = np.arange(n_cams) != reference
    log_a = np.zeros(n_cams)
    log_a[free] = irls_l1(A[:, free], E[:, 3], w0, n_iter, 1e-6)
    b = np.zeros(n_cams)
    b[free] = irls_l1(A[:, free], np.exp(log_a)[i] * E[:, 2], w0, n_iter, 1e-2)
    ok = np.abs(A @ b - np.exp(log_a)[i] * E[:, 2]) <= tolerance
    if ok.any():
        # a single pair that finds a drift the cycles through the other cameras do not show
        # (crowd, 40 s, seed 0: one pair at +0.31 % with an s.d. of 0.08 %, five at 0) would
        # otherwise pull every camera's rate by a share of it
        sd_r = E[:, 6]
        with np.errstate(invalid="ignore"):
            rate_ok = ~np.isfinite(sd_r) | (np.abs(A[:, free] @ log_a[free] - E[:, 3])
                                             <= rate_tolerance * sd_r)
        use = ok & rate_ok
        if np.linalg.matrix_rank(A[use][:, free]) < np.linalg.matrix_rank(A[ok][:, free]):
            use = ok
        # the consistent pairs agree to noise level: average them by weighted least squares
        w_r = np.where(np.isfinite(sd_r), 1.0 / (sd_r ** 2 + 1e-10), w0)[use]
        w_o = np.where(np.isfinite(E[:, 5]), 1.0 / (E[:, 5] ** 2 + 1e-4), w0)[use]
        Ak = A[use][:, free]
        log_a[free] = _wlstsq(Ak, E[use, 3], w_r)
        b[free] = _wlstsq(Ak, np.exp(log_a)[i[use]] * E[use, 2], w_o)
    return np.exp(log_a), b, ok


def _wlstsq(A: NDArray[np.float64], y: NDArray[np.float64], w: NDArray[np.float64]
            ) -> NDArray[np.float64]:
    sw = np.sqrt(w / w.max())
    return np.linalg.lstsq(A * sw[:, None], y * sw, rcond=None)[0]


def irls_l1(A: NDArray[np.float64], y: NDArray[np.float64], w0: NDArray[np.float64],
             n_iter: int, eps: float) -> NDArray[np.float64]:
    """Weighted L1 regression ``min sum w0 |A x - y|`` by iteratively reweighted least squares.
    Unconnected unknowns stay 0 (minimum-norm solution)."""
    w = w0.copy()
    x = np.zeros(A.shape[1])
    for _ in range(n_iter):
        sw = np.sqrt(w)
        x = np.linalg.lstsq(A * sw[:, None], y * sw, rcond=None)[0]  # type: ignore[assignment]
        r = np.abs(A @ x - y)
        w = w0 / np.maximum(r, eps)
    return x
