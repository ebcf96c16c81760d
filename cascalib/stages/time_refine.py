"""Sub-frame time offsets for stage V.

Stage III finds each camera's offset to about a frame. Between bundle-adjustment rounds, each
non-reference camera's offset is refined against the others: the persons are triangulated at
reference times *without* that camera, projected into it, and compared with its 2D tracks
interpolated at ``(t - offset - delta) / rate`` for a grid of ``delta``; a parabola through the
best grid point and its neighbours gives the sub-frame minimum. The frame-rate ratio from stage III
is kept, so the time mapping of every camera stays affine and consistent with the reference clock.
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
from cascalib.stages.triangulation import triangulate

__all__ = ["offset_cost", "refine_offsets"]

log = logging.getLogger(__name__)


def offset_cost(proj: NDArray[np.float64], candidates: NDArray[np.float64], *,
                cap: float) -> float:
    """Robust distance between projected persons and the nearest detected person.

    Parameters
    ----------
    proj : ndarray, shape (G, J, 2)
        Projections of the leave-one-out triangulations.
    candidates : ndarray, shape (G, P, J, 2)
        The camera's interpolated persons at the same times.
    cap : float
        Distances are truncated here (px) so missed or wrong persons weigh little.

    Returns
    -------
    float
        Mean truncated distance (px); NaN if nothing overlaps.
    """
    d = norm_xy(candidates - proj[:, None])  # (G, P, J)
    # no nanmin: its all-NaN warning would need warnings.catch_warnings, which is not
    # thread-safe (cameras are measured in threads)
    best = np.min(np.nan_to_num(nanmedian_last(d), nan=np.inf), axis=-1)
    best = best[np.isfinite(best)]
    if best.size == 0:
        return float("nan")
    return float(np.minimum(best, cap).mean())


def _parabola_min(x: NDArray[np.float64], y: NDArray[np.float64]) -> float:
    i = int(np.nanargmin(y))
    if 0 < i < len(x) - 1 and np.all(np.isfinite(y[i - 1 : i + 2])):
        a, b, _ = np.polyfit(x[i - 1 : i + 2], y[i - 1 : i + 2], 2)
        if a > 0:
            return float(np.clip(-b / (2 * a), x[i - 1], x[i + 1]))
    return float(x[i])


def refine_offsets(keypoints: list[NDArray[np.float64]], links: list[NDArray[np.int64]],
                   cameras: list[Camera], assoc: Association, reference: int, joints:
                   NDArray[np.int64], *, search: float = 1.0, step: float = 0.05,
                   max_groups: int = 1500, cap_px: float = 30.0,
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
    search, step : float
        Half-width and step of the offset grid (reference frames).
    max_groups : int
        Groups used per camera (a random subset keeps this cheap).
    cap_px : float
        Truncation of the per-group distance.

    Returns
    -------
    list of Camera
        Cameras with refined ``time_offset`` (unchanged where the cost is flat or undefined).
    """
    rng = np.random.default_rng(rng)
    n_cams = len(cameras)
    measured = np.array([c.time_offset for c in cameras], dtype=float)
    coupling = np.zeros((n_cams, n_cams))
    ok = np.zeros(n_cams, dtype=bool)
    seeds = rng.integers(2**62, size=n_cams)  # one stream per camera: same result in any order

    def measure(c: int) -> tuple[float, NDArray[np.float64]] | None:
        return _measure(keypoints[c], links[c], cameras, c, assoc, joints, search=search,
                        step=step, max_groups=max_groups, cap_px=cap_px,
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
             step: float, max_groups: int, cap_px: float, rng: np.random.Generator
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
    # only what is compared, as one contiguous array: the grid re-samples it many times, and
    # the fancy index alone leaves the joints axis outermost in memory (5x slower to resample)
    kp = np.ascontiguousarray(keypoints[:, :, joints, :2])

    def cost(d: float) -> float:
        frames = (times - cam.time_offset - d) / cam.time_rate
        return offset_cost(proj, interpolate_views(kp, links, frames), cap=cap_px)

    # coarse to fine: a grid 4 steps wide over the window, then the fine step around its best
    coarse = np.arange(-search, search + 2 * step, 4 * step)
    c_costs = np.array([cost(d) for d in coarse])
    if not np.isfinite(c_costs).any() or np.nanmax(c_costs) - np.nanmin(c_costs) < 1e-3:
        log.info("camera %s: time offset not observable (flat cost)", cam.name)
        return None
    centre = coarse[int(np.nanargmin(c_costs))]
    grid = centre + np.arange(-4, 5) * step
    costs = np.array([cost(d) for d in grid])
    weights = np.zeros(n_cams)
    weights[others] = (np.isfinite(sub[..., 0]) & (conf.reshape(len(others), n_g, n_j)
                                                    .transpose(1, 0, 2) > 0)).sum((0, 2))
    return cam.time_offset + _parabola_min(grid, costs), weights / max(weights.sum(), 1.0)
