"""aniposelib / Pose2Sim TOML calibration files, and caliscope's older ``config.toml``.

caliscope's current ``camera_array.toml`` (``[cameras.<id>]`` tables) is
:mod:`~cascalib.formats.calibration.caliscope_toml`.

One table per camera::

    [cam_0]
    name = "A"                     # aniposelib, Pose2Sim; caliscope has none (table name used)
    size = [W, H]
    matrix = [[fx, 0, cx], [0, fy, cy], [0, 0, 1]]
    distortions = [k1, k2, p1, p2] or [k1, k2, p1, p2, k3]
    rotation = [rx, ry, rz]        # Rodrigues (aniposelib, Pose2Sim) or a 3x3 matrix (caliscope)
    translation = [tx, ty, tz]     # cam_from_world, metres

Tables without ``matrix`` (``[metadata]``, caliscope's ``[charuco]``, ``[capture_volume]``) and
top-level keys are skipped. Camera order is the file's table order (never re-sorted).

cascalib writes Rodrigues rotations, ``fisheye = false`` and, as extension keys the other tools
ignore, ``fps``, ``time_offset``, ``time_rate`` per camera and ``reference_camera`` and ``world`` in
``[metadata]``; so a cascalib TOML round trip keeps everything but ``quality``. Table names are
``cam_00``, ``cam_01`` ... zero-padded so that aniposelib, which sorts the table names, keeps the
camera order.

World frame: these files do not say what their world is. A file written by cascalib carries it in
``[metadata] world``; a caliscope file (recognised by a 3x3 ``rotation`` or its ``[charuco]`` /
``port`` keys) has the frame of one camera as world (its cam_1 in the shipped example), and the
world string names that camera; any other file gets ``"unknown (from TOML)"``.
"""

from __future__ import annotations

import logging
import tomllib
from pathlib import Path
from typing import Any

import numpy as np
import tomli_w

from cascalib.calibration import Calibration
from cascalib.camera import Camera
from cascalib.errors import CalibrationFileError
from cascalib.formats.calibration._validate import build_camera, matrix, require
from cascalib.geometry import matrix_to_rodrigues, rodrigues_to_matrix, rotation_angle_deg

__all__ = ["caliscope_world", "dump_toml", "from_dict", "load_toml", "read", "to_dict", "write"]

logger = logging.getLogger(__name__)

UNKNOWN_WORLD = "unknown (from TOML)"
_FIELDS = {"image_size": "size", "K": "matrix", "dist": "distortions", "R": "rotation",
           "t": "translation"}


def to_dict(calib: Calibration) -> dict[str, Any]:
    """The TOML-ready dict (aniposelib layout plus cascalib's extension keys)."""
    width = len(str(len(calib.cameras) - 1))
    out: dict[str, Any] = {}
    for i, cam in enumerate(calib.cameras):
        entry: dict[str, Any] = {
            "name": cam.name,
            "size": [int(v) for v in cam.image_size],
            "matrix": cam.K.tolist(),
            "distortions": cam.dist.tolist(),
            "rotation": matrix_to_rodrigues(cam.R).tolist(),
            "translation": cam.t.tolist(),
            "fisheye": False,
            "time_offset": float(cam.time_offset),
            "time_rate": float(cam.time_rate),
        }
        if cam.fps is not None:  # TOML has no null: an unknown rate is an absent key
            entry["fps"] = float(cam.fps)
        out[f"cam_{i:0{max(width, 2)}d}"] = entry
    out["metadata"] = {"adjusted": False, "error": 0.0,
                       "reference_camera": calib.reference_camera, "world": calib.world}
    return out


def from_dict(data: dict[str, Any], *, file: str | None = None) -> Calibration:
    """Build a :class:`Calibration` from a parsed TOML document (see the module docstring)."""
    tables = [(key, value) for key, value in data.items()
              if isinstance(value, dict) and "matrix" in value]
    if not tables:
        hint = (": a [cameras.<id>] table is caliscope's camera_array.toml, read it as format "
                "'caliscope'" if isinstance(data.get("cameras"), dict) else "")
        raise CalibrationFileError(f"no camera tables (a table with 'matrix') found{hint}",
                                   file=file, field="matrix")
    caliscope = "charuco" in data or any("port" in v for _, v in tables)
    cameras = []
    for key, entry in tables:
        name = str(entry.get("name", key))
        camera, was_matrix = _camera(name, entry, file=file)
        caliscope = caliscope or was_matrix
        cameras.append(camera)
    meta = data.get("metadata", {}) if isinstance(data.get("metadata"), dict) else {}
    world = str(meta.get("world", caliscope_world(cameras) if caliscope else UNKNOWN_WORLD))
    try:
        return Calibration(cameras, reference_camera=meta.get("reference_camera"), world=world)
    except CalibrationFileError as exc:
        raise CalibrationFileError(exc.message, file=file, field=exc.field) from None


def _camera(name: str, entry: dict[str, Any], *, file: str | None) -> tuple[Camera, bool]:
    """One camera table; also says whether its rotation was a 3x3 matrix (caliscope)."""
    if entry.get("fisheye", False):
        raise CalibrationFileError("fisheye cameras are not supported (OpenCV pinhole model "
                                   "with k1 k2 p1 p2 k3 only)", file=file, camera=name,
                                   field="fisheye")
    rot = require(entry, "rotation", file=file, camera=name)
    arr = np.asarray(rot, dtype=object)
    is_matrix = arr.shape == (3, 3)
    R = rot if is_matrix else rodrigues_to_matrix(
        matrix(rot, (3,), file=file, camera=name, field="rotation"))
    camera = build_camera(
        name, file=file, fields=_FIELDS,
        image_size=require(entry, "size", file=file, camera=name),
        K=require(entry, "matrix", file=file, camera=name),
        dist=require(entry, "distortions", file=file, camera=name),
        R=R, t=require(entry, "translation", file=file, camera=name),
        fps=entry.get("fps"), time_offset=entry.get("time_offset", 0.0),
        time_rate=entry.get("time_rate", 1.0))
    return camera, is_matrix


def caliscope_world(cameras: list[Camera]) -> str:
    """caliscope puts the world at one camera: name the camera whose pose is the identity."""
    for cam in cameras:
        if rotation_angle_deg(cam.R) < 1.0 and np.linalg.norm(cam.t) < 0.01:
            return f"camera '{cam.name}' frame (x right, y down, z forward; not the ground)"
    return "caliscope world (a camera or board frame, not the ground)"


def load_toml(path: Path) -> dict[str, Any]:
    """The parsed TOML document, or a CalibrationFileError naming the file."""
    try:
        with path.open("rb") as fh:
            return tomllib.load(fh)
    except tomllib.TOMLDecodeError as exc:
        raise CalibrationFileError(f"not valid TOML: {exc}", file=str(path)) from None


def dump_toml(data: dict[str, Any], path: Path) -> list[Path]:
    """Write ``data`` as TOML to ``path`` (parent folders made); returns ``[path]``."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with path.open("wb") as fh:
        tomli_w.dump(data, fh)
    return [path]


def read(path: str | Path) -> Calibration:
    """Read an aniposelib / Pose2Sim (or older caliscope) TOML file."""
    path = Path(path)
    calib = from_dict(load_toml(path), file=str(path))
    logger.debug("read %d cameras from %s (world: %s)", len(calib), path, calib.world)
    return calib


def write(calib: Calibration, path: str | Path) -> list[Path]:
    """Write ``calib`` as TOML to ``path``; returns the files written."""
    return dump_toml(to_dict(calib), Path(path))
