"""Pick a small, well-spread subset of person-frames for the bundle adjustment.

The factor graph grows with every selected person-frame (26 joints, 3 unknowns each), while the
camera parameters are pinned down by *coverage*: observations spread over each image (focal,
distortion), over the floor (pose) and over time (no single walking phase dominates). A greedy
facility-location choice gives exactly that: each group covers one cell per criterion (a time bin, a
floor cell, an image cell per camera); a cell's value halves with every group already chosen in it,
and each step takes the group of highest quality-weighted value. The frames left out are
triangulated afterwards with the refined cameras.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

from cascalib.stages.association import Association

__all__ = ["select_groups", "usable_groups"]


def _cells(assoc: Association, image_sizes: list[tuple[int, int]], *, n_time_bins: int,
           floor_cell_m: float, image_grid: int) -> NDArray[np.int64]:
    """Cell id of every group per criterion, shape (G, 2 + C); -1 where not applicable."""
    g = assoc.n_groups
    n_cams = assoc.obs.shape[1]
    cells = np.full((g, 2 + n_cams), -1, dtype=np.int64)
    t = assoc.times
    span = max(float(t.max() - t.min()), 1.0)
    cells[:, 0] = np.minimum(((t - t.min()) / span * n_time_bins).astype(int), n_time_bins - 1)
    fl = np.floor(np.nan_to_num(assoc.ground) / floor_cell_m).astype(np.int64)
    fl -= fl.min(0)
    cells[:, 1] = n_time_bins + fl[:, 0] * (fl[:, 1].max() + 1) + fl[:, 1]
    offset = cells[:, 1].max() + 1
    with np.errstate(invalid="ignore"):
        import warnings
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", RuntimeWarning)
            centre = np.nanmean(assoc.obs[..., :2], axis=2)  # (G, C, 2)
    for c, (w, h) in enumerate(image_sizes):
        ok = np.isfinite(centre[:, c]).all(1)
        gx = np.clip((centre[ok, c, 0] / w * image_grid).astype(int), 0, image_grid - 1)
        gy = np.clip((centre[ok, c, 1] / h * image_grid).astype(int), 0, image_grid - 1)
        cells[ok, 2 + c] = offset + c * image_grid**2 + gy * image_grid + gx
    return cells


def group_quality(assoc: Association, joints: NDArray[np.int64]) -> NDArray[np.float64]:
    """Quality of each group: summed confidence of its observed joints (views x joints), (G,)."""
    conf = np.nan_to_num(assoc.obs[:, :, joints, 2])
    seen = np.isfinite(assoc.obs[:, :, joints, 0])
    # joints seen by a single view add nothing to the geometry
    multi = seen.sum(1) >= 2
    return (conf * multi[:, None, :]).sum((1, 2))


def usable_groups(assoc: Association, joints: NDArray[np.int64], residual_quantile: float = 0.75,
                  *, quality: NDArray[np.float64] | None = None) -> NDArray[np.int64]:
    """Indices of the groups :func:`select_groups` chooses from: some joint seen twice, and an
    association residual at most its ``residual_quantile`` (the least consistent quarter holds
    most wrong matches: cheap insurance, any round)."""
    ok = (group_quality(assoc, joints) if quality is None else quality) > 0
    if assoc.residual is not None and np.isfinite(assoc.residual).any():
        cut = np.nanpercentile(assoc.residual, 100 * residual_quantile)
        ok &= np.nan_to_num(assoc.residual, nan=np.inf) <= cut
    return np.flatnonzero(ok)


def select_groups(assoc: Association, image_sizes: list[tuple[int, int]], n_select: int,
                  joints: NDArray[np.int64], *, n_time_bins: int = 50, floor_cell_m: float = 1.0,
                  image_grid: int = 4, residual_quantile: float = 0.75) -> NDArray[np.int64]:
    """Indices of at most ``n_select`` groups, spread over time, floor and image.

    Parameters
    ----------
    assoc : Association
        All associated person-frames.
    image_sizes : list of (int, int)
        (width, height) per camera.
    n_select : int
        Budget of person-frames.
    joints : ndarray of int
        Canonical joints used by the refinement (for the quality score).
    n_time_bins, floor_cell_m, image_grid : int, float, int
        Cell sizes of the three coverage criteria.
    residual_quantile : float
        Groups whose association residual is above this quantile are not selected.

    Returns
    -------
    ndarray of int, shape (n,)
        Sorted group indices, ``n = min(n_select, number of groups with quality > 0)``.
    """
    quality = group_quality(assoc, joints)
    usable = usable_groups(assoc, joints, residual_quantile, quality=quality)
    if usable.size <= n_select:
        return usable
    cells = _cells(assoc.subset(usable), image_sizes, n_time_bins=n_time_bins,
                   floor_cell_m=floor_cell_m, image_grid=image_grid)
    q = quality[usable] / quality[usable].max()
    return np.sort(usable[_greedy_cover(cells, q, n_select)])


def _greedy_cover(cells: NDArray[np.int64], q: NDArray[np.float64], n_select: int
                  ) -> list[int]:
    """Greedy facility location: ``n_select`` rows of ``cells`` (G, K), -1 = no cell.

    Row ``g`` scores ``q[g] * (0.25 + sum_k 0.5 ** n[cells[g, k]])`` with ``n`` the number of
    rows already chosen in each cell; each step takes the best row (the first on ties). The
    terms ``0.5 ** n`` are kept in a (K, G) table and a pick rewrites only the entries of its
    own cells: the same picks as re-scoring every row at every step, several times faster.
    The sum over k runs in order (as numpy's sum does for fewer than 8 terms; with more, numpy
    pairs them, and a tie between two rows could go the other way).
    """
    counts = np.zeros(cells.max() + 1)
    valid = cells >= 0
    # (K, G): one contiguous row per criterion, summed by adding rows (numpy's sum over the
    # short axis of a (G, K) table took most of the selection's time)
    term = valid.T.astype(np.float64)  # 0.5 ** 0 in every cell a row has
    # the (row, column) entries of each cell, grouped by cell
    rows, cols = np.nonzero(valid)
    order = np.argsort(cells[rows, cols], kind="stable")
    rows, cols = rows[order], cols[order]
    start = np.searchsorted(cells[rows, cols], np.arange(counts.size + 1))
    chosen = np.zeros(len(q), dtype=bool)
    total = np.empty(len(q))
    picks: list[int] = []
    for _ in range(n_select):
        total[:] = term[0]
        for t in term[1:]:
            total += t
        score = np.where(chosen, -1.0, q * (0.25 + total))
        i = int(np.argmax(score))
        chosen[i] = True
        picks.append(i)
        for c in cells[i][valid[i]]:
            counts[c] += 1
            at = slice(start[c], start[c + 1])
            term[cols[at], rows[at]] = 0.5 ** counts[c]
    return picks
