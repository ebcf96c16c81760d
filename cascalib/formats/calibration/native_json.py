"""cascalib's own ``calibration.json`` (schema ``cascalib/calibration@1``).

The layout is a contract other tools rely on; extend it with new keys, never rename::

    {"schema": "cascalib/calibration@1", "units": "m", "world": "z-up, ground z=0",
     "reference_camera": NAME,
     "cameras": {NAME: {"image_size": [W, H], "K": 3x3, "dist": [k1, k2, p1, p2, k3],
                        "R": 3x3, "t": [3], "fps": F or null,
                        "time_offset": O, "time_rate": S}},
     "quality": {...}}

``R``, ``t`` are cam_from_world (``x_cam = R x_world + t``), metres, OpenCV camera axes. Frame
``k`` of a camera shows the scene at reference-camera frame ``S * k + O`` (the reference camera has
``O = 0``, ``S = 1``). Camera order is the insertion order of the ``cameras`` object. Unknown
keys are accepted on read (and dropped).
"""

from __future__ import annotations

import json
import logging
import math
from pathlib import Path
from typing import Any

import numpy as np

from cascalib.calibration import Calibration
from cascalib.errors import CalibrationFileError
from cascalib.formats.calibration._validate import build_camera, require

__all__ = ["SCHEMA", "from_dict", "read", "to_dict", "write"]

logger = logging.getLogger(__name__)

SCHEMA = "cascalib/calibration@1"
_CAMERA_KEYS = ("image_size", "K", "dist", "R", "t", "fps", "time_offset", "time_rate")


def to_dict(calib: Calibration) -> dict[str, Any]:
    """The JSON-ready dict of a calibration (plain lists and floats only)."""
    cameras: dict[str, Any] = {}
    for cam in calib.cameras:
        cameras[cam.name] = {
            "image_size": [int(v) for v in cam.image_size],
            "K": cam.K.tolist(),
            "dist": cam.dist.tolist(),
            "R": cam.R.tolist(),
            "t": cam.t.tolist(),
            "fps": None if cam.fps is None else float(cam.fps),
            "time_offset": float(cam.time_offset),
            "time_rate": float(cam.time_rate),
        }
    return {
        "schema": SCHEMA,
        "units": "m",
        "world": calib.world,
        "reference_camera": calib.reference_camera,
        "cameras": cameras,
        "quality": _plain(calib.quality),
    }


def from_dict(data: Any, *, file: str | None = None) -> Calibration:
    """Validate a parsed ``calibration.json`` and build the :class:`Calibration`.

    Raises
    ------
    CalibrationFileError
        Wrong schema tag, missing keys, bad values; naming file, camera and field.
    """
    if not isinstance(data, dict):
        raise CalibrationFileError("expected a JSON object at the top level", file=file)
    schema = require(data, "schema", file=file)
    if schema != SCHEMA:
        raise CalibrationFileError(f"unsupported schema {schema!r}, expected {SCHEMA!r}",
                                   file=file, field="schema")
    units = require(data, "units", file=file)
    if units != "m":
        raise CalibrationFileError(f"units must be 'm', got {units!r}", file=file,
                                   field="units")
    world = require(data, "world", file=file)
    reference = require(data, "reference_camera", file=file)
    entries = require(data, "cameras", file=file)
    if not isinstance(entries, dict) or not entries:
        raise CalibrationFileError("'cameras' must be a non-empty object {name: camera}",
                                   file=file, field="cameras")
    cameras = []
    for name, entry in entries.items():
        values = {k: require(entry, k, file=file, camera=name) for k in _CAMERA_KEYS}
        cameras.append(build_camera(name, file=file, **values))
    quality = data.get("quality", {})
    if not isinstance(quality, dict):
        raise CalibrationFileError("'quality' must be an object", file=file, field="quality")
    try:
        calib = Calibration(cameras, reference_camera=reference, quality=quality,
                            world=str(world))
    except CalibrationFileError as exc:
        raise CalibrationFileError(exc.message, file=file, field=exc.field) from None
    ref = calib[str(calib.reference_camera)]
    if ref.time_offset != 0 or ref.time_rate != 1:
        # Readable (metrics re-express times per reference camera) but against the contract.
        logger.warning("%s: reference camera %s has time_offset %g and time_rate %g; the "
                       "schema expects 0 and 1", file, ref.name, ref.time_offset, ref.time_rate)
    return calib


def read(path: str | Path) -> Calibration:
    """Read a ``calibration.json`` file (or the one in the folder ``path``)."""
    path = Path(path)
    if path.is_dir():
        path = path / "calibration.json"
    if not path.is_file():
        raise CalibrationFileError("file not found", file=str(path))
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise CalibrationFileError(f"not valid JSON: {exc}", file=str(path)) from None
    return from_dict(data, file=str(path))


def write(calib: Calibration, path: str | Path) -> list[Path]:
    """Write ``calib`` to ``path`` (a ``.json`` file); returns the files written."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    # allow_nan=False: the schema forbids NaN, which is not JSON and other tools reject.
    text = json.dumps(to_dict(calib), indent=2, allow_nan=False)
    path.write_text(text + "\n", encoding="utf-8")
    return [path]


def _plain(value: Any) -> Any:
    """Quality reports may hold numpy scalars/arrays and NaN: make them strict-JSON values."""
    if isinstance(value, dict):
        return {str(k): _plain(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_plain(v) for v in value]
    if isinstance(value, np.ndarray):
        return _plain(value.tolist())
    if isinstance(value, np.generic):
        value = value.item()
    if isinstance(value, float) and not math.isfinite(value):
        return None  # JSON has no NaN; null means "not available"
    if value is None or isinstance(value, (str, int, float, bool)):
        return value
    return str(value)
