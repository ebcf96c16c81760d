"""``cascalib_time.json``: the clocks of a rig beside a COLMAP or EasyMocap folder.

Those formats have no place for frame rates, time offsets/rates or the reference camera; cascalib
writes them into this file next to the model, and its readers put them back::

    {"schema": "cascalib/time@1", "reference_camera": NAME,
     "cameras": {NAME: {"fps": F or null, "time_offset": O, "time_rate": S}}}

A folder without the file, or whose file names other cameras than the model, is read with the
neutral values (fps unknown, offset 0, rate 1) and a warning, never with guessed clocks.
"""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import Any

from cascalib.calibration import Calibration
from cascalib.errors import CalibrationFileError
from cascalib.formats.calibration._validate import build_camera

__all__ = ["SCHEMA", "TIME_SIDECAR", "apply_time_sidecar", "write_time_sidecar"]

logger = logging.getLogger(__name__)

TIME_SIDECAR = "cascalib_time.json"
SCHEMA = "cascalib/time@1"


def write_time_sidecar(calib: Calibration, folder: Path) -> Path:
    """Write the rig's clocks to ``folder/cascalib_time.json``; returns the file."""
    data = {"schema": SCHEMA, "reference_camera": calib.reference_camera,
            "cameras": {c.name: {"fps": c.fps, "time_offset": float(c.time_offset),
                                 "time_rate": float(c.time_rate)} for c in calib.cameras}}
    path = folder / TIME_SIDECAR
    path.write_text(json.dumps(data, indent=2, allow_nan=False) + "\n", encoding="utf-8")
    return path


def apply_time_sidecar(calib: Calibration, folder: Path, *, fmt: str) -> Calibration:
    """``calib`` with the clocks of ``folder/cascalib_time.json``, or as it is (with a warning
    saying what is missing) when the file is absent or names other cameras.

    Raises
    ------
    CalibrationFileError
        The file exists but is not valid (bad JSON, schema or values).
    """
    path = folder / TIME_SIDECAR
    if not path.is_file():
        logger.warning("%s: %s holds no frame rates or time offsets and there is no %s beside "
                       "it: fps unknown, time offsets 0, rates 1", folder, fmt, TIME_SIDECAR)
        return calib
    data = _load(path)
    cameras = data["cameras"]
    if sorted(cameras) != sorted(calib.names):
        logger.warning("%s: %s names cameras %s, the %s model %s: its clocks are not used (fps "
                       "unknown, time offsets 0, rates 1)", folder, TIME_SIDECAR,
                       sorted(cameras), fmt, sorted(calib.names))
        return calib
    timed = [build_camera(c.name, image_size=c.image_size, K=c.K, dist=c.dist, R=c.R, t=c.t,
                          fps=cameras[c.name].get("fps"),
                          time_offset=cameras[c.name].get("time_offset", 0.0),
                          time_rate=cameras[c.name].get("time_rate", 1.0), file=str(path))
             for c in calib.cameras]
    try:
        return Calibration(timed, reference_camera=data.get("reference_camera"),
                           world=calib.world)
    except CalibrationFileError as exc:
        raise CalibrationFileError(exc.message, file=str(path), field=exc.field) from None


def _load(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except json.JSONDecodeError as exc:
        raise CalibrationFileError(f"not valid JSON: {exc}", file=str(path)) from None
    if not isinstance(data, dict) or data.get("schema") != SCHEMA:
        raise CalibrationFileError(f"expected an object with schema {SCHEMA!r}", file=str(path),
                                   field="schema")
    cameras = data.get("cameras")
    if not isinstance(cameras, dict) or not all(isinstance(v, dict) for v in cameras.values()):
        raise CalibrationFileError("'cameras' must be an object {name: {fps, time_offset, "
                                   "time_rate}}", file=str(path), field="cameras")
    return data
