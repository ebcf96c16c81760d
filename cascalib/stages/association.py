"""Cross-view person association for stage V, without appearance and without identities.

Three steps, each vectorised over frames where it can be:

1. *Temporal alignment.* Camera frame ``k`` shows reference frame ``time_rate * k + time_offset``
   (cascalib's TIME CONVENTION). The 2D tracks of every camera are interpolated to common reference
   times (:mod:`cascalib.stages.track_interpolation`: persons of consecutive frames are linked and
   their keypoints blended linearly); this module receives them as views.
2. *Association per reference time.* Each person's ground position is the back-projection of its
   ankles onto the plane at ankle height (or of its hip at hip height). Cameras are added one at
   a time and matched to the clusters so far with the Hungarian algorithm on ground distance;
   unmatched persons start new clusters. Missing, extra (false positive) and partly visible
   persons simply stay in small clusters, which are dropped below two views.
3. *Consistency.* Every cluster is triangulated robustly; a view whose reprojection error is large
   for its size in the image is removed (a wrong match or a false detection).

Clusters of consecutive reference times are then linked into tracks by ground position, so bone
lengths can be tied over time.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from cascalib.camera import Camera
from cascalib.geometry import norm_xy
from cascalib.nanstats import joint_extent, nanmean, nanmedian_last
from cascalib.skeletons import CANONICAL_INDEX
from cascalib.stages.triangulation import triangulate

__all__ = ["Association", "associate", "check_consistency", "ground_velocity", "link_tracks",
           "row_minima_assignment", "stitch_tracks"]

log = logging.getLogger(__name__)

_ANKLES = [CANONICAL_INDEX["left_ankle"], CANONICAL_INDEX["right_ankle"]]
_HIP = CANONICAL_INDEX["mid_hip"]
_LR_HIPS = [CANONICAL_INDEX["left_hip"], CANONICAL_INDEX["right_hip"]]
#: Joints that judge a view's consistency: spread over the body, reliably detected.
_CHECK_JOINTS = [CANONICAL_INDEX[n] for n in (
    "nose", "neck", "left_shoulder", "right_shoulder", "left_wrist", "right_wrist", "left_hip",
    "right_hip", "left_knee", "right_knee", "left_ankle", "right_ankle")]
#: Typical fraction of the body height at the hip joints (Winter, Biomechanics, 2009: 0.53).
HIP_FRACTION = 0.53


@dataclass(frozen=True)
class Association:
    """Persons matched across cameras at common reference times.

    Attributes
    ----------
    times : ndarray, shape (G,)
        Reference frame of each group (person at one time).
    obs : ndarray, shape (G, C, 26, 3)
        Canonical 2D keypoints (x, y, confidence) of the group in each camera, interpolated to the
        reference time; NaN where the camera does not see the person.
    tracks : ndarray of int, shape (G,)
        Person track over reference times (-1 when not linked).
    ground : ndarray, shape (G, 2)
        Ground position (metres) from the cameras used for the association.
    residual : ndarray, shape (G,), optional
        Worst view's median reprojection error after triangulation, as a fraction of the
        person's image size (a wrong match shows here first).
    """

    times: NDArray[np.float64]
    obs: NDArray[np.float64]
    tracks: NDArray[np.int64]
    ground: NDArray[np.float64]
    residual: NDArray[np.float64] | None = None
    velocity: NDArray[np.float64] | None = None

    @property
    def n_groups(self) -> int:
        return int(self.times.shape[0])

    def subset(self, index: NDArray[np.int64]) -> Association:
        """The groups ``index`` only."""
        return Association(self.times[index], self.obs[index], self.tracks[index],
                           self.ground[index],
                           None if self.residual is None else self.residual[index],
                           None if self.velocity is None else self.velocity[index])


# -- 1. temporal alignment -----------------------------------------------------------------------
def ground_velocity(assoc: Association, *, steps: int = 4, max_gap: float = 30.0
                    ) -> NDArray[np.float64]:
    """Ground velocity (metres per reference frame) of every group along its track, (G, 2).

    Central difference of the ground positions up to ``steps`` groups before and after in the
    same track and within ``max_gap / 2`` frames (one-sided at a track's ends and gaps); NaN for
    untracked groups and groups with no such neighbour.
    """
    n = assoc.n_groups
    order = np.lexsort((assoc.times, assoc.tracks))
    tr, t, g = assoc.tracks[order], assoc.times[order], assoc.ground[order]
    pos = np.arange(n)
    lo = np.maximum(pos - steps, 0)
    hi = np.minimum(pos + steps, n - 1)
    # stay within the track and the time window: move the ends inwards until they are
    for _ in range(steps):
        lo = np.where((tr[lo] != tr) | (t - t[lo] > max_gap / 2), lo + 1, lo)
        hi = np.where((tr[hi] != tr) | (t[hi] - t > max_gap / 2), hi - 1, hi)
    dt = t[hi] - t[lo]
    ok = (tr >= 0) & (dt > 0)
    out = np.full((n, 2), np.nan)
    out[order[ok]] = (g[hi[ok]] - g[lo[ok]]) / dt[ok, None]
    return out


# -- 2. association per time -----------------------------------------------------------------------
def ground_positions(camera: Camera, views: NDArray[np.float64], *, height: float,
                     ankle_height: float) -> NDArray[np.float64]:
    """Ground position of each person in each frame seen by one camera.

    Parameters
    ----------
    views : ndarray, shape (T, P, 26, 3)

    Returns
    -------
    ndarray, shape (T, P, 2)
        NaN where neither ankles nor hips are visible or the ray misses the plane.
    """
    ank = camera.backproject_to_plane(views[..., _ANKLES, :2], z=ankle_height)
    g_ank = nanmean(ank[..., :2], axis=-2)
    hip_uv = np.where(np.isfinite(views[..., _HIP, :2]), views[..., _HIP, :2],
                      nanmean(views[..., _LR_HIPS, :2], axis=-2))
    g_hip = camera.backproject_to_plane(hip_uv, z=HIP_FRACTION * height)[..., :2]
    return np.where(np.isfinite(g_ank), g_ank, g_hip)


def row_minima_assignment(cost: NDArray[np.float64], rows: NDArray[np.bool_]
                           ) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """Optimal assignment of many small problems at once, where it is just the row minima.

    When the rows' cheapest columns are all different, taking them is an optimal assignment
    (no assignment costs less than the sum of the row minima), so the Hungarian method is only
    needed for the problems where two rows want the same column.

    Parameters
    ----------
    cost : ndarray, shape (N, R, K), K >= 1
        ``inf`` where a pairing is impossible.
    rows : ndarray of bool, shape (N, R)
        The rows that take part.

    Returns
    -------
    best : ndarray of int, shape (N, R)
        Each row's cheapest column.
    solved : ndarray of bool, shape (N,)
        Problems where ``best`` is the assignment (distinct columns, every row has one and
        no tie for it).
    """
    r, k = rows.shape[1], cost.shape[-1]
    best = np.argmin(cost, axis=-1)
    low = np.take_along_axis(cost, best[..., None], -1)[..., 0]
    # a tie leaves the choice to the Hungarian method, as it would be without this shortcut
    unique = np.partition(cost, 1, axis=-1)[..., 1] > low if k > 1 else np.ones_like(rows)
    # rows that do not take part get distinct negative labels, so they never collide
    label = np.sort(np.where(rows, best, -1 - np.arange(r)[None, :]), axis=1)
    distinct = ~(label[:, 1:] == label[:, :-1]).any(1)
    return best, distinct & (np.isfinite(low) & unique | ~rows).all(1)


def _cluster_all(grounds: list[NDArray[np.float64]], gate_m: float
                 ) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Cluster the persons of all cameras at every time: clusters of at least two views.

    At each time the cameras are taken in order; each camera's persons are matched to the
    current clusters (mean ground position of their members) by an optimal assignment, a pair
    within ``gate_m`` joins the cluster and every other person starts a new one. All times are
    processed together (the assignments are the row minima wherever those are distinct, see
    :func:`row_minima_assignment`; the Hungarian method solves the rest).

    Parameters
    ----------
    grounds : list of ndarray, shape (T, P_c, 2)
        Ground positions per camera (NaN rows are absent persons).

    Returns
    -------
    t_all : ndarray of int, shape (G,)
        Time index of each cluster (times in order, clusters in order of creation).
    s_all : ndarray of int, shape (G, C)
        Person slot of each camera in each cluster, -1 where absent.
    """
    n_cams, n_t = len(grounds), grounds[0].shape[0]
    k_max = sum(g.shape[1] for g in grounds)
    members = np.full((n_t, k_max, n_cams), -1, dtype=np.int64)
    sums = np.zeros((n_t, k_max, 2))
    counts = np.zeros((n_t, k_max))
    n_cl = np.zeros(n_t, dtype=np.int64)
    for c, g in enumerate(grounds):
        n_p = g.shape[1]
        if n_p == 0:
            continue
        valid = np.isfinite(g).all(-1)  # (T, P)
        matched = np.zeros((n_t, n_p), dtype=bool)
        k_used = int(n_cl.max())
        if k_used:
            with np.errstate(invalid="ignore", divide="ignore"):
                centres = sums[:, :k_used] / counts[:, :k_used, None]
            cost = norm_xy(g[:, :, None] - centres[:, None])  # (T, P, K)
            exists = np.arange(k_used)[None, :] < n_cl[:, None]
            cost = np.where(valid[:, :, None] & exists[:, None, :], cost, np.inf)  # type: ignore[index]
            best, solved = row_minima_assignment(cost, valid)  # type: ignore[arg-type]
            assign = np.where(valid, best, -1)
            for t in np.flatnonzero(~solved & (n_cl > 0) & valid.any(1)):  # type: ignore[call-overload]
                rows = np.flatnonzero(valid[t])  # type: ignore[index]
                r, q = linear_sum_assignment(cost[t][np.ix_(rows, np.arange(n_cl[t]))])
                assign[t] = -1
                assign[t, rows[r]] = q
            ok = assign >= 0
            d = np.take_along_axis(cost, np.maximum(assign, 0)[..., None], -1)[..., 0]
            matched = ok & (d < gate_m)
            tt, pp = np.nonzero(matched)
            kk = assign[tt, pp]
            members[tt, kk, c] = pp
            sums[tt, kk] += g[tt, pp]
            counts[tt, kk] += 1
        new = valid & ~matched
        # new clusters in slot order after the existing ones
        k_new = n_cl[:, None] + np.cumsum(new, axis=1) - 1
        tt, pp = np.nonzero(new)
        members[tt, k_new[tt, pp], c] = pp
        sums[tt, k_new[tt, pp]] = g[tt, pp]
        counts[tt, k_new[tt, pp]] = 1
        n_cl = n_cl + new.sum(1)
    keep = (members >= 0).sum(-1) >= 2
    t_all, k_all = np.nonzero(keep)
    return t_all.astype(np.int64), members[t_all, k_all]


def _align_grounds(grounds: list[NDArray[np.float64]], t_all: NDArray[np.int64],
                   s_all: NDArray[np.int64], reference: int) -> list[NDArray[np.float64]]:
    """Warp each camera's ground positions onto the others' by a robust 2D affine map.

    Calibration errors of a few degrees move a camera's ground positions by metres at shallow
    viewing angles, but smoothly: an affine map fitted to the first clusters removes most of it,
    so the second clustering can use the same gate with far fewer wrong matches.
    """
    out = list(grounds)
    for c in range(len(grounds)):
        if c == reference:
            continue
        rows = np.flatnonzero((s_all[:, c] >= 0) & ((s_all >= 0).sum(1) >= 2))
        src = grounds[c][t_all[rows], s_all[rows, c]]
        dst = np.zeros_like(src)
        n = np.zeros(len(rows))
        for o in range(len(grounds)):
            if o == c:
                continue
            has = s_all[rows, o] >= 0
            dst[has] += grounds[o][t_all[rows[has]], s_all[rows[has], o]]
            n[has] += 1
        ok = (n > 0) & np.isfinite(src).all(1)
        dst = dst[ok] / n[ok, None]
        src = src[ok]
        if len(src) < 20:
            continue
        A = np.c_[src, np.ones(len(src))]
        w = np.ones(len(src))
        for _ in range(5):  # IRLS with Huber weights (0.3 m)
            M = np.linalg.lstsq(A * w[:, None], dst * w[:, None], rcond=None)[0]
            r = np.linalg.norm(A @ M - dst, axis=1)
            w = np.sqrt(np.where(r < 0.3, 1.0, 0.3 / np.maximum(r, 1e-9)))
        g = grounds[c]
        out[c] = (np.c_[g.reshape(-1, 2), np.ones(g.shape[0] * g.shape[1])] @ M).reshape(g.shape)
    return out


def associate(views: list[NDArray[np.float64]], cameras: list[Camera], times: NDArray[np.float64],
              *, height: float, ankle_height: float, gate_m: float, consistency: float,
              huber_px: float = 4.0, align_ground: int = 0, reference: int = 0,
              link: bool = True) -> Association:
    """Associate persons across cameras at every reference time.

    Parameters
    ----------
    views : list of ndarray, shape (T, P_c, 26, 3)
        Per camera, the canonical keypoints interpolated to the reference times.
    cameras : list of Camera
        Current cameras (same order).
    times : ndarray, shape (T,)
        Reference frames of the rows of ``views``.
    height, ankle_height : float
        Person height prior and ankle height (metres) for the ground positions.
    gate_m : float
        Largest ground distance (metres) between views of one person.
    consistency : float
        Largest median reprojection error of a view after triangulation, as a fraction of the
        person's size in that image.
    align_ground : int
        Rounds of per-camera affine ground alignment before re-clustering (for poor cameras).
    reference : int
        Camera whose ground positions are not warped.
    link : bool
        Link the groups into person tracks (:func:`link_tracks`); else every track is -1
        (for callers that only triangulate the groups: the linking is a Python loop over the
        reference times).

    Returns
    -------
    Association
        Groups seen by at least two cameras.
    """
    n_cams = len(cameras)
    grounds = [ground_positions(cam, v, height=height, ankle_height=ankle_height)
               for cam, v in zip(cameras, views, strict=True)]
    t_all, s_all = _cluster_all(grounds, gate_m)
    for _ in range(align_ground):
        grounds = _align_grounds(grounds, t_all, s_all, reference)
        t_all, s_all = _cluster_all(grounds, gate_m)
    obs = np.full((len(t_all), n_cams, 26, 3), np.nan)
    ground = np.zeros((len(t_all), 2))
    n_g = np.zeros(len(t_all))
    for c in range(n_cams):
        has = s_all[:, c] >= 0
        obs[has, c] = views[c][t_all[has], s_all[has, c]]
        g = grounds[c][t_all[has], s_all[has, c]]
        ground[has] += g
        n_g[has] += 1
    ground /= np.maximum(n_g, 1)[:, None]
    obs, residual = check_consistency(obs, cameras, consistency, huber_px=huber_px)
    keep = (np.isfinite(obs[..., 0]).any(-1).sum(1) >= 2)
    log.info("associated %d person-frames over %d reference times (%d dropped as inconsistent)",
             keep.sum(), len(times), (~keep).sum())
    assoc = Association(times[t_all[keep]], obs[keep], np.full(keep.sum(), -1, dtype=np.int64),
                        ground[keep], residual[keep])
    return link_tracks(assoc) if link else assoc


def check_consistency(obs: NDArray[np.float64], cameras: list[Camera], tolerance: float,
                      *, huber_px: float = 4.0
                      ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Remove views whose keypoints disagree with the group's robust triangulation.

    Parameters
    ----------
    obs : ndarray, shape (G, C, 26, 3)
    tolerance : float
        Largest median reprojection error as a fraction of the person's image size.

    Returns
    -------
    obs : ndarray, shape (G, C, 26, 3)
        ``obs`` with inconsistent views set to NaN.
    residual : ndarray, shape (G,)
        Largest relative error among the kept views (NaN if none).
    """
    n_g, n_cams = obs.shape[:2]
    if n_g == 0:
        return obs, np.zeros(0)
    sub = obs[:, :, _CHECK_JOINTS]
    n_j = len(_CHECK_JOINTS)
    uv = sub[..., :2].transpose(1, 0, 2, 3).reshape(n_cams, -1, 2)
    conf = sub[..., 2].transpose(1, 0, 2).reshape(n_cams, -1)
    _, err = triangulate(cameras, uv, conf, huber_px=huber_px, n_iter=2)
    err = err.reshape(n_cams, n_g, n_j).transpose(1, 0, 2)
    med = nanmedian_last(err)  # (G, C)
    ext = joint_extent(obs)
    size = np.maximum(norm_xy(ext), 10.0)
    bad = np.isfinite(obs[..., 0]).any(-1) & ~(med / size < tolerance)
    # only judge groups that keep two views: with a 2-view group both views get the same error
    out = obs.copy()
    out[bad] = np.nan
    rel = np.where(bad, np.nan, med / size)
    # np.nanmax's values without its all-NaN warning, which only warnings.catch_warnings (not
    # thread-safe, and stage III's pairs run in threads) could silence
    residual = np.fmax.reduce(rel, axis=1)
    return out, residual


# -- 3. tracks over time ---------------------------------------------------------------------------
def link_tracks(assoc: Association, *, gate_m: float = 0.4, max_gap: float = 3.0,
                alpha: float = 0.4) -> Association:
    """Link groups of nearby reference times into person tracks by ground position.

    Each live track predicts where its person is now from a position and a velocity (an
    alpha-beta filter: the least-squares line through its first points, then the fixed gains
    ``alpha`` and ``beta = alpha**2 / (2 - alpha)``, Benedict and Bordner's choice); the groups
    of a reference time are matched to the predictions with the Hungarian algorithm. Walkers
    who cross are then followed by their headings, where the last positions alone swapped them.
    Measured at the true cameras of 40 s simulator scenes, the share of person-frames that are
    in a track of mostly their own person went 0.92 -> 0.98 and 0.91 -> 0.98 (terrace seeds 2
    and 0), 0.72 -> 0.97 (people walking circles), 0.94 -> 0.95 (crowd), but 0.82 -> 0.75 on
    a lab ring. Two people passing close can still swap: stage V cuts its tracks where the
    person's size jumps (:func:`cascalib.stages.person_size.split_by_size`).

    Parameters
    ----------
    gate_m : float
        Largest distance (metres) between a group and a track's predicted position.
    max_gap : float
        Largest time gap (reference frames) bridged.
    alpha : float
        Steady-state position gain of the filter (0-1; higher follows turns faster).
    """
    n = assoc.n_groups
    tracks = np.full(n, -1, dtype=np.int64)
    if n == 0:
        return assoc
    beta = alpha**2 / (2 - alpha)
    order = np.argsort(assoc.times, kind="stable")
    uniq, starts = np.unique(assoc.times[order], return_index=True)
    groups = np.split(order, starts[1:])
    next_id = 0
    # live tracks: id -> [last time, x, y, velocity x, y (m per reference frame), updates], in
    # Python floats: a few 2-vectors per time, where numpy's per-call cost was most of the time
    live: dict[int, list] = {}
    ground = assoc.ground.tolist()
    for t, idx in zip(uniq.tolist(), groups, strict=True):
        # tracks silent for longer than max_gap can never be linked again: forget them, so
        # each time looks only at the few live tracks (not at every track ever started)
        for k in [k for k, st in live.items() if t - st[0] > max_gap]:
            del live[k]
        ids = list(live)
        idx = idx.tolist()
        if ids:
            pred = [(st[1] + st[3] * (t - st[0]), st[2] + st[4] * (t - st[0]))
                    for st in (live[k] for k in ids)]
            cost = np.nan_to_num(np.array(
                [[math.sqrt((gx - px) * (gx - px) + (gy - py) * (gy - py)) for px, py in pred]
                 for gx, gy in (ground[i] for i in idx)]), nan=1e9)
            r, q = linear_sum_assignment(cost)
            for i, k in zip(r.tolist(), q.tolist(), strict=True):
                if cost[i, k] < gate_m:
                    tracks[idx[i]] = ids[k]
        for i in idx:
            gx, gy = ground[i]
            if not (math.isfinite(gx) and math.isfinite(gy)):
                continue
            if tracks[i] < 0:
                tracks[i] = next_id
                live[next_id] = [t, gx, gy, 0.0, 0.0, 0]
                next_id += 1
                continue
            st = live[int(tracks[i])]
            dt = t - st[0]
            st[5] += 1
            m = st[5] + 1  # points in the track so far
            # the least-squares line's gains while the track is young, then the steady ones
            a = max(alpha, 2 * (2 * m - 1) / (m * (m + 1)))
            b = max(beta, 6 / (m * (m + 1)))
            px, py = st[1] + st[3] * dt, st[2] + st[4] * dt
            rx, ry = gx - px, gy - py
            step = max(dt, 1e-9)
            st[:5] = t, px + a * rx, py + a * ry, st[3] + b * rx / step, st[4] + b * ry / step
    lone = tracks < 0  # groups without a ground position
    tracks[lone] = next_id + np.arange(lone.sum())
    return Association(assoc.times, assoc.obs, tracks, assoc.ground, assoc.residual)


def _ends(times: NDArray[np.float64], ground: NDArray[np.float64], window: float
          ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Position and velocity (per reference frame) at the last sample of a track, from a line
    fitted to the samples of the last ``window`` frames."""
    last = times >= times[-1] - window
    t, g = times[last], ground[last]
    ok = np.isfinite(g).all(1)
    t, g = t[ok], g[ok]
    if len(t) == 0:
        return np.full(2, np.nan), np.zeros(2)
    if len(t) < 3 or np.ptp(t) < 1:
        return g[-1], np.zeros(2)
    A = np.c_[t - t[-1], np.ones(len(t))]
    coef = np.linalg.lstsq(A, g, rcond=None)[0]
    return coef[1], coef[0]


def stitch_tracks(assoc: Association, *, fps: float, max_gap_s: float = 2.0,
                  gate_m: float = 0.5, speed_sd_m_s: float = 0.8,
                  ambiguity: float = 0.5) -> Association:
    """Join track fragments across gaps (occlusion, a person seen by one camera only).

    :func:`link_tracks` bridges a few frames; here each fragment's end is extrapolated at its
    walking velocity over the gap and matched one-to-one (Hungarian) with the fragments that start
    within ``max_gap_s``, gate ``gate_m + speed_sd_m_s * gap``. A join is made only when it is
    each side's best candidate by a clear margin (distance < ``ambiguity`` x the second best).
    Fragments that overlap in time are never joined, so two persons seen together stay apart.

    Parameters
    ----------
    assoc : Association
        With ``tracks`` from :func:`link_tracks`.
    fps : float
        Reference frame rate (times are reference frames).
    max_gap_s, gate_m, speed_sd_m_s : float
        Largest gap bridged (s); gate at zero gap (m); its growth with the gap (m/s), for turns
        and speed changes the constant-velocity extrapolation misses.
    ambiguity : float
        Largest ratio of a join's distance to the second-best candidate's.

    Returns
    -------
    Association
        Same groups, tracks renumbered 0.. in order of first appearance.
    """
    if assoc.n_groups == 0:
        return assoc
    ids, inverse = np.unique(assoc.tracks, return_inverse=True)
    n = len(ids)
    members = [np.flatnonzero(inverse == k) for k in range(n)]
    members = [m[np.argsort(assoc.times[m], kind="stable")] for m in members]
    start = np.array([assoc.times[m[0]] for m in members])
    end = np.array([assoc.times[m[-1]] for m in members])
    window = 0.5 * fps
    tail = [_ends(assoc.times[m], assoc.ground[m], window) for m in members]
    head = [_ends(-assoc.times[m][::-1], assoc.ground[m][::-1], window)[0] for m in members]
    max_gap = max_gap_s * fps
    gap = start[None, :] - end[:, None]  # (ends, starts), reference frames
    allowed = (gap > 0) & (gap <= max_gap)
    cost = np.full((n, n), np.inf)
    for i, j in zip(*np.nonzero(allowed), strict=True):
        pos, vel = tail[i]
        pred = pos + vel * gap[i, j]
        d = float(np.linalg.norm(pred - head[j]))
        if d < gate_m + speed_sd_m_s * gap[i, j] / fps:
            cost[i, j] = d
    nxt = np.full(n, -1)
    if np.isfinite(cost).any():
        r, q = linear_sum_assignment(np.where(np.isfinite(cost), cost, 1e9))
        # a join must be unambiguous: in a crowd a wrong join is worse than a missed one
        srt_r, srt_c = np.sort(cost, axis=1), np.sort(cost, axis=0)
        second_r = srt_r[:, 1] if n > 1 else np.full(n, np.inf)
        second_c = srt_c[1, :] if n > 1 else np.full(n, np.inf)
        c = cost[r, q]
        keep = (np.isfinite(c) & (c <= srt_r[r, 0]) & (c <= srt_c[0, q])
                & (c < ambiguity * second_r[r]) & (c < ambiguity * second_c[q]))
        nxt[r[keep]] = q[keep]
    has_prev = np.zeros(n, dtype=bool)
    has_prev[nxt[nxt >= 0]] = True
    new = np.full(n, -1, dtype=np.int64)
    label = 0
    for k in np.argsort(start, kind="stable"):
        if has_prev[k]:
            continue
        while k >= 0:
            new[k] = label
            k = nxt[k]
        label += 1
    return Association(assoc.times, assoc.obs, new[inverse], assoc.ground, assoc.residual)

