"""Upright-person filter and the ankle/upper-point observations it feeds to Stage I.

The paper (supplement, "Filtering") keeps a 2D pose when its legs and trunk are straight: the
angles at the knee (ankle-knee-hip) and at the hip (knee-hip-shoulder) must both be close to
180 deg, on the straighter side of the body. The printed equation subtracts pi from a cosine and
measures the second angle at the knee; we implement its evident intent with angles in degrees,
the knee angle per side and the trunk angle at the hip on the body's centre line (mid-knee,
mid-hip, mid-shoulder). We also reject

* truncated or unreliable persons: a required joint missing, below ``min_confidence``, or within
  ``border_px`` of the image edge (a clipped person has a wrong ankle);
* foreshortened legs (sitting, kneeling, crouching seen from the front, where the angles can look
  straight): the image ratio of ankle-to-hip over hip-to-shoulder length must be near the
  standing value (0.491 H / 0.288 H = 1.7 with Drillis-Contini segment heights);
* persons smaller than ``min_pixel_height`` (ankle to shoulder), whose joints are too noisy.

Body point heights (fractions of stature H) from Drillis & Contini (1966), as tabulated in
D. A. Winter, "Biomechanics and Motor Control of Human Movement", 4th ed., Fig. 4.1: ankle 0.039,
knee 0.285, hip 0.530, shoulder 0.818, top of head 1.0.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from dataclasses import dataclass

import numpy as np
from numpy.typing import NDArray

from cascalib.errors import InputError
from cascalib.skeletons import CANONICAL_INDEX
from cascalib.stages.single_view_solver import Observations
from cascalib.tracks import Tracks

__all__ = ["Extracted", "bend_angle", "upright_mask", "extract_observations", "UPPER_POINTS"]

F64 = NDArray[np.float64]

#: Upper points Stage I can use; each is the mean of the listed canonical joints.
UPPER_POINTS: dict[str, tuple[str, ...]] = {
    "shoulder": ("left_shoulder", "right_shoulder"),
    "hip": ("left_hip", "right_hip"),
    "neck": ("neck",),
    "head_top": ("head_top",),
}
_REQUIRED = ("left_ankle", "right_ankle", "left_knee", "right_knee", "left_hip", "right_hip",
             "left_shoulder", "right_shoulder")


def _angle_deg(u: F64, v: F64) -> F64:
    with np.errstate(invalid="ignore", divide="ignore"):
        cos = np.sum(u * v, -1) / (np.linalg.norm(u, axis=-1) * np.linalg.norm(v, axis=-1))
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def bend_angle(kp: F64) -> F64:
    """Straightness of each pose (supplement Eq. "supp_angle_filter", in degrees).

    Parameters
    ----------
    kp : ndarray, shape (..., 26, >=2)
        Canonical keypoints.

    Returns
    -------
    ndarray, shape (...)
        ``min over sides of (180 - knee angle)`` plus ``180 -`` the centre-line hip angle (between
        mid-knee and mid-shoulder); 0 for a straight pose,
        NaN where a joint is missing.
    """
    J = CANONICAL_INDEX
    # the trunk angle is taken on the body's centre line: the shoulders are wider than the
    # hips, so a per-side knee-hip-shoulder angle is ~10 deg off even for a straight pose
    mid_knee = _mid(kp, "left_knee", "right_knee")
    mid_hip = _mid(kp, "left_hip", "right_hip")
    hip_dev = 180.0 - _angle_deg(mid_knee - mid_hip, _mid(kp, "left_shoulder",
                                                          "right_shoulder") - mid_hip)
    out = []
    for side in ("left", "right"):
        ankle, knee = kp[..., J[f"{side}_ankle"], :2], kp[..., J[f"{side}_knee"], :2]
        hip = kp[..., J[f"{side}_hip"], :2]
        out.append(180.0 - _angle_deg(ankle - knee, hip - knee) + hip_dev)
    return np.fmin(out[0], out[1])


def _mid(kp: F64, a: str, b: str) -> F64:
    return 0.5 * (kp[..., CANONICAL_INDEX[a], :2] + kp[..., CANONICAL_INDEX[b], :2])


def upright_mask(kp: F64, image_size: tuple[int, int], *, max_bend_deg: float,
                 min_confidence: float, border_px: float, leg_torso_ratio: tuple[float, float],
                 min_pixel_height: float) -> NDArray[np.bool_]:
    """Which poses stand upright, untruncated and confidently detected.

    Parameters
    ----------
    kp : ndarray, shape (F, P, 26, 3)
        Canonical keypoints.
    image_size : (int, int)
        (width, height).

    Returns
    -------
    ndarray of bool, shape (F, P)
    """
    w, h = image_size
    req = kp[..., [CANONICAL_INDEX[j] for j in _REQUIRED], :]
    x, y, conf = req[..., 0], req[..., 1], req[..., 2]
    with np.errstate(invalid="ignore"):
        present = (np.isfinite(x) & (conf >= min_confidence)).all(-1)
        inside = ((x >= border_px) & (x <= w - 1 - border_px)
                  & (y >= border_px) & (y <= h - 1 - border_px)).all(-1)
        ankle = _mid(kp, "left_ankle", "right_ankle")
        hip = _mid(kp, "left_hip", "right_hip")
        shoulder = _mid(kp, "left_shoulder", "right_shoulder")
        leg = np.linalg.norm(ankle - hip, axis=-1)
        torso = np.linalg.norm(hip - shoulder, axis=-1)
        ratio = leg / torso
        tall = np.linalg.norm(ankle - shoulder, axis=-1) >= min_pixel_height
        straight = bend_angle(kp) <= max_bend_deg
        proportions = (ratio >= leg_torso_ratio[0]) & (ratio <= leg_torso_ratio[1])
    return present & inside & tall & straight & proportions


def _person_heights(height: float | Mapping[int, float] | Sequence[float], default: float,
                    ids: NDArray[np.int64]) -> F64:
    """Height (m) of each detection from a scalar, a {track_id: height} map or a list by id."""
    if np.isscalar(height):
        return np.full(len(ids), float(height))  # type: ignore[arg-type]
    lookup = dict(height) if isinstance(height, Mapping) else dict(enumerate(height))  # type: ignore[arg-type]
    return np.array([float(lookup.get(int(i), default)) for i in ids])


@dataclass(frozen=True)
class Extracted:
    """Observations of the upright detections and where they come from.

    Attributes
    ----------
    obs : Observations
        ``offset[i, k] = H_i (ratio_k - ratio_ankle)``; ``group`` the track id (-1 unknown).
    frame, person : ndarray of int, shape (N,)
        Frame and person slot of each detection.
    stature : ndarray, shape (N,)
        The height assumed for each detection (m).
    names : tuple of str
        The upper point of each column of ``obs.upper`` (first: "shoulder").
    """

    obs: Observations
    frame: NDArray[np.int64]
    person: NDArray[np.int64]
    stature: F64
    names: tuple[str, ...]


def extract_observations(tracks: Tracks, mask: NDArray[np.bool_], *,
                         ratios: Mapping[str, float], upper_points: Sequence[str],
                         height: float | Mapping[int, float] | Sequence[float],
                         default_height: float, min_confidence: float,
                         motion_s: float = 0.4) -> Extracted:
    """Ankle centres and upper points of the masked detections.

    Parameters
    ----------
    tracks : Tracks
    mask : ndarray of bool, shape (F, P)
        Upright detections to use.
    ratios : mapping
        Height above the ground as a fraction of stature, for ``"ankle"`` and each upper point.
    upper_points : sequence of str
        Names from :data:`UPPER_POINTS`; a point is used only where the skeleton has its joints
        natively (a neck derived from the shoulders would count the shoulders twice).
    height : float, mapping or sequence
        Stature (m): one for everyone, or per track id.
    motion_s : float
        Span (s) of the ankle motion recorded per detection (``obs.motion``): the ankle centre
        of the same person ``motion_s / 2`` before and after (whole frames), NaN where the
        person is not found then.

    Returns
    -------
    Extracted
    """
    kp = tracks.canonical()
    f_idx, p_idx = np.nonzero(mask)
    sel = kp[f_idx, p_idx]                                       # (N, 26, 3)
    ankle = _mid(sel, "left_ankle", "right_ankle")
    # the shoulder centre is always column 0: it anchors the scale in the refinement
    names = ["shoulder"] + [u for u in upper_points if u != "shoulder" and all(
        tracks.skeleton.index(j) is not None for j in UPPER_POINTS[u])]
    ids = (tracks.track_ids[f_idx, p_idx] if tracks.track_ids is not None
           else np.full(len(f_idx), -1, dtype=np.int64))
    stature = _person_heights(height, default_height, ids)
    upper = np.full((len(f_idx), len(names), 2), np.nan)
    offset = np.full((len(f_idx), len(names)), np.nan)
    for k, name in enumerate(names):
        joints = sel[:, [CANONICAL_INDEX[j] for j in UPPER_POINTS[name]], :]
        with np.errstate(invalid="ignore"):
            ok = (np.isfinite(joints[..., 0]) & (joints[..., 2] >= min_confidence)).all(-1)
        upper[ok, k] = joints[ok, :, :2].mean(1)
        offset[ok, k] = stature[ok] * (ratios[name] - ratios["ankle"])
    motion, dt = _ankle_motion(tracks, kp, f_idx, p_idx, motion_s)
    obs = Observations(ankle, upper, offset, ids.astype(np.int64), motion, dt)
    return Extracted(obs, f_idx.astype(np.int64), p_idx.astype(np.int64), stature, tuple(names))


def _ankle_motion(tracks: Tracks, kp: F64, f_idx: NDArray[np.int64], p_idx: NDArray[np.int64],
                  span_s: float) -> tuple[F64, F64]:
    """Ankle centres (N, 2, 2) of each detection's person ``k`` frames before and after, and
    the time (s) between them.

    The person there is the detection whose ankle centre is nearest, within half the
    ankle-to-shoulder length and at most half as far as the next nearest (no track ids needed:
    detectors rarely give them, and a walker moves a few tens of pixels in ``k`` frames).
    """
    try:
        times: F64 | None = tracks.frame_times()
    except InputError:  # neither timestamps nor a frame rate: frames of 25 fps
        times = None
    fps = tracks.frame_rate() or 25.0
    k = max(1, int(round(0.5 * span_s * fps)))
    n_frames = kp.shape[0]
    mid = _mid(kp, "left_ankle", "right_ankle")                                # (F, P, 2)
    me = mid[f_idx, p_idx]                                                     # (N, 2)
    size = np.linalg.norm(_mid(kp[f_idx, p_idx], "left_shoulder", "right_shoulder") - me,
                          axis=-1)
    motion = np.full((len(f_idx), 2, 2), np.nan)
    for side, shift in enumerate((-k, k)):
        g = f_idx + shift
        rows = np.flatnonzero((g >= 0) & (g < n_frames))
        cand = mid[g[rows]]                                                    # (n, P, 2)
        d = np.linalg.norm(cand - me[rows, None], axis=-1)
        d = np.where(np.isfinite(d), d, np.inf)
        order = np.argsort(d, axis=1)
        best = np.take_along_axis(d, order[:, :1], 1)[:, 0]
        second = (np.take_along_axis(d, order[:, 1:2], 1)[:, 0] if d.shape[1] > 1
                  else np.full(len(rows), np.inf))
        with np.errstate(invalid="ignore"):
            ok = (best < 0.5 * size[rows]) & (best < 0.5 * second)
        pick = rows[ok]
        motion[pick, side] = cand[ok, order[ok, 0]]
    t = np.arange(n_frames) / fps if times is None else np.asarray(times, dtype=np.float64)
    before, after = f_idx - k, f_idx + k
    # one end outside the recording: twice the other half (velocities() then halves it)
    t_b = np.where(before >= 0, t[np.clip(before, 0, None)], np.nan)
    t_a = np.where(after < n_frames, t[np.clip(after, None, n_frames - 1)], np.nan)
    t_me = t[f_idx]
    dt = np.where(np.isfinite(t_b) & np.isfinite(t_a), t_a - t_b,
                  2 * np.where(np.isfinite(t_a), t_a - t_me, t_me - t_b))
    return motion, np.where(dt > 0, dt, np.nan)
