"""Synthetic ground-trajectory scenes for the stage II-IV tests (independent of the simulator).

People are points walking on the ground (random smooth paths, or laps of a loop with a chosen
lap-to-lap variability: the paper's periodic failure case); a ring of cameras sees their ankles
with pixel noise, outliers, limited fields of view, their own frame rates and time offsets. The
plane cameras are the true cameras expressed in per-camera frames with a random yaw, shift and
optional scale error: exactly the ambiguity stage I leaves.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from cascalib.calibration import Calibration
from cascalib.camera import Camera, look_at
from cascalib.geometry import rot_z
from cascalib.tracks import Tracks

FOOT = 0.066


@dataclass
class AlignScene:
    tracks: list[Tracks]
    truth: list[Camera]
    plane: list[Camera]
    plane_from_world: list[tuple[float, float, np.ndarray]]  # (scale, yaw, shift)


def smooth_path(rng: np.random.Generator, duration: float, area: float = 5.0,
                speed: float = 1.3) -> callable:
    """Random smooth walk: heading is a random smooth function; kept inside ``area`` by a
    soft pull to the centre. Returns f(t_seconds) -> (n, 2)."""
    dt = 0.02
    n = int(duration / dt) + 2
    p = rng.uniform(-area / 2, area / 2, 2)
    h = rng.uniform(0, 2 * np.pi)
    turn = 0.0
    pts = np.empty((n, 2))
    v = speed * rng.uniform(0.8, 1.2)
    stop = 0.0
    for k in range(n):
        pts[k] = p
        turn = 0.97 * turn + rng.normal(0, 0.08)
        pull = np.arctan2(-p[1], -p[0]) - h
        pull = (pull + np.pi) % (2 * np.pi) - np.pi
        h += turn * dt * 10 + (0.8 * pull * dt if np.linalg.norm(p) > area / 2 else 0.0)
        if stop <= 0 and rng.random() < dt / 8:  # occasional pauses (stop/start events)
            stop = rng.uniform(0.5, 2.0)
        speed_now = 0.0 if stop > 0 else v
        stop -= dt
        p = p + speed_now * dt * np.array([np.cos(h), np.sin(h)])
    t = np.arange(n) * dt

    def f(tt: np.ndarray) -> np.ndarray:
        return np.stack([np.interp(tt, t, pts[:, 0]), np.interp(tt, t, pts[:, 1])], -1)

    return f


def loop_path(rng: np.random.Generator, period: float, variability: float,
              radius: float = 2.5) -> callable:
    """Laps of a rounded loop with period ``period`` s; each lap's shape and pace vary by
    ``variability`` (metres of radius wobble) like a person walking the same circuit again."""
    n_laps = 64
    wob = rng.normal(0, variability, (n_laps, 3))
    pace = 1 + rng.normal(0, variability / 10, n_laps)
    phase0 = rng.uniform(0, 2 * np.pi)

    def f(tt: np.ndarray) -> np.ndarray:
        tt = np.asarray(tt, float)
        lap_t = np.cumsum(np.r_[0, period * pace])
        lap = np.clip(np.searchsorted(lap_t, tt, side="right") - 1, 0, n_laps - 1)
        frac = (tt - lap_t[lap]) / (period * pace[lap])
        a = phase0 + 2 * np.pi * frac
        w = wob[lap]
        blend = 0.5 - 0.5 * np.cos(2 * np.pi * frac)  # continuous across laps
        r = radius + blend * (w[:, 0] * np.cos(2 * a) + w[:, 1] * np.sin(3 * a))
        return np.stack([1.3 * r * np.cos(a) + blend * w[:, 2], r * np.sin(a)], -1)

    return f


def ring_cameras(n: int, rng: np.random.Generator, radius: float = 10.0,
                 height: float = 3.0) -> list[Camera]:
    cams = []
    for c in range(n):
        ang = 2 * np.pi * c / n + rng.uniform(-0.3, 0.3)
        eye = np.array([radius * np.cos(ang), radius * np.sin(ang), height + rng.uniform(-.5, .5)])
        R, t = look_at(eye, rng.uniform(-1, 1, 3) * [1, 1, 0])
        cams.append(Camera.from_params(f"cam{c}", (1920, 1080), rng.uniform(900, 1400), R, t))
    return cams


def plane_camera(cam: Camera, scale: float, yaw: float, shift: np.ndarray) -> Camera:
    """The camera in a frame ``X_p = scale * Rz(yaw) X + (shift, 0)``."""
    Rz = rot_z(yaw)
    center = scale * Rz @ cam.center + np.r_[shift, 0.0]
    R = cam.R @ Rz.T
    return cam.with_(R=R, t=-R @ center, time_offset=0.0, time_rate=1.0)


def make_scene(*, n_cams: int = 3, n_persons: int = 3, n_ref_frames: int = 900,
               fps: list[float] | None = None, offsets: list[float] | None = None,
               rates: list[float] | None = None, noise_px: float = 1.0,
               outlier_rate: float = 0.01, scale_error: float = 0.0, path: str = "random",
               period: float = 8.0, variability: float = 0.3, track_ids: bool = True,
               seed: int = 0) -> AlignScene:
    """A rig seeing ``n_persons`` walkers; camera c's frame k shows reference frame
    ``rates[c] * k + offsets[c]`` (offsets[0] = 0, rates[0] = 1)."""
    rng = np.random.default_rng(seed)
    fps = fps or [30.0] * n_cams
    offsets = offsets or [0.0] * n_cams
    rates = rates or [fps[0] / f for f in fps]
    dur = (n_ref_frames + 2 * max(abs(o) for o in offsets) + 10) / fps[0] * 1.2
    t0 = max(abs(o) for o in offsets) / fps[0] + 1.0
    if path == "loop":
        # radius for a walking pace of 1.3 m/s around the (1.3 x 1) ellipse
        walkers = []
        for _ in range(n_persons):
            per = period * rng.uniform(0.9, 1.1)
            walkers.append(loop_path(rng, per, variability, radius=1.3 * per / (2.3 * np.pi)))
    else:
        walkers = [smooth_path(rng, dur + 2 * t0, area=7.0) for _ in range(n_persons)]
    cams = ring_cameras(n_cams, rng)
    tracks, truth, plane, pfw = [], [], [], []
    for c, cam in enumerate(cams):
        n_frames = int(n_ref_frames / rates[c])
        ref_frame = rates[c] * np.arange(n_frames) + offsets[c]
        secs = t0 + ref_frame / fps[0]
        kp = np.full((n_frames, n_persons, 17, 3), np.nan)
        for p, w in enumerate(walkers):
            xy = w(secs)
            for side, j in ((-1, 15), (1, 16)):
                X = np.c_[xy + side * 0.1 * np.array([0.0, 1.0]), np.full(n_frames, FOOT)]
                uv = cam.project(X) + rng.normal(0, noise_px, (n_frames, 2))
                out = rng.random(n_frames) < outlier_rate
                uv[out] += rng.normal(0, 80, (out.sum(), 2))
                inside = (uv[:, 0] > 0) & (uv[:, 0] < 1919) & (uv[:, 1] > 0) & (uv[:, 1] < 1079)
                kp[inside, p, j, :2] = uv[inside]
                kp[inside, p, j, 2] = 0.9
        ids = np.where(np.isfinite(kp[..., 0]).any(-1), np.arange(n_persons)[None], -1)
        perm = rng.permutation(n_persons)  # slot order differs between cameras
        kp, ids = kp[:, perm], ids[:, perm]
        tracks.append(Tracks(cam.name, kp, "coco17", (1920, 1080), fps[c],
                             track_ids=ids if track_ids else None))
        truth.append(cam.with_(fps=fps[c], time_offset=offsets[c], time_rate=rates[c]))
        s = 1.0 + (rng.normal(0, scale_error) if c else 0.0)
        yaw, shift = rng.uniform(0, 2 * np.pi), rng.uniform(-5, 5, 2)
        plane.append(plane_camera(cam, s, yaw, shift))
        pfw.append((s, yaw, shift))
    return AlignScene(tracks, truth, plane, pfw)


def _rx(a: float) -> np.ndarray:
    c, s = np.cos(a), np.sin(a)
    return np.array([[1.0, 0, 0], [0, c, -s], [0, s, c]])


def stage1_like(cam: Camera, rng: np.random.Generator, *, errors: bool) -> Camera:
    """The true camera in its own plane frame, with stage-I-like errors when asked:
    focal 3 %, tilt 1 deg, metric scale 5 % (1 s.d.)."""
    scale = 1.0 + (rng.normal(0, 0.05) if errors else 0.0)
    pc = plane_camera(cam, scale, rng.uniform(0, 2 * np.pi), rng.uniform(-5, 5, 2))
    if not errors:
        return pc
    K = pc.K.copy()
    K[:2, :2] *= 1.0 + rng.normal(0, 0.03)
    R = _rx(np.radians(rng.normal(0, 1.0))) @ pc.R
    return pc.with_(K=K, R=R, t=-R @ pc.center)


def cut_windows(tracks: list[Tracks], truth: Calibration, frac: float,
                rng: np.random.Generator) -> tuple[list[Tracks], Calibration]:
    """Cut every camera to ``frac`` of the reference's length with start times spread so that
    offsets to the reference span +-50 % of the window."""
    cams = truth.cameras
    n_ref = tracks[0].n_frames
    L = int(frac * n_ref)  # window length in reference frames
    w_ref = (n_ref - L) // 2
    out_t, out_c = [], []
    for tr, cam in zip(tracks, cams, strict=True):
        lo = max(0.0, w_ref - 0.5 * L, cam.time_offset)
        hi = min(w_ref + 0.5 * L, cam.time_offset + cam.time_rate * tr.n_frames - L)
        w = w_ref if cam.name == truth.reference_camera else rng.uniform(lo, max(lo, hi))
        k0 = int(np.ceil((w - cam.time_offset) / cam.time_rate))
        n = int(L / cam.time_rate)
        sl = slice(k0, k0 + n)
        out_t.append(tr.with_(keypoints=tr.keypoints[sl],
                              track_ids=None if tr.track_ids is None else tr.track_ids[sl],
                              timestamps=None if tr.timestamps is None else tr.timestamps[sl]))
        out_c.append(cam.with_(time_offset=cam.time_rate * k0 + cam.time_offset - w_ref))
    return out_t, Calibration(out_c, reference_camera=truth.reference_camera)


def simulated_windows(preset: str, seed: int, *, errors: bool
                      ) -> tuple[list[Tracks], Calibration, list[Camera]]:
    """The stage II-IV benchmark's scene: an 80 s simulator preset at 25/30 fps in turn with
    clock drift, cut to windows of 45 % whose offsets span +-50 %; returns the tracks, the
    true calibration of the windows and stage-I-like plane cameras."""
    from cascalib.simulate import simulate  # the simulator is only needed here

    sc = simulate(preset, seed=seed, **{"timing.fps": (25.0, 30.0), "timing.fps_in_turn": True,
                                        "timing.drift_sd": 1e-4, "timing.max_offset_s": 1.0,
                                        "duration_s": 80.0})
    rng = np.random.default_rng(seed)
    tracks, truth = cut_windows(sc.tracks, sc.truth, 0.45, rng)
    return tracks, truth, [stage1_like(c, rng, errors=errors) for c in truth.cameras]


def paper_walker_scene(offset: int, subject: int, *, n_frames: int = 1000, max_offset: int = 200
                       ) -> tuple[list[Tracks], list[Camera], float]:
    """The paper's sync experiment in the full simulator: one person (26 joints, detector
    noise, missed and swapped joints) walking laps of a circle of 1.66 m radius at 1.3 m/s
    (8 s per lap) whose radius wobbles by 0.15 m s.d. from lap to lap, 2 cameras at 50 fps;
    the second video starts ``offset`` frames (at most ``max_offset``) later. Returns the
    tracks, stage-I-like plane cameras (focal 3 %, tilt 1 deg, scale 5 %) and the true offset
    of the second camera."""
    from cascalib.simulate import simulate  # the simulator is only needed here

    sc = simulate("periodic", seed=100 + subject, **{
        "people.n_persons": 1, "people.speed_range": (1.3, 1.3),
        "people.circle_radius": (1.66, 1.66), "people.circle_wobble_m": 0.15,
        "people.action_prob": 0.0, "rig.n_cameras": 2, "timing.fps": (50.0,),
        "timing.max_offset_s": 0.0, "timing.drift_sd": 0.0, "timing.late_start_prob": 0.0,
        "timing.early_stop_prob": 0.0, "duration_s": (n_frames + max_offset) / 50 + 1})
    (ta, tb), (ca, cb) = sc.tracks, sc.truth.cameras
    cut = [slice(0, n_frames), slice(offset, offset + n_frames)]
    tracks = [t.with_(keypoints=t.keypoints[sl], timestamps=None,
                      track_ids=None if t.track_ids is None else t.track_ids[sl])
              for t, sl in zip((ta, tb), cut, strict=True)]
    rng = np.random.default_rng(subject)
    plane = [stage1_like(c, rng, errors=True) for c in (ca, cb)]
    return tracks, plane, cb.time_offset + offset * cb.time_rate - ca.time_offset
