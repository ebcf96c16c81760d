"""One identity per person: link the track pieces of the 3D poses across gaps and crossings.

The reconstruction's tracks break where a person is seen by fewer than two cameras, and are cut
where two people pass close (:func:`cascalib.stages.person_size.split_by_size`). Here the pieces
are chained into persons by a minimum-cost path cover (Hungarian assignment of each piece's end
to the start of a later piece, or to nothing): the cost of a link is how far the end, carried on
at its walking velocity, lands from the start (the tolerance growing with the gap), plus how
much the two pieces' body sizes differ. Pieces that overlap in time are not linked (but for a
fraction of a second where a cut track goes on in a new one). Rounds
with longer gaps then link the chains, whose sizes and velocities are better known.

Axes as in :mod:`cascalib.poses`: ``joints[t, p, j, c]``, world metres, z up.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import linear_sum_assignment

from cascalib.skeletons import CANONICAL_INDEX, CANONICAL_JOINTS
from cascalib.stages.person_size import bone_pairs

__all__ = ["link_persons"]

#: Longest gap (s) bridged in each round: short gaps first, where continuity is reliable.
GAP_ROUNDS_S = (0.5, 2.0, 8.0, 30.0)
#: Seconds at either end of a piece whose floor positions give its position and velocity.
END_WINDOW_S = 0.5
#: Longest time (s) a velocity is carried across a gap: people turn.
MAX_EXTRAPOLATION_S = 1.0
#: Longest overlap (s) of two linked pieces: a track cut often goes on in a new one at the
#: same sample or a few after (the overlap's samples then keep one slot, see _one_slot_each).
MAX_OVERLAP_S = 0.5
#: Position tolerance (m): at zero gap, and its growth with the gap (m/s).
POSITION_SD_M = 0.25
SPEED_SD_M_S = 0.7
#: Fastest walk (m/s) between two pieces' ends, whatever the extrapolation says.
MAX_SPEED_M_S = 2.5
#: Floor on the relative size difference's standard deviation (detection and model error).
SIZE_SD_FLOOR = 0.015
#: Cost (sum of squared standard scores) above which a link is not made.
MAX_LINK_COST = 9.0
#: Cost per second of gap: of two fits, the shorter gap wins.
GAP_COST_PER_S = 0.3
#: Longest piece (s) that may fill a hole inside another piece's time span.
FILL_MAX_S = 1.0
#: Floor distance (m) within which a short piece next to another slot is a duplicate of it.
DUPLICATE_M = 0.4
#: Persons seen for less than this (s) get no identity: too short to be a person's file.
MIN_PERSON_S = 1.0

_FLOOR_JOINTS = [CANONICAL_INDEX[n] for n in ("mid_hip", "left_hip", "right_hip", "neck")]


@dataclass(frozen=True)
class _Pieces:
    """Per piece: its times (sample indices), end states and body size."""

    rows: list[NDArray[np.int64]]  # sample indices of each piece, sorted
    start: NDArray[np.float64]  # (n,) seconds
    end: NDArray[np.float64]
    head: NDArray[np.float64]  # (n, 2, 2): position, velocity at the start (m, m/s)
    tail: NDArray[np.float64]  # (n, 2, 2): at the end
    size: NDArray[np.float64]  # (n,) relative body size (median bone length ratio)
    size_se: NDArray[np.float64]  # (n,) its standard error


def link_persons(joints: NDArray[np.float64], track_ids: NDArray[np.int64],
                 times: NDArray[np.float64]) -> NDArray[np.int64]:
    """A person identity for every slot, linking the tracks that are one person.

    Parameters
    ----------
    joints : ndarray, shape (T, P, 26, 3)
        Canonical joints in world metres (z up), NaN where missing.
    track_ids : ndarray of int, shape (T, P)
        Track of each slot, -1 where empty.
    times : ndarray, shape (T,)
        Seconds of each time sample.

    Returns
    -------
    ndarray of int, shape (T, P)
        Person of each slot, numbered 0.. in order of first appearance; -1 where empty or where
        the person is seen for less than :data:`MIN_PERSON_S` in all.
    """
    floor, size = _floor_and_size(joints)
    slot = (track_ids >= 0) & np.isfinite(floor[..., 0])
    labels = _drop_duplicates(np.where(slot, track_ids, -1), floor, times)
    labels = _fill_holes(labels, floor, size, times)
    for max_gap in GAP_ROUNDS_S:
        pieces, ids = _pieces(labels, floor, size, times)
        nxt = _link(pieces, max_gap, FILL_MAX_S if max_gap > GAP_ROUNDS_S[0] else 0.0)
        labels = _relabel(labels, ids, nxt)
    return _number_persons(_one_slot_each(labels, joints), times)


def _floor_and_size(joints: NDArray[np.float64]) -> tuple[NDArray[np.float64],
                                                          NDArray[np.float64]]:
    """Floor position (T, P, 2) of each slot (mean of hips and neck) and its relative body
    size (T, P): the median over bones of the length over that bone class's median length."""
    bones, classes = bone_pairs(CANONICAL_JOINTS)
    lengths = np.linalg.norm(joints[:, :, bones[:, 0]] - joints[:, :, bones[:, 1]], axis=-1)
    with warnings.catch_warnings():  # empty slots and unseen bones stay NaN
        warnings.simplefilter("ignore", RuntimeWarning)
        floor = np.nanmean(joints[:, :, _FLOOR_JOINTS, :2], axis=2)
        ref = np.array([np.nanmedian(lengths[..., classes == k])
                        for k in range(classes.max() + 1)])
        size = np.nanmedian(lengths / ref[classes], axis=-1)
    return floor, size


def _pieces(labels: NDArray[np.int64], floor: NDArray[np.float64], size: NDArray[np.float64],
            times: NDArray[np.float64]) -> tuple[_Pieces, NDArray[np.int64]]:
    """The pieces (one per label) with their end states and sizes, and their labels."""
    t_idx, p_idx = np.nonzero(labels >= 0)
    lab = labels[t_idx, p_idx]
    order = np.lexsort((t_idx, lab))
    t_idx, p_idx, lab = t_idx[order], p_idx[order], lab[order]
    ids, first = np.unique(lab, return_index=True)
    bounds = np.r_[first, lab.size]
    rows, heads, tails, sizes, ses = [], [], [], [], []
    for a, b in zip(bounds[:-1], bounds[1:], strict=True):
        t, p = t_idx[a:b], p_idx[a:b]
        ts, xy = times[t], floor[t, p]
        heads.append(_end_state(ts[::-1], xy[::-1]))
        tails.append(_end_state(ts, xy))
        s = size[t, p]
        s = s[np.isfinite(s)]
        sizes.append(float(np.median(s)) if s.size else np.nan)
        mad = 1.4826 * float(np.median(np.abs(s - sizes[-1]))) if s.size else np.inf
        ses.append(max(mad, SIZE_SD_FLOOR) / np.sqrt(max(s.size, 1)))
        rows.append(t)
    pieces = _Pieces(rows, np.array([times[r[0]] for r in rows]),
                     np.array([times[r[-1]] for r in rows]), np.array(heads), np.array(tails),
                     np.array(sizes), np.array(ses))
    return pieces, ids


def _drop_duplicates(labels: NDArray[np.int64], floor: NDArray[np.float64],
                     times: NDArray[np.float64]) -> NDArray[np.int64]:
    """Unlabel short pieces (at most :data:`FILL_MAX_S`) that, at each of their samples, stand
    within :data:`DUPLICATE_M` of another slot: a second reconstruction of someone present."""
    d = np.linalg.norm(floor[:, :, None] - floor[:, None, :], axis=-1)  # (T, P, P)
    d[:, np.arange(floor.shape[1]), np.arange(floor.shape[1])] = np.inf
    near = (np.nan_to_num(d, nan=np.inf) < DUPLICATE_M).any(axis=2)  # (T, P)
    out = labels.copy()
    for k in np.unique(labels[labels >= 0]):
        t, p = np.nonzero(labels == k)
        if times[t.max()] - times[t.min()] <= FILL_MAX_S and near[t, p].all():
            out[t, p] = -1
    return out


def _fill_holes(labels: NDArray[np.int64], floor: NDArray[np.float64],
                size: NDArray[np.float64], times: NDArray[np.float64]) -> NDArray[np.int64]:
    """Give a short piece that lies within the time span of a longer one, at samples the longer
    one misses, the longer one's label when it sits where that one is at those times (a person
    lost by one association for a few frames). Path covers only link end to start, so they
    cannot."""
    pc, ids = _pieces(labels, floor, size, times)
    spans = [(times[r[-1]] - times[r[0]]) for r in pc.rows]
    where = {int(k): np.nonzero(labels == k) for k in ids}
    out = labels.copy()
    taken = {int(k): set(where[int(k)][0].tolist()) for k in ids}
    fills: list[tuple[float, int, int]] = []
    for j in np.flatnonzero(np.array(spans) <= FILL_MAX_S):
        hosts = np.flatnonzero((pc.start < pc.start[j]) & (pc.end > pc.end[j]))
        tj, pj = where[int(ids[j])]
        for i in hosts:
            ti, pi = where[int(ids[i])]
            xy = np.column_stack([np.interp(times[tj], times[ti], floor[ti, pi, c])
                                  for c in range(2)])
            miss = float(np.max(np.linalg.norm(xy - floor[tj, pj], axis=-1)))
            z2 = (pc.size[i] - pc.size[j]) ** 2 / (pc.size_se[i] ** 2 + pc.size_se[j] ** 2
                                                     + SIZE_SD_FLOOR ** 2)
            cost = (miss / POSITION_SD_M) ** 2 + float(np.nan_to_num(z2))
            if cost < MAX_LINK_COST:
                fills.append((cost, int(j), int(i)))
    done: set[int] = set()
    for _, short, host in sorted(fills):
        rows = set(where[int(ids[short])][0].tolist())
        if short in done or rows & taken[int(ids[host])]:
            continue
        out[labels == ids[short]] = ids[host]
        taken[int(ids[host])] |= rows
        done.add(short)
    return out


def _end_state(ts: NDArray[np.float64], xy: NDArray[np.float64]) -> NDArray[np.float64]:
    """Position and velocity (2, 2) at the last sample of ``ts``: a least-squares line through
    the samples within :data:`END_WINDOW_S` of it (``ts`` reversed gives the first sample's)."""
    near = np.abs(ts - ts[-1]) <= END_WINDOW_S
    dt, p = ts[near] - ts[-1], xy[near]
    if near.sum() < 3 or np.ptp(dt) == 0:
        return np.array([p.mean(axis=0), np.zeros(2)])
    A = np.c_[np.ones_like(dt), dt]
    (pos, vel), *_ = np.linalg.lstsq(A, p, rcond=None)
    return np.array([pos, vel])


def _link_cost(pc: _Pieces, max_gap: float) -> NDArray[np.float64]:
    """Cost (n, n) of linking the end of piece i to the start of piece j; inf where not
    allowed (overlap in time beyond :data:`MAX_OVERLAP_S`, a gap beyond ``max_gap``, out of
    reach)."""
    overlap = pc.start[None, :] - pc.end[:, None]
    allowed = (overlap > -MAX_OVERLAP_S) & (overlap <= max_gap)
    gap = np.abs(overlap)
    h = np.clip(overlap, -MAX_OVERLAP_S, MAX_EXTRAPOLATION_S)[..., None]  # signed
    p_end, v_end = pc.tail[:, None, 0], pc.tail[:, None, 1]
    p_start, v_start = pc.head[None, :, 0], pc.head[None, :, 1]
    # both ends carried half-way to each other in time (the start backwards; an overlap's
    # end backwards and start forwards)
    miss = np.linalg.norm((p_end + v_end * h / 2) - (p_start - v_start * h / 2), axis=-1)
    sd = POSITION_SD_M + SPEED_SD_M_S * gap
    reach = np.linalg.norm(p_start - p_end, axis=-1) <= POSITION_SD_M + MAX_SPEED_M_S * gap
    dsize = pc.size[:, None] - pc.size[None, :]
    size_z2 = np.nan_to_num(dsize**2 / (pc.size_se[:, None]**2 + pc.size_se[None, :]**2
                                        + SIZE_SD_FLOOR**2), nan=0.0)
    with np.errstate(invalid="ignore", divide="ignore"):
        cost = (miss / sd) ** 2 + size_z2 + GAP_COST_PER_S * gap
    return np.where(allowed & reach & (cost < MAX_LINK_COST), cost, np.inf)


def _link(pc: _Pieces, max_gap: float, min_span: float) -> NDArray[np.int64]:
    """Successor of each piece (-1: none) from a minimum-cost path cover of the pieces that
    span more than ``min_span`` seconds (a few frames' velocity and size are too uncertain for
    gaps of seconds)."""
    n = len(pc.rows)
    nxt = np.full(n, -1)
    cost = _link_cost(pc, max_gap)
    short = pc.end - pc.start <= min_span
    cost[short] = np.inf
    cost[:, short] = np.inf
    rows_ok = np.isfinite(cost).any(axis=1)
    cols_ok = np.isfinite(cost).any(axis=0)
    if not rows_ok.any():
        return nxt
    r_idx, c_idx = np.flatnonzero(rows_ok), np.flatnonzero(cols_ok)
    sub = cost[np.ix_(r_idx, c_idx)]
    # "no link" costs half the threshold on each side: a link is made when it costs less
    big = 1e9
    n_r, n_c = sub.shape
    full = np.full((n_r + n_c, n_c + n_r), big)
    full[:n_r, :n_c] = np.where(np.isfinite(sub), sub, big)
    full[:n_r, n_c:][np.diag_indices(n_r)] = MAX_LINK_COST / 2
    full[n_r:, :n_c][np.diag_indices(n_c)] = MAX_LINK_COST / 2
    full[n_r:, n_c:] = 0.0
    r, c = linear_sum_assignment(full)
    made = (r < n_r) & (c < n_c)
    made[made] = full[r[made], c[made]] < big
    nxt[r_idx[r[made]]] = c_idx[c[made]]
    return nxt


def _relabel(labels: NDArray[np.int64], ids: NDArray[np.int64],
             nxt: NDArray[np.int64]) -> NDArray[np.int64]:
    """Give every piece of a chain (``nxt``: successor per piece) its first piece's label."""
    has_prev = np.zeros(len(ids), dtype=bool)
    has_prev[nxt[nxt >= 0]] = True
    root = np.arange(len(ids))
    for k in np.flatnonzero(~has_prev):
        j = nxt[k]
        while j >= 0:
            root[j] = k
            j = nxt[j]
    out = labels.copy()
    m = labels >= 0
    out[m] = ids[root][np.searchsorted(ids, labels[m])]
    return out


def _one_slot_each(labels: NDArray[np.int64], joints: NDArray[np.float64]) -> NDArray[np.int64]:
    """Where linked pieces overlap, one slot per person and time: the one with the most joints."""
    out = labels.copy()
    n_joints = np.isfinite(joints[..., 0]).sum(axis=-1)
    distinct_empty = np.where(labels >= 0, labels, -1 - np.arange(labels.shape[1]))
    for t in np.flatnonzero((np.diff(np.sort(distinct_empty, axis=1), axis=1) == 0).any(1)):
        row = labels[t]
        for k in np.unique(row[row >= 0]):
            slots = np.flatnonzero(row == k)
            if slots.size > 1:
                keep = slots[np.argmax(n_joints[t, slots])]
                out[t, slots[slots != keep]] = -1
    return out


def _number_persons(labels: NDArray[np.int64], times: NDArray[np.float64]) -> NDArray[np.int64]:
    """Persons 0.. in order of first appearance; those seen under :data:`MIN_PERSON_S`: -1."""
    out = np.full(labels.shape, -1, dtype=np.int64)
    if not (labels >= 0).any():
        return out
    dt = float(np.median(np.diff(times))) if times.size > 1 else 1.0
    t_idx, _ = np.nonzero(labels >= 0)
    lab = labels[labels >= 0]
    ids, first, counts = np.unique(lab, return_index=True, return_counts=True)
    keep = counts * dt >= MIN_PERSON_S
    order = ids[keep][np.argsort(t_idx[first[keep]], kind="stable")]
    lut = np.full(int(ids.max()) + 1, -1)
    lut[order] = np.arange(order.size)
    out[labels >= 0] = lut[lab]
    return out
