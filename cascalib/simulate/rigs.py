"""Camera rigs: where the cameras stand, where they look, and their intrinsics.

A :class:`RigConfig` is a parameter set; :data:`RIG_PRESETS` holds the realistic ones (indoor lab
ring, outdoor terrace, high security cameras, a sports field, phones on tripods). Every camera
looks at a point of the capture area (:func:`cascalib.camera.look_at`) with a small roll, and
draws its own field of view, principal point offset, image size and lens distortion.
"""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from pydantic import BaseModel, ConfigDict, Field

from cascalib.camera import Camera, look_at
from cascalib.geometry import rot_z

__all__ = ["RigConfig", "RIG_PRESETS", "make_rig", "valid_radius"]


class RigConfig(BaseModel):
    """Camera placement and intrinsics, drawn per camera from these ranges."""

    model_config = ConfigDict(extra="forbid")

    n_cameras: int = Field(default=4, ge=1, le=32, description="Number of cameras.")
    layout: str = Field(
        default="ring", pattern="^(ring|sides)$",
        description="'ring': evenly spread azimuths around the area centre (with jitter); "
        "'sides': cameras on the two long sides of a field, facing it.")
    height_range: tuple[float, float] = Field(default=(2.0, 3.0), description="Camera height (m).")
    distance_range: tuple[float, float] = Field(
        default=(4.0, 6.0), description="Horizontal distance from the area centre (m).")
    azimuth_jitter_deg: float = Field(default=15.0, ge=0, description="Azimuth jitter (deg).")
    target_jitter: float = Field(
        default=0.15, ge=0, description="s.d. of the look-at point as a fraction of the area size.")
    target_height: float = Field(default=1.0, description="Height of the look-at point (m).")
    fov_range_deg: tuple[float, float] = Field(
        default=(50.0, 90.0), description="Field of view across the long image side (deg).")
    image_sizes: tuple[tuple[int, int], ...] = Field(
        default=((1920, 1080),), description="Landscape (W, H) sizes to choose from.")
    portrait_prob: float = Field(default=0.0, ge=0, le=1, description="Probability of portrait.")
    principal_offset: float = Field(
        default=0.03, ge=0, lt=0.5, description="Max principal point offset from the image centre, "
        "as a fraction of the image size.")
    radial_distortion: float = Field(
        default=0.0, ge=0, le=0.5,
        description="Max |k1| (barrel, k1 < 0); k2 is drawn at a fifth of "
        "it; 0 disables distortion.")
    radial_distortion_min: float = Field(
        default=0.2, ge=0, le=1,
        description="Least |k1| as a fraction of `radial_distortion` (|k1| is drawn uniformly "
        "between them): near 1 for lenses that all bend alike, such as one webcam model.")
    tangential_distortion: float = Field(
        default=0.0, ge=0, le=0.01, description="s.d. of p1, p2.")
    roll_sd_deg: float = Field(default=2.0, ge=0, description="s.d. of the camera roll (deg).")


#: Realistic rigs. The capture area each is meant for is set by the scene preset.
RIG_PRESETS: dict[str, RigConfig] = {
    "lab_ring": RigConfig(n_cameras=6, height_range=(2.0, 3.0), distance_range=(4.0, 6.0),
                          fov_range_deg=(50, 90), image_sizes=((1920, 1080), (1280, 720))),
    "terrace": RigConfig(n_cameras=4, height_range=(2.0, 3.0), distance_range=(7.0, 9.0),
                         fov_range_deg=(55, 80), image_sizes=((640, 480), (1280, 720)),
                         azimuth_jitter_deg=20, target_jitter=0.08),
    "security": RigConfig(n_cameras=4, height_range=(6.0, 10.0), distance_range=(6.0, 11.0),
                          fov_range_deg=(60, 100), image_sizes=((1920, 1080), (2560, 1440)),
                          radial_distortion=0.15, target_height=0.5),
    "sports": RigConfig(n_cameras=6, layout="sides", height_range=(8.0, 15.0),
                        distance_range=(18.0, 26.0), fov_range_deg=(40, 60),
                        image_sizes=((3840, 2160), (1920, 1080)), target_jitter=0.1),
    "phones": RigConfig(n_cameras=4, height_range=(1.2, 1.7), distance_range=(4.0, 7.0),
                        fov_range_deg=(60, 80), image_sizes=((1920, 1080), (1280, 720)),
                        portrait_prob=0.5, radial_distortion=0.12,
                        tangential_distortion=0.002, roll_sd_deg=3.0),
}


def _positions(cfg: RigConfig, area: tuple[float, float], rng: np.random.Generator
               ) -> NDArray[np.float64]:
    """Camera centres, shape (n_cameras, 3)."""
    n = cfg.n_cameras
    dist = rng.uniform(*cfg.distance_range, n)
    height = rng.uniform(*cfg.height_range, n)
    jitter = np.deg2rad(cfg.azimuth_jitter_deg) * rng.uniform(-1, 1, n)
    if cfg.layout == "ring":
        az = rng.uniform(0, 2 * np.pi) + 2 * np.pi * np.arange(n) / n + jitter
        xy = dist[:, None] * np.stack([np.cos(az), np.sin(az)], -1)
    else:  # two long sides (y = +-), spread along x
        side = np.where(np.arange(n) % 2 == 0, -1.0, 1.0)
        k = np.arange(n) // 2
        n_side = (n + 1) // 2
        x = (k + 0.5) / n_side - 0.5
        x = x * area[0] * 0.8 + jitter * area[0] * 0.05
        xy = np.stack([x, side * dist], -1)
    return np.column_stack([xy, height])


def _intrinsics(cfg: RigConfig, rng: np.random.Generator
                ) -> tuple[tuple[int, int], float, tuple[float, float], NDArray[np.float64]]:
    """Image size, focal (px), principal point and distortion of one camera."""
    w, h = cfg.image_sizes[int(rng.integers(len(cfg.image_sizes)))]
    if rng.random() < cfg.portrait_prob:
        w, h = h, w
    fov = np.deg2rad(rng.uniform(*cfg.fov_range_deg))
    f = 0.5 * max(w, h) / np.tan(fov / 2)
    off = cfg.principal_offset * rng.uniform(-1, 1, 2) * np.array([w, h])
    c = ((w - 1) / 2 + off[0], (h - 1) / 2 + off[1])
    dist = np.zeros(5)
    if cfg.radial_distortion > 0:
        k1 = -rng.uniform(cfg.radial_distortion_min, 1.0) * cfg.radial_distortion
        dist[0], dist[1] = k1, -0.2 * k1 * rng.uniform(0, 1)
    if cfg.tangential_distortion > 0:
        dist[2:4] = rng.normal(0, cfg.tangential_distortion, 2)
    return (int(w), int(h)), float(f), c, dist


def make_rig(cfg: RigConfig, area: tuple[float, float], rng: np.random.Generator,
             names: list[str] | None = None) -> list[Camera]:
    """Draw the cameras of a rig around a capture area centred on the origin.

    Parameters
    ----------
    cfg : RigConfig
    area : (float, float)
        Capture area size (x, y) in metres.
    rng : numpy.random.Generator
    names : list of str, optional
        Camera names (default ``cam0``, ``cam1`` ...).

    Returns
    -------
    list of Camera
        Without time fields (those come from :mod:`cascalib.simulate.timing`).
    """
    names = names or [f"cam{i}" for i in range(cfg.n_cameras)]
    centres = _positions(cfg, area, rng)
    cams = []
    for name, eye in zip(names, centres, strict=True):
        target = np.array([*(rng.normal(0, cfg.target_jitter, 2) * np.asarray(area)),
                           cfg.target_height])
        R, _ = look_at(eye, target)
        roll = np.deg2rad(rng.normal(0, cfg.roll_sd_deg))
        R = rot_z(roll) @ R  # roll about the optical (camera z) axis
        size, f, c, dist = _intrinsics(cfg, rng)
        cams.append(Camera.from_params(name, size, f, R, -R @ eye, c=c, dist=dist))
    return cams


def valid_radius(cam: Camera) -> float:
    """Largest normalised (undistorted) image radius the lens model maps one-to-one.

    Points farther off-axis than the image corners (with a margin) are not seen; without this
    check the distortion polynomial would fold points far outside the field of view back into
    the image.
    """
    w, h = cam.image_size
    corners = np.array([[0, 0], [w - 1, 0], [0, h - 1], [w - 1, h - 1]], dtype=np.float64)
    r = np.linalg.norm(cam.undistort(corners), axis=-1)
    limit = 1.15 * float(np.nanmax(r))
    k1, k2 = cam.dist[0], cam.dist[1]
    if k1 < 0:
        # d(r (1 + k1 r^2 + k2 r^4))/dr > 0 needs 1 + 3 k1 r^2 + 5 k2 r^4 > 0.
        rr = np.linspace(0, limit, 200)
        ok = 1 + 3 * k1 * rr**2 + 5 * k2 * rr**4 > 0.2
        if not ok.all():
            limit = float(rr[np.argmin(ok)])
    return limit
