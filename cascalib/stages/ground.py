"""Stage II input: ground-plane trajectories of the people seen by one camera.

Each camera's stage-I result is a camera in its *own* plane frame (ground z = 0, yaw and xy
arbitrary). Back-projecting the feet of every detection onto that plane gives a bird's-eye view
of the scene that differs from the reference camera's view only by a 2D rigid (or similarity)
transform and a time shift (paper, "Relating multiple cameras through their ground planes").

The points are cleaned (range gate, DBSCAN, temporal jump test) and linked into *tracklets*:
runs of one person over consecutive frames, the unit every later step matches between cameras.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.ndimage import gaussian_filter1d, median_filter
from scipy.optimize import linear_sum_assignment
from sklearn.cluster import DBSCAN

from cascalib.camera import Camera
from cascalib.skeletons import CANONICAL_INDEX
from cascalib.tracks import Tracks

__all__ = ["Tracklet", "GroundTracks", "foot_pixels", "ground_points", "remove_outliers",
           "link_tracklets", "ground_trajectories"]

logger = logging.getLogger(__name__)

_FOOT_JOINTS = (("left_ankle", "right_ankle"), ("left_heel", "right_heel"),
                ("left_big_toe", "right_big_toe"))


@dataclass(frozen=True)
class Tracklet:
    """One person followed over (nearly) consecutive frames of one camera.

    Parameters
    ----------
    frames : ndarray of int, shape (n,)
        Increasing native frame indices of the camera.
    xy : ndarray, shape (n, 2)
        Foot position on the camera's own ground plane (metres).
    slot : ndarray of int, shape (n,)
        Person slot of the detection in ``Tracks.keypoints``.
    """

    frames: NDArray[np.int64]
    xy: NDArray[np.float64]
    slot: NDArray[np.int64]

    def __len__(self) -> int:
        return int(self.frames.size)


@dataclass(frozen=True)
class GroundTracks:
    """Ground-plane trajectories of one camera.

    Parameters
    ----------
    camera : str
    n_frames : int
        Number of frames of the camera's video.
    xy : ndarray, shape (n_frames, n_persons, 2)
        Cleaned foot positions per frame and slot, NaN where missing or rejected.
    tracklets : list of Tracklet
    n_outliers : int
        Points rejected by the range gate, DBSCAN and the jump test.
    """

    camera: str
    n_frames: int
    xy: NDArray[np.float64]
    tracklets: list[Tracklet]
    n_outliers: int


def foot_pixels(tracks: Tracks, min_confidence: float = 0.0) -> NDArray[np.float64]:
    """Foot pixel per detection: midpoint of the two ankles, or the one ankle seen.

    Falls back to heels, then big toes, for skeletons or frames without ankles.

    Returns
    -------
    ndarray, shape (n_frames, n_persons, 2)
        NaN where no foot joint is seen with confidence above ``min_confidence``.
    """
    can = tracks.canonical()
    out = np.full(can.shape[:2] + (2,), np.nan)
    for left, right in _FOOT_JOINTS:
        pair = can[:, :, [CANONICAL_INDEX[left], CANONICAL_INDEX[right]], :]
        ok = np.isfinite(pair[..., 0]) & (np.nan_to_num(pair[..., 2], nan=-1.0) > min_confidence)
        xy = np.where(ok[..., None], pair[..., :2], np.nan)
        n = ok.sum(-1)[..., None]
        with np.errstate(invalid="ignore", divide="ignore"):
            mid = np.where(n > 0, np.nansum(xy, axis=2) / n, np.nan)
        fill = np.isnan(out[..., 0]) & np.isfinite(mid[..., 0])
        out[fill] = mid[fill]
    return out


def ankle_ground_points(tracks: Tracks, plane_camera: Camera, *, foot_height: float = 0.0,
                        min_confidence: float = 0.0) -> NDArray[np.float64]:
    """Each ankle back-projected on its own onto the plane ``z = foot_height``.

    Returns
    -------
    ndarray, shape (n_frames, n_persons, 2 (left, right), 2 (x, y))
    """
    can = tracks.canonical()
    pair = can[:, :, [CANONICAL_INDEX["left_ankle"], CANONICAL_INDEX["right_ankle"]], :]
    ok = np.isfinite(pair[..., 0]) & (np.nan_to_num(pair[..., 2], nan=-1.0) > min_confidence)
    uv = np.where(ok[..., None], pair[..., :2], np.nan)
    return plane_camera.backproject_to_plane(uv, z=foot_height)[..., :2]


def stance_weighted(tl: Tracklet, ankles: NDArray[np.float64], v0: float,
                    smooth: float = 2.0) -> Tracklet:
    """Replace a tracklet's foot points by the ankles weighted towards the standing foot.

    A swinging ankle is up to ~10 cm above the ground, which moves its back-projection along
    the viewing ray by ``dz * d / h`` (decimetres at 10 m), differently in every camera; the
    standing ankle is at the height the plane assumes. Weights ``1 / (v + v0)^2`` with ``v`` the
    ankle's ground speed (m per frame) favour the standing foot, and give the midpoint in
    double support.

    Parameters
    ----------
    tl : Tracklet
    ankles : ndarray, shape (n_frames, n_persons, 2, 2)
        From :func:`ankle_ground_points`.
    v0 : float
        Speed (m per frame) below which an ankle counts as standing.
    smooth : float
        Gaussian s.d. (frames) of the ankle track before differentiating: give the same time
        in every camera, else cameras at different frame rates weigh differently.
    """
    a = ankles[tl.frames, tl.slot]  # (n, 2 ankles, 2)
    if len(tl) < 3:
        return tl
    v = np.full(a.shape[:2], np.nan)
    for k in (0, 1):
        # speed of the smoothed ankle track: detection noise must not look like a swing
        fin = np.isfinite(a[:, k, 0])
        if smooth > 0:
            m = gaussian_filter1d(fin.astype(np.float64), smooth, mode="nearest")
            sm = gaussian_filter1d(np.where(fin[:, None], a[:, k], 0.0), smooth, axis=0,
                                   mode="nearest") / np.maximum(m, 1e-9)[:, None]
        else:
            m, sm = fin.astype(np.float64), a[:, k]
        g = np.gradient(sm, tl.frames.astype(np.float64), axis=0)
        v[:, k] = np.where(fin & (m > 0.3), np.linalg.norm(g, axis=1), np.nan)
    ok = np.isfinite(v) & np.isfinite(a[..., 0])
    w = np.where(ok, 1.0 / (np.nan_to_num(v) + v0) ** 2, 0.0)
    both = ok.all(1)  # with one ankle only, the (pixel) midpoint fallback stays
    xy = tl.xy.copy()
    wsum = w[both].sum(1, keepdims=True)
    xy[both] = (w[both, :, None] * a[both]).sum(1) / wsum
    return Tracklet(tl.frames, xy, tl.slot)


def ground_points(tracks: Tracks, plane_camera: Camera, *, foot_height: float = 0.0,
                  max_range: float = 60.0, min_confidence: float = 0.0) -> NDArray[np.float64]:
    """Back-project the feet onto the camera's own ground plane.

    Parameters
    ----------
    tracks : Tracks
    plane_camera : Camera
        The camera in its own plane frame (stage I).
    foot_height : float
        Height of the foot joint above the plane stage I fitted (metres).
    max_range : float
        Points farther than this from the point below the camera are rejected: near the horizon
        a pixel of noise moves the point by metres.

    Returns
    -------
    ndarray, shape (n_frames, n_persons, 2)
    """
    uv = foot_pixels(tracks, min_confidence)
    pts = plane_camera.backproject_to_plane(uv, z=foot_height)[..., :2]
    c = plane_camera.center[:2]
    with np.errstate(invalid="ignore"):
        far = np.linalg.norm(pts - c, axis=-1) > max_range
    pts[far] = np.nan
    return pts


def remove_outliers(xy: NDArray[np.float64], *, eps: float = 0.6, min_samples: int = 8,
                    min_cluster_fraction: float = 0.02) -> NDArray[np.bool_]:
    """Density-based rejection of ground points (paper: DBSCAN, "Filtering").

    Unlike the paper, which keeps only the largest cluster, every cluster holding at least
    ``min_cluster_fraction`` of the points is kept, so that people walking in separate areas
    of the scene all survive.

    Parameters
    ----------
    xy : ndarray, shape (..., 2)
        Points, NaN where missing.

    Returns
    -------
    ndarray of bool, shape (...)
        True for kept points (False for NaN input).
    """
    flat = xy.reshape(-1, 2)
    ok = np.isfinite(flat).all(1)
    keep = np.zeros(len(flat), bool)
    pts = flat[ok]
    if len(pts) < min_samples:
        keep[ok] = True
        return keep.reshape(xy.shape[:-1])
    if len(pts) > 40000:  # DBSCAN memory grows with density: grid-quantise heavy inputs first
        q = np.round(pts / (eps / 4)).astype(np.int64)
        uq, inv, counts = np.unique(q, axis=0, return_inverse=True, return_counts=True)
        inv = inv.ravel()
        db = DBSCAN(eps=eps, min_samples=min_samples).fit(uq * (eps / 4), sample_weight=counts)
        labels = db.labels_[inv]
    else:
        labels = DBSCAN(eps=eps, min_samples=min_samples).fit(pts).labels_
    good = labels >= 0
    if good.any():
        ids, counts = np.unique(labels[good], return_counts=True)
        big = ids[counts >= min_cluster_fraction * len(pts)]
        good &= np.isin(labels, big)
    keep[np.flatnonzero(ok)[good]] = True
    return keep.reshape(xy.shape[:-1])


def _split_runs(frames: NDArray[np.int64], xy: NDArray[np.float64], max_gap: int,
                max_step: float) -> list[NDArray[np.int64]]:
    """Index runs of one id split where frames jump by more than ``max_gap`` or the position
    moves faster than ``max_step`` metres per frame (an identity switch)."""
    if frames.size == 0:
        return []
    df = np.diff(frames)
    dist = np.linalg.norm(np.diff(xy, axis=0), axis=1)
    cut = (df > max_gap) | (dist > max_step * df)
    starts = np.r_[0, np.flatnonzero(cut) + 1]
    ends = np.r_[starts[1:], frames.size]
    return [np.arange(s, e) for s, e in zip(starts, ends, strict=True)]


def link_tracklets(xy: NDArray[np.float64], track_ids: NDArray[np.int64] | None = None, *,
                   max_gap: int = 3, max_step: float = 0.35, min_length: int = 10,
                   jump_threshold: float = 0.5, link_speed: float = 0.1) -> list[Tracklet]:
    """Link per-frame ground points into tracklets.

    With detector track ids the ids are followed and only split at gaps and implausible jumps;
    without them consecutive frames are linked by Hungarian matching of positions (gated by
    ``jump_threshold + link_speed * gap`` metres, ``link_speed`` in metres per frame). Along an
    id, isolated points farther than
    ``jump_threshold`` from the running median are dropped before splitting, so that a single
    outlier does not cut a track in three.

    Parameters
    ----------
    xy : ndarray, shape (n_frames, n_persons, 2)
    track_ids : ndarray of int, shape (n_frames, n_persons), optional

    Returns
    -------
    list of Tracklet, each at least ``min_length`` detections long.
    """
    n_f, n_p = xy.shape[:2]
    ok = np.isfinite(xy).all(-1)
    if track_ids is None or not (track_ids[ok] >= 0).any():
        ids = _hungarian_ids(xy, ok, max_gap, jump_threshold, link_speed)  # type: ignore[arg-type]
    else:
        ids = np.where(ok & (track_ids >= 0), track_ids, -1)
        # detections without an id get fresh singleton ids (dropped below as too short)
        lonely = ok & (ids < 0)
        ids[lonely] = ids.max() + 1 + np.arange(lonely.sum())
    out: list[Tracklet] = []
    ff, pp = np.nonzero(ids >= 0)
    order = np.lexsort((ff, ids[ff, pp]))
    ff, pp = ff[order], pp[order]
    lab = ids[ff, pp]
    if lab.size == 0:
        return out
    bounds = np.r_[0, np.flatnonzero(np.diff(lab)) + 1, lab.size]
    for s, e in zip(bounds[:-1], bounds[1:], strict=True):
        f, p = ff[s:e], pp[s:e]
        # one id twice in a frame: keep the first slot
        uniq = np.r_[True, np.diff(f) > 0]
        f, p = f[uniq], p[uniq]
        pts = xy[f, p]
        # split on steps of the running median: a lone outlier does not step, a switch does
        med = _running_median(pts, 9)
        good = np.linalg.norm(pts - med, axis=1) <= jump_threshold
        f, p, pts, med = f[good], p[good], pts[good], med[good]
        for run in _split_runs(f, med, max_gap, max_step):
            if run.size >= min_length:
                out.append(Tracklet(f[run].astype(np.int64), pts[run], p[run].astype(np.int64)))
    return out


def _hungarian_ids(xy: NDArray[np.float64], ok: NDArray[np.bool_], max_gap: int,
                   gate0: float, speed: float) -> NDArray[np.int64]:
    """Frame-to-frame linking by optimal assignment; ids (n_frames, n_persons), -1 missing.

    A frame holds a handful of persons, so the loop keeps its live tracks in Python lists and
    computes the few distances in Python floats (``sqrt(dx * dx + dy * dy)``, as numpy's norm
    does): per-frame numpy calls on arrays of five elements cost more than the arithmetic
    (4 cameras x 3000 frames: 0.7 s -> 0.2 s, the same ids).
    """
    n_f, n_p = ok.shape
    ids = np.full((n_f, n_p), -1, np.int64)
    frames, slots = np.nonzero(ok)
    bounds = np.searchsorted(frames, np.arange(n_f + 1))
    pts_all = xy[frames, slots].tolist()
    slots_l = slots.tolist()
    # live tracks as parallel lists: id, last frame, last position
    t_id: list[int] = []
    t_f: list[int] = []
    t_xy: list[list[float]] = []
    next_id = 0
    for f in range(n_f):
        lo, hi = int(bounds[f]), int(bounds[f + 1])
        if lo == hi:
            continue
        alive = [k for k, tf in enumerate(t_f) if f - tf <= max_gap]
        if len(alive) < len(t_f):
            t_id = [t_id[k] for k in alive]
            t_f = [t_f[k] for k in alive]
            t_xy = [t_xy[k] for k in alive]
        pts = pts_all[lo:hi]
        got = [-1] * len(pts)
        if t_id:
            d = [[math.sqrt((px - tx) * (px - tx) + (py - ty) * (py - ty)) for tx, ty in t_xy]
                 for px, py in pts]
            gate = [gate0 + speed * (f - tf) for tf in t_f]
            if len(pts) == 1:  # the common cases need no assignment solver
                row = d[0]
                pairs = [(0, row.index(min(row)))]
            elif len(t_id) == 1:
                col = [r[0] for r in d]
                pairs = [(col.index(min(col)), 0)]
            else:
                dm = np.array(d)
                r, c = linear_sum_assignment(np.where(dm <= np.array(gate)[None, :], dm, 1e6))
                pairs = list(zip(r.tolist(), c.tolist(), strict=True))
            for i, k in pairs:
                if d[i][k] <= gate[k]:
                    got[i] = k
        # matched tracks move on, the rest start new ones (appended: matched indices hold)
        for i, k in enumerate(got):
            slot = slots_l[lo + i]
            if k >= 0:
                ids[f, slot] = t_id[k]
                t_f[k] = f
                t_xy[k] = pts[i]
            else:
                ids[f, slot] = next_id
                t_id.append(next_id)
                t_f.append(f)
                t_xy.append(pts[i])
                next_id += 1
    return ids


def _running_median(xy: NDArray[np.float64], window: int) -> NDArray[np.float64]:
    """Running median of a track (n, 2) over ``window`` samples (shorter at the ends)."""
    if len(xy) < 3:
        return xy.copy()
    w = min(window, len(xy) if len(xy) % 2 else len(xy) - 1)
    return np.stack([median_filter(xy[:, k], size=w, mode="nearest") for k in (0, 1)], 1)


def _jump_outliers(tracklet_xy: NDArray[np.float64], window: int, threshold: float
                   ) -> NDArray[np.bool_]:
    """Points farther than ``threshold`` from the running median of their tracklet."""
    med = _running_median(tracklet_xy, window)
    return np.linalg.norm(tracklet_xy - med, axis=1) > threshold


def ground_trajectories(tracks: Tracks, plane_camera: Camera, *, foot_height: float = 0.0,
                        max_range: float = 60.0, min_confidence: float = 0.0,
                        dbscan_eps: float = 0.6, dbscan_min_samples: int = 8,
                        dbscan_min_cluster_fraction: float = 0.02,
                        max_step: float = 0.35, max_gap: int = 3, min_length: int = 10,
                        jump_threshold: float = 0.5, link_speed: float = 0.1,
                        stance_speed: float | None = 0.02, stance_smooth: float = 2.0
                        ) -> GroundTracks:
    """Foot trajectories of one camera on its own ground plane, cleaned and linked.

    ``max_step``, ``link_speed`` (metres per frame) and ``max_gap`` (frames) are for the
    camera's own frame rate; 0.35 m per frame is 10 m/s at 30 fps. ``stance_speed`` (m per
    frame, None to use the ankle midpoint) and ``stance_smooth`` (frames) are ``v0`` and
    ``smooth`` of :func:`stance_weighted`.

    Returns
    -------
    GroundTracks
    """
    raw = ground_points(tracks, plane_camera, foot_height=foot_height, max_range=max_range,
                        min_confidence=min_confidence)
    n_raw = int(np.isfinite(raw).all(-1).sum())
    keep = remove_outliers(raw, eps=dbscan_eps, min_samples=dbscan_min_samples,
                           min_cluster_fraction=dbscan_min_cluster_fraction)
    xy = np.where(keep[..., None], raw, np.nan)
    tls = link_tracklets(xy, tracks.track_ids, max_gap=max_gap, max_step=max_step,
                         min_length=min_length, jump_threshold=jump_threshold,
                         link_speed=link_speed)
    if stance_speed is not None:
        ankles = ankle_ground_points(tracks, plane_camera, foot_height=foot_height,
                                     min_confidence=min_confidence)
        tls = [stance_weighted(tl, ankles, stance_speed, stance_smooth) for tl in tls]
    clean = np.full_like(xy, np.nan)
    out: list[Tracklet] = []
    for tl in tls:
        bad = _jump_outliers(tl.xy, 9, jump_threshold)
        if (~bad).sum() >= min_length:
            tl = Tracklet(tl.frames[~bad], tl.xy[~bad], tl.slot[~bad])
            clean[tl.frames, tl.slot] = tl.xy
            out.append(tl)
    n_kept = int(np.isfinite(clean).all(-1).sum())
    logger.debug("camera %s: %d ground points, %d kept in %d tracklets", tracks.camera, n_raw,
                 n_kept, len(out))
    return GroundTracks(tracks.camera, tracks.n_frames, clean, out, n_raw - n_kept)
