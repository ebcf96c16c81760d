"""Checks shared by every calibration reader: one place that turns raw values into a Camera.

Every reader hands the values it parsed to :func:`build_camera`, so that a bad file fails the
same way whatever its format: a :class:`~cascalib.errors.CalibrationFileError` naming the file,
the camera and the field.
"""

from __future__ import annotations

import math
import re
from collections.abc import Mapping
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cascalib.camera import Camera
from cascalib.errors import CalibrationFileError
from cascalib.geometry import project_to_so3

__all__ = [
    "ROTATION_TOLERANCE",
    "build_camera",
    "check_node_name",
    "matrix",
    "require",
]

#: Largest accepted ``max |R R^T - I|``: files print rotations to 6-17 digits; a matrix further
#: from a rotation than this is a different quantity (a scaled or sheared matrix, a typo).
ROTATION_TOLERANCE = 1e-5

# Names that can follow a prefix in an OpenCV FileStorage key (``K_<name>``).
_NODE_NAME = re.compile(r"^[A-Za-z0-9_\-]+$")


def require(mapping: Mapping[str, Any], key: str, *, file: str | None,
            camera: str | None = None, field: str | None = None) -> Any:
    """``mapping[key]``, or a CalibrationFileError naming what is missing."""
    if not isinstance(mapping, Mapping):
        raise CalibrationFileError(f"expected a table/object, got {type(mapping).__name__}",
                                   file=file, camera=camera, field=field)
    if key not in mapping:
        raise CalibrationFileError(f"missing key {key!r}", file=file, camera=camera,
                                   field=field or key)
    return mapping[key]


def matrix(value: Any, shape: tuple[int, ...], *, file: str | None, camera: str | None,
           field: str) -> NDArray[np.float64]:
    """A finite float array of the given shape (sizes of -1 are free), or a clear error."""
    try:
        arr = np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise CalibrationFileError(f"not a numeric array ({exc})", file=file, camera=camera,
                                   field=field) from None
    if arr.ndim != len(shape) or any(s not in (-1, a) for s, a in zip(shape, arr.shape,
                                                                         strict=True)):
        want = "x".join("N" if s == -1 else str(s) for s in shape)
        raise CalibrationFileError(f"expected shape {want}, got {list(arr.shape)}",
                                   file=file, camera=camera, field=field)
    if not np.isfinite(arr).all():
        raise CalibrationFileError("non-finite value (NaN or infinity)", file=file,
                                   camera=camera, field=field)
    return arr


def _check_image_size(size: Any, *, file: str | None, camera: str, field: str
                      ) -> tuple[int, int]:
    arr = matrix(size, (2,), file=file, camera=camera, field=field)
    if (arr <= 0).any() or (arr != np.round(arr)).any():
        raise CalibrationFileError(f"image size must be two positive integers, got {size}",
                                   file=file, camera=camera, field=field)
    return int(arr[0]), int(arr[1])


def _check_K(K: Any, *, file: str | None, camera: str, field: str) -> NDArray[np.float64]:
    k = matrix(K, (3, 3), file=file, camera=camera, field=field)
    if k[0, 0] <= 0 or k[1, 1] <= 0:
        raise CalibrationFileError(
            f"focal lengths must be positive, got fx={k[0, 0]:g}, fy={k[1, 1]:g}",
            file=file, camera=camera, field=field)
    if abs(k[1, 0]) > 1e-9 or abs(k[2, 0]) > 1e-9 or abs(k[2, 1]) > 1e-9 or abs(k[2, 2] - 1) > 1e-9:
        raise CalibrationFileError(
            f"not an upper-triangular intrinsic matrix with K[2,2] = 1: {k.tolist()}",
            file=file, camera=camera, field=field)
    return k


def _check_R(R: Any, *, file: str | None, camera: str, field: str) -> NDArray[np.float64]:
    R = matrix(R, (3, 3), file=file, camera=camera, field=field)
    off = float(np.abs(R @ R.T - np.eye(3)).max())
    if off > ROTATION_TOLERANCE:
        raise CalibrationFileError(
            f"not a rotation matrix: max |R R^T - I| = {off:.3g} (> {ROTATION_TOLERANCE:g})",
            file=file, camera=camera, field=field)
    if np.linalg.det(R) <= 0:
        raise CalibrationFileError("not a rotation matrix: determinant is negative "
                                   "(a reflection)", file=file, camera=camera, field=field)
    # Snap to the nearest rotation: files keep 6-17 digits and downstream code assumes R R^T = I.
    return project_to_so3(R)


def _check_dist(dist: Any, *, file: str | None, camera: str, field: str) -> NDArray[np.float64]:
    if dist is None:
        dist = []
    d = matrix(np.ravel(np.asarray(dist, dtype=np.float64)) if _is_numeric(dist) else dist,
               (-1,), file=file, camera=camera, field=field)
    if d.size not in (0, 4, 5):
        raise CalibrationFileError(
            f"expected 4 or 5 distortion coefficients (k1 k2 p1 p2 [k3]), got {d.size}",
            file=file, camera=camera, field=field)
    out = np.zeros(5)
    out[: d.size] = d
    return out


def _finite_number(value: Any, *, file: str | None, camera: str, field: str) -> float:
    try:
        x = float(value)
    except (TypeError, ValueError):
        raise CalibrationFileError(f"expected a number, got {value!r}", file=file,
                                   camera=camera, field=field) from None
    if not math.isfinite(x):
        raise CalibrationFileError("non-finite value (NaN or infinity)", file=file,
                                   camera=camera, field=field)
    return x


def build_camera(name: str, *, image_size: Any, K: Any, dist: Any, R: Any, t: Any,
                 fps: Any = None, time_offset: Any = 0.0, time_rate: Any = 1.0,
                 file: str | None = None, fields: Mapping[str, str] | None = None) -> Camera:
    """Validate raw values and build a :class:`~cascalib.camera.Camera`.

    Parameters
    ----------
    name : str
        Camera name (used in error messages).
    image_size : sequence of 2 int
        (width, height) in pixels.
    K : array_like, shape (3, 3)
        Intrinsics; focal lengths must be positive.
    dist : array_like, shape (0,), (4,) or (5,)
        OpenCV ``k1 k2 p1 p2 [k3]``; missing values are zero.
    R : array_like, shape (3, 3)
        cam_from_world rotation (orthonormal within :data:`ROTATION_TOLERANCE`, det > 0).
    t : array_like, shape (3,)
        cam_from_world translation in metres.
    fps : float, optional
        Nominal frame rate; ``None`` when unknown.
    time_offset, time_rate : float
        Time mapping to the reference camera (rate must be positive).
    file : str, optional
        File named in error messages.
    fields : mapping, optional
        The file's own names of the fields, for error messages: ``{"K": "matrix", ...}``
        (keys ``image_size``, ``K``, ``dist``, ``R``, ``t``; default: these names).

    Raises
    ------
    CalibrationFileError
        Naming the file, camera and field of the first problem found.
    """
    if not isinstance(name, str) or not name:
        raise CalibrationFileError(f"camera name must be a non-empty string, got {name!r}",
                                   file=file, field="name")
    names = {k: k for k in ("image_size", "K", "dist", "R", "t")} | dict(fields or {})
    size = _check_image_size(image_size, file=file, camera=name, field=names["image_size"])
    K_ = _check_K(K, file=file, camera=name, field=names["K"])
    R_ = _check_R(R, file=file, camera=name, field=names["R"])
    t_ = matrix(np.ravel(np.asarray(t, dtype=np.float64)) if _is_numeric(t) else t, (3,),
                file=file, camera=name, field=names["t"])
    d_ = _check_dist(dist, file=file, camera=name, field=names["dist"])
    fps_ = None if fps is None else _finite_number(fps, file=file, camera=name, field="fps")
    if fps_ is not None and fps_ <= 0:
        raise CalibrationFileError(f"fps must be positive, got {fps_:g}", file=file,
                                   camera=name, field="fps")
    offset = _finite_number(time_offset, file=file, camera=name, field="time_offset")
    rate = _finite_number(time_rate, file=file, camera=name, field="time_rate")
    if rate <= 0:
        raise CalibrationFileError(f"time_rate must be positive, got {rate:g}", file=file,
                                   camera=name, field="time_rate")
    return Camera(name, size, K_, d_, R_, t_, fps=fps_, time_offset=offset, time_rate=rate)


def _is_numeric(value: Any) -> bool:
    try:
        np.asarray(value, dtype=np.float64)
    except (TypeError, ValueError):
        return False
    return True


def check_node_name(name: str, *, file: str | None, fmt: str) -> None:
    """Camera names become OpenCV FileStorage keys (``K_<name>``): letters, digits, ``_``, ``-``."""
    if not _NODE_NAME.match(name):
        raise CalibrationFileError(
            f"camera name {name!r} cannot be written to {fmt}: node names allow only letters, "
            "digits, '_' and '-'", file=file, camera=name, field="name")
