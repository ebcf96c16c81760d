"""Stage IV: ICP between two cameras' ground trajectories, then sub-frame time and rate.

Paper, "Iterative Closest Point": with the time shift known, points are associated frame by
frame (Hungarian matching when several people are present) and the 2D rotation and translation
re-estimated until convergence. Here:

* the per-frame assignment is truncated (a pair farther apart than the gate costs the gate, so
  people seen by one camera only stay unmatched) and vectorised over frames by enumerating the
  permutations for up to six people (``scipy.optimize.linear_sum_assignment`` beyond);
* the fit is a trimmed similarity (Umeyama) whose scale is clamped to the stage-I error range;
* :func:`refine_sync` then fits the offset (sub-frame), the residual frame-rate ratio and the
  similarity jointly by robust least squares on the matched tracklets, interpolating camera B's
  trajectory at continuous times: time is the third coordinate of the alignment.
"""

from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass
from functools import cached_property

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares, linear_sum_assignment

from cascalib.geometry import umeyama
from cascalib.stages.sync import GridTrack

__all__ = ["Lanes", "Similarity2D", "IcpResult", "SyncFit", "dense_lanes", "assign_frames",
           "icp_pair", "refine_sync"]

logger = logging.getLogger(__name__)

_PERMS = {n: np.array(list(itertools.permutations(range(n)))) for n in range(1, 7)}


@dataclass(frozen=True)
class Similarity2D:
    """``x_a = scale * R(angle) @ x_b + t``."""

    angle: float
    t: NDArray[np.float64]
    scale: float = 1.0

    @property
    def R(self) -> NDArray[np.float64]:
        c, s = np.cos(self.angle), np.sin(self.angle)
        return np.array([[c, -s], [s, c]])

    def apply(self, xy: NDArray[np.float64]) -> NDArray[np.float64]:
        """Map points (..., 2) from B's frame to A's."""
        return self.scale * xy @ self.R.T + self.t

    def compose(self, other: Similarity2D) -> Similarity2D:
        """``self o other`` (apply ``other`` first)."""
        return Similarity2D(self.angle + other.angle, self.apply(other.t),
                            self.scale * other.scale)

    def inverse(self) -> Similarity2D:
        return Similarity2D(-self.angle, -(self.t @ self.R) / self.scale, 1.0 / self.scale)


@dataclass(frozen=True)
class Lanes:
    """A camera's grid tracks as a dense array: at most one tracklet per lane at a time.

    pos : (n_grid, n_lanes, 2), NaN empty; tid : (n_grid, n_lanes) tracklet index, -1 empty.
    """

    pos: NDArray[np.float64]
    tid: NDArray[np.int64]

    @cached_property
    def spans(self) -> dict[int, tuple[int, int]]:
        """First and last grid frame of every tracklet (computed once: every candidate's
        evidence needs them)."""
        g, k = np.nonzero(self.tid >= 0)
        t = self.tid[g, k]
        order = np.argsort(t, kind="stable")
        t, g = t[order], g[order]
        first = np.flatnonzero(np.r_[True, t[1:] != t[:-1]])
        last = np.r_[first[1:] - 1, t.size - 1]
        return {int(t[i]): (int(g[i]), int(g[j])) for i, j in zip(first, last, strict=True)}


def dense_lanes(track: GridTrack) -> Lanes:
    """Pack the tracklets of a step-1 :class:`GridTrack` into lanes (interval scheduling)."""
    ends: list[int] = []
    lane_of = []
    order = np.argsort(track.start, kind="stable")
    for i in order:
        s0, n = int(track.start[i]), len(track.xy[i])
        free = [k for k, e in enumerate(ends) if e <= s0]
        k = free[0] if free else len(ends)
        if k == len(ends):
            ends.append(0)
        ends[k] = s0 + n
        lane_of.append((i, k))
    n_grid = max(track.length, max((s + len(x) for s, x in zip(track.start, track.xy,
                                                                  strict=True)), default=0))
    pos = np.full((n_grid, max(1, len(ends)), 2), np.nan)
    tid = np.full((n_grid, max(1, len(ends))), -1, np.int64)
    for i, k in lane_of:
        s0, xy = int(track.start[i]), track.xy[i]
        pos[s0:s0 + len(xy), k] = xy
        tid[s0:s0 + len(xy), k] = np.where(np.isfinite(xy[:, 0]), i, -1)
    return Lanes(pos, tid)


def assign_frames(cost: NDArray[np.float64], gate2: float) -> NDArray[np.int64]:
    """Truncated optimal assignment per frame.

    Parameters
    ----------
    cost : ndarray, shape (n_frames, k, l)
        Squared distances, NaN where either side is missing.
    gate2 : float
        Pairs costing more than this are not matched.

    Returns
    -------
    ndarray of int, shape (n_frames, k)
        Column matched to each row, -1 if none.
    """
    g, k, m = cost.shape
    c = np.where(np.isfinite(cost), np.minimum(cost, gate2), gate2)
    out = np.full((g, k), -1, np.int64)
    if k == 0 or m == 0:
        return out
    # frames grouped by their problem size: rows/cols past the last present one are padding
    fin = np.isfinite(cost)
    nk = np.where(fin.any(2), np.arange(1, k + 1)[None, :], 0).max(1)
    nl = np.where(fin.any(1), np.arange(1, m + 1)[None, :], 0).max(1)
    size = np.maximum(nk, nl)
    for n in np.unique(size):
        fr = np.flatnonzero(size == n)
        if n == 0:
            continue
        if n <= 6:
            pad = np.full((fr.size, n, n), gate2)
            kk, mm = min(k, n), min(m, n)
            pad[:, :kk, :mm] = c[fr, :kk, :mm]
            perms = _PERMS[n]
            total = pad[:, np.arange(n)[None, :], perms].sum(-1)  # (frames, n_perm)
            best = perms[np.argmin(total, axis=1)][:, :kk]
            out[fr, :kk] = np.where(best < mm, best, -1)
        else:
            for f in fr:
                r, cc = linear_sum_assignment(c[f])
                out[f, r] = cc
    rows = np.arange(k)[None, :]
    matched = out >= 0
    val = np.where(matched, cost[np.arange(g)[:, None], rows, np.maximum(out, 0)], np.inf)
    out[~(np.nan_to_num(val, nan=np.inf) < gate2)] = -1
    return out


@dataclass(frozen=True)
class IcpResult:
    """Result of :func:`icp_pair`.

    transform : Similarity2D mapping B's ground frame into A's; score : sum of
    ``exp(-d^2 / 2 sigma^2)`` over matches (the candidate's evidence); rms : inlier RMS (m);
    n_matches : matched detections; n_frames : overlapping frames compared (of n_overlap);
    frames_a, lanes_a, frames_b, lanes_b : the matches;
    distances : their residual distances (m).
    """

    transform: Similarity2D
    score: float
    rms: float
    n_matches: int
    frames_a: NDArray[np.int64]
    lanes_a: NDArray[np.int64]
    frames_b: NDArray[np.int64]
    lanes_b: NDArray[np.int64]
    distances: NDArray[np.float64]
    n_frames: int = 0
    n_overlap: int = 0

    def evidence(self, sigma: float, la: Lanes | None = None, lb: Lanes | None = None
                 ) -> float:
        """Sum of ``exp(-d^2 / 2 sigma^2)`` over the matches.

        With the lanes, identities must persist: a tracklet of A may stand for several
        tracklets of B only when those never exist at the same time (one person whose track
        broke), and the other way round. People walking the same circle coincide now and then
        at a wrong offset, each time with another person, but never for the length of a
        tracklet. Tracklet pairs are accepted greedily by their summed weight.
        """
        w = np.exp(-0.5 * (self.distances / sigma) ** 2)
        if la is None or lb is None:
            return float(w.sum())
        ta = la.tid[self.frames_a, self.lanes_a]
        tb = lb.tid[self.frames_b, self.lanes_b]
        nb = int(tb.max(initial=0)) + 2
        uk, inv = np.unique(ta.astype(np.int64) * nb + (tb + 1), return_inverse=True)
        per_pair = np.bincount(inv.ravel(), weights=w, minlength=uk.size)
        span_a, span_b = la.spans, lb.spans
        taken_a: dict[int, list[tuple[int, int]]] = {}  # A tracklet -> spans of its B partners
        taken_b: dict[int, list[tuple[int, int]]] = {}
        total = 0.0
        for k in np.argsort(per_pair)[::-1]:
            a, b = int(uk[k] // nb), int(uk[k] % nb) - 1
            sa, sb = span_a[a], span_b[b]
            if _clash(sb, taken_a.get(a, [])) or _clash(sa, taken_b.get(b, [])):
                continue
            taken_a.setdefault(a, []).append(sb)
            taken_b.setdefault(b, []).append(sa)
            total += float(per_pair[k])
        return total


def _clash(span: tuple[int, int], others: list[tuple[int, int]], share: float = 0.2) -> bool:
    """Does ``span`` overlap any of ``others`` by more than ``share`` of the shorter one
    (trackers overlap broken pieces of one person by a few frames)?"""
    for o in others:
        common = min(span[1], o[1]) - max(span[0], o[0]) + 1
        if common > share * (1 + min(span[1] - span[0], o[1] - o[0])):
            return True
    return False


def _overlap_frames(la: Lanes, lb: Lanes, offset: int, max_frames: int
                    ) -> tuple[NDArray[np.int64], int]:
    """Frames of A (at most ``max_frames``, evenly spread) where both cameras see someone,
    and how many such frames there are in all."""
    ga = np.arange(la.pos.shape[0])
    gb = ga - offset
    ok = (gb >= 0) & (gb < lb.pos.shape[0])
    ga = ga[ok]
    ok = np.isfinite(la.pos[ga, :, 0]).any(1) & np.isfinite(lb.pos[ga - offset, :, 0]).any(1)
    ga = ga[ok]
    n_all = int(ga.size)
    if ga.size > max_frames:
        ga = ga[np.linspace(0, ga.size - 1, max_frames).astype(int)]
    return ga, n_all


def _compact(pos: NDArray[np.float64]) -> tuple[NDArray[np.float64], NDArray[np.int64]]:
    """Move each frame's present lanes to the front: (g, k, 2) -> (g, k_eff, 2) and the lane
    index of each kept column (sparse lanes would otherwise blow up the assignment)."""
    valid = np.isfinite(pos[..., 0])
    order = np.argsort(~valid, axis=1, kind="stable")
    k_eff = max(1, int(valid.sum(1).max()))
    order = order[:, :k_eff]
    return np.take_along_axis(pos, order[..., None], axis=1), order


def _init_translation(pa: NDArray[np.float64], pb: NDArray[np.float64], angle: float,
                      bin_size: float = 0.25) -> NDArray[np.float64]:
    """Mode of all per-frame differences ``a - R b`` (robust to unmatched people)."""
    c, s = np.cos(angle), np.sin(angle)
    qb = pb @ np.array([[c, -s], [s, c]]).T
    if len(pa) > 300:
        sel = np.linspace(0, len(pa) - 1, 300).astype(int)
        pa, qb = pa[sel], qb[sel]
    d = (pa[:, :, None, :] - qb[:, None, :, :]).reshape(-1, 2)
    d = d[np.isfinite(d).all(1)]
    if d.size == 0:
        return np.zeros(2)
    q = np.round(d / bin_size).astype(np.int64)
    u, inv, cnt = np.unique(q, axis=0, return_inverse=True, return_counts=True)
    best = int(np.argmax(cnt))
    near = np.abs(q - u[best]).max(1) <= 1
    return np.median(d[near], axis=0)


def icp_pair(la: Lanes, lb: Lanes, offset: int, angle: float, *, sigma: float = 0.2,
             gate: float = 1.5, min_gate: float = 0.3, scale_range: float = 1.0,
             n_iter: int = 15, max_frames: int = 2000, trim: float = 0.9) -> IcpResult | None:
    """Trimmed similarity ICP of B's ground points onto A's with frames matched by ``offset``.

    Parameters
    ----------
    la, lb : Lanes
        Step-1 grids of cameras A and B.
    offset : int
        Grid frame ``g`` of A matches frame ``g - offset`` of B.
    angle : float
        Initial rotation B -> A (radians).
    scale_range : float
        Largest allowed scale (and 1 / smallest); 1 = rigid.
    trim : float
        Fraction of the gated matches kept for the fit (the worst are dropped).

    Returns
    -------
    IcpResult, or None when the cameras share fewer than 10 matched detections.
    """
    ga, n_overlap = _overlap_frames(la, lb, offset, max_frames)
    if ga.size < 10:
        return None
    pa, ia = _compact(la.pos[ga])
    pb, ib = _compact(lb.pos[ga - offset])
    tr = Similarity2D(angle, _init_translation(pa, pb, angle))
    g2 = gate
    for it in range(n_iter):
        qb = tr.apply(pb)
        cost = ((pa[:, :, None, :] - qb[:, None, :, :]) ** 2).sum(-1)
        col = assign_frames(cost, g2**2)
        fi, ka = np.nonzero(col >= 0)
        kb = col[fi, ka]
        if fi.size < 10:
            return None
        d = np.sqrt(cost[fi, ka, kb])
        keep = d <= np.quantile(d, trim) if it > 2 else np.ones(d.size, bool)
        s, R, t = umeyama(pb[fi[keep], kb[keep]], pa[fi[keep], ka[keep]],
                          with_scale=scale_range > 1.0)
        s = float(np.clip(s, 1.0 / scale_range, scale_range))
        new = Similarity2D(float(np.arctan2(R[1, 0], R[0, 0])), t, s)
        if s != 1.0 and scale_range > 1.0:  # re-solve t for the clamped scale
            new = Similarity2D(new.angle, np.mean(pa[fi[keep], ka[keep]]
                                                  - s * pb[fi[keep], kb[keep]] @ new.R.T, 0), s)
        moved = np.abs(new.apply(pb[fi, kb]) - tr.apply(pb[fi, kb])).max()
        tr = new
        rms = float(np.sqrt(np.mean(d[keep] ** 2)))
        g2 = max(min_gate, min(g2, 4.0 * rms))
        if moved < 1e-3 and it > 2:
            break
    qb = tr.apply(pb)
    cost = ((pa[:, :, None, :] - qb[:, None, :, :]) ** 2).sum(-1)
    col = assign_frames(cost, g2**2)
    fi, ka = np.nonzero(col >= 0)
    kb = col[fi, ka]
    d2 = cost[fi, ka, kb]
    score = float(np.exp(-0.5 * d2 / sigma**2).sum())
    rms = float(np.sqrt(np.mean(d2))) if d2.size else np.inf
    return IcpResult(tr, score, rms, int(fi.size), ga[fi], ia[fi, ka], ga[fi] - offset,
                     ib[fi, kb], np.sqrt(d2), int(ga.size), n_overlap)


def _noise_sd(xa: NDArray[np.float64], xb: NDArray[np.float64],
              noise_a: tuple[NDArray[np.float64], float] | None,
              noise_b: tuple[NDArray[np.float64], float] | None, floor: float, scale: float
              ) -> NDArray[np.float64]:
    """Per-sample s.d. (m, A's frame) of ``x_a - T(x_b)`` under the ground noise models."""
    var = np.full(len(xa), floor**2)
    if noise_a is not None:
        var += (noise_a[1] * np.sum((xa - noise_a[0]) ** 2, axis=1)) ** 2
    if noise_b is not None:
        var += (scale * noise_b[1] * np.sum((xb - noise_b[0]) ** 2, axis=1)) ** 2
    return np.sqrt(var)


@dataclass(frozen=True)
class SyncFit:
    """Continuous pairwise clock and ground alignment.

    ``u_a = rate * u_b + offset`` (grid times in reference frames) and ``x_a = T(x_b)``.
    ``pairs_a``, ``pairs_b`` (n, 2): matched ground points (at the fitted time) for the global
    alignment; ``rms``: robust residual (m); ``offset_sd``, ``rate_sd``: 1-sigma of the offset
    at ``u_b = 0`` (frames) and of the rate; ``pivot_offset``: the offset in the middle of the
    matched samples (where the integer ICP offset applies).
    """

    offset: float
    rate: float
    transform: Similarity2D
    rms: float
    offset_sd: float
    pairs_a: NDArray[np.float64]
    pairs_b: NDArray[np.float64]
    rate_sd: float = np.inf
    pivot_offset: float = np.nan


def _sync_samples(a: GridTrack, b: GridTrack, la: Lanes, lb: Lanes, icp: IcpResult,
                  offset: int, margin: float, max_samples: int, rng: np.random.Generator
                  ) -> tuple[NDArray[np.float64], ...] | None:
    """Matched samples of the sub-frame fit and B's interpolation tables.

    Returns (u_a (n,), x_a (n, 2), virtual-axis shift of each sample's B tracklet (n,),
    virtual times (m,), B positions (m, 2)), or None with fewer than 20 samples.
    """
    ua = icp.frames_a.astype(np.float64)
    xa = la.pos[icp.frames_a, icp.lanes_a]
    tid = lb.tid[icp.frames_b, icp.lanes_b]
    tida = la.tid[icp.frames_a, icp.lanes_a]
    ok = (tid >= 0) & (tida >= 0) & np.isfinite(xa).all(1)
    # smoothing is one-sided near a tracklet's ends: keep clear of A's ends (B's below)
    start_a = a.start[np.maximum(tida, 0)]
    len_a = np.array([len(a.xy[t]) for t in np.maximum(tida, 0)])
    ok &= (ua >= start_a + margin) & (ua <= start_a + len_a - 1 - margin)
    ua, xa, tid = ua[ok], xa[ok], tid[ok]
    if ua.size < 20:
        return None
    # B's tracklets (gaps removed) laid end to end on one virtual time axis, far apart, so one
    # np.interp serves all; samples that could leave their tracklet are dropped
    base, gv, xyv = {}, [], []
    cursor = 0.0
    for t in np.unique(tid):
        xy = b.xy[t]
        good = np.isfinite(xy[:, 0])
        g = (b.start[t] + np.arange(len(xy)))[good].astype(np.float64)
        base[int(t)] = cursor - g[0]
        gv.append(g + base[int(t)])
        xyv.append(xy[good])
        cursor = gv[-1][-1] + 1000.0
    gv_all, xy_all = np.concatenate(gv), np.concatenate(xyv)
    off_t = np.array([base[int(t)] for t in tid])
    ub0 = ua - offset
    lo_t = np.array([b.start[t] + margin + 6.0 for t in tid])  # + the offset's bound
    hi_t = np.array([b.start[t] + len(b.xy[t]) - 7.0 - margin for t in tid])
    keep = (ub0 >= lo_t) & (ub0 <= hi_t)
    ua, xa, off_t = ua[keep], xa[keep], off_t[keep]
    if ua.size < 20:
        return None
    if ua.size > max_samples:
        sel = rng.choice(ua.size, max_samples, replace=False)
        ua, xa, off_t = ua[sel], xa[sel], off_t[sel]
    return ua, xa, off_t, gv_all, xy_all


def refine_sync(a: GridTrack, b: GridTrack, la: Lanes, lb: Lanes, icp: IcpResult, offset: int,
                *, sigma: float = 0.1, estimate_rate: bool = True, scale_range: float = 1.0,
                margin: float = 6.0, rate_prior_sd: float = 2e-3,
                rate_significance: float = 3.0, corr_frames: float = 15.0,
                max_samples: int = 6000,
                noise_a: tuple[NDArray[np.float64], float] | None = None,
                noise_b: tuple[NDArray[np.float64], float] | None = None,
                rng: np.random.Generator | None = None) -> SyncFit | None:
    """Fit sub-frame offset, rate ratio and 2D similarity on the ICP's matched tracklets.

    Camera A's matched samples stay at their grid times; camera B's tracklet is interpolated at
    ``u_b = (u_a - offset) / rate``. Robust (soft-L1) least squares. Samples within
    ``margin`` grid frames of a tracklet's end are left out (three smoothing s.d.). A rate
    that differs from 1 by less than ``rate_significance`` s.d. is set to 1 and the rest refit;
    ``corr_frames`` is the correlation length (grid frames) of the residuals for the s.d.

    ``noise_a`` / ``noise_b``: ``(centre_xy, k)`` of each camera's ground noise model
    ``sigma(x) = sigma + k |x - centre|^2`` (metres): a pixel of error moves a ground point by
    ``d^2 / (f h)`` at distance ``d`` from a camera at height ``h``, so far points weigh less.

    Returns None when fewer than 20 matched samples stay clear of the tracklet ends.
    """
    rng = np.random.default_rng(rng)
    samples = _sync_samples(a, b, la, lb, icp, offset, margin, max_samples, rng)
    if samples is None:
        return None
    ua, xa, off_t, gv_all, xy_all = samples
    u0 = float(np.median(ua))  # rate pivots about the middle: offset and rate decorrelate

    def predict(p: NDArray[np.float64]) -> NDArray[np.float64]:
        off, eps = p[0], p[1] * 1e-3
        ub = (ua - u0 - off) / (1.0 + eps) + u0 + off_t
        out = np.stack([np.interp(ub, gv_all, xy_all[:, 0]),
                        np.interp(ub, gv_all, xy_all[:, 1])], axis=1)
        tr = Similarity2D(p[2], p[3:5], float(np.exp(p[5])))
        return tr.apply(out)

    def raw(p: NDArray[np.float64]) -> NDArray[np.float64]:
        return xa - predict(p)

    p0 = np.r_[float(offset), 0.0, icp.transform.angle, icp.transform.t,
               np.log(icp.transform.scale)]
    tr0 = Similarity2D(icp.transform.angle, icp.transform.t, icp.transform.scale)
    w_sd = _noise_sd(xa, tr0.inverse().apply(xa), noise_a, noise_b, sigma, tr0.scale)

    def resid(p: NDArray[np.float64]) -> NDArray[np.float64]:
        # one prior row keeps the rate near the fps prior when the overlap is too short to
        # measure it (a few seconds cannot tell 0.1 % apart); residuals in noise s.d.
        return np.r_[(raw(p) / w_sd[:, None]).ravel(), p[1] * 1e-3 / rate_prior_sd]

    ls = np.log(scale_range) + 1e-9

    def solve(rate_free: bool, p_init: NDArray[np.float64]) -> tuple:
        r_lim = 5.0 if rate_free else 1e-9
        lo = np.r_[offset - 6.0, -r_lim, -np.inf, -np.inf, -np.inf, -ls]
        hi = np.r_[offset + 6.0, r_lim, np.inf, np.inf, np.inf, ls]
        sol = least_squares(resid, np.clip(p_init, lo + 1e-12, hi - 1e-12), bounds=(lo, hi),
                            loss="soft_l1", f_scale=2.0, x_scale="jac",
                            diff_step=np.r_[1e-3, 1e-3, 1e-5, 1e-5, 1e-5, 1e-5])
        rn = np.linalg.norm(sol.fun[:-1].reshape(-1, 2), axis=1)  # in noise s.d.
        inl = rn < 3 * max(1.0, 1.5 * np.median(rn))
        chi = float(np.sqrt(np.mean(rn[inl] ** 2) / 2)) if inl.any() else np.inf
        try:
            J = sol.jac[np.r_[np.repeat(inl, 2), True]]
            if not rate_free:
                J = J.copy()
                J[:, 1] = resid_rate_column(sol.x)[np.r_[np.repeat(inl, 2), True]]
            # a rigid fit pins the scale at its bound: it has no variance (and its zero
            # column can make the normal matrix singular)
            free = np.arange(6) if scale_range > 1.0 else np.arange(5)
            Jf = J[:, free]
            # residuals are correlated over the smoothing and, through the gait, over about
            # half a second: inflate the covariance by that many samples
            cov = np.zeros((6, 6))
            cov[np.ix_(free, free)] = (np.linalg.inv(Jf.T @ Jf) * chi**2
                                       * max(1.0, corr_frames))
        except np.linalg.LinAlgError:
            cov = np.full((6, 6), np.inf)
        return sol, inl, cov

    def resid_rate_column(p: NDArray[np.float64]) -> NDArray[np.float64]:
        """d resid / d p[1] by central differences (the bounded fit has none for it)."""
        h = 1e-3
        return (resid(p + np.r_[0, h, 0, 0, 0, 0]) - resid(p - np.r_[0, h, 0, 0, 0, 0])) / (2 * h)

    sol, inl, cov = solve(estimate_rate, p0)
    rate_sd = float(np.sqrt(max(cov[1, 1], 0.0)) * 1e-3)
    if estimate_rate and abs(sol.x[1] * 1e-3) < rate_significance * rate_sd:
        # not measurably different from the prior: a fitted rate would only add its noise
        sol, inl, cov = solve(False, np.r_[sol.x[0], 0.0, sol.x[2:]])
    d = np.linalg.norm(raw(sol.x), axis=1)
    rms = float(np.sqrt(np.mean(d[inl] ** 2))) if inl.any() else np.inf
    p = sol.x
    rate = 1.0 + p[1] * 1e-3
    offset_at_zero = p[0] + u0 - rate * u0  # u_a = rate * u_b + offset_at_zero
    g = np.array([1.0, -u0 * 1e-3])
    with np.errstate(invalid="ignore"):  # a singular fit's covariance is inf: inf - inf
        var = float(g @ cov[:2, :2] @ g)
    off_sd = float(np.sqrt(max(var, 0.0))) if np.isfinite(var) else np.inf
    rate_sd = float(np.sqrt(max(cov[1, 1], 0.0)) * 1e-3)  # the measurement's s.d.
    tr = Similarity2D(float(p[2]), p[3:5].copy(), float(np.exp(p[5])))
    pb = predict(p)
    sel = np.flatnonzero(inl)
    if sel.size > 400:
        sel = rng.choice(sel, 400, replace=False)
    pb_native = tr.inverse().apply(pb[sel])
    return SyncFit(float(offset_at_zero), float(rate), tr, rms, off_sd, xa[sel], pb_native,
                   rate_sd, float(p[0]))
