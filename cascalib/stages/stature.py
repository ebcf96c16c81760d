"""The metric scale from the people: the statures their limbs and trunks imply.

A bundle of joints seen by several cameras is known up to scale; the people's bones set it. The
ankle-knee-hip-neck chain carries it where legs are seen: its ends sit where detectors put them
consistently (the hip keypoints' placement shifts length between thigh and trunk, not their sum).
Upper bodies fall back on the trunk and arm segments. A figure that never moves (mannequin,
poster, composited figure) is not a person the stature prior describes: its groups are found
(:func:`moving_groups`) and left out.

References
----------
Drillis, R. & Contini, R. *Body segment parameters*, Report 1166-03, New York University, 1966
(segment lengths as fractions of stature, as tabulated in Winter, D. A., *Biomechanics and Motor
Control of Human Movement*, 4th ed., 2009, fig. 4.1).
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy.spatial import cKDTree

from cascalib.camera import Camera
from cascalib.nanstats import nanmean, nanmedian_last
from cascalib.skeletons import CANONICAL_INDEX

__all__ = ["CHAIN_FRACTION", "SEGMENT_FRACTIONS", "chain_statures", "joint_points",
           "metric_scale", "moving_groups", "people_who_move", "rescale_to_statures"]

#: Segment lengths as fractions of standing height (Drillis & Contini 1966, joint centres):
#: the bones that carry the metric scale where no legs are seen.
SEGMENT_FRACTIONS: dict[tuple[str, str], float] = {
    ("neck", "mid_hip"): 0.288, ("left_hip", "left_knee"): 0.245,
    ("right_hip", "right_knee"): 0.245, ("left_knee", "left_ankle"): 0.246,
    ("right_knee", "right_ankle"): 0.246, ("left_shoulder", "left_elbow"): 0.186,
    ("right_shoulder", "right_elbow"): 0.186, ("left_elbow", "left_wrist"): 0.146,
    ("right_elbow", "right_wrist"): 0.146,
}
#: The ankle-knee-hip-neck chain as a fraction of stature: shoulder height 0.818 less ankle
#: height 0.039 (Drillis & Contini 1966); what carries the metric scale where legs are seen.
CHAIN_FRACTION = 0.779
#: A group repeats another when its joints sit within this fraction of its size (median
#: distance of its joints from their centre) of the other's.
STILL_FRACTION = 0.01
#: Nearest groups (by centre) each group is compared with.
STILL_NEIGHBOURS = 8
#: Fewest groups that must show a chain or segment for it to set the scale.
MIN_GROUPS = 10


def joint_points(points: NDArray[np.float64], joints: NDArray[np.int64], name: str
                 ) -> NDArray[np.float64]:
    """The canonical joint ``name`` of every group, shape (G, 3); NaN where ``joints`` lacks it.

    Parameters
    ----------
    points : ndarray, shape (G, J, 3)
    joints : ndarray of int, shape (J,)
        Canonical index of each of the J joints.
    name : str
    """
    where = np.flatnonzero(joints == CANONICAL_INDEX[name])
    return points[:, where[0]] if where.size else np.full((len(points), 3), np.nan)


def chain_statures(points: NDArray[np.float64], joints: NDArray[np.int64]) -> NDArray[np.float64]:
    """Per group, the stature its ankle-knee-hip-neck chain implies (NaN without one): the
    chain's ends sit where detectors put them consistently, whatever the hips' placement."""
    def at(name: str) -> NDArray[np.float64]:
        return joint_points(points, joints, name)

    trunk = np.linalg.norm(at("neck") - at("mid_hip"), axis=1)
    sides = [np.linalg.norm(at(f"{side}_ankle") - at(f"{side}_knee"), axis=1)
             + np.linalg.norm(at(f"{side}_knee") - at(f"{side}_hip"), axis=1)
             for side in ("left", "right")]
    return (nanmean(np.stack(sides, axis=1), axis=1) + trunk) / CHAIN_FRACTION


def metric_scale(points: NDArray[np.float64], joints: NDArray[np.int64], height: float) -> float:
    """Metres per bundle unit: from the leg-and-trunk chains where legs are seen (the median
    over groups), else the median over segments of the stature each one implies."""
    chain = chain_statures(points, joints)
    chain = chain[np.isfinite(chain)]
    if chain.size >= MIN_GROUPS:
        return float(height / np.median(chain))
    implied = []
    for (a, b), frac in SEGMENT_FRACTIONS.items():
        d = np.linalg.norm(joint_points(points, joints, b) - joint_points(points, joints, a),
                           axis=1)
        d = d[np.isfinite(d)]
        if d.size >= MIN_GROUPS:
            implied.append(np.median(d) / frac)
    if not implied:
        raise ValueError("no limb or trunk seen by two cameras: the metric scale is unknown")
    return float(height / np.median(implied))


def moving_groups(points: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Groups that do not repeat another group's pose to within :data:`STILL_FRACTION` of the
    figure's size: a figure that never moves (mannequin, poster, composited figure) is not a
    person the stature prior describes, and its copies would outweigh the people.

    Parameters
    ----------
    points : ndarray, shape (G, J, 3)

    Returns
    -------
    ndarray of bool, shape (G,)
        False for groups without a finite joint and for repeats.
    """
    centre = nanmean(points, axis=1)
    out: NDArray[np.bool_] = np.asarray(np.isfinite(centre).all(1))
    idx = np.flatnonzero(out)
    if idx.size < 2:
        return out
    spread = nanmedian_last(np.linalg.norm(points[idx] - centre[idx, None], axis=-1))
    _, near = cKDTree(centre[idx]).query(centre[idx], k=min(STILL_NEIGHBOURS + 1, idx.size))
    d = nanmedian_last(np.linalg.norm(points[idx[near]] - points[idx, None], axis=-1))
    d[near == np.arange(idx.size)[:, None]] = np.inf  # a group does not repeat itself
    out[idx] = ~np.any(d < STILL_FRACTION * spread[:, None], axis=1)
    return out


def people_who_move(points: NDArray[np.float64]) -> NDArray[np.float64]:
    """The groups of ``points`` (G, J, 3) that :func:`moving_groups` keeps, or all of them where
    fewer than :data:`MIN_GROUPS` would remain (everyone holds still)."""
    moving = moving_groups(points)
    return points[moving] if moving.sum() >= MIN_GROUPS else points


def rescale_to_statures(cameras: list[Camera], points: NDArray[np.float64], height: float
                        ) -> tuple[list[Camera], NDArray[np.float64], float]:
    """Cameras and canonical joints scaled about the world origin so that the moving people's
    leg-and-trunk chains imply ``height`` (unchanged where fewer than :data:`MIN_GROUPS` show a
    chain): the factor graph's head-height prior depends on posture, the chain does not.

    Parameters
    ----------
    cameras : list of Camera
        In a world whose origin lies on the ground (z = 0 stays the ground).
    points : ndarray, shape (G, 26, 3)
        Every canonical joint of every group.
    height : float
        Mean stature of the people (m).

    Returns
    -------
    cameras, points, factor
    """
    joints = np.arange(points.shape[1])
    statures = chain_statures(people_who_move(points), joints)
    statures = statures[np.isfinite(statures)]
    if statures.size < MIN_GROUPS:
        return cameras, points, 1.0
    k = float(height / np.median(statures))
    return [c.with_(t=k * c.t) for c in cameras], points * k, k
