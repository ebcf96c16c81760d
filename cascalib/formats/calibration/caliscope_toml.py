"""caliscope's ``camera_array.toml`` (caliscope 0.11: ``CameraArray.from_toml`` / ``to_toml``).

One table per camera under ``[cameras]``, keyed by caliscope's integer camera id::

    [cameras.0]
    cam_id = 0
    size = [W, H]
    rotation_count = 0             # caliscope's display rotation, in quarter turns
    matrix = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]
    distortions = [k1, k2, p1, p2, k3]
    rotation = [rx, ry, rz]        # Rodrigues, cam_from_world (cv2.projectPoints' rvec)
    translation = [tx, ty, tz]     # cam_from_world (tvec), metres
    fisheye = false

caliscope reads only these keys (and ``error``, ``exposure``, ``grid_count``, ``ignore``), so
cascalib adds ``name``, ``fps``, ``time_offset`` and ``time_rate`` to each camera table and a
``[cascalib]`` table with ``reference_camera`` and ``world``: a cascalib round trip keeps
everything but ``quality``; a file caliscope rewrites loses them. Cameras are numbered by the
digits their names end with when those are unique (``cam3`` -> ``3``), else 0..N-1 in rig order.

On read, a camera without ``name`` is called ``cam_<id>``; a camera caliscope has not posed (no
``rotation``/``translation``) is refused, as are fisheye cameras. Files without a ``[cameras]``
table (caliscope's older ``config.toml`` with ``[cam_N]`` tables and 3x3 rotations) are read by
:mod:`~cascalib.formats.calibration.anipose_toml`.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cascalib.calibration import Calibration
from cascalib.camera import Camera
from cascalib.errors import CalibrationFileError
from cascalib.formats.calibration import anipose_toml
from cascalib.formats.calibration._validate import build_camera, matrix, require
from cascalib.geometry import matrix_to_rodrigues, rodrigues_to_matrix

__all__ = ["FILENAME", "from_dict", "is_camera_array", "read", "to_dict", "write"]

#: The name caliscope gives the file in a project's output folders.
FILENAME = "camera_array.toml"
_FIELDS = {"image_size": "size", "K": "matrix", "dist": "distortions", "R": "rotation",
           "t": "translation"}
_TRAILING_DIGITS = re.compile(r"(\d+)$")


def camera_ids(names: list[str]) -> list[int]:
    """caliscope's integer ids for ``names``: their trailing digits if unique, else 0..N-1."""
    found = [_TRAILING_DIGITS.search(n) for n in names]
    ids = [int(m.group(1)) for m in found if m]
    if len(ids) == len(names) and len(set(ids)) == len(ids):
        return ids
    return list(range(len(names)))


def to_dict(calib: Calibration) -> dict[str, Any]:
    """The TOML-ready dict: caliscope's ``[cameras.<id>]`` tables plus cascalib's keys."""
    cameras: dict[str, Any] = {}
    for cam_id, cam in zip(camera_ids(calib.names), calib.cameras, strict=True):
        entry: dict[str, Any] = {
            "cam_id": cam_id,
            "size": [int(v) for v in cam.image_size],
            "rotation_count": 0,
            "matrix": cam.K.tolist(),
            "distortions": cam.dist.tolist(),
            "rotation": matrix_to_rodrigues(cam.R).tolist(),
            "translation": cam.t.tolist(),
            "fisheye": False,
            "name": cam.name,
            "time_offset": float(cam.time_offset),
            "time_rate": float(cam.time_rate),
        }
        if cam.fps is not None:  # TOML has no null: an unknown rate is an absent key
            entry["fps"] = float(cam.fps)
        cameras[str(cam_id)] = entry
    return {"cameras": cameras,
            "cascalib": {"reference_camera": calib.reference_camera, "world": calib.world}}


def is_camera_array(data: dict[str, Any]) -> bool:
    """Whether a parsed TOML document has caliscope's current layout (a ``[cameras]`` table)."""
    return isinstance(data.get("cameras"), dict)


def from_dict(data: dict[str, Any], *, file: str | None = None) -> Calibration:
    """Build a :class:`Calibration` from a parsed ``camera_array.toml`` (or an older
    caliscope ``config.toml``, handed to the aniposelib-layout reader)."""
    if not is_camera_array(data):
        return anipose_toml.from_dict(data, file=file)
    tables = data["cameras"]
    if not tables:
        raise CalibrationFileError("the [cameras] table holds no camera", file=file,
                                   field="cameras")
    cameras = [_camera(str(key), entry, file=file) for key, entry in tables.items()]
    meta = data.get("cascalib")
    meta = meta if isinstance(meta, dict) else {}
    world = str(meta.get("world", anipose_toml.caliscope_world(cameras)))
    try:
        return Calibration(cameras, reference_camera=meta.get("reference_camera"), world=world)
    except CalibrationFileError as exc:
        raise CalibrationFileError(exc.message, file=file, field=exc.field) from None


def _camera(key: str, entry: Any, *, file: str | None) -> Camera:
    """One ``[cameras.<id>]`` table."""
    if not isinstance(entry, dict):
        raise CalibrationFileError(f"[cameras.{key}] is not a table", file=file, field="cameras")
    name = str(entry.get("name", f"cam_{key}"))
    if entry.get("fisheye", False):
        raise CalibrationFileError("fisheye cameras are not supported (OpenCV pinhole model "
                                   "with k1 k2 p1 p2 k3 only)", file=file, camera=name,
                                   field="fisheye")
    for key_ in ("rotation", "translation"):
        if key_ not in entry:
            raise CalibrationFileError(f"missing key {key_!r}: caliscope has not posed this "
                                       "camera (extrinsic calibration not run)", file=file,
                                       camera=name, field=key_)
    R = _rotation(entry["rotation"], file=file, camera=name)
    return build_camera(
        name, file=file, fields=_FIELDS,
        image_size=require(entry, "size", file=file, camera=name),
        K=require(entry, "matrix", file=file, camera=name),
        dist=require(entry, "distortions", file=file, camera=name),
        R=R, t=entry["translation"], fps=entry.get("fps"),
        time_offset=entry.get("time_offset", 0.0), time_rate=entry.get("time_rate", 1.0))


def _rotation(value: Any, *, file: str | None, camera: str) -> NDArray[np.float64]:
    """caliscope writes a Rodrigues vector (3 or 3x1) and reads a 3x3 matrix too (legacy)."""
    try:
        shape = np.shape(value)
    except ValueError:  # ragged nested lists
        shape = ()
    if shape == (3, 3):
        return matrix(value, (3, 3), file=file, camera=camera, field="rotation")
    flat = np.ravel(value) if shape == (3, 1) else value
    return rodrigues_to_matrix(matrix(flat, (3,), file=file, camera=camera, field="rotation"))


def read(path: str | Path) -> Calibration:
    """Read a caliscope ``camera_array.toml`` (or older ``config.toml``)."""
    path = Path(path)
    return from_dict(anipose_toml.load_toml(path), file=str(path))


def write(calib: Calibration, path: str | Path) -> list[Path]:
    """Write ``calib`` in caliscope's ``camera_array.toml`` layout; returns the files written."""
    return anipose_toml.dump_toml(to_dict(calib), Path(path))
