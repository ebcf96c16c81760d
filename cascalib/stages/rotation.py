"""Stage III: brute-force 2D rotation search between two synchronised ground point clouds.

Paper, "2D Rotation Search" and supplement eq. (plane error): after the time shift is known,
shift both point clouds to their means, try every rotation angle, and score the symmetric
closest-point distance of the points augmented with time, ``(x, y, t)``. There is no closed
form because correspondences are unknown. Differences to the paper:

* the closest-point distance is truncated at ``trim`` metres so that outliers and people seen
  by only one of the cameras cost a constant instead of pulling the score;
* the search is coarse-to-fine (all angles at ``step_deg``, then a golden-section refinement);
* the centroid alignment is replaced by the median translation of the nearest neighbours at
  each angle, which survives partial visibility (the two cameras seeing different people).
"""

from __future__ import annotations

import logging
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import minimize_scalar
from scipy.spatial import cKDTree

__all__ = ["RotationSearch", "rotation_search"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class RotationSearch:
    """Result of :func:`rotation_search`.

    Parameters
    ----------
    angle : float
        Rotation (radians) taking B's ground frame into A's.
    translation : ndarray, shape (2,)
        ``x_a ~ R(angle) x_b + translation``.
    cost : float
        Mean truncated closest-point distance at the optimum (metres).
    angles, costs : ndarray, shape (n,)
        The coarse cost curve.
    """

    angle: float
    translation: NDArray[np.float64]
    cost: float
    angles: NDArray[np.float64]
    costs: NDArray[np.float64]


def _rot(angle: float) -> NDArray[np.float64]:
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s], [s, c]])


def _cost(angle: float, tree_a: cKDTree, pa: NDArray[np.float64], pb: NDArray[np.float64],
          tree_b: cKDTree, trim: float) -> tuple[float, NDArray[np.float64]]:
    """Symmetric truncated closest-point cost of rotated B against A and its translation."""
    R = _rot(angle)
    qb = pb.copy()
    qb[:, :2] = pb[:, :2] @ R.T
    # translation: median offset of B's points to their nearest A points, twice (re-centring)
    shift = np.median(pa[:, :2], axis=0) - np.median(qb[:, :2], axis=0)
    for _ in range(2):
        q = qb.copy()
        q[:, :2] += shift
        d, idx = tree_a.query(q, distance_upper_bound=4 * trim)
        ok = np.isfinite(d)
        if ok.sum() < 3:
            break
        shift = shift + np.median(pa[idx[ok], :2] - q[ok, :2], axis=0)
    q = qb.copy()
    q[:, :2] += shift
    d_ab, _ = tree_a.query(q, distance_upper_bound=trim)
    # A against B: rotate A into B's frame instead of rebuilding a tree per angle
    pa_in_b = pa.copy()
    pa_in_b[:, :2] = (pa[:, :2] - shift) @ R
    d_ba, _ = tree_b.query(pa_in_b, distance_upper_bound=trim)
    cost = 0.5 * (np.minimum(d_ab, trim).mean() + np.minimum(d_ba, trim).mean())
    return float(cost), shift


def rotation_search(points_a: NDArray[np.float64], points_b: NDArray[np.float64], *,
                    step_deg: float = 5.0, trim: float = 1.0, time_scale: float = 0.05,
                    max_points: int = 1500, rng: np.random.Generator | int | None = None
                    ) -> RotationSearch:
    """Search the rotation (0-360 degrees) aligning B's synchronised ground points to A's.

    Parameters
    ----------
    points_a, points_b : ndarray, shape (n, 3)
        ``(x, y, t)`` with x, y in metres and t the synchronised time (reference frames).
    step_deg : float
        Coarse angle step (degrees).
    trim : float
        Closest-point distances are truncated at this many metres.
    time_scale : float
        Metres per frame of the time axis (0.05: one frame weighs like 5 cm, about one frame
        of walking at 1.5 m/s and 30 fps).
    max_points : int
        Random subsample size per cloud (speed).

    Returns
    -------
    RotationSearch

    Examples
    --------
    >>> t = np.arange(200.0)
    >>> a = np.c_[np.cos(t / 30) * 3, np.sin(t / 50) * 2, t]
    >>> R = _rot(np.pi / 3)
    >>> b = np.c_[(a[:, :2] - [1.0, 2.0]) @ R, t]   # B = R^T (A - t)
    >>> res = rotation_search(a, b)
    >>> bool(abs(np.degrees(res.angle) - 60) < 1)
    True
    """
    rng = np.random.default_rng(rng)
    pa = np.asarray(points_a, np.float64)
    pb = np.asarray(points_b, np.float64)
    pa = pa[np.isfinite(pa).all(1)]
    pb = pb[np.isfinite(pb).all(1)]
    if len(pa) > max_points:
        pa = pa[rng.choice(len(pa), max_points, replace=False)]
    if len(pb) > max_points:
        pb = pb[rng.choice(len(pb), max_points, replace=False)]
    pa = pa * [1.0, 1.0, time_scale]
    pb = pb * [1.0, 1.0, time_scale]
    tree_a, tree_b = cKDTree(pa), cKDTree(pb)
    angles = np.radians(np.arange(0.0, 360.0, step_deg))
    costs = np.array([_cost(a, tree_a, pa, pb, tree_b, trim)[0] for a in angles])
    k = int(np.argmin(costs))
    h = np.radians(step_deg)
    res = minimize_scalar(lambda a: _cost(a, tree_a, pa, pb, tree_b, trim)[0],
                          bounds=(angles[k] - h, angles[k] + h), method="bounded",
                          options={"xatol": 1e-4})
    angle = float(np.mod(res.x, 2 * np.pi))
    cost, shift = _cost(angle, tree_a, pa, pb, tree_b, trim)
    return RotationSearch(angle, shift, cost, angles, costs)
