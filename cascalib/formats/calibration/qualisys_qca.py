"""Qualisys Track Manager calibration export (``.qca.txt``, XML); reader only.

Per ``<camera serial=...>``:

* image size from ``<fov_video left right top bottom>``: ``W = right - left + 1``,
  ``H = bottom - top + 1``;
* ``<intrinsic>`` values are in 1/64 pixel of the full sensor: ``fx = focalLengthU / 64``,
  ``fy = focalLengthV / 64``, ``cx = centerPointU / 64 - fov_video.left``,
  ``cy = centerPointV / 64 - fov_video.top``;
* ``<transform>`` holds the camera centre ``x y z`` in millimetres and the rotation ``r11..r33``
  (rows) of the camera in the lab; OpenCV cam_from_world is ``R = diag(1, -1, -1) @ Rq``,
  ``C = xyz / 1000``, ``t = -R @ C``;
* distortion: QTM's lens model is not documented; like Pose2Sim's converter
  (``calib_qca_fun``), the coefficients are divided by 64 and used as OpenCV
  ``k1 k2 p1 p2 k3`` (they are then negligible: at most 0.13 px, at the image corners, on the
  demo file).

The Qualisys lab frame has z up and the floor at z = 0 (the L-frame lies on the floor), so the
world is cascalib's. Cameras with ``viewrotation`` other than 0 (images rotated by QTM) are
refused: their intrinsics refer to the unrotated sensor and no test file covers them.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path
from typing import Any

import numpy as np

from cascalib.calibration import Calibration
from cascalib.camera import Camera
from cascalib.errors import CalibrationFileError
from cascalib.formats.calibration._validate import build_camera

__all__ = ["WORLD", "from_dict", "read", "to_dict_raw"]

WORLD = "z-up, ground z=0 (Qualisys lab frame)"
#: Qualisys image axes are flipped against OpenCV's in y and z.
_FLIP = np.diag([1.0, -1.0, -1.0])


def _float(attrs: dict[str, str], key: str, *, file: str | None, camera: str, tag: str) -> float:
    if key not in attrs:
        raise CalibrationFileError(f"missing attribute {key!r} in <{tag}>", file=file,
                                   camera=camera, field=f"{tag}.{key}")
    try:
        return float(attrs[key])
    except ValueError:
        raise CalibrationFileError(f"not a number: {attrs[key]!r}", file=file, camera=camera,
                                   field=f"{tag}.{key}") from None


def to_dict_raw(root: ET.Element, *, file: str | None = None) -> list[dict[str, Any]]:
    """The attributes of each camera's elements: ``[{"serial", "viewrotation", "fov_video",
    "transform", "intrinsic"}]`` (strings, as in the XML)."""
    cams = root.findall("./cameras/camera")
    if not cams:
        raise CalibrationFileError("no <cameras>/<camera> elements", file=file, field="cameras")
    out: list[dict[str, Any]] = []
    for el in cams:
        serial = el.get("serial", f"camera_{len(out)}")
        entry: dict[str, Any] = {"serial": serial, "viewrotation": el.get("viewrotation", "0")}
        for tag in ("fov_video", "transform", "intrinsic"):
            child = el.find(tag)
            if child is None:
                raise CalibrationFileError(f"missing <{tag}>", file=file, camera=serial,
                                           field=tag)
            entry[tag] = dict(child.attrib)
        out.append(entry)
    return out


def _camera(entry: dict[str, Any], *, file: str | None) -> Camera:
    name = entry["serial"]
    if entry["viewrotation"] not in ("0", "0.0", ""):
        raise CalibrationFileError(f"viewrotation={entry['viewrotation']} is not supported",
                                   file=file, camera=name, field="viewrotation")

    def get(tag: str, key: str) -> float:
        return _float(entry[tag], key, file=file, camera=name, tag=tag)

    left, top = get("fov_video", "left"), get("fov_video", "top")
    size = [get("fov_video", "right") - left + 1, get("fov_video", "bottom") - top + 1]
    K = np.array([[get("intrinsic", "focalLengthU") / 64, 0.0,
                   get("intrinsic", "centerPointU") / 64 - left],
                  [0.0, get("intrinsic", "focalLengthV") / 64,
                   get("intrinsic", "centerPointV") / 64 - top],
                  [0.0, 0.0, 1.0]])
    # Pose2Sim's convention (see the module docstring); absent coefficients are zero.
    dist = np.array([get("intrinsic", k) if k in entry["intrinsic"] else 0.0
                     for k in ("radialDistortion1", "radialDistortion2", "tangentalDistortion1",
                               "tangentalDistortion2", "radialDistortion3")]) / 64
    Rq = np.array([[get("transform", f"r{i}{j}") for j in (1, 2, 3)] for i in (1, 2, 3)])
    C = np.array([get("transform", k) for k in ("x", "y", "z")]) / 1000.0
    R = _FLIP @ Rq
    return build_camera(name, file=file, image_size=size, K=K, dist=dist, R=R, t=-R @ C,
                        fields={"image_size": "fov_video", "K": "intrinsic",
                                "dist": "intrinsic", "R": "transform", "t": "transform"})


def from_dict(entries: list[dict[str, Any]], *, file: str | None = None) -> Calibration:
    """Build a :class:`Calibration` from :func:`to_dict_raw` entries."""
    cameras = [_camera(e, file=file) for e in entries]
    try:
        return Calibration(cameras, world=WORLD)
    except CalibrationFileError as exc:
        raise CalibrationFileError(exc.message, file=file, field=exc.field) from None


def read(path: str | Path) -> Calibration:
    """Read a Qualisys ``.qca.txt`` calibration."""
    path = Path(path)
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as exc:
        raise CalibrationFileError(f"not a readable XML file: {exc}", file=str(path)) from None
    return from_dict(to_dict_raw(root, file=str(path)), file=str(path))
