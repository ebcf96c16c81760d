"""Person tracks held to one person by body size.

Stage V ties each person's bone lengths over their track (``RangeFactor3`` terms). Tracks are
linked over time by ground position (:func:`cascalib.stages.association.link_tracks`); where two
people pass close, a track can go on with the other one, and the bone terms would then ask one
person to have two people's lengths. A person's size does not change, so a sudden jump of the
size along a track marks such a swap: the track is cut there, and pieces of one size that never
overlap in time are joined again (for the bone terms only: joined pieces can be two people of
one size seen at different times, which is harmless for bone lengths but not for the 3D poses'
person ids, so the final reconstruction cuts without joining).

Measured at the true cameras of 40 s simulator scenes (share of person-frames in a track of
mostly their own person, after linking -> after the cut): terrace 0.98 -> 0.98 (seed 2), lab
ring 0.75 -> 1.00, circles 0.97 -> 1.00; in stage V's quick matrix this lowered the rotation
error on 9 of 12 scenes (terrace median 1.05 / 0.60 / 0.57 -> 0.76 / 0.47 / 0.28 deg).
"""

from __future__ import annotations

import warnings

import numpy as np
from numpy.typing import NDArray
from scipy.stats import median_abs_deviation

__all__ = ["BONE_CLASSES", "bone_pairs", "split_by_size"]

#: Bone classes of the length terms: a left/right pair shares one target (symmetry).
BONE_CLASSES: tuple[tuple[tuple[str, str], ...], ...] = (
    (("left_shoulder", "left_elbow"), ("right_shoulder", "right_elbow")),
    (("left_elbow", "left_wrist"), ("right_elbow", "right_wrist")),
    (("left_hip", "left_knee"), ("right_hip", "right_knee")),
    (("left_knee", "left_ankle"), ("right_knee", "right_ankle")),
    (("left_ankle", "left_heel"), ("right_ankle", "right_heel")),
    (("left_ankle", "left_big_toe"), ("right_ankle", "right_big_toe")),
    (("neck", "left_shoulder"), ("neck", "right_shoulder")),
    (("mid_hip", "left_hip"), ("mid_hip", "right_hip")),
    (("neck", "mid_hip"),),
    (("neck", "head_top"),),
)


#: The least per-group size noise (relative) that the cut and join tests count on. A size step
#: must then be at least 2 % to cut a track (``threshold`` 6 standard errors of the medians of
#: two 15-group windows): adult heights differ by about 4 % (sd), so two people are seldom
#: closer, while geometry that is still off makes a person's size drift along the floor by about
#: 1 % between such windows (the largest step of each track, median: 1.2 % on a rig 2 deg off).
#: Without a floor, precise detections made every such drift a "jump": on simulated
#: detections with 0.01 px noise (terrace seed 1, from the true rig with the principal points
#: at the image centre) the sizes' noise was 0.04 %, tracks of 5 persons were cut into 51-65
#: pieces, and their bone targets, each from a few seconds of one place, held the principal-point
#: pass near its start: relative rotations 0.95 deg, against 0.009 deg with 0.2 px noise (5
#: tracks, sizes' noise 0.2 %). With the simulator's usual detector the sizes' noise is 1.6-4 %,
#: above the floor.
MIN_SIZE_SD = 0.0075


def bone_pairs(names: tuple[str, ...]) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Bone joint pairs (indices into ``names``) and their class, for bones fully in ``names``."""
    pos = {n: i for i, n in enumerate(names)}
    pairs, cls = [], []
    for k, bone_class in enumerate(BONE_CLASSES):
        for a, b in bone_class:
            if a in pos and b in pos:
                pairs.append((pos[a], pos[b]))
                cls.append(k)
    return np.array(pairs, dtype=np.int64).reshape(-1, 2), np.array(cls, dtype=np.int64)


def split_by_size(points: NDArray[np.float64], tracks: NDArray[np.int64],
                  times: NDArray[np.float64], bones: NDArray[np.int64],
                  classes: NDArray[np.int64], *, window: int = 15,
                  threshold: float = 6.0, join: bool = True) -> NDArray[np.int64]:
    """Cut person tracks where the person's size jumps: where the track went on with another
    person (two people passing close), unless the two are of a size.

    A group's size is the median over its bones of the length relative to the median of the
    bone's class over all groups. Along each track (in time order) the median size of the
    ``window`` groups after each point is compared with that of the ``window`` before; the
    track is cut at each local maximum of the step that exceeds ``threshold`` standard errors
    (noise from the differences of consecutive sizes, at least :data:`MIN_SIZE_SD`). Only a jump
    within a few frames counts: a camera's residual error makes a person's size drift slowly
    along the floor, and cutting there would tie the bone lengths only locally, which keeps that
    error instead of correcting it.

    Parameters
    ----------
    points : ndarray, shape (G, J, 3)
        Triangulated joints of every group.
    tracks, times : ndarray, shape (G,)
        Track of each group (-1 for none) and its reference time.
    bones, classes : ndarray, shape (B, 2) and (B,)
        Joint pairs into J and their bone class (:func:`bone_pairs`).
    window : int
        Groups on each side of a cut; shorter pieces are not cut off.
    threshold : float
        Size step, in standard errors, that makes a cut (and the largest difference of two
        pieces' median sizes, in standard errors, that still joins them).
    join : bool
        Join pieces of one size that never overlap in time (see the module notes).

    Returns
    -------
    ndarray of int, shape (G,)
        New track labels (the pieces of a track after the first get new numbers).
    """
    lengths = np.linalg.norm(points[:, bones[:, 0]] - points[:, bones[:, 1]], axis=-1)  # (G, B)
    with warnings.catch_warnings():  # all-NaN classes and groups stay NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        ref = np.array([np.nanmedian(lengths[:, classes == k]) for k in range(classes.max() + 1)])
        size = np.nanmedian(lengths / ref[classes], axis=1)
    out = tracks.copy()
    next_id = int(tracks.max()) + 1 if tracks.size else 0
    for tr in np.unique(tracks[tracks >= 0]):
        whole = tracks == tr  # groups without a size go with the piece of their time
        idx = np.flatnonzero(whole & np.isfinite(size))
        idx = idx[np.argsort(times[idx], kind="stable")]
        n = idx.size
        if n < 2 * window:
            continue
        s = size[idx]
        sd = max(median_abs_deviation(np.diff(s), scale="normal") / np.sqrt(2), MIN_SIZE_SD)
        win = np.lib.stride_tricks.sliding_window_view(s, window)  # win[j] = s[j:j + window]
        med = np.median(win, axis=1)
        i = np.arange(window, n - window + 1)  # cut before point i
        # a median of w noisy values has a standard error of about 1.25 sd / sqrt(w)
        z = np.abs(med[i] - med[i - window]) / (1.25 * sd * np.sqrt(2 / window))
        cuts = []  # type: ignore[var-annotated]
        for k in np.argsort(-z):
            if z[k] < threshold:
                break
            if all(abs(i[k] - c) >= window for c in cuts):
                cuts.append(int(i[k]))
        for lo in sorted(cuts):
            out[whole & (times >= times[idx[lo]])] = next_id  # later cuts relabel their tail
            next_id += 1
    return _join_by_size(out, times, size, window, threshold) if join else out


def _join_by_size(tracks: NDArray[np.int64], times: NDArray[np.float64], size: NDArray[np.float64],
                  min_groups: int, threshold: float) -> NDArray[np.int64]:
    """Give pieces of track that never overlap in time and whose median sizes agree within
    ``threshold`` standard errors one label (longest pieces first): a person's bone lengths are
    then tied over the whole sequence, not only between two encounters."""
    ok = (tracks >= 0) & np.isfinite(size)
    ids, inv, counts = np.unique(tracks[ok], return_inverse=True, return_counts=True)
    members = np.split(np.argsort(inv, kind="stable"), np.cumsum(counts)[:-1])
    s_ok = size[ok]
    t_all = np.unique(times)
    labels: list[int] = []  # per person: label, median size, standard error, times seen
    p_size: list[float] = []
    p_se: list[float] = []
    p_seen: list[NDArray[np.bool_]] = []
    relabel: dict[int, int] = {}
    for j in np.argsort(-counts, kind="stable"):
        if counts[j] < min_groups:
            break
        v = s_ok[members[j]]
        seen = np.zeros(t_all.size, dtype=bool)
        seen[np.searchsorted(t_all, times[tracks == ids[j]])] = True
        med = float(np.median(v))
        se = max(float(median_abs_deviation(v, scale="normal")), MIN_SIZE_SD) / np.sqrt(v.size)
        if labels:
            z = np.abs(np.array(p_size) - med) / np.hypot(np.array(p_se), se)
            for q in np.argsort(z):
                if z[q] >= threshold:
                    break
                if not (p_seen[q] & seen).any():
                    relabel[int(ids[j])] = labels[q]
                    p_seen[q] |= seen
                    break
            if int(ids[j]) in relabel:
                continue
        labels.append(int(ids[j]))
        p_size.append(med)
        p_se.append(se)
        p_seen.append(seen)
    out = tracks.copy()
    for k, lab in relabel.items():
        out[tracks == k] = lab
    return out
