"""COLMAP text model (``cameras.txt``, ``images.txt``, ``points3D.txt``) in a folder.

Each cascalib camera is one COLMAP camera and one image (ids 1..N, in rig order). The image
``NAME`` is the camera name; on read a common image extension (``.jpg`` ...) is stripped from it.

* ``cameras.txt``: ``CAMERA_ID MODEL WIDTH HEIGHT PARAMS``; written as ``OPENCV``
  (``fx fy cx cy k1 k2 p1 p2``), or ``FULL_OPENCV`` (``... k3 k4 k5 k6``, k4-k6 = 0) when k3 is not
  zero, so nothing is lost. Read: ``SIMPLE_PINHOLE``, ``PINHOLE``, ``SIMPLE_RADIAL``, ``RADIAL``,
  ``OPENCV`` and ``FULL_OPENCV`` with k4 = k5 = k6 = 0.
* ``images.txt``: ``IMAGE_ID QW QX QY QZ TX TY TZ CAMERA_ID NAME`` (cam_from_world, Hamilton
  quaternion), then the image's 2D-points line, empty here.
* ``points3D.txt``: header only (COLMAP needs the file to load the model).

Pixel convention: COLMAP puts the centre of the top-left pixel at (0.5, 0.5), OpenCV and cascalib
at (0, 0); the principal point is shifted by 0.5 px each way on write and back on read.

The format cannot hold frame rates, time offsets/rates, the reference camera, the world
description, ``quality`` or a skewed K (refused on write). The clocks and the reference camera go
to ``cascalib_time.json`` beside the model (:mod:`._time_sidecar`) and :func:`read` takes them
back; without it a read gives ``fps=None``, offset 0, rate 1 and the first image as reference
camera (with a warning). The world is always ``"COLMAP model frame"``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np
from scipy.spatial.transform import Rotation

from cascalib.calibration import Calibration
from cascalib.camera import Camera
from cascalib.errors import CalibrationFileError
from cascalib.formats.calibration._time_sidecar import apply_time_sidecar, write_time_sidecar
from cascalib.formats.calibration._validate import build_camera, matrix

__all__ = ["from_dict", "read", "to_dict", "write"]

WORLD = "COLMAP model frame (as in the files)"
_FIELDS = {"image_size": "WIDTH HEIGHT", "K": "params", "dist": "params", "R": "QW QX QY QZ",
           "t": "TX TY TZ"}
_IMAGE_EXTENSIONS = (".jpg", ".jpeg", ".png", ".bmp", ".tif", ".tiff")
#: Number of parameters and the order of (fx, fy, cx, cy, dist...) per supported model.
_MODELS = {"SIMPLE_PINHOLE": 3, "PINHOLE": 4, "SIMPLE_RADIAL": 4, "RADIAL": 5,
           "OPENCV": 8, "FULL_OPENCV": 12}


def _camera_row(cam: Camera, camera_id: int) -> dict[str, Any]:
    if abs(cam.K[0, 1]) > 0:
        raise CalibrationFileError("COLMAP cameras have no skew; K[0,1] must be 0", camera=cam.name,
                                   field="K")
    fx, fy, cx, cy = cam.K[0, 0], cam.K[1, 1], cam.K[0, 2] + 0.5, cam.K[1, 2] + 0.5
    k1, k2, p1, p2, k3 = cam.dist
    if k3 == 0:
        model, params = "OPENCV", [fx, fy, cx, cy, k1, k2, p1, p2]
    else:
        model, params = "FULL_OPENCV", [fx, fy, cx, cy, k1, k2, p1, p2, k3, 0.0, 0.0, 0.0]
    return {"camera_id": camera_id, "model": model, "width": int(cam.image_size[0]),
            "height": int(cam.image_size[1]), "params": [float(p) for p in params]}


def to_dict(calib: Calibration) -> dict[str, list[dict[str, Any]]]:
    """``{"cameras": [row...], "images": [row...]}`` with the fields of the two text files."""
    cameras, images = [], []
    for i, cam in enumerate(calib.cameras, start=1):
        if any(ch.isspace() for ch in cam.name):
            raise CalibrationFileError("COLMAP image names cannot contain whitespace",
                                       camera=cam.name, field="name")
        cameras.append(_camera_row(cam, i))
        x, y, z, w = Rotation.from_matrix(cam.R).as_quat()
        q = [w, x, y, z] if w >= 0 else [-w, -x, -y, -z]  # COLMAP keeps qw >= 0
        images.append({"image_id": i, "qvec": [float(v) for v in q],
                       "tvec": cam.t.tolist(), "camera_id": i, "name": cam.name})
    return {"cameras": cameras, "images": images}


def _intrinsics(row: dict[str, Any], name: str, *, file: str | None
                ) -> tuple[np.ndarray, np.ndarray]:
    model, p = row["model"], row["params"]
    if model not in _MODELS:
        raise CalibrationFileError(f"unsupported COLMAP camera model {model!r} (supported: "
                                   f"{', '.join(_MODELS)})", file=file, camera=name, field="model")
    p = matrix(p, (_MODELS[model],), file=file, camera=name, field="params")
    dist = np.zeros(5)
    if model in ("SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL"):
        fx = fy = p[0]
        cx, cy = p[1], p[2]
        dist[: len(p) - 3] = p[3:]
    else:
        fx, fy, cx, cy = p[:4]
        dist[: min(5, len(p) - 4)] = p[4:9]
        if model == "FULL_OPENCV" and np.any(p[9:] != 0):
            raise CalibrationFileError("FULL_OPENCV with k4-k6 (rational model) is not supported",
                                       file=file, camera=name, field="params")
    K = np.array([[fx, 0.0, cx - 0.5], [0.0, fy, cy - 0.5], [0.0, 0.0, 1.0]])
    return K, dist


def from_dict(data: dict[str, list[dict[str, Any]]], *, file: str | None = None) -> Calibration:
    """Build a :class:`Calibration` (one camera per image) from parsed COLMAP rows."""
    by_id = {row["camera_id"]: row for row in data["cameras"]}
    cameras = []
    for img in data["images"]:
        name = img["name"]
        if img["camera_id"] not in by_id:
            raise CalibrationFileError(f"image refers to unknown CAMERA_ID {img['camera_id']}",
                                       file=file, camera=name, field="CAMERA_ID")
        row = by_id[img["camera_id"]]
        K, dist = _intrinsics(row, name, file=file)
        q = matrix(img["qvec"], (4,), file=file, camera=name, field="QW QX QY QZ")
        norm = np.linalg.norm(q)
        if abs(norm - 1) > 1e-4:
            raise CalibrationFileError(f"quaternion is not unit length (|q| = {norm:.6g})",
                                       file=file, camera=name, field="QW QX QY QZ")
        R = Rotation.from_quat([q[1], q[2], q[3], q[0]]).as_matrix()
        cameras.append(build_camera(name, file=file, image_size=[row["width"], row["height"]],
                                    K=K, dist=dist, R=R, t=img["tvec"], fields=_FIELDS))
    if not cameras:
        raise CalibrationFileError("no images in images.txt", file=file, field="images")
    try:
        return Calibration(cameras, world=WORLD)
    except CalibrationFileError as exc:
        raise CalibrationFileError(exc.message, file=file, field=exc.field) from None


def _data_lines(path: Path) -> list[tuple[int, str]]:
    """(line number, text) of the non-comment lines, blank ones included (images.txt needs them)."""
    if not path.is_file():
        raise CalibrationFileError("file not found", file=str(path))
    lines = path.read_text(encoding="utf-8").splitlines()
    return [(i + 1, ln.strip()) for i, ln in enumerate(lines) if not ln.startswith("#")]


def _parse_cameras(path: Path) -> list[dict[str, Any]]:
    rows = []
    for lineno, line in _data_lines(path):
        if not line:
            continue
        e = line.split()
        try:
            rows.append({"camera_id": int(e[0]), "model": e[1], "width": int(e[2]),
                         "height": int(e[3]), "params": [float(v) for v in e[4:]]})
        except (IndexError, ValueError):
            raise CalibrationFileError(f"line {lineno}: expected 'CAMERA_ID MODEL WIDTH HEIGHT "
                                       f"PARAMS...', got {line!r}", file=str(path)) from None
    return rows


def _parse_images(path: Path) -> list[dict[str, Any]]:
    rows = []
    lines = _data_lines(path)
    i = 0
    while i < len(lines):
        lineno, line = lines[i]
        i += 1
        if not line:
            continue
        e = line.split()
        try:
            name = e[9]
            if name.lower().endswith(_IMAGE_EXTENSIONS):
                name = name.rsplit(".", 1)[0]
            rows.append({"image_id": int(e[0]), "qvec": [float(v) for v in e[1:5]],
                         "tvec": [float(v) for v in e[5:8]], "camera_id": int(e[8]),
                         "name": name})
        except (IndexError, ValueError):
            raise CalibrationFileError(f"line {lineno}: expected 'IMAGE_ID QW QX QY QZ TX TY TZ "
                                       f"CAMERA_ID NAME', got {line!r}", file=str(path)) from None
        i += 1  # the image's 2D-points line (cascalib does not use the points)
    return rows


def read(path: str | Path) -> Calibration:
    """Read a COLMAP text model from a folder (or given its cameras.txt or images.txt), with
    the clocks of ``cascalib_time.json`` beside it."""
    folder = Path(path)
    if folder.is_file():
        folder = folder.parent
    data = {"cameras": _parse_cameras(folder / "cameras.txt"),
            "images": _parse_images(folder / "images.txt")}
    return apply_time_sidecar(from_dict(data, file=str(folder)), folder, fmt="COLMAP")


def write(calib: Calibration, path: str | Path) -> list[Path]:
    """Write ``cameras.txt``, ``images.txt``, an empty ``points3D.txt`` and the clocks'
    ``cascalib_time.json`` into the folder ``path``; returns the four files."""
    folder = Path(path)
    data = to_dict(calib)
    folder.mkdir(parents=True, exist_ok=True)
    cam_lines = ["# Camera list with one line of data per camera:",
                 "#   CAMERA_ID, MODEL, WIDTH, HEIGHT, PARAMS[]",
                 f"# Number of cameras: {len(data['cameras'])}"]
    for c in data["cameras"]:
        params = " ".join(repr(p) for p in c["params"])
        cam_lines.append(f"{c['camera_id']} {c['model']} {c['width']} {c['height']} {params}")
    img_lines = ["# Image list with two lines of data per image:",
                 "#   IMAGE_ID, QW, QX, QY, QZ, TX, TY, TZ, CAMERA_ID, NAME",
                 "#   POINTS2D[] as (X, Y, POINT3D_ID)",
                 f"# Number of images: {len(data['images'])}, mean observations per image: 0"]
    for im in data["images"]:
        pose = " ".join(repr(float(v)) for v in [*im["qvec"], *im["tvec"]])
        img_lines += [f"{im['image_id']} {pose} {im['camera_id']} {im['name']}", ""]
    pts_lines = ["# 3D point list with one line of data per point:",
                 "#   POINT3D_ID, X, Y, Z, R, G, B, ERROR, TRACK[] as (IMAGE_ID, POINT2D_IDX)",
                 "# Number of points: 0, mean track length: 0"]
    out = []
    for name, lines in (("cameras.txt", cam_lines), ("images.txt", img_lines),
                        ("points3D.txt", pts_lines)):
        (folder / name).write_text("\n".join(lines) + "\n", encoding="utf-8")
        out.append(folder / name)
    return [*out, write_time_sidecar(calib, folder)]
