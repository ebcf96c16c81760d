"""Statistics over arrays with NaN for missing values, fast where numpy's are slow."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["joint_extent", "nanmean", "nanmedian_last"]


def nanmean(a: NDArray[np.float64], axis: int) -> NDArray[np.float64]:
    """``np.nanmean(a, axis)``, the same values, without its "mean of empty slice" warning.

    That warning can only be silenced by ``warnings.catch_warnings``, which is not thread-safe:
    where two threads do it at once, one restores the filters while the other still relies on
    them (stage III's pairs run in threads). Here an all-NaN slice is 0 / 0 under
    ``np.errstate``, which is per thread.
    """
    missing = np.isnan(a)
    total = np.where(missing, 0.0, a).sum(axis)
    count = (~missing).sum(axis)
    with np.errstate(invalid="ignore", divide="ignore"):
        return total / count


def nanmedian_last(a: NDArray[np.float64]) -> NDArray[np.float64]:
    """``np.nanmedian(a, axis=-1)`` without its all-NaN warnings, several times faster for a
    short last axis: NaN sorts last, so the median of the finite values sits at known positions.

    Parameters
    ----------
    a : ndarray, shape (..., N)

    Returns
    -------
    ndarray, shape (...)
        NaN where a row has no finite value.
    """
    s = np.sort(a, axis=-1)
    n = np.isfinite(a).sum(-1)
    hi = a.shape[-1] - 1
    lo_v = np.take_along_axis(s, np.clip((n - 1) // 2, 0, hi)[..., None], -1)[..., 0]
    hi_v = np.take_along_axis(s, np.clip(n // 2, 0, hi)[..., None], -1)[..., 0]
    return np.where(n > 0, 0.5 * (lo_v + hi_v), np.nan)


def joint_extent(keypoints: NDArray[np.float64]) -> NDArray[np.float64]:
    """Extent (max - min) of x and y over the joints, ignoring missing ones.

    ``np.nanmax(kp[..., :2], axis=-2) - np.nanmin(...)`` without the all-NaN warnings and about
    5x faster: one elementwise pass per joint instead of numpy's strided reduce.

    Parameters
    ----------
    keypoints : ndarray, shape (..., J, D), D >= 2

    Returns
    -------
    ndarray, shape (..., 2)
        NaN where no joint is present.
    """
    xy = keypoints[..., :2]
    hi = xy[..., 0, :].copy()
    lo = hi.copy()
    for j in range(1, xy.shape[-2]):
        np.fmax(hi, xy[..., j, :], out=hi)
        np.fmin(lo, xy[..., j, :], out=lo)
    return hi - lo
