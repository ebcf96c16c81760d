"""A tiny synthetic rig for the stage V tests: walking stick figures seen by a ring of cameras.

Independent of the full simulator so the refinement can be tested in isolation with exactly known
noise, outliers and time offsets.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cascalib.calibration import Calibration
from cascalib.camera import Camera, look_at
from cascalib.geometry import rodrigues_to_matrix
from cascalib.skeletons import CANONICAL_INDEX, get_skeleton
from cascalib.tracks import Tracks

# Joint positions of a standing person of height 1 facing +x (x forward, y left, z up).
_TEMPLATE = {
    "head_top": (0, 0, 1.0), "nose": (0.06, 0, 0.93), "left_eye": (0.05, 0.03, 0.945),
    "right_eye": (0.05, -0.03, 0.945), "left_ear": (0, 0.07, 0.93), "right_ear": (0, -0.07, 0.93),
    "neck": (0, 0, 0.85), "left_shoulder": (0, 0.13, 0.82), "right_shoulder": (0, -0.13, 0.82),
    "left_elbow": (0, 0.15, 0.63), "right_elbow": (0, -0.15, 0.63),
    "left_wrist": (0.02, 0.15, 0.48), "right_wrist": (0.02, -0.15, 0.48),
    "mid_hip": (0, 0, 0.53), "left_hip": (0, 0.06, 0.53), "right_hip": (0, -0.06, 0.53),
    "left_knee": (0, 0.07, 0.29), "right_knee": (0, -0.07, 0.29),
    "left_ankle": (0, 0.07, 0.05), "right_ankle": (0, -0.07, 0.05),
    "left_heel": (-0.03, 0.07, 0.02), "right_heel": (-0.03, -0.07, 0.02),
    "left_big_toe": (0.1, 0.08, 0.01), "right_big_toe": (0.1, -0.08, 0.01),
    "left_small_toe": (0.09, 0.1, 0.01), "right_small_toe": (0.09, -0.1, 0.01),
}  # fmt: skip
TEMPLATE = np.array([_TEMPLATE[n] for n in CANONICAL_INDEX], dtype=float)
ANKLE_FRACTION = 0.05


@dataclass
class RefineScene:
    truth: Calibration
    tracks: list[Tracks]
    joints: np.ndarray  # (T, P, 26, 3) true joints at reference frames 0..T-1 (+ margin)
    heights: np.ndarray


def _pose(height: float, pos: np.ndarray, heading: float, phase: float) -> np.ndarray:
    """26 joints of a walking person; the swing leg is lifted, arms swing opposite."""
    J = TEMPLATE * height
    s = np.sin(phase)
    out = J.copy()
    for side, sign in (("left", 1.0), ("right", -1.0)):
        swing = sign * s * 0.12 * height
        for name in ("knee", "ankle", "heel", "big_toe", "small_toe"):
            out[CANONICAL_INDEX[f"{side}_{name}"], 0] += swing * (0.5 if name == "knee" else 1.0)
        lift = max(0.0, sign * np.cos(phase)) * 0.06 * height
        for name in ("ankle", "heel", "big_toe", "small_toe"):
            out[CANONICAL_INDEX[f"{side}_{name}"], 2] += lift
        for name in ("elbow", "wrist"):
            out[CANONICAL_INDEX[f"{side}_{name}"], 0] -= swing * (0.5 if name == "elbow" else 1.0)
    c, sn = np.cos(heading), np.sin(heading)
    Rz = np.array([[c, -sn, 0], [sn, c, 0], [0, 0, 1]])
    return out @ Rz.T + np.array([pos[0], pos[1], 0.0])


def _walk(n_frames: int, n_persons: int, rng: np.random.Generator, fps: float, area: float
          ) -> tuple[np.ndarray, np.ndarray]:
    heights = rng.normal(1.72, 0.07, n_persons)
    joints = np.zeros((n_frames, n_persons, 26, 3))
    for p in range(n_persons):
        pos = rng.uniform(-area, area, 2)
        heading = rng.uniform(0, 2 * np.pi)
        speed = rng.uniform(0.8, 1.4) / fps
        phase = rng.uniform(0, 2 * np.pi)
        for f in range(n_frames):
            direction = np.array([np.cos(heading), np.sin(heading)])
            nxt = pos + speed * direction
            if np.any(np.abs(nxt) > area):  # turn around at the border of the area
                heading += np.pi * rng.uniform(0.7, 1.3)
                direction = np.array([np.cos(heading), np.sin(heading)])
                nxt = pos + speed * direction
            pos = nxt
            heading += rng.normal(0, 0.01)
            phase += 2 * np.pi * 0.9 / fps
            joints[f, p] = _pose(heights[p], pos, heading, phase)
    return joints, heights


def make_scene(*, n_cams: int = 4, n_frames: int = 60, n_persons: int = 3, noise_px: float = 0.0,
               outlier_rate: float = 0.0, offsets: tuple[float, ...] | None = None,
               radius: float = 8.0, focal: float = 1200.0, seed: int = 0,
               distortion: tuple[float, ...] | None = None, area: float = 3.0,
               principal_offset: float = 0.0, rates: tuple[float, ...] | None = None
               ) -> RefineScene:
    """Cameras on a ring at 2.5-3.5 m height looking at the centre; people walk inside.

    ``offsets[c]`` is the (possibly fractional) time offset of camera c in reference frames; the
    person motion is sampled at 1/10 frame and interpolated so fractional offsets are exact.
    ``principal_offset``: each camera's principal point is off the image centre by up to this
    fraction of the image size in x and y (uniform, from a stream of its own, so that the
    scene is otherwise the same). ``rates[c]``: camera c's frame k shows reference frame
    ``rates[c] * k + offsets[c]`` (default 1).
    """
    rng = np.random.default_rng(seed)
    fps = 25.0
    offsets = offsets or (0.0,) * n_cams
    rates = rates or (1.0,) * n_cams
    sub = 10
    margin = int(np.ceil(max(abs(o) for o in offsets)
                         + n_frames * max(max(rates) - 1.0, 0.0))) + 2
    fine, heights = _walk((n_frames + 2 * margin) * sub, n_persons, rng, fps * sub, area)
    size = (1920, 1080)
    cams = []
    for c in range(n_cams):
        ang = 2 * np.pi * c / n_cams + rng.normal(0, 0.2)
        eye = np.array([radius * np.cos(ang), radius * np.sin(ang), rng.uniform(2.5, 3.5)])
        R, t = look_at(eye, [rng.normal(0, 0.5), rng.normal(0, 0.5), 0.9])
        f = focal * rng.uniform(0.9, 1.1)
        dist = None if distortion is None else np.asarray(distortion)
        cams.append(Camera.from_params(f"cam{c}", size, f, R, t, dist=dist, fps=fps,
                                       time_offset=offsets[c], time_rate=rates[c]))
    if principal_offset > 0:
        shift = np.random.default_rng([seed, 7]).uniform(-1, 1, (n_cams, 2)) * principal_offset
        for c, cam in enumerate(cams):
            K = cam.K.copy()
            K[:2, 2] += shift[c] * np.array(size)
            cams[c] = cam.with_(K=K)
    truth = Calibration(cams)
    skel = get_skeleton("halpe26")
    tracks = []
    for cam in cams:
        # frame k shows reference time rate k + offset: fine index (that + margin) * sub
        idx = np.round((cam.time_rate * np.arange(n_frames) + cam.time_offset + margin)
                       * sub).astype(int)
        X = fine[idx]
        uv = cam.project(X)
        uv = uv + rng.normal(0, noise_px, uv.shape)
        if outlier_rate > 0:
            bad = rng.random(uv.shape[:-1]) < outlier_rate
            uv[bad] += rng.uniform(-150, 150, (bad.sum(), 2))
        conf = np.full(uv.shape[:-1] + (1,), 0.9)
        kp = np.concatenate([uv, conf], -1)
        w, h = size
        out = ~((uv[..., 0] >= 0) & (uv[..., 0] < w) & (uv[..., 1] >= 0) & (uv[..., 1] < h))
        kp[out] = np.nan
        perm = np.stack([rng.permutation(n_persons) for _ in range(n_frames)])
        kp = np.take_along_axis(kp, perm[:, :, None, None], axis=1)  # no identities
        tracks.append(Tracks(cam.name, kp, skel, image_size=size, fps=fps))
    ref_idx = np.round((np.arange(n_frames) + margin) * sub).astype(int)
    return RefineScene(truth, tracks, fine[ref_idx], heights)


def perturb(calib: Calibration, *, rot_deg: float = 3.0, pos_m: float = 0.3,
            focal_rel: float = 0.05, offset_frames: float = 0.0, seed: int = 1) -> Calibration:
    """The rig with random errors of the given size (reference camera's time offset kept 0)."""
    rng = np.random.default_rng(seed)
    cams = []
    for i, cam in enumerate(calib.cameras):
        axis = rng.normal(size=3)
        dR = rodrigues_to_matrix(axis / np.linalg.norm(axis) * np.radians(rot_deg))
        R = dR @ cam.R
        center = cam.center + rng.normal(size=3) / np.sqrt(3) * pos_m
        K = cam.K.copy()
        K[0, 0] *= 1 + focal_rel * rng.choice([-1, 1])
        K[1, 1] = K[0, 0]
        off = cam.time_offset + (0.0 if i == 0 else offset_frames * rng.choice([-1, 1]))
        cams.append(cam.with_(R=R, t=-R @ center, K=K, dist=np.zeros(5), time_offset=off))
    return Calibration(cams)
