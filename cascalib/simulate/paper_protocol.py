"""The supplement's single-view simulation protocol (CasCalib supplement, "Simulations").

Following Fei et al. (2021), each trial is one 1920x1080 camera with focal length 960 px (a 90
degree horizontal field of view, principal point at the image centre) above a random ground
plane, and ``n_people`` ankle-centre / shoulder-centre detection pairs of people standing upright
on it. The shoulder centre is the ankle centre plus ``h * n`` (``n`` the ground normal), with
``h ~ N(height, height_sd)`` -- exactly the model the DLT of the supplement inverts, so ``h``
here is the ankle-to-shoulder-centre distance. Zero-mean Gaussian pixel noise of s.d.
``noise_px`` is added to every detection.

The three sweeps of the supplement are in :data:`SWEEPS`:

* measurement noise: ``h = 1.6`` fixed, 3 people, noise 0.1 ... 5 px (Table "Measurement noise");
* height variation: noise 0.5 px, ``h ~ N(1.7, sd)`` with sd 0.05 ... 0.25 (Table "Height");
  the number of people is not stated in the paper, we use 3 as in the noise sweep;
* number of people: noise 0.5 px, sd 0.1, 5 ... 100 people (Table "Number of people").

The paper runs 5000 trials per setting; :func:`errors` computes its metrics.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cascalib.camera import Camera, look_at

__all__ = ["ProtocolSample", "sample", "SWEEPS", "sweep", "errors", "IMAGE_SIZE", "FOCAL"]

IMAGE_SIZE = (1920, 1080)
FOCAL = 960.0

#: The supplement's three sweeps: the varied parameter, its values, and the fixed ones.
SWEEPS: dict[str, dict[str, Any]] = {
    "measurement_noise": {"vary": "noise_px", "values": (0.1, 0.2, 0.5, 1.0, 2.0, 5.0),
                          "fixed": {"n_people": 3, "height": 1.6, "height_sd": 0.0},
                          "assumed_height": 1.6},
    "height_variation": {"vary": "height_sd", "values": (0.05, 0.1, 0.15, 0.2, 0.25),
                         "fixed": {"n_people": 3, "noise_px": 0.5, "height": 1.7},
                         "assumed_height": 1.7},
    "number_of_people": {"vary": "n_people", "values": (5, 10, 20, 50, 100),
                         "fixed": {"noise_px": 0.5, "height": 1.7, "height_sd": 0.1},
                         "assumed_height": 1.7},
}


@dataclass(frozen=True)
class ProtocolSample:
    """One trial of the single-view protocol.

    Attributes
    ----------
    ankles, shoulders : ndarray, shape (N, 2)
        Noisy ankle-centre and shoulder-centre pixels.
    ankles_true, shoulders_true : ndarray, shape (N, 2)
        The same without noise.
    heights : ndarray, shape (N,)
        True ankle-to-shoulder-centre distances (m).
    focal : float
        True focal length (px), 960.
    principal_point : ndarray, shape (2,)
        True principal point (image centre).
    image_size : (int, int)
    normal_cam : ndarray, shape (3,)
        Unit ground normal in camera coordinates, pointing from the ground up.
    camera_height : float
        Distance of the camera centre above the ground (m).
    ankles3d, shoulders3d : ndarray, shape (N, 3)
        True 3D points in camera coordinates (m).
    camera : Camera
        The true camera in a z-up world with the ground at z = 0.
    """

    ankles: NDArray[np.float64]
    shoulders: NDArray[np.float64]
    ankles_true: NDArray[np.float64]
    shoulders_true: NDArray[np.float64]
    heights: NDArray[np.float64]
    focal: float
    principal_point: NDArray[np.float64]
    image_size: tuple[int, int]
    normal_cam: NDArray[np.float64]
    camera_height: float
    ankles3d: NDArray[np.float64]
    shoulders3d: NDArray[np.float64]
    camera: Camera


def _random_camera(rng: np.random.Generator) -> Camera:
    """A camera 2-6 m above the ground, tilted down 5-40 degrees, rolled up to 10 degrees."""
    h = rng.uniform(2.0, 6.0)
    tilt = np.deg2rad(rng.uniform(5.0, 40.0))
    eye = np.array([0.0, 0.0, h])
    target = eye + np.array([np.cos(tilt), 0.0, -np.sin(tilt)])
    R, _ = look_at(eye, target)
    roll = np.deg2rad(rng.uniform(-10.0, 10.0))
    c, s = np.cos(roll), np.sin(roll)
    R = np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]]) @ R
    return Camera.from_params("sim", IMAGE_SIZE, FOCAL, R, -R @ eye)


def _draw_people(cam: Camera, heights: NDArray[np.float64], rng: np.random.Generator,
                 max_distance: float = 25.0) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """World ankle and shoulder points (N, 3) of people fully inside the image."""
    n = heights.size
    w, h = cam.image_size
    ankles = np.empty((n, 3))
    filled = 0
    for _ in range(200):  # rejection sampling; a handful of rounds suffice
        k = n - filled
        uv = rng.uniform([0, 0], [w - 1, h - 1], (4 * k + 8, 2))
        g = cam.backproject_to_plane(uv)
        d = np.linalg.norm(g[:, :2] - cam.center[:2], axis=1)
        sh = cam.project(g + np.array([0.0, 0.0, 1.0]) * heights[filled:].max())
        ok = (np.isfinite(g[:, 0]) & (d < max_distance) & (sh[:, 0] >= 0) & (sh[:, 0] <= w - 1)
              & (sh[:, 1] >= 0) & (sh[:, 1] <= h - 1))
        take = g[ok][:k]
        ankles[filled:filled + len(take)] = take
        filled += len(take)
        if filled == n:
            break
    else:  # pragma: no cover - only for absurd cameras
        raise RuntimeError("could not place people in view")
    shoulders = ankles + heights[:, None] * np.array([0.0, 0.0, 1.0])
    return ankles, shoulders


def sample(n_people: int = 3, noise_px: float = 0.5, height_sd: float = 0.0, *,
           height: float = 1.7, rng: np.random.Generator | int | None = None) -> ProtocolSample:
    """Draw one trial of the protocol.

    Parameters
    ----------
    n_people : int
        Number of ankle/shoulder pairs.
    noise_px : float
        s.d. of the Gaussian pixel noise.
    height_sd : float
        s.d. of the person heights (m); 0 gives everyone ``height``.
    height : float
        Mean ankle-to-shoulder-centre height (m).
    rng : Generator or seed

    Returns
    -------
    ProtocolSample
    """
    rng = np.random.default_rng(rng)
    cam = _random_camera(rng)
    heights = height + height_sd * rng.standard_normal(n_people)
    a_w, s_w = _draw_people(cam, heights, rng)
    a_uv, s_uv = cam.project(a_w), cam.project(s_w)
    normal_cam = cam.R @ np.array([0.0, 0.0, 1.0])
    return ProtocolSample(
        ankles=a_uv + noise_px * rng.standard_normal(a_uv.shape),
        shoulders=s_uv + noise_px * rng.standard_normal(s_uv.shape),
        ankles_true=a_uv, shoulders_true=s_uv, heights=heights, focal=FOCAL,
        principal_point=cam.principal_point, image_size=IMAGE_SIZE, normal_cam=normal_cam,
        camera_height=float(cam.center[2]), ankles3d=cam.world_to_cam(a_w),
        shoulders3d=cam.world_to_cam(s_w), camera=cam)


def sweep(name: str, n_trials: int, rng: np.random.Generator | int | None = None
          ) -> dict[Any, list[ProtocolSample]]:
    """All trials of one of the supplement's sweeps: ``{value: [ProtocolSample, ...]}``."""
    spec = SWEEPS[name]
    rng = np.random.default_rng(rng)
    out: dict[Any, list[ProtocolSample]] = {}
    for value in spec["values"]:
        kw = {**spec["fixed"], spec["vary"]: value}
        out[value] = [sample(rng=rng, **kw) for _ in range(n_trials)]
    return out


def errors(truth: ProtocolSample, focal: float, normal_cam: NDArray[np.float64],
           camera_height: float, ankles3d: NDArray[np.float64] | None = None
           ) -> dict[str, float]:
    """The supplement's metrics for one trial.

    Returns
    -------
    dict
        ``focal_pct`` 100 |f - f_gt| / f_gt; ``normal_deg`` angle between normals;
        ``height_pct`` (the paper's rho%) 100 |rho - rho_gt| / rho_gt; ``points_pct`` (X%)
        mean over people of 100 |X - X_gt| / |X_gt| for the ankle points, when given.
    """
    n = np.asarray(normal_cam, dtype=np.float64)
    n = n / np.linalg.norm(n)
    cos = float(np.clip(n @ truth.normal_cam, -1.0, 1.0))
    out = {
        "focal_pct": 100 * abs(focal - truth.focal) / truth.focal,
        "normal_deg": float(np.degrees(np.arccos(cos))),
        "height_pct": 100 * abs(camera_height - truth.camera_height) / truth.camera_height,
    }
    if ankles3d is not None:
        d = np.linalg.norm(np.asarray(ankles3d) - truth.ankles3d, axis=1)
        out["points_pct"] = float(100 * np.mean(d / np.linalg.norm(truth.ankles3d, axis=1)))
    return out
