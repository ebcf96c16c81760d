"""One camera's 2D tracks over time: persons linked from frame to frame, and their keypoints at
fractional frames.

Camera frame ``k`` shows reference frame ``time_rate * k + time_offset`` (cascalib's TIME
CONVENTION), so a reference time falls between two frames of every other camera. Persons of
consecutive frames are linked (:func:`frame_links`: track ids when the detector gives them, else
a Hungarian match of keypoint distances) and their keypoints blended linearly
(:func:`interpolate_views`, :func:`interpolate_slots`). Stage V's association
(:mod:`cascalib.stages.association`), clock search (:mod:`cascalib.stages.time_refine`) and
epipolar sync read the tracks through these.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from cascalib.geometry import norm_xy
from cascalib.nanstats import joint_extent, nanmedian_last
from cascalib.stages.association import row_minima_assignment

__all__ = ["frame_links", "interpolate_slots", "interpolate_views", "linked_pairs",
           "person_distances"]


def frame_links(keypoints: NDArray[np.float64], track_ids: NDArray[np.int64] | None = None,
                *, gate: float = 0.5, id_tolerance: float = 0.05) -> NDArray[np.int64]:
    """Which person slot of frame ``k + 1`` continues each slot of frame ``k``.

    Parameters
    ----------
    keypoints : ndarray, shape (F, P, J, 3)
    track_ids : ndarray, shape (F, P), optional
        Per-camera track ids; followed where both frames have them and the id's step is
        plausible (see ``id_tolerance``).
    gate : float
        Largest mean keypoint displacement between frames, as a fraction of the person's size.
    id_tolerance : float
        A track id is followed where its step is no more than this (as a fraction of the
        person's size) longer than the nearest continuation's: a tracker's swap of ids between
        overlapping persons is not (see :func:`_follow_ids`).

    Returns
    -------
    ndarray of int, shape (F, P)
        ``links[k, p]`` is the slot in frame ``k + 1`` or -1 (the last row is all -1).
    """
    n_f, n_p = keypoints.shape[:2]
    links = np.full((n_f, n_p), -1, dtype=np.int64)
    if n_f < 2 or n_p == 0:
        return links
    # mean joint displacement of every pair of persons present in consecutive frames (only
    # those: empty slots are common, and the full (F-1, P, P, J) difference is large)
    present = np.isfinite(keypoints[..., 0]).any(-1)  # (F, P)
    k, p, q = np.nonzero(present[:-1, :, None] & present[1:, None, :])  # type: ignore[index]
    d = np.full((n_f - 1, n_p, n_p), np.nan)
    xy = np.ascontiguousarray(keypoints[..., :2])  # gathers of whole rows: twice as fast
    with np.errstate(invalid="ignore"):  # 0 / 0 for pairs with no joint in common: NaN
        step = norm_xy(xy[k, p] - xy[k + 1, q])  # (pairs, J)
        seen = np.isfinite(step)
        d[k, p, q] = np.where(seen, step, 0.0).sum(-1) / seen.sum(-1)  # nanmean, no copies
        ext = joint_extent(keypoints)
        size = norm_xy(ext)  # (F, P)
    cost = np.where(np.isfinite(d), d / np.maximum(size[:-1, :, None], 1.0), np.inf)
    rows_ok = np.isfinite(cost).any(2)
    best, solved = row_minima_assignment(cost, rows_ok)  # type: ignore[arg-type]
    c_best = np.take_along_axis(cost, best[..., None], -1)[..., 0]
    links[:-1] = np.where(solved[:, None] & rows_ok & (c_best < gate), best, -1)
    for k in np.flatnonzero(~solved & rows_ok.any(1)):  # type: ignore[assignment, call-overload]  # two persons want one slot: Hungarian
        c = cost[k]
        r, q = linear_sum_assignment(np.where(np.isfinite(c), c, 1e9))
        good = c[r, q] < gate
        links[k, r[good]] = q[good]
    if track_ids is not None:
        _follow_ids(links, cost, track_ids, gate, id_tolerance)
    return links


def _follow_ids(links: NDArray[np.int64], cost: NDArray[np.float64],
                track_ids: NDArray[np.int64], gate: float, tolerance: float) -> None:
    """Replace motion links (in place) by the track ids' where the ids' step is within the
    gate and no more than ``tolerance`` (of the person's size) longer than the motion link's.

    Trackers swap ids where persons overlap, which is where ids would help; a swapped id links
    two different persons, whose blend at a fractional frame is neither of them, and whose
    velocity is a jump. Measured on bench_sync.py's windowed crowds (per-camera ids, swapped at
    30 % of overlaps), ids followed wherever they continue -> only where plausible:

    * one clock update from the true rig and clocks (seeds 0-2 / 3-5), clock error over the
      shared frames 0.029 / 0.029 -> 0.022 / 0.015 frame rms (0.020 / 0.015 with no swaps in
      the simulator);
    * bench_sync.py --refine, crowd rows without / with stage-I errors: stage IV's worst offset
      error 0.175 / 0.179 -> 0.137 / 0.111 frame, Stage V's 0.114 / 0.091 -> 0.079 / 0.077
      (medians 0.015 / 0.022 -> 0.036 / 0.027), rates 0.019 / 0.012 -> 0.011 / 0.010 %;
    * the six crowds of 24 simulated 40 s whole-cascade scenes (Stage V from cached stage
      II-IV results): mean of median relative rotations 0.310 -> 0.264 deg (single scenes
      -0.22 .. +0.06), worst 0.577 -> 0.531, sum of worst offsets 0.161 -> 0.099 frame;
    * bench_refine.py's crowd rows (from the true rig 3-5 deg off, seeds 0-2): median / max
      relative rotation 0.313 / 0.478, 0.464 / 0.762, 0.349 / 0.554 -> 0.154 / 0.267, 0.226 /
      0.362, 0.328 / 0.336 deg, focal max 0.44 / 0.92 / 0.47 -> 0.17 / 0.43 / 0.27 %.
    """
    ta, tb = track_ids[:-1, :, None], track_ids[1:, None, :]
    same = (ta == tb) & (ta >= 0)
    q_id = same.argmax(-1)
    c_id = np.take_along_axis(cost, q_id[..., None], -1)[..., 0]
    motion = links[:-1]  # a view: the assignments below change ``links``
    c_motion = np.where(motion >= 0, np.take_along_axis(cost, np.maximum(motion, 0)[..., None],
                                                        -1)[..., 0], np.inf)
    use = same.any(-1) & (c_id < gate) & (c_id <= c_motion + tolerance)
    motion[use] = q_id[use]
    # a slot an id now continues into is nobody else's continuation
    claimed = np.zeros(motion.shape, dtype=bool)
    k, _ = np.nonzero(use)
    claimed[k, q_id[use]] = True
    rows = np.arange(motion.shape[0])[:, None]
    motion[(motion >= 0) & ~use & claimed[rows, np.maximum(motion, 0)]] = -1


def interpolate_views(keypoints: NDArray[np.float64], links: NDArray[np.int64],
                      frames: NDArray[np.float64]) -> NDArray[np.float64]:
    """Keypoints of one camera at fractional frame positions.

    Parameters
    ----------
    keypoints : ndarray, shape (F, P, J, 3)
    links : ndarray, shape (F, P)
        From :func:`frame_links`.
    frames : ndarray, shape (T,)
        Fractional frame indices of this camera.

    Returns
    -------
    ndarray, shape (T, P, J, 3)
        Person slots follow frame ``floor(frames)``; where the link or a joint of the next frame is
        missing, the nearer frame's value is used if it is within half a frame, else NaN.
    """
    n_f, n_p = keypoints.shape[:2]
    inside = (frames > -0.5) & (frames < n_f - 0.5)
    # only the frames inside are gathered: out-of-range times stay NaN
    fr = frames[inside]
    k0 = np.clip(np.floor(fr), 0, n_f - 1).astype(np.int64)
    w = np.clip(fr - k0, 0.0, 1.0)[:, None, None, None]
    a, b = linked_pairs(keypoints, links, k0)
    res = _blend(a, b, w)
    if inside.all():
        return res
    out = np.full((len(frames), n_p) + keypoints.shape[2:], np.nan)
    out[inside] = res
    return out


def person_distances(views: NDArray[np.float64], target: NDArray[np.float64]
                     ) -> NDArray[np.float64]:
    """Median joint distance (px) of each person of ``views`` (T, P, J, 2) to ``target``
    (T, J, 2), shape (T, P); inf where they share no joint."""
    return np.nan_to_num(nanmedian_last(norm_xy(views - target[:, None])), nan=np.inf)


def interpolate_slots(keypoints: NDArray[np.float64], links: NDArray[np.int64],
                      frames: NDArray[np.float64], slots: NDArray[np.int64]
                      ) -> NDArray[np.float64]:
    """:func:`interpolate_views` of a few persons per time only.

    Parameters
    ----------
    keypoints, links : ndarray
        As for :func:`interpolate_views`.
    frames : ndarray, shape (T,)
        Fractional frame indices.
    slots : ndarray of int, shape (T, K)
        Person slots of frame ``floor(frames)`` (clipped to the recording), -1 for none.

    Returns
    -------
    ndarray, shape (T, K, J, D)
        ``interpolate_views(keypoints, links, frames)[t, slots[t, k]]``; NaN for slot -1.
    """
    n_f = keypoints.shape[0]
    inside = (frames > -0.5) & (frames < n_f - 0.5)
    k0 = np.clip(np.floor(frames), 0, n_f - 1).astype(np.int64)
    w = np.clip(frames - k0, 0.0, 1.0)[:, None, None, None]
    a, b = linked_pairs(keypoints, links, k0, slots)
    res = _blend(a, b, w)
    res[(slots < 0) | ~inside[:, None]] = np.nan
    return res


def linked_pairs(keypoints: NDArray[np.float64], links: NDArray[np.int64],
                 frames: NDArray[np.int64], slots: NDArray[np.int64] | None = None
                 ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Each person's detection in frame ``k`` and the one linked to it in frame ``k + 1``
    (NaN where unlinked, as everyone in the last frame) for whole frames ``frames`` (T,), or
    only for ``slots`` (T, K) of them (slot -1 gives slot 0's values: mask them yourself).

    Returns
    -------
    a, b : ndarray, shape (T, P or K, J, D)
    """
    n_f = keypoints.shape[0]
    k1 = np.minimum(frames + 1, n_f - 1)[:, None]
    if slots is None:
        a = keypoints[frames]  # (T, P, J, D)
        nxt = links[frames]  # (T, P)
    else:
        s = np.maximum(slots, 0)
        a = keypoints[frames[:, None], s]  # (T, K, J, D)
        nxt = links[frames[:, None], s]
    # one fancy index gathers the linked slot of the next frame (no full copy of that frame)
    b = keypoints[k1, np.maximum(nxt, 0)]
    b[nxt < 0] = np.nan
    return a, b


def _blend(a: NDArray[np.float64], b: NDArray[np.float64], w: NDArray[np.float64]
           ) -> NDArray[np.float64]:
    """``a + w (b - a)`` (computed in place in a new array: the clock search calls this on large
    arrays); where one side is missing, the nearer frame's value if it is within half a frame
    (``a`` before, ``b`` at exactly half a frame if ``a`` is missing), else NaN."""
    res = b - a
    res *= w
    res += a
    gap = ~np.isfinite(res)
    if gap.any():
        near = np.where(w <= 0.5, np.where(np.isfinite(a) | (w < 0.5), a, b), b)
        np.copyto(res, near, where=gap)
    return res
