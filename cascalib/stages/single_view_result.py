"""The result of Stage I for one camera, and the camera it implies in its own plane frame."""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cascalib.camera import Camera
from cascalib.stages.single_view_solver import GroundModel

__all__ = ["SingleViewResult", "plane_frame_rotation"]

F64 = NDArray[np.float64]


def plane_frame_rotation(normal_cam: F64) -> F64:
    """Rotation cam_from_world of the plane frame: world z = ``normal_cam`` (up), world x = the
    optical axis projected on the ground, world y = z cross x.

    Parameters
    ----------
    normal_cam : ndarray, shape (3,)
        Unit ground normal in camera coordinates, pointing up.

    Returns
    -------
    ndarray, shape (3, 3)
        ``R`` with ``x_cam = R x_world + t``; its columns are the world axes in camera coordinates.
    """
    z = np.asarray(normal_cam, dtype=np.float64)
    z = z / np.linalg.norm(z)
    axis = np.array([0.0, 0.0, 1.0])
    x = axis - (axis @ z) * z
    if np.linalg.norm(x) < 1e-9:
        # looking straight along the normal: any horizontal direction; take the image x axis
        x = np.array([1.0, 0.0, 0.0]) - z[0] * z
    x /= np.linalg.norm(x)
    y = np.cross(z, x)
    return np.stack([x, y, z], axis=1)


@dataclass(frozen=True, eq=False)
class SingleViewResult:
    """Focal length, principal point and ground plane of one camera (Stage I).

    Attributes
    ----------
    camera : str
    image_size : (int, int)
    focal : float
        Focal length (px); with known intrinsics the known ``fx``.
    focal_interval : (float, float)
        Confidence interval of the focal length (level ``diagnostics["confidence_level"]``);
        ``(focal, focal)`` with known intrinsics.
    focal_sd_rel : float
        1-s.d. relative uncertainty of the focal length.
    principal_point : ndarray, shape (2,)
    principal_point_estimated : bool
        False when held at the image centre.
    normal_cam : ndarray, shape (3,)
        Unit ground normal in camera coordinates, pointing from the ground up.
    normal_sd_deg : float
        1-s.d. of the normal direction (deg).
    camera_height : float
        Distance (m) of the camera centre above the ground (z = 0, the floor under the feet).
    upper_points : tuple of str
        Names of the upper-point columns (first: "shoulder").
    frames, persons : ndarray of int, shape (N,)
        Frame and person slot of each upright detection used.
    ankle : ndarray, shape (N, 2)
        Ankle centre pixels (with known intrinsics: undistorted, y scaled by ``fx / fy`` about
        ``cy``, i.e. the pixels of a square-pixel pinhole of focal ``focal``; so are ``upper``).
    upper : ndarray, shape (N, K, 2)
        Upper point pixels (NaN missing).
    offset : ndarray, shape (N, K)
        Vertical distance (m) of each upper point above the ankle under the fitted model.
    inliers : ndarray of bool, shape (N,)
    residuals : ndarray, shape (N,)
        Worst upper-point error over the person's pixel height (the paper's inlier measure).
    residuals_px : ndarray, shape (N,)
        Worst upper-point error in pixels.
    upright_mask : ndarray of bool, shape (F, P)
        Which detections passed the upright filter.
    diagnostics : dict
        Counts, timings, RANSAC iterations, pitch, ankle spread, refined ratios and heights.
    dist : ndarray, shape (5,)
        OpenCV distortion ``(k1, k2, p1, p2, k3)`` of the camera: the known one, else zeros.
    known_K : ndarray, shape (3, 3), optional
        The known intrinsic matrix when the intrinsics were given (then ``K`` returns it).
    """

    camera: str
    image_size: tuple[int, int]
    focal: float
    focal_interval: tuple[float, float]
    focal_sd_rel: float
    principal_point: F64
    principal_point_estimated: bool
    normal_cam: F64
    normal_sd_deg: float
    camera_height: float
    upper_points: tuple[str, ...]
    frames: NDArray[np.int64]
    persons: NDArray[np.int64]
    ankle: F64
    upper: F64
    offset: F64
    inliers: NDArray[np.bool_]
    residuals: F64
    residuals_px: F64
    upright_mask: NDArray[np.bool_]
    diagnostics: dict[str, Any] = field(default_factory=dict)
    dist: F64 = field(default_factory=lambda: np.zeros(5))
    known_K: F64 | None = None

    @property
    def n_inliers(self) -> int:
        return int(self.inliers.sum())

    @property
    def K(self) -> F64:
        """Intrinsic matrix, shape (3, 3) (the known one when the intrinsics were given)."""
        if self.known_K is not None:
            return self.known_K.copy()
        cx, cy = self.principal_point
        return np.array([[self.focal, 0.0, cx], [0.0, self.focal, cy], [0.0, 0.0, 1.0]])

    @property
    def pitch_deg(self) -> float:
        """Downward tilt of the optical axis below the horizon (90 = straight down)."""
        return float(np.degrees(np.arcsin(np.clip(-self.normal_cam[2], -1.0, 1.0))))

    def to_camera(self) -> Camera:
        """The camera in its own plane frame.

        World z = ground normal (up), the ground is z = 0, the camera centre is at
        ``(0, 0, camera_height)`` and the optical axis projected on the ground is world +x
        (yaw and ground position are fixed only by the later stages). Intrinsics: :attr:`K`
        and :attr:`dist`.
        """
        R = plane_frame_rotation(self.normal_cam)
        t = -self.camera_height * self.normal_cam
        return Camera(self.camera, self.image_size, self.K, self.dist.copy(), R, t)

    def predicted_upper(self) -> F64:
        """Upper points predicted from the ankles by the fitted model, shape (N, K, 2)."""
        ankle_ratio = float(self.diagnostics.get("ankle_height_m", 0.0))
        model = GroundModel(self.focal, self.principal_point, self.normal_cam,
                            self.camera_height - ankle_ratio)
        return model.predict_upper(self.ankle, self.offset)

    def summary(self) -> str:
        """One line for logs and the CLI."""
        lo, hi = self.focal_interval
        return (f"{self.camera}: f = {self.focal:.1f} px [{lo:.1f}, {hi:.1f}], "
                f"c = ({self.principal_point[0]:.1f}, {self.principal_point[1]:.1f})"
                f"{' (fitted)' if self.principal_point_estimated else ''}, "
                f"camera height {self.camera_height:.2f} m, pitch {self.pitch_deg:.1f} deg, "
                f"{self.n_inliers}/{len(self.inliers)} inliers")
