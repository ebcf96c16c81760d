"""Sub-frame time offsets and frame-rate ratios for stage V.

Stage III finds each camera's offset to about a frame and its rate ratio to about 1e-4. Between
bundle-adjustment rounds, each non-reference camera's clock is refined against the others: the
persons are triangulated at reference times *without* that camera and projected into it, and the
camera's 2D tracks are interpolated at ``(t - offset - delta - rho u) / rate``, where
``u = (t - t_mid) / half_span`` runs from -1 to 1 over the recording. ``delta`` (the offset at
mid-recording) and ``rho`` (the rate change, in frames gained over half the recording) are the
root of the robust (Cauchy) least-squares normal equation ``sum w J . r = 0``, ``J = (v, v u)``,
where ``r`` is the residual of each joint and ``v`` its image velocity (a Gauss-Newton start,
then Broyden's secant steps). The velocity comes from the frames two before and two after the
interpolated pair, so that its noise is independent of the residual's. Each camera's time
mapping stays affine, consistent with the reference clock.

Why the rate: with the rate held at stage III's, the offset settles where the recording's middle
agrees, and the rate's error then shows as an error of the offset at frame 0 (a simulated
terrace: rate 0.0185 % off over 1074 frames, offset 0.10 frame off at frame 0 and 0.00 at
mid-recording, with the true geometry).

Why not a cost curve: the earlier search took the minimum of a truncated mean of per-person median
distances on a grid of ``delta``. Its curve was flat (0.1 px over a frame on 8 px) and its minimum
moved by +-0.3 frame between random subsets of the same scene, with the true geometry. The normal
equation uses every joint, weighted by how fast it moves: from the truth it stays within 0.03
frame, from any start within 0.4 frame of it (simulated crowd, true geometry).

Why Cauchy weights, not Huber's: a residual along the motion is the one that moves a clock, and
under Huber's weights a wrong person matched in a crowd, or a detection of another instant,
pulled it in proportion to its distance beyond the knee. One update from the true rig and clocks
(bench_sync.py's windowed scenes, seeds 0-2, three subsets each), clock error over the frames
each camera shares with the reference: crowd rms 0.044 -> 0.029 frame (worst 0.085 -> 0.070);
terrace, lab ring and periodic walking rms 0.017 -> 0.014 (worst 0.041 -> 0.027). Through the
whole cascade: bench_sync.py --refine (84 cameras), offset error at frame 0 after Stage V, the
sum of the 8 rows' worst 0.658 -> 0.552 frame (windowed crowds 0.121 / 0.162 -> 0.114 / 0.091;
periodic walking 0.044 -> 0.056 / 0.058, the one row that lost); 24 simulated 40 s scenes from
Stage V's input, sum of the scenes' worst 0.784 -> 0.712 frame, relative rotations the same on
average (mean of medians 0.236 -> 0.239 deg; scenes meeting median <= 0.3 and max <= 1 deg
21 -> 18: three that were less than 0.01 deg under 0.3 came out at 0.304-0.360; single crowd
scenes moved by up to 0.17 deg either way, as with any change upstream of them). The README
example: rotation median / max 0.54 / 0.57 -> 0.28 / 0.42 deg, offsets max 0.04 -> 0.02 frame.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from cascalib.camera import Camera
from cascalib.geometry import norm_xy
from cascalib.stages.association import Association
from cascalib.stages.track_interpolation import (
    interpolate_slots,
    interpolate_views,
    linked_pairs,
    person_distances,
)
from cascalib.stages.triangulation import cauchy_weight, triangulate

__all__ = ["previous_slots", "refine_offsets", "regroup", "track_velocity"]

log = logging.getLogger(__name__)

#: Factors of a camera's rate ratio that a wrongly declared frame rate gives: NTSC rates
#: (29.97, 59.94, 23.976 fps, ...) are the nominal ones times 1000/1001, and recordings at one
#: are often labelled with the other (a phone's 29.97 fps video declared 30).
MISLABEL_FACTORS = (1000.0 / 1001.0, 1001.0 / 1000.0)
#: Prior odds of a declared rate against a mislabel: the clock search moves a camera's rate
#: prior to a mislabel only where the data favour it by more.
MISLABEL_ODDS = 100.0


def previous_slots(links: NDArray[np.int64]) -> NDArray[np.int64]:
    """Inverse of :func:`~cascalib.stages.track_interpolation.frame_links`: ``prev[k, q]`` is
    the slot of frame ``k - 1`` that continues into slot ``q`` of frame ``k``, or -1."""
    prev = np.full_like(links, -1)
    k, p = np.nonzero(links[:-1] >= 0)
    prev[k + 1, links[k, p]] = p
    return prev


def _follow(links: NDArray[np.int64], prev: NDArray[np.int64], k: NDArray[np.int64],
            p: NDArray[np.int64], steps: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """Frame and slot ``steps`` frames after (or before, if negative) slot ``p`` of frame ``k``
    along the links; slot -1 where the person is lost."""
    n_f = links.shape[0]
    table = links if steps > 0 else prev
    k, p = k.copy(), p.copy()
    for _ in range(abs(steps)):
        ok = (p >= 0) & (k >= 0) & (k < n_f)
        nxt = np.full_like(p, -1)
        nxt[ok] = table[k[ok], p[ok]]
        k = k + (1 if steps > 0 else -1)
        p = nxt
    return k, p


def _nearest_of(keypoints: NDArray[np.float64], links: NDArray[np.int64],
                frames: NDArray[np.float64], slots: NDArray[np.int64] | None,
                target: NDArray[np.float64]
                ) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
    """The detected person nearest to ``target`` (T, J, 2) by median joint distance, among
    ``slots`` (T, K; -1 for none) of frames ``floor(frames)`` or, with None, among all.

    Returns its slot (T,), keypoints (T, J, 2) and distance (T,), inf where nobody is seen
    (ties go to the first slot, as with argmin).
    """
    if slots is None:
        cand = interpolate_views(keypoints, links, frames)  # (T, P, J, 2)
        slots = np.broadcast_to(np.arange(cand.shape[1]), cand.shape[:2])
    else:
        cand = interpolate_slots(keypoints, links, frames, slots)
    dist = person_distances(cand, target)
    t = np.arange(len(frames))
    i = np.argmin(dist, axis=1)
    return slots[t, i], cand[t, i], dist[t, i]


def regroup(keypoints: list[NDArray[np.float64]], links: list[NDArray[np.int64]],
            cameras: list[Camera], assoc: Association) -> Association:
    """The groups of ``assoc`` seen through the clocks of ``cameras``: each camera's view of a
    group is the detected person nearest to it (median joint distance), interpolated at the
    group's reference time through that camera's clock.

    For comparing clocks that differ by less than a frame on the same persons and times: two
    associations made anew differ in which groups they keep, and that changes a median of
    their reprojection errors by more than a tenth of a frame of one camera's clock does.
    A view that the other clock puts outside the recording (or where nobody is detected) is NaN.
    """
    obs = np.full_like(assoc.obs, np.nan)
    for c, (kp, lk, cam) in enumerate(zip(keypoints, links, cameras, strict=True)):
        seen = np.flatnonzero(np.isfinite(assoc.obs[:, c, :, 0]).any(-1))
        if seen.size == 0:
            continue
        frames = (assoc.times[seen] - cam.time_offset) / cam.time_rate
        _, views, dist = _nearest_of(kp, lk, frames, None, assoc.obs[seen, c])
        found = np.isfinite(dist)
        obs[seen[found], c] = views[found]
    return replace(assoc, obs=obs)


def _cell(frames: NDArray[np.float64], n_f: int) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The frame (``floor``, clipped to the recording) of fractional frames, and the half of it
    they fall in (-1, 0 at exactly half-way, 1)."""
    k = np.clip(np.floor(frames), 0, n_f - 1).astype(np.int64)
    return k, np.sign(frames - k - 0.5).astype(np.int64)


def _within_reach(keypoints: NDArray[np.float64], links: NDArray[np.int64],
                  frames: NDArray[np.float64], target: NDArray[np.float64], reach: float,
                  most: int = 3) -> tuple[NDArray[np.int64], NDArray[np.bool_]]:
    """Slots (T, ``most``; -1 padding) of the persons of frames ``floor(frames)`` whose median
    joint distance to ``target`` can fall below ``reach`` while the frame and its half stay the
    same, and whether that is all of them (T,; no more than ``most``).

    Inside that cell a joint moves linearly between its two detections and no joint appears
    or vanishes (:func:`~cascalib.stages.track_interpolation.interpolate_views` takes a
    missing joint from the nearer frame), so by at most half of the distance between the two
    detections; a median of distances moves by no more than its largest joint does.
    """
    a, b = linked_pairs(keypoints, links, _cell(frames, keypoints.shape[0])[0])
    step = np.nan_to_num(norm_xy(b - a), nan=0.0).max(-1)  # (T, P): largest joint move
    dist = person_distances(interpolate_views(keypoints, links, frames), target)
    near = dist - 0.5 * step < reach
    order = np.argsort(~near, axis=1, kind="stable")[:, :most]  # the persons in reach first
    slots = np.where(np.take_along_axis(near, order, 1), order, -1)
    return slots, near.sum(1) <= most


def track_velocity(keypoints: NDArray[np.float64], links: NDArray[np.int64],
                   prev: NDArray[np.int64], frames: NDArray[np.float64],
                   slots: NDArray[np.int64]) -> NDArray[np.float64]:
    """Image velocity (px per frame) of one person per time, at fractional frame positions.

    Parameters
    ----------
    keypoints : ndarray, shape (F, P, J, D)
    links, prev : ndarray of int, shape (F, P)
        :func:`~cascalib.stages.track_interpolation.frame_links` and :func:`previous_slots`.
    frames : ndarray, shape (T,)
        Fractional frames ``k + w``.
    slots : ndarray of int, shape (T,)
        The person's slot in frame ``k`` (as :func:`interpolate_views` numbers them).

    Returns
    -------
    ndarray, shape (T, J, D)
        ``(x(k + 2 + w) - x(k - 2 + w)) / 4`` from frames ``k - 2, k - 1, k + 2, k + 3``: none of
        them is one of the two detections interpolated at ``k + w``, so the velocity's noise does
        not correlate with that interpolation's. NaN where the person is not followed that far.
    """
    n_f = keypoints.shape[0]
    k = np.floor(frames).astype(np.int64)
    w = (frames - k)[:, None, None]

    def at(kk: NDArray[np.int64], pp: NDArray[np.int64]) -> NDArray[np.float64]:
        ok = (pp >= 0) & (kk >= 0) & (kk < n_f)
        x = np.full((k.size,) + keypoints.shape[2:], np.nan)
        x[ok] = keypoints[kk[ok], pp[ok]]
        return x

    # each frame from its neighbour along the links: four steps back and forth, not eight
    back1 = _follow(links, prev, k, slots, -1)
    back2 = _follow(links, prev, *back1, -1)
    ahead2 = _follow(links, prev, k, slots, 2)
    ahead3 = _follow(links, prev, *ahead2, 1)
    before = at(*back2) + w * (at(*back1) - at(*back2))
    after = at(*ahead2) + w * (at(*ahead3) - at(*ahead2))
    return (after - before) / 4.0


def refine_offsets(keypoints: list[NDArray[np.float64]], links: list[NDArray[np.int64]],
                   cameras: list[Camera], assoc: Association, reference: int, joints:
                   NDArray[np.int64], *, search: float = 1.0, max_groups: int = 6000,
                   cap_px: float = 30.0, huber_px: float = 3.0, rates: bool = False,
                   rate_sd: float | Sequence[float] = 1e-4,
                   anchor_rates: Sequence[float] | None = None,
                   declared: Sequence[int] = (), rng: np.random.Generator | None = None,
                   sd: NDArray[np.float64] | None = None) -> list[Camera]:
    """Refine the time offset (and frame-rate ratio) of every non-reference camera.

    Parameters
    ----------
    keypoints : list of ndarray, shape (F_c, P_c, 26, 3)
        Canonical tracks per camera.
    links : list of ndarray, shape (F_c, P_c)
        Frame-to-frame person links (:func:`cascalib.stages.track_interpolation.frame_links`).
    cameras : list of Camera
        Current cameras (refined geometry, current offsets).
    assoc : Association
        Associated groups at reference times.
    reference : int
        Reference camera (offset 0, not refined).
    joints : ndarray of int
        Canonical joints compared.
    search : float
        Largest change of an offset (reference frames).
    max_groups : int
        Groups used per camera (a random subset keeps this cheap).
    cap_px : float
        A group whose nearest detected person lies farther (median over joints, px) is left out:
        a missed or wrong person.
    huber_px : float
        Scale of the Cauchy weights of the joint residuals (px); the name is from the Huber
        weights they replaced, under which residuals far beyond the scale kept a pull that grew
        with their distance (wrong persons, detections out of time; see the module
        docstring).
    rates : bool
        Refine the frame-rate ratios too (else stage III's are kept). Off here so that a
        caller gets the plain offset search; the pipeline turns it on
        (``RefineConfig.time_rates``, with the measurements).
    rate_sd : float or sequence of float
        Prior sd of the relative rate around ``anchor_rates``, or one per camera (a declared
        frame rate's ratio is exact unless mislabelled, a rate stage III measured is not).
        Where the people's motion determines the rate better (the scatter of time blocks, see
        :func:`_block_line`), the data outweigh it; over a short recording, whose ends a rate
        error hardly moves, the rate stays at the anchor.
    anchor_rates : sequence of float, optional
        The rates the prior is centred on, one per camera: stage III's, so that repeated
        updates cannot wander off them by noise; default the cameras' current rates.
    declared : sequence of int
        Cameras whose anchor rate is their declared frame rate's ratio (stage III did not
        measure one): their rate prior moves to a mislabelled rate (:data:`MISLABEL_FACTORS`)
        where the data favour it, as a camera declared at 30 fps that records 29.97 needs.
    sd : ndarray, shape (C,), optional
        Filled with the standard error (reference frames) of each camera's new
        ``time_offset`` from the scatter of time blocks (:func:`_block_line`; a rate the data
        do not determine adds the prior's), NaN where not measured (the reference among them). The
        offset is the clock at the camera's frame 0: for a camera that starts long before or
        after the middle of the recording it extrapolates the rate.

    Returns
    -------
    list of Camera
        Cameras with refined ``time_offset`` and ``time_rate`` (unchanged where nobody moves
        enough to tell).
    """
    rng = np.random.default_rng(rng)
    n_cams = len(cameras)
    # one time frame for every camera's rate term, so that the decoupling below applies to it
    t_mid = float(np.median(assoc.times)) if assoc.n_groups else 0.0
    half = max(1.0, 0.5 * float(np.ptp(assoc.times))) if assoc.n_groups else 1.0
    measured = np.zeros((n_cams, 2))
    coupling = np.zeros((n_cams, n_cams, 2, 2))
    ok = np.zeros(n_cams, dtype=bool)
    seeds = rng.integers(2**62, size=n_cams)  # one stream per camera: same result in any order

    anchor = [c.time_rate for c in cameras] if anchor_rates is None else list(anchor_rates)
    rate_sds = np.broadcast_to(np.asarray(rate_sd, dtype=float), (n_cams,))

    def measure(c: int
                ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]] | None:
        # the rate term that brings the camera back to its anchor rate
        back = half * (anchor[c] / cameras[c].time_rate - 1.0)
        mislabels = [half * (anchor[c] * f / cameras[c].time_rate - 1.0)
                     for f in MISLABEL_FACTORS] if c in declared else []
        return _measure(keypoints[c], links[c], cameras, c, assoc, joints, search=search,
                        max_groups=max_groups, cap_px=cap_px, huber_px=huber_px,
                        centre=(t_mid, half),
                        rate_prior=(back, rate_sds[c] * half if rates else 0.0),
                        rng=np.random.default_rng(seeds[c]), mislabels=mislabels)

    others = [c for c in range(n_cams) if c != reference]
    # numpy releases the GIL in the sorts and products that dominate: cameras in parallel, one
    # thread each (with one per core, 3 cameras on 2 cores took two rounds: the last alone)
    cov = np.full((n_cams, 2, 2), np.nan)
    with ThreadPoolExecutor(max_workers=max(len(others), 1)) as pool:
        for c, res in zip(others, pool.map(measure, others), strict=True):
            if res is not None:
                measured[c], coupling[c], cov[c] = res
                ok[c] = True
    step = _decouple(measured, coupling, ok)
    out = []
    for c, cam in enumerate(cameras):
        if ok[c]:
            d, rho = step[c]
            # t' = t + d + rho (t - t_mid) / half at t = rate k + offset
            new = cam.with_(time_offset=float(cam.time_offset + d
                                              + rho * (cam.time_offset - t_mid) / half),
                            time_rate=float(cam.time_rate * (1.0 + rho / half)))
            log.info("camera %s: time offset %+.3f -> %+.3f frames, rate %.6f -> %.6f",
                     cam.name, cam.time_offset, new.time_offset, cam.time_rate, new.time_rate)
            cam = new
        out.append(cam)
    if sd is not None:
        # offset = the clock at mid-recording + rho u at the camera's frame 0
        a = np.array([(cam.time_offset - t_mid) / half for cam in cameras])
        known = ok & np.isfinite(cov).all(axis=(1, 2))
        cov[~known] = 0.0
        var = cov[:, 0, 0] + a * a * cov[:, 1, 1] + 2 * a * cov[:, 0, 1]
        sd[:] = np.where(known, np.sqrt(np.maximum(var, 0.0)), np.nan)
    return out


def _decouple(change: NDArray[np.float64], coupling: NDArray[np.float64],
              ok: NDArray[np.bool_]) -> NDArray[np.float64]:
    """Undo the clock errors the leave-one-out triangulation inherits from the other cameras.

    ``change`` (C, 2) holds each camera's measured clock change (offset at mid-recording, rate
    term). The persons triangulated at time ``t`` move as if at the observation-weighted mean
    clock error ``sum_i m_i(t) (d_i + rho_i u)`` of the cameras that saw them, and a camera's
    measurement follows it: ``change = -err + C @ err`` with ``err`` (C, 2) the current clock
    errors and ``C`` the blocks of ``coupling`` (C, C, 2, 2; the reference has no error). Where
    the share ``m_i`` changes over the recording (people walking from one camera's view into
    another's) an offset error leaks into the rate, which the off-diagonal terms of the blocks
    carry. Hence ``(I - C) @ err = -change``: one linear solve instead of slow, oscillating
    fixed-point sweeps. Returns the damped step (C, 2) of each camera (0 where not ``ok``).
    """
    idx = np.flatnonzero(ok)
    out = np.zeros_like(change)
    if idx.size == 0:
        return out
    n = idx.size
    blocks = coupling[np.ix_(idx, idx)].transpose(0, 2, 1, 3).reshape(2 * n, 2 * n)
    rhs = -change[idx].ravel()
    try:
        err = np.linalg.solve(np.eye(2 * n) - blocks, rhs)
    except np.linalg.LinAlgError:
        err = rhs
    # the weights are only a model of the coupling: damp, and never step past the search window
    out[idx] = np.clip(-0.7 * err.reshape(n, 2), -0.5, 0.5)
    return out


def _measure(keypoints: NDArray[np.float64], links: NDArray[np.int64], cameras: list[Camera],
             c: int, assoc: Association, joints: NDArray[np.int64], *, search: float,
             max_groups: int, cap_px: float, huber_px: float, centre: tuple[float, float],
             rate_prior: tuple[float, float], rng: np.random.Generator,
             mislabels: Sequence[float] = ()
             ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.float64]] | None:
    """Best clock change ``(delta, rho)`` of camera ``c`` against the others (see the module
    docstring; ``rate_prior`` is the prior mean and sd of ``rho`` in frames, and ``rho`` stays
    0 when the sd is 0 or the motion does not span the recording), the coupling blocks of
    :func:`_decouple`'s row of camera ``c``, and the covariance (2, 2) of ``(delta, rho)``
    (:func:`_block_line`; a rate the data do not determine is as uncertain as the prior
    says). ``mislabels``: the ``rho`` of the rates a mislabelled frame rate would give (see
    :func:`_mislabel_anchor`), which the prior moves to where the data clearly ask for one."""
    rho_prior, rate_sd = rate_prior
    n_cams = len(cameras)
    others = [i for i in range(n_cams) if i != c]
    obs = assoc.obs[:, others][:, :, joints]
    enough = (np.isfinite(obs[..., 0]).sum(1) >= 2).sum(-1) >= 5
    idx = np.flatnonzero(enough)
    if idx.size < 10:
        return None
    if idx.size > max_groups:
        idx = np.sort(rng.choice(idx, max_groups, replace=False))
    sub = obs[idx]
    n_g, _, n_j = sub.shape[:3]
    uv = sub[..., :2].transpose(1, 0, 2, 3).reshape(len(others), -1, 2)
    conf = sub[..., 2].transpose(1, 0, 2).reshape(len(others), -1)
    # workers=1: the cameras are measured in parallel already (refine_offsets)
    Xw, _ = triangulate([cameras[i] for i in others], uv, conf, workers=1)
    proj = cameras[c].project(Xw).reshape(n_g, n_j, 2)
    times = assoc.times[idx]
    u = ((times - centre[0]) / centre[1])[:, None, None]  # (G, 1, 1), about -1 .. 1
    cam = cameras[c]
    # only what is compared, as one contiguous array: it is re-sampled at every step, and the
    # fancy index alone leaves the joints axis outermost in memory (5x slower to resample)
    kp = np.ascontiguousarray(keypoints[:, :, joints, :2])
    prev = previous_slots(links)
    # the rate prior in the normal equation's units (px^2): huber_px of residual per rate_sd
    prior = (huber_px / rate_sd) ** 2 if rate_sd > 0 else 0.0
    info = np.zeros(n_g)  # offset information of each group at the last evaluation
    grad_g = np.zeros(n_g)  # offset gradient (sum w J_d r) of each group there
    # the persons each group may be matched to while the clock stays in the frame and
    # half-frame of the start (theta = 0: the first step)
    n_f = kp.shape[0]
    frames0 = (times - cam.time_offset) / cam.time_rate
    cell0 = _cell(frames0, n_f)
    reach, few = _within_reach(kp, links, frames0, proj, cap_px)

    def nearest(frames: NDArray[np.float64]
                ) -> tuple[NDArray[np.int64], NDArray[np.float64], NDArray[np.float64]]:
        """Each group's nearest detected person (median joint distance) at ``frames``: its
        slot in frame ``floor(frames)``, keypoints (G, J, 2) and distance (inf if none).

        Only a person nearer than ``cap_px`` counts (the group is left out otherwise), so
        where ``frames`` stays in the frame and half-frame of the start, only the few persons
        that can come that near there (:func:`_within_reach`) are compared; every person
        elsewhere, and where more than a few can. The same persons are found as by comparing
        all of them at every step, which in a crowd (17 slots) was most of the search's time.
        """
        k, half = _cell(frames, n_f)
        same = (k == cell0[0]) & (half == cell0[1]) & few
        p, x, dist = np.empty(n_g, dtype=np.int64), np.empty((n_g,) + proj.shape[1:]), \
            np.empty(n_g)
        for rows, slots in ((np.flatnonzero(same), reach[same]), (np.flatnonzero(~same), None)):
            if rows.size:
                p[rows], x[rows], dist[rows] = _nearest_of(kp, links, frames[rows], slots,
                                                           proj[rows])
        return p, x, dist

    def normal_equation(theta: NDArray[np.float64]
                        ) -> tuple[NDArray[np.float64], NDArray[np.float64], int]:
        """``sum w J.r`` (2,) and ``sum w J J^T`` (2, 2) at clock change ``theta``, with
        ``J = d residual / d (delta, rho)`` per joint."""
        frames = (times - cam.time_offset - theta[0] - theta[1] * u[:, 0, 0]) / cam.time_rate
        p, x, dist = nearest(frames)
        r = x - proj  # (G, J, 2)
        jac = track_velocity(kp, links, prev, frames, p) / -cam.time_rate
        rn, vn = norm_xy(r), norm_xy(jac)
        use = (dist < cap_px)[:, None] & np.isfinite(rn) & np.isfinite(vn)
        if use.sum() < 50:
            return np.zeros(2), np.zeros((2, 2)), 0
        # the fastest 1 % are swapped or outlying joints: their velocity would dominate the sums
        use &= vn <= np.percentile(vn[use], 99)
        w = np.where(use, cauchy_weight(rn, huber_px), 0.0)[..., None]
        r, jac = np.where(use[..., None], r, 0.0), np.where(use[..., None], jac, 0.0)
        jr, jj = (w * jac * r).sum(-1), (w * jac * jac).sum(-1)  # (G, J)
        jju = jj * u[..., 0]
        grad = np.array([jr.sum(), (jr * u[..., 0]).sum() + prior * (theta[1] - rho_prior)])
        hess = np.array([[jj.sum(), jju.sum()], [jju.sum(), (jju * u[..., 0]).sum() + prior]])
        info[:] = jj.sum(-1)
        grad_g[:] = jr.sum(-1)
        return grad, hess, int(use.sum())

    s0, h0, n_used = normal_equation(np.zeros(2))
    # moving joints carry the information: below 0.25 px of residual change per frame of offset
    # on average (people standing still, or too few seen) the offset is left as it is
    if n_used == 0 or h0[0, 0] < 0.0625 * n_used:
        log.info("camera %s: time offset not observable (too little motion)", cam.name)
        return None
    # the rate only where the motion spans the recording (the data's rate curvature at least a
    # tenth of the offset's, as for samples spread evenly over more than half of it) and
    # determines it better than the prior does (a residual of the weights' scale per unit of
    # information): a short recording's ends hardly show a rate error, and noise or the other
    # cameras' offset errors would move the rate far off (1e-4 .. 7e-4 in 60 frames); else the
    # offset alone, at stage III's rate
    data_rr = h0[1, 1] - prior
    free = np.array([True, prior > 0 and data_rr >= 0.1 * h0[0, 0]
                     and huber_px / np.sqrt(max(data_rr, 1e-12)) < rate_sd])

    def newton(grad: NDArray[np.float64], hess: NDArray[np.float64]) -> NDArray[np.float64]:
        out = np.zeros(2)
        try:
            out[free] = -np.linalg.solve(hess[np.ix_(free, free)], grad[free])
        except np.linalg.LinAlgError:
            out[free] = -grad[free] / np.maximum(np.diag(hess)[free], 1e-12)
        return out

    # a Gauss-Newton start, then Broyden's secant steps on the normal equation (in one unknown,
    # the secant method): the robust weights overstate the loss's curvature (past the scale
    # the loss grows slower than its weighted square; in a crowd half the residuals are there),
    # so Gauss-Newton alone moved a tenth of the error per step; the secant measures the slope
    t0, t1 = np.zeros(2), np.clip(newton(s0, h0), -0.5, 0.5)
    slope, hess = h0.copy(), h0
    for _ in range(10):
        s1, h1, n1 = normal_equation(t1)
        if n1 == 0 or h1[0, 0] <= 0:
            break
        hess = h1  # the Gauss-Newton matrix of the groups' information in ``info``
        ds, dt = s1 - s0, t1 - t0
        if dt @ dt > 0:
            slope = slope + np.outer(ds - slope @ dt, dt) / (dt @ dt)
        sub_slope = slope[np.ix_(free, free)]
        positive = np.all(np.diag(sub_slope) > 0) and np.linalg.det(sub_slope) > 0
        step = newton(s1, slope if positive else h1)
        if not positive:
            slope = h1.copy()
        t0, s0 = t1, s1
        t1 = np.clip(t1 + np.clip(step, -0.5, 0.5), -search, search)
        if np.abs(t1 - t0).max() < 1e-3:
            break
    # the clock's real uncertainty: the nominal one counts every joint as independent, while
    # association slips and geometry errors that change as people move are correlated over
    # seconds; the scatter of the offsets of time blocks about the fitted line shows them
    kappa = float(np.clip(slope[0, 0] / hess[0, 0], 0.05, 1.0)) if hess[0, 0] > 0 else 1.0
    cov, line = _block_line(grad_g, info, u[:, 0, 0], kappa)
    if free[1]:
        # the rate is weighed against the anchor's (prior sd rate_sd) by it
        se = float(np.sqrt(max(cov[1, 1], 0.0)))
        moved = _mislabel_anchor(cam.name, rho_prior, mislabels, t1[1] + line[1], se)
        if moved != rho_prior:  # a mislabel: the data's rate (not the one pulled toward
            # the declared rate by the solve's prior), shrunk toward the mislabel instead
            t1[1], rho_prior = t1[1] + line[1], moved
        shrink = rate_sd**2 / (rate_sd**2 + se**2)
        t1[1] = rho_prior + shrink * (t1[1] - rho_prior)
        cov = (cov * np.array([[1.0, shrink], [shrink, shrink]])  # the shrunk estimate's
               if np.isfinite(cov).all() else np.full((2, 2), np.nan))
    else:  # the rate is kept as it is (stage III's, or an earlier update's), as uncertain as
        # the prior says (0 when the caller keeps stage III's rates: rates=False)
        cov = np.diag([cov[0, 0], rate_sd**2])
    # how the others' clock errors reach this measurement (see _decouple): each group's
    # triangulation follows the others' clocks by their share of its observations, and the
    # measurement weighs the groups by their information
    seen = (np.isfinite(sub[..., 0]) & (conf.reshape(len(others), n_g, n_j).transpose(1, 0, 2)
                                        > 0)).sum(-1).astype(float)  # (G, others)
    share = seen / np.maximum(seen.sum(1, keepdims=True), 1.0)
    ug = u[:, 0, 0]
    basis = np.stack([np.ones(n_g), ug], axis=1)  # (G, 2)
    moments = np.einsum("g,gi,gk,gl->ikl", info, share, basis, basis)  # (others, 2, 2)
    blocks = np.zeros((n_cams, 2, 2))
    if free[1]:
        blocks[others] = np.linalg.solve(hess, moments)
        blocks[others, 1] *= shrink  # the shrunk rate follows the others' errors less
    else:  # the offset alone
        blocks[others, 0, 0] = moments[:, 0, 0] / max(hess[0, 0], 1e-12)
        t1[1] = 0.0
    return t1, blocks, cov


def _mislabel_anchor(name: str, rho_prior: float, mislabels: Sequence[float], rho_data: float,
                     se: float) -> float:
    """The rate prior's centre: ``rho_prior`` (the declared rate), or the mislabel of
    ``mislabels`` (``rho``, frames) that the data's rate ``rho_data`` (standard error ``se``)
    favour over it by the odds :data:`MISLABEL_ODDS`."""
    if not mislabels or not (np.isfinite(rho_data) and np.isfinite(se) and se > 0):
        return rho_prior
    best = min(mislabels, key=lambda r: abs(rho_data - r))
    log_ratio = ((rho_data - rho_prior) ** 2 - (rho_data - best) ** 2) / (2 * se**2)
    moved = log_ratio > np.log(MISLABEL_ODDS)
    (log.info if moved else log.debug)(
        "camera %s: rate %+.3f frames (se %.3f) against the declared %+.3f and the mislabel "
        "%+.3f: log likelihood ratio %.1f", name, rho_data, se, rho_prior, best, log_ratio)
    return float(best) if moved else rho_prior


def _block_line(jr: NDArray[np.float64], jj: NDArray[np.float64], u: NDArray[np.float64],
                kappa: float, n_blocks: int = 8
                ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Covariance (2, 2) of the clock change ``(delta, rho)`` (frames; ``rho`` over half the
    recording) from the scatter of time blocks.

    Each of ``n_blocks`` blocks of the recording (by ``u``) gets the offset its own groups ask
    for, ``-sum jr / (kappa sum jj)`` (``kappa``: the secant's share of the Gauss-Newton
    curvature, which the robust weights overstate); a weighted line through them has the offset
    at mid-recording as its intercept and the rate as its slope, and the blocks' scatter about
    it gives their covariance: association slips and geometry errors that change as people move
    are correlated over seconds, which the nominal information (every joint independent) does
    not see. Infinite with fewer than four blocks that carry information. Also returns the line
    (2,): the further clock change ``(delta, rho)`` the blocks ask for (NaN where infinite).
    """
    inf = np.full((2, 2), np.inf), np.full(2, np.nan)
    b = np.clip(((u + 1.0) * 0.5 * n_blocks).astype(int), 0, n_blocks - 1)
    g = np.bincount(b, jr, n_blocks)
    h = np.bincount(b, jj, n_blocks)
    hu = np.bincount(b, jj * u, n_blocks)
    keep = h > 0.02 * h.sum()
    if keep.sum() < 4:
        return inf
    d, ub, w = -g[keep] / (kappa * h[keep]), hu[keep] / h[keep], h[keep] / h[keep].mean()
    A = np.stack([np.ones_like(ub), ub], axis=1) * np.sqrt(w)[:, None]
    coef, *_ = np.linalg.lstsq(A, d * np.sqrt(w), rcond=None)
    resid = d * np.sqrt(w) - A @ coef
    sigma2 = float(resid @ resid) / (keep.sum() - 2)
    try:
        return sigma2 * np.linalg.inv(A.T @ A), coef
    except np.linalg.LinAlgError:
        return inf
