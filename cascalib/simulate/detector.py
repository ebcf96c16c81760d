"""Detector model: turn projected true joints into realistic 2D keypoint detections.

The effects, each switched off by setting its parameter to 0 (:meth:`DetectorConfig.clean` turns
all of them off, and then the detections are exactly the projected truth):

* Gaussian pixel noise whose s.d. grows with the person's size in the image
  (``noise_px + noise_rel * pixel_height``, per-joint factors as in COCO's keypoint sigmas);
* heavy-tailed outliers (a fraction of the joints get a Cauchy-distributed error);
* confidences that fall as the error grows;
* randomly missed joints and left/right swaps;
* occlusion: joints of a farther person inside a nearer person's bounding box are dropped or
  degraded;
* truncation at the image border; persons too small to detect are dropped;
* false-positive detections;
* track ids: none, per camera only, or consistent, with id switches when people cross.
"""

from __future__ import annotations

import warnings
from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field
from scipy.signal import lfilter

from cascalib.camera import Camera
from cascalib.simulate.rigs import valid_radius
from cascalib.skeletons import LEFT_RIGHT_PAIRS
from cascalib.tracks import IMAGE_MARGIN

__all__ = ["DetectorConfig", "Detections", "detect", "project_truth", "JOINT_SIGMA"]

#: Relative localisation difficulty per canonical joint (COCO keypoint sigmas, normalised so
#: the shoulders are 1; the extra Halpe joints get the value of their nearest COCO neighbour).
JOINT_SIGMA = np.array([
    0.33, 0.32, 0.32, 0.45, 0.45,  # nose, eyes, ears
    1.0, 1.0, 0.92, 0.92, 0.79, 0.79,  # shoulders, elbows, wrists
    1.35, 1.35, 1.10, 1.10, 1.13, 1.13,  # hips, knees, ankles
    0.45, 1.0, 1.35,  # head top, neck, mid hip
    1.13, 1.13, 1.13, 1.13, 1.13, 1.13,  # toes and heels
])  # fmt: skip


class DetectorConfig(BaseModel):
    """Parameters of the simulated 2D pose detector (0 disables an effect)."""

    model_config = ConfigDict(extra="forbid")

    noise_px: float = Field(default=1.0, ge=0, description="Constant pixel noise s.d. (px).")
    noise_rel: float = Field(
        default=0.005, ge=0,
        description="Extra noise s.d. per pixel of person height (0.005: 2.5 px "
        "for a 500 px tall person).")
    noise_corr: float = Field(
        default=0.0, ge=0, lt=1,
        description="Frame-to-frame correlation of the pixel noise (AR(1) coefficient): "
        "detectors jitter smoothly, not independently per frame; 0 gives white noise.")
    outlier_rate: float = Field(
        default=0.0, ge=0, le=1,
        description="Fraction of joints with a heavy-tailed (Cauchy) error.")
    outlier_scale: float = Field(
        default=0.1, ge=0,
        description="Scale of the outlier error, as a fraction of person height.")
    miss_rate: float = Field(default=0.0, ge=0, le=1, description="Fraction of joints missed.")
    swap_rate: float = Field(
        default=0.0, ge=0, le=1, description="Fraction of detections with left and right swapped.")
    occlusion: float = Field(
        default=0.0, ge=0, le=1,
        description="Probability that a joint hidden behind a nearer person "
        "is dropped (otherwise its noise is tripled and its confidence halved).")
    truncation: bool = Field(
        default=True, description="Drop joints outside the image (a detector does not see them). "
        "When off, joints up to the Tracks margin outside the image are kept.")
    min_height_px: float = Field(
        default=0.0, ge=0, description="Persons smaller than this (px) are not detected.")
    false_positive_rate: float = Field(
        default=0.0, ge=0, description="Expected false-positive detections per frame.")
    confidence: bool = Field(
        default=True, description="Confidences fall with the error (else every confidence is 1).")
    track_ids: str = Field(
        default="none", pattern="^(none|per_camera|global)$",
        description="'none': no ids; 'per_camera': ids consistent within a camera only; "
        "'global': the true person index in every camera.")
    id_switch: float = Field(
        default=0.0, ge=0, le=1,
        description="Probability that two persons whose boxes overlap swap "
        "their track ids.")
    shuffle_slots: bool = Field(
        default=False,
        description="Order the persons of each frame randomly (as detectors do) instead "
        "of slot p = person p.")

    @classmethod
    def clean(cls) -> DetectorConfig:
        """No noise, no outliers, no misses: detections equal the projected truth."""
        return cls(noise_px=0.0, noise_rel=0.0, confidence=False)


def project_truth(cam: Camera, joints: NDArray[np.float64], heights: NDArray[np.float64],
                  margin: float = IMAGE_MARGIN) -> tuple[NDArray[Any], ...]:
    """Project true joints and tell which a camera can see.

    Parameters
    ----------
    cam : Camera
    joints : ndarray, shape (F, P, 26, 3)
        World joints.
    heights : ndarray, shape (P,)
        Person heights (m).
    margin : float
        Fraction of the image size outside the border still counted as in-frame (for the
        non-truncating detector).

    Returns
    -------
    uv : ndarray, shape (F, P, 26, 2)
        Pixels (NaN behind the camera or outside the lens' valid field).
    inside : ndarray of bool, shape (F, P, 26)
        Inside the image.
    in_margin : ndarray of bool, shape (F, P, 26)
        Inside the image grown by ``margin``.
    pixel_height : ndarray, shape (F, P)
        Person height in pixels at the mid-hip depth (``f * H / z``).
    depth : ndarray, shape (F, P)
        Mid-hip depth (m).
    """
    xc = cam.world_to_cam(joints)
    z = xc[..., 2]
    with np.errstate(invalid="ignore", divide="ignore"):
        r = np.linalg.norm(xc[..., :2] / z[..., None], axis=-1)
    seen = (z > 0.1) & (r < valid_radius(cam))
    uv = cam.project(joints)
    uv[~seen] = np.nan
    w, h = cam.image_size
    x, y = uv[..., 0], uv[..., 1]
    with np.errstate(invalid="ignore"):
        inside = (x >= 0) & (x <= w - 1) & (y >= 0) & (y <= h - 1)
        in_margin = ((x >= -margin * w) & (x <= (1 + margin) * w - 1)
                     & (y >= -margin * h) & (y <= (1 + margin) * h - 1))
    depth = z[..., 19]  # mid hip
    with np.errstate(invalid="ignore", divide="ignore"):
        pixel_height = np.where(depth > 0.1, cam.focal * heights[None, :] / depth, 0.0)
    return uv, inside, in_margin, pixel_height, depth


def _occluded(uv: NDArray[np.float64], visible: NDArray[np.bool_],
              depth: NDArray[np.float64]) -> NDArray[np.bool_]:
    """Joints (F, P, 26) inside the bounding box of a nearer person in the same frame."""
    F, P = uv.shape[:2]
    u = np.where(visible, uv[..., 0], np.nan)
    v = np.where(visible, uv[..., 1], np.nan)
    any_vis = visible.any(-1)
    with np.errstate(invalid="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # empty slots: all-NaN rows
        box = np.stack([np.nanmin(u, -1), np.nanmin(v, -1), np.nanmax(u, -1), np.nanmax(v, -1)],
                       -1)  # (F, P, 4)
    out = np.zeros((F, P, 26), dtype=bool)
    step = max(1, int(2e7 // max(P * P * 26, 1)))  # bound the (f, near, far, joint) temporaries
    for f0 in range(0, F, step):
        sl = slice(f0, f0 + step)
        b = box[sl][:, :, None, None, :]  # near person p
        uu, vv = uv[sl][:, None, :, :, 0], uv[sl][:, None, :, :, 1]  # far person q
        with np.errstate(invalid="ignore"):
            inside = (uu >= b[..., 0]) & (uu <= b[..., 2]) & (vv >= b[..., 1]) & (vv <= b[..., 3])
            d = depth[sl]
            nearer = (d[:, :, None] < d[:, None, :]) & np.asarray(any_vis)[sl][:, :, None]
        out[sl] = (inside & nearer[..., None]).any(1)
    return out


def _confidence(err: NDArray[np.float64], pixel_height: NDArray[np.float64],
                rng: np.random.Generator) -> NDArray[np.float64]:
    """Confidence in (0.05, 1) that falls with the error relative to the person size."""
    rel = err / np.maximum(pixel_height, 1.0)[..., None]
    c = 1.0 - 4.0 * rel + rng.normal(0, 0.05, rel.shape)
    return np.clip(c, 0.05, 1.0)


def _swap_left_right(kp: NDArray[np.float64], swap: NDArray[np.bool_]) -> NDArray[np.float64]:
    perm = np.arange(26)
    for a, b in LEFT_RIGHT_PAIRS:
        perm[a], perm[b] = b, a
    return np.where(swap[..., None, None], kp[..., perm, :], kp)


@dataclass(frozen=True)
class Detections:
    """Output of :func:`detect` for one camera.

    Attributes
    ----------
    keypoints : ndarray, shape (F, S, 26, 3)
        Canonical x, y, confidence; NaN where missing.
    slot_to_person : ndarray of int, shape (F, S)
        True person of each slot; -1 for a false positive, -2 for an empty slot.
    track_ids : ndarray of int, shape (F, S), or None
        Track ids (-1 unknown), None when the detector gives none.
    """

    keypoints: NDArray[np.float64]
    slot_to_person: NDArray[np.int64]
    track_ids: NDArray[np.int64] | None


def _noisy(cfg: DetectorConfig, uv: NDArray[np.float64], pixel_height: NDArray[np.float64],
           degraded: NDArray[np.bool_], rng: np.random.Generator
           ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Noisy pixels (F, P, 26, 2) and confidences (F, P, 26)."""
    shape = uv.shape[:-1]
    sigma = (cfg.noise_px + cfg.noise_rel * pixel_height)[..., None] * JOINT_SIGMA
    sigma = np.where(degraded, 3.0 * sigma, sigma)
    noise = np.zeros(uv.shape)
    if np.any(sigma > 0):
        white = rng.standard_normal(uv.shape)
        if cfg.noise_corr > 0:  # AR(1) along the frame axis, unit variance kept
            a = cfg.noise_corr
            white[0] /= np.sqrt(1 - a * a)
            white = lfilter([np.sqrt(1 - a * a)], [1.0, -a], white, axis=0)
        noise = white * sigma[..., None]
    if cfg.outlier_rate > 0:
        hit = rng.random(shape) < cfg.outlier_rate
        scale = (cfg.outlier_scale * pixel_height)[..., None, None]
        # Cauchy tails, capped at one body height: detectors err to a nearby body part.
        cauchy = np.clip(rng.standard_cauchy(uv.shape), -10, 10) * scale
        noise = noise + np.where(hit[..., None], cauchy, 0.0)
    conf = np.ones(shape)
    if cfg.confidence:
        conf = _confidence(np.linalg.norm(noise, axis=-1), pixel_height, rng)
        conf = np.where(degraded, 0.5 * conf, conf)
    return uv + noise, conf


def _false_positives(cfg: DetectorConfig, uv: NDArray[np.float64], size: tuple[int, int],
                     rng: np.random.Generator) -> NDArray[np.float64]:
    """False detections (F, M, 26, 3): true-looking poses at wrong places and scales."""
    F = uv.shape[0]
    n = np.asarray(rng.poisson(cfg.false_positive_rate, F))
    m = int(n.max()) if F else 0
    out = np.full((F, m, 26, 3), np.nan)
    pool = uv.reshape(-1, 26, 2)
    pool = pool[np.isfinite(pool[..., 0]).sum(-1) >= 13]
    if m == 0 or pool.shape[0] == 0:
        return out
    w, h = size
    f_idx, k_idx = np.nonzero(np.arange(m)[None, :] < n[:, None])
    tmpl = pool[rng.integers(pool.shape[0], size=f_idx.size)]
    centre = np.nanmean(tmpl, axis=1, keepdims=True)
    scale = rng.uniform(0.4, 1.2, (f_idx.size, 1, 1))
    where = rng.uniform([0, 0], [w - 1, h - 1], (f_idx.size, 1, 2))
    pts = (tmpl - centre) * scale + where
    pts = pts + rng.normal(0, 0.05, pts.shape) * np.nanstd(tmpl, axis=1, keepdims=True)
    conf = rng.uniform(0.05, 0.5, pts.shape[:2])
    gone = rng.random(pts.shape[:2]) < 0.3
    det = np.concatenate([pts, conf[..., None]], -1)
    det[gone | ~np.isfinite(pts[..., 0])] = np.nan
    out[f_idx, k_idx] = det
    return out


def _drop_outside(kp: NDArray[np.float64], size: tuple[int, int], truncation: bool
                  ) -> NDArray[np.float64]:
    w, h = size
    m = 0.0 if truncation else IMAGE_MARGIN
    x, y = kp[..., 0], kp[..., 1]
    with np.errstate(invalid="ignore"):
        ok = (x >= -m * w) & (x <= (1 + m) * w - 1) & (y >= -m * h) & (y <= (1 + m) * h - 1)
    return np.where(ok[..., None], kp, np.nan)


def detect(cam: Camera, joints: NDArray[np.float64], heights: NDArray[np.float64],
           cfg: DetectorConfig, rng: np.random.Generator) -> Detections:
    """Simulate a 2D pose detector on one camera.

    Parameters
    ----------
    cam : Camera
    joints : ndarray, shape (F, P, 26, 3)
        True world joints at this camera's frames.
    heights : ndarray, shape (P,)
    cfg : DetectorConfig
    rng : numpy.random.Generator

    Returns
    -------
    Detections
    """
    F, P = joints.shape[:2]
    uv, inside, in_margin, ph, depth = project_truth(cam, joints, heights)
    keep = (inside if cfg.truncation else in_margin) & np.isfinite(uv[..., 0])
    keep &= (ph >= cfg.min_height_px)[..., None]
    degraded = np.zeros_like(keep)
    if cfg.occlusion > 0 and P > 1:
        occ = _occluded(uv, keep, depth)
        dropped = occ & (rng.random(occ.shape) < cfg.occlusion)
        keep &= ~dropped
        degraded = occ & ~dropped
    det, conf = _noisy(cfg, uv, ph, degraded, rng)
    if cfg.miss_rate > 0:
        keep &= rng.random(keep.shape) >= cfg.miss_rate
    kp = np.concatenate([det, conf[..., None]], -1)
    kp[~keep] = np.nan
    if cfg.swap_rate > 0:
        kp = _swap_left_right(kp, rng.random((F, P)) < cfg.swap_rate)
    kp = _drop_outside(kp, cam.image_size, cfg.truncation)
    person = np.broadcast_to(np.arange(P), (F, P)).copy()
    if cfg.false_positive_rate > 0:
        fp = _false_positives(cfg, uv, cam.image_size, rng)
        kp = np.concatenate([kp, _drop_outside(fp, cam.image_size, True)], 1)
        person = np.concatenate([person, np.full(fp.shape[:2], -1)], 1)
    present = np.isfinite(kp[..., 0]).any(-1)
    person = np.where(present, person, -2)
    ids = _track_ids(cfg, uv, keep, person, rng)
    if cfg.shuffle_slots:
        kp, person, ids = _shuffle(kp, person, ids, rng)
    return Detections(kp, person.astype(np.int64), ids)


def _boxes_overlap(uv: NDArray[np.float64], keep: NDArray[np.bool_]) -> NDArray[np.bool_]:
    """(F, P, P) whether the visible-joint boxes of two persons overlap."""
    u = np.where(keep, uv[..., 0], np.nan)
    v = np.where(keep, uv[..., 1], np.nan)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)
        lo_u, hi_u = np.nanmin(u, -1), np.nanmax(u, -1)
        lo_v, hi_v = np.nanmin(v, -1), np.nanmax(v, -1)
    with np.errstate(invalid="ignore"):
        ov = ((lo_u[:, :, None] <= hi_u[:, None, :]) & (lo_u[:, None, :] <= hi_u[:, :, None])
              & (lo_v[:, :, None] <= hi_v[:, None, :]) & (lo_v[:, None, :] <= hi_v[:, :, None]))
    return ov


def _track_ids(cfg: DetectorConfig, uv: NDArray[np.float64], keep: NDArray[np.bool_],
               person: NDArray[np.int64], rng: np.random.Generator) -> NDArray[np.int64] | None:
    """Track id of every slot (F, S), or None when the detector has no tracker."""
    if cfg.track_ids == "none":
        return None
    F, P = uv.shape[:2]
    base = np.arange(P) if cfg.track_ids == "global" else rng.permutation(P) + 1 + rng.integers(50)
    label = np.broadcast_to(base, (F, P)).copy()
    if cfg.id_switch > 0 and P > 1:
        ov = _boxes_overlap(uv, keep)
        onset = ov[1:] & ~ov[:-1]
        events = np.argwhere(np.triu(onset, 1))  # (frame-1, p, q), in frame order
        for f, p, q in events[rng.random(len(events)) < cfg.id_switch]:
            label[f + 1:, [p, q]] = label[f + 1:, [q, p]]
    ids = np.full(person.shape, -1, dtype=np.int64)
    true_slot = person[:, :P] >= 0
    ids[:, :P] = np.where(true_slot, label, -1)
    return ids


def _shuffle(kp: NDArray[np.float64], person: NDArray[np.int64],
             ids: NDArray[np.int64] | None, rng: np.random.Generator
             ) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.int64] | None]:
    """Random slot order per frame, detections first (empty slots last)."""
    key = rng.random(person.shape) + 2.0 * (person == -2)
    order = np.argsort(key, axis=1)
    kp = np.take_along_axis(kp, order[:, :, None, None], 1)
    person = np.take_along_axis(person, order, 1)
    if ids is not None:
        ids = np.take_along_axis(ids, order, 1)
    return kp, person, ids
