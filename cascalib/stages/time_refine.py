"""Sub-frame time offsets for stage V.

Stage III finds each camera's offset to about a frame. Between bundle-adjustment rounds, each
non-reference camera's offset is refined against the others: the persons are triangulated at
reference times *without* that camera and projected into it, and the camera's 2D tracks are
interpolated at ``(t - offset - delta) / rate``. ``delta`` is the root of the robust (Huber)
least-squares normal equation ``sum w v . r(delta) = 0``, where ``r`` is the residual of each
joint and ``v`` its image velocity (a Gauss-Newton start, then secant steps). The velocity comes
from the frames two before and two after the interpolated pair, so that its noise is independent of
the residual's. The frame-rate ratio from stage III is kept, so the time mapping of every camera
stays affine and consistent with the reference clock.

Why not a cost curve: the earlier search took the minimum of a truncated mean of per-person median
distances on a grid of ``delta``. Its curve was flat (0.1 px over a frame on 8 px) and its minimum
moved by +-0.3 frame between random subsets of the same scene, with the true geometry. The normal
equation uses every joint, weighted by how fast it moves: from the truth it stays within 0.03
frame, from any start within 0.4 frame of it (simulated crowd, true geometry).
"""

from __future__ import annotations

import logging
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numpy.typing import NDArray

from cascalib.camera import Camera
from cascalib.geometry import norm_xy
from cascalib.nanstats import nanmedian_last
from cascalib.stages.association import Association, interpolate_views
from cascalib.stages.triangulation import huber_weight, triangulate

__all__ = ["previous_slots", "refine_offsets", "track_velocity"]

log = logging.getLogger(__name__)


def previous_slots(links: NDArray[np.int64]) -> NDArray[np.int64]:
    """Inverse of :func:`~cascalib.stages.association.frame_links`: ``prev[k, q]`` is the slot of
    frame ``k - 1`` that continues into slot ``q`` of frame ``k``, or -1."""
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


def track_velocity(keypoints: NDArray[np.float64], links: NDArray[np.int64],
                   prev: NDArray[np.int64], frames: NDArray[np.float64],
                   slots: NDArray[np.int64]) -> NDArray[np.float64]:
    """Image velocity (px per frame) of one person per time, at fractional frame positions.

    Parameters
    ----------
    keypoints : ndarray, shape (F, P, J, D)
    links, prev : ndarray of int, shape (F, P)
        :func:`~cascalib.stages.association.frame_links` and :func:`previous_slots`.
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
                   cap_px: float = 30.0, huber_px: float = 3.0,
                   rng: np.random.Generator | None = None) -> list[Camera]:
    """Refine the time offset of every non-reference camera.

    Parameters
    ----------
    keypoints : list of ndarray, shape (F_c, P_c, 26, 3)
        Canonical tracks per camera.
    links : list of ndarray, shape (F_c, P_c)
        Frame-to-frame person links (:func:`cascalib.stages.association.frame_links`).
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
        Scale of the Huber weights of the joint residuals (px).

    Returns
    -------
    list of Camera
        Cameras with refined ``time_offset`` (unchanged where nobody moves enough to tell).
    """
    rng = np.random.default_rng(rng)
    n_cams = len(cameras)
    measured = np.array([c.time_offset for c in cameras], dtype=float)
    coupling = np.zeros((n_cams, n_cams))
    ok = np.zeros(n_cams, dtype=bool)
    seeds = rng.integers(2**62, size=n_cams)  # one stream per camera: same result in any order

    def measure(c: int) -> tuple[float, NDArray[np.float64]] | None:
        return _measure(keypoints[c], links[c], cameras, c, assoc, joints, search=search,
                        max_groups=max_groups, cap_px=cap_px, huber_px=huber_px,
                        rng=np.random.default_rng(seeds[c]))

    others = [c for c in range(n_cams) if c != reference]
    # numpy releases the GIL in the sorts and products that dominate: cameras in parallel, one
    # thread each (with one per core, 3 cameras on 2 cores took two rounds: the last alone)
    with ThreadPoolExecutor(max_workers=max(len(others), 1)) as pool:
        for c, res in zip(others, pool.map(measure, others), strict=True):
            if res is not None:
                measured[c], coupling[c] = res
                ok[c] = True
    new = _decouple(np.array([c.time_offset for c in cameras]), measured, coupling, ok)
    out = []
    for c, cam in enumerate(cameras):
        if ok[c]:
            log.info("camera %s: time offset %+.3f -> %+.3f frames", cam.name, cam.time_offset,
                     new[c])
            cam = cam.with_(time_offset=float(new[c]))
        out.append(cam)
    return out


def _decouple(current: NDArray[np.float64], measured: NDArray[np.float64],
              coupling: NDArray[np.float64], ok: NDArray[np.bool_]) -> NDArray[np.float64]:
    """Undo the clock errors the leave-one-out triangulation inherits from the other cameras.

    The triangulated persons move as if at the observation-weighted mean clock error of the
    cameras that saw them, so ``measured = true + M @ err`` with ``err = current - true`` and
    ``M`` the weights (rows of ``coupling``, the reference has no error). Hence
    ``(I - M) @ err = current - measured``: one linear solve instead of slow, oscillating
    fixed-point sweeps.
    """
    idx = np.flatnonzero(ok)
    if idx.size == 0:
        return current
    M = coupling[np.ix_(idx, idx)]
    A = np.eye(idx.size) - M
    try:
        err = np.linalg.solve(A, current[idx] - measured[idx])
    except np.linalg.LinAlgError:
        err = current[idx] - measured[idx]
    # the weights are only a model of the coupling: damp, and never step past the search window
    step = np.clip(-0.7 * err, -0.5, 0.5)
    out = current.copy()
    out[idx] = current[idx] + step
    return out


def _measure(keypoints: NDArray[np.float64], links: NDArray[np.int64], cameras: list[Camera],
             c: int, assoc: Association, joints: NDArray[np.int64], *, search: float,
             max_groups: int, cap_px: float, huber_px: float, rng: np.random.Generator
             ) -> tuple[float, NDArray[np.float64]] | None:
    """Best offset of camera ``c`` against the others, and the others' observation weights."""
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
    Xw, _ = triangulate([cameras[i] for i in others], uv, conf)
    proj = cameras[c].project(Xw).reshape(n_g, n_j, 2)
    times = assoc.times[idx]
    cam = cameras[c]
    # only what is compared, as one contiguous array: it is re-sampled at every step, and the
    # fancy index alone leaves the joints axis outermost in memory (5x slower to resample)
    kp = np.ascontiguousarray(keypoints[:, :, joints, :2])
    prev = previous_slots(links)
    g = np.arange(n_g)

    def normal_equation(d: float) -> tuple[float, float, int]:
        """``sum w J.r`` and ``sum w J.J`` at offset change ``d`` (J = d residual / d d)."""
        frames = (times - cam.time_offset - d) / cam.time_rate
        cand = interpolate_views(kp, links, frames)
        dist = np.nan_to_num(nanmedian_last(norm_xy(cand - proj[:, None])), nan=np.inf)
        p = np.argmin(dist, axis=-1)  # the nearest detected person of each group
        r = cand[g, p] - proj  # (G, J, 2)
        jac = track_velocity(kp, links, prev, frames, p) / -cam.time_rate
        rn, vn = norm_xy(r), norm_xy(jac)
        use = (dist[g, p] < cap_px)[:, None] & np.isfinite(rn) & np.isfinite(vn)
        if use.sum() < 50:
            return 0.0, 0.0, 0
        # the fastest 1 % are swapped or outlying joints: their velocity would dominate the sums
        use &= vn <= np.percentile(vn[use], 99)
        w = np.where(use, huber_weight(rn, huber_px), 0.0)[..., None]
        r, jac = np.where(use[..., None], r, 0.0), np.where(use[..., None], jac, 0.0)
        return float((w * jac * r).sum()), float((w * jac * jac).sum()), int(use.sum())

    s0, curv, n_used = normal_equation(0.0)
    # moving joints carry the information: below 0.25 px of residual change per frame of offset
    # on average (people standing still, or too few seen) the offset is left as it is
    if n_used == 0 or curv < 0.0625 * n_used:
        log.info("camera %s: time offset not observable (too little motion)", cam.name)
        return None
    # a Gauss-Newton step, then secant steps on the normal equation: the Huber weights overstate
    # the loss's curvature (past the knee it grows linearly with |r|; in a crowd half the
    # residuals are there), so Gauss-Newton alone moved a tenth of the error per step; the
    # secant measures the slope
    d0, d1 = 0.0, float(np.clip(-s0 / curv, -0.5, 0.5))
    for _ in range(10):
        s1, c1, n1 = normal_equation(d1)
        if n1 == 0 or c1 <= 0:
            break
        slope = (s1 - s0) / (d1 - d0) if d1 != d0 else 0.0
        step = -s1 / slope if slope > 0 else -s1 / c1
        d0, s0 = d1, s1
        d1 = float(np.clip(d1 + np.clip(step, -0.5, 0.5), -search, search))
        if abs(d1 - d0) < 1e-3:
            break
    weights = np.zeros(n_cams)
    weights[others] = (np.isfinite(sub[..., 0]) & (conf.reshape(len(others), n_g, n_j)
                                                    .transpose(1, 0, 2) > 0)).sum((0, 2))
    return cam.time_offset + d1, weights / max(weights.sum(), 1.0)
