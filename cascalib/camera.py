"""Pinhole camera with OpenCV lens distortion, in cascalib's world frame.

Conventions (the same in every file format cascalib writes natively):

* ``x_cam = R @ x_world + t`` (``R``, ``t`` are *cam_from_world*); metres;
* world z points up and the ground is the plane z = 0;
* camera axes as in OpenCV: x right, y down, z forward;
* pixels with the origin at the centre of the top-left pixel;
* distortion ``(k1, k2, p1, p2, k3)`` as in OpenCV's ``projectPoints``.

Time: frame ``k`` of this camera shows the scene at reference-camera frame
``time_rate * k + time_offset`` (the reference camera has offset 0 and rate 1).
"""

from __future__ import annotations

from dataclasses import dataclass, replace
from typing import Any

import cv2
import numpy as np
from numpy.typing import ArrayLike, NDArray

__all__ = ["Camera", "distort_normalized", "look_at"]


def _undistort_iter(pts: NDArray[np.float64], K: NDArray[np.float64], dist: NDArray[np.float64],
                    crit: tuple[int, int, float]) -> NDArray[np.float64]:
    # OpenCV 4 has a separate undistortPointsIter; OpenCV 5 takes the criteria in undistortPoints.
    if hasattr(cv2, "undistortPointsIter"):
        return cv2.undistortPointsIter(pts, K, dist, np.eye(3), np.eye(3), crit)
    return np.asarray(cv2.undistortPoints(pts, K, dist, None, np.eye(3), np.eye(3), crit),
                      dtype=np.float64)


def distort_normalized(xy: NDArray[np.float64], dist: NDArray[np.float64]) -> NDArray[np.float64]:
    """Apply OpenCV's radial-tangential model to normalised image coordinates, shape (..., 2)."""
    k1, k2, p1, p2, k3 = dist
    x, y = xy[..., 0], xy[..., 1]
    r2 = x * x + y * y
    radial = 1 + r2 * (k1 + r2 * (k2 + r2 * k3))
    xd = x * radial + 2 * p1 * x * y + p2 * (r2 + 2 * x * x)
    yd = y * radial + p1 * (r2 + 2 * y * y) + 2 * p2 * x * y
    return np.stack([xd, yd], axis=-1)


@dataclass(frozen=True, eq=False)
class Camera:
    """One calibrated camera.

    Parameters
    ----------
    name : str
        Camera name.
    image_size : (int, int)
        (width, height) in pixels.
    K : ndarray, shape (3, 3)
        Intrinsic matrix ``[[fx, s, cx], [0, fy, cy], [0, 0, 1]]``.
    dist : ndarray, shape (5,)
        OpenCV distortion ``(k1, k2, p1, p2, k3)``.
    R : ndarray, shape (3, 3)
        Rotation cam_from_world.
    t : ndarray, shape (3,)
        Translation cam_from_world (metres).
    fps : float, optional
        Nominal frame rate.
    time_offset, time_rate : float
        Frame ``k`` shows reference frame ``time_rate * k + time_offset``.
    """

    name: str
    image_size: tuple[int, int]
    K: NDArray[np.float64]
    dist: NDArray[np.float64]
    R: NDArray[np.float64]
    t: NDArray[np.float64]
    fps: float | None = None
    time_offset: float = 0.0
    time_rate: float = 1.0

    def __post_init__(self) -> None:
        object.__setattr__(self, "image_size", tuple(int(v) for v in self.image_size))
        object.__setattr__(self, "K", np.asarray(self.K, dtype=np.float64).reshape(3, 3))
        d = np.zeros(5)
        given = np.asarray(self.dist if self.dist is not None else [], dtype=np.float64).ravel()
        d[: min(5, given.size)] = given[:5]
        object.__setattr__(self, "dist", d)
        object.__setattr__(self, "R", np.asarray(self.R, dtype=np.float64).reshape(3, 3))
        object.__setattr__(self, "t", np.asarray(self.t, dtype=np.float64).reshape(3))

    # -- constructors -----------------------------------------------------------------------
    @classmethod
    def from_params(cls, name: str, image_size: tuple[int, int], f: float | tuple[float, float],
                    R: ArrayLike, t: ArrayLike, c: tuple[float, float] | None = None,
                    dist: ArrayLike | None = None, **kw: Any) -> Camera:
        """Build from a focal length (one or (fx, fy)), principal point (default: image centre)."""
        fx, fy = (f, f) if np.isscalar(f) else f  # type: ignore[misc]
        w, h = image_size
        cx, cy = c if c is not None else ((w - 1) / 2.0, (h - 1) / 2.0)
        K = np.array([[fx, 0.0, cx], [0.0, fy, cy], [0.0, 0.0, 1.0]])
        return cls(name, image_size, K, np.zeros(5) if dist is None else np.asarray(dist),
                   np.asarray(R), np.asarray(t), **kw)

    def with_(self, **changes: Any) -> Camera:
        """A copy with some fields replaced."""
        return replace(self, **changes)

    # -- parameters -------------------------------------------------------------------------
    @property
    def fx(self) -> float:
        return float(self.K[0, 0])

    @property
    def fy(self) -> float:
        return float(self.K[1, 1])

    @property
    def focal(self) -> float:
        """Mean focal length in pixels."""
        return 0.5 * (self.fx + self.fy)

    @property
    def principal_point(self) -> NDArray[np.float64]:
        return self.K[:2, 2].copy()

    @property
    def image_centre(self) -> NDArray[np.float64]:
        """Centre of the image in pixels (pixel centres at integers): where stage I, which cannot
        tell the principal point, puts it."""
        w, h = self.image_size
        return np.array([(w - 1) / 2.0, (h - 1) / 2.0])

    def with_centred_principal_point(self) -> Camera:
        """A copy with the principal point at :attr:`image_centre`, the rest unchanged."""
        K = self.K.copy()
        K[:2, 2] = self.image_centre
        return self.with_(K=K)

    @property
    def center(self) -> NDArray[np.float64]:
        """Camera centre in world coordinates, ``-R.T @ t``."""
        return -self.R.T @ self.t

    @property
    def P(self) -> NDArray[np.float64]:
        """3x4 projection matrix ``K [R | t]`` (ignores distortion)."""
        return self.K @ np.hstack([self.R, self.t[:, None]])

    @property
    def has_distortion(self) -> bool:
        return bool(np.any(self.dist != 0))

    # -- geometry ---------------------------------------------------------------------------
    def world_to_cam(self, X: ArrayLike) -> NDArray[np.float64]:
        """Points (..., 3) from world to camera coordinates."""
        X = np.asarray(X, dtype=np.float64)
        return X @ self.R.T + self.t

    def project(self, X: ArrayLike) -> NDArray[np.float64]:
        """Project world points, shape (..., 3), to pixels, shape (..., 2), with distortion.

        Points behind the camera (z <= 0) and NaN inputs give NaN.
        """
        Xc = self.world_to_cam(X)
        z = Xc[..., 2:3]
        with np.errstate(invalid="ignore", divide="ignore"):
            xy = np.where(z > 0, Xc[..., :2] / z, np.nan)
        if self.has_distortion:
            xy = distort_normalized(xy, self.dist)
        return self._normalized_to_pixels(xy)

    def _normalized_to_pixels(self, xy: NDArray[np.float64]) -> NDArray[np.float64]:
        K = self.K
        u = K[0, 0] * xy[..., 0] + K[0, 1] * xy[..., 1] + K[0, 2]
        v = K[1, 1] * xy[..., 1] + K[1, 2]
        return np.stack([u, v], axis=-1)

    def undistort(self, uv: ArrayLike) -> NDArray[np.float64]:
        """Pixels (..., 2) to ideal (distortion-free) normalised coordinates (..., 2).

        Uses OpenCV's iterative inversion with a tight stopping rule (the default five iterations
        are not enough for strong wide-angle distortion).
        """
        uv = np.asarray(uv, dtype=np.float64)
        shape = uv.shape
        flat = uv.reshape(-1, 2)
        out = np.full_like(flat, np.nan)
        ok = np.isfinite(flat[:, 0]) & np.isfinite(flat[:, 1])  # .all(1): a slow short-axis reduce
        if ok.any():
            # distorted normalised coordinates, K inverted by hand (exact with skew; a tall
            # (N, 3) @ (3, 3) matmul is several times slower)
            K = self.K
            y = (flat[ok, 1] - K[1, 2]) / K[1, 1]
            x = (flat[ok, 0] - K[0, 2] - K[0, 1] * y) / K[0, 0]
            xy = np.stack([x, y], axis=-1)
            if self.has_distortion:
                # Iterate with an identity K: OpenCV's undistortPoints ignores K[0, 1] (skew),
                # which would make undistort() disagree with project() for skewed cameras.
                crit = (cv2.TERM_CRITERIA_COUNT | cv2.TERM_CRITERIA_EPS, 200, 1e-14)
                xy = _undistort_iter(xy.reshape(-1, 1, 2), np.eye(3), self.dist,
                                     crit).reshape(-1, 2)
            out[ok] = xy
        return out.reshape(shape)

    def undistort_pixels(self, uv: ArrayLike) -> NDArray[np.float64]:
        """Pixels (..., 2) to the pixels an ideal pinhole camera with the same K would see."""
        return self._normalized_to_pixels(self.undistort(uv))

    def rays(self, uv: ArrayLike) -> NDArray[np.float64]:
        """Unit ray directions in world coordinates, shape (..., 3), for pixels (..., 2).

        The rays start at :attr:`center`.
        """
        xy = self.undistort(uv)
        d_cam = np.concatenate([xy, np.ones(xy.shape[:-1] + (1,))], axis=-1)
        d = d_cam @ self.R  # R.T @ d for each row
        return d / np.linalg.norm(d, axis=-1, keepdims=True)

    def backproject_to_plane(self, uv: ArrayLike, z: float = 0.0) -> NDArray[np.float64]:
        """Intersect the rays of pixels (..., 2) with the horizontal plane ``Z = z``.

        Returns world points (..., 3); NaN where the ray is parallel to the plane or meets it
        behind the camera.
        """
        d = self.rays(uv)
        c = self.center
        with np.errstate(invalid="ignore", divide="ignore"):
            s = (z - c[2]) / d[..., 2]
            s = np.where(s > 0, s, np.nan)
        return c + s[..., None] * d

    def reference_frame(self, k: ArrayLike) -> NDArray[np.float64]:
        """Reference-camera frame shown by this camera's frame(s) ``k``."""
        return self.time_rate * np.asarray(k, dtype=np.float64) + self.time_offset

    def __repr__(self) -> str:
        c = self.center
        return (f"Camera({self.name!r}, {self.image_size[0]}x{self.image_size[1]}, "
                f"f={self.focal:.1f}, C=({c[0]:.2f}, {c[1]:.2f}, {c[2]:.2f}), "
                f"offset={self.time_offset:g}, rate={self.time_rate:g})")


def look_at(eye: ArrayLike, target: ArrayLike, up: ArrayLike = (0.0, 0.0, 1.0)
            ) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Rotation and translation (cam_from_world) of a camera at ``eye`` looking at ``target``.

    The image's "up" is as close as possible to the world's ``up``.
    """
    eye = np.asarray(eye, dtype=np.float64)
    z = np.asarray(target, dtype=np.float64) - eye
    z /= np.linalg.norm(z)
    x = np.cross(z, np.asarray(up, dtype=np.float64))
    if np.linalg.norm(x) < 1e-9:  # looking straight along "up": pick any image x axis
        x = np.cross(z, [0.0, 1.0, 0.0])
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    R = np.stack([x, y, z])
    return R, -R @ eye
