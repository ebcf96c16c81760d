"""Statistics over arrays with NaN for missing values, fast where numpy's are slow."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray

__all__ = ["nanmedian_last"]


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
