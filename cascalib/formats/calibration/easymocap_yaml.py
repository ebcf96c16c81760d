"""EasyMocap ``intri.yml`` + ``extri.yml`` (OpenCV FileStorage), written into a folder.

``intri.yml``: ``names``, then per camera ``K_<cam>`` (3x3), ``dist_<cam>`` (1x5), ``H_<cam>``,
``W_<cam>`` (image size; older EasyMocap files lack them: the size is then taken as twice the
principal point, with a warning). ``extri.yml``: ``names``, then per camera ``R_<cam>`` (3x1
Rodrigues), ``Rot_<cam>`` (3x3) and ``T_<cam>`` (3x1, metres), cam_from_world.

The format cannot hold frame rates, time offsets/rates, the reference camera, the world
description or ``quality``. The clocks and the reference camera go to ``cascalib_time.json`` in
the same folder (:mod:`._time_sidecar`) and :func:`read` takes them back; without it a read gives
``fps=None``, offset 0, rate 1 and the first camera as reference (with a warning).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from cascalib.calibration import Calibration
from cascalib.errors import CalibrationFileError
from cascalib.formats.calibration._filestorage import read_nodes, write_nodes
from cascalib.formats.calibration._time_sidecar import apply_time_sidecar, write_time_sidecar
from cascalib.formats.calibration._validate import check_node_name
from cascalib.formats.calibration.opencv_yaml import camera_from_nodes, camera_names, camera_nodes

__all__ = ["INTRI", "EXTRI", "from_dict", "read", "to_dict", "write"]

INTRI = "intri.yml"
EXTRI = "extri.yml"
WORLD = "EasyMocap world (as in the file; usually the calibration board's frame)"
_INTRI_FIELDS = ("K_", "dist_", "H_", "W_")
_EXTRI_FIELDS = ("R_", "Rot_", "T_")


def to_dict(calib: Calibration) -> dict[str, dict[str, Any]]:
    """``{"intri": nodes, "extri": nodes}`` as written to the two files."""
    intri: dict[str, Any] = {"names": list(calib.names)}
    extri: dict[str, Any] = {"names": list(calib.names)}
    for cam in calib.cameras:
        nodes = camera_nodes(cam, time=False)
        for field in _INTRI_FIELDS:
            intri[f"{field}{cam.name}"] = nodes[f"{field}{cam.name}"]
        for field in _EXTRI_FIELDS:
            extri[f"{field}{cam.name}"] = nodes[f"{field}{cam.name}"]
    return {"intri": intri, "extri": extri}


def from_dict(data: dict[str, dict[str, Any]], *, file: str | None = None) -> Calibration:
    """Build a :class:`Calibration` from ``{"intri": nodes, "extri": nodes}``."""
    names = camera_names(data["intri"], file=file)
    merged = {**data["extri"], **data["intri"]}
    cameras = [camera_from_nodes(n, merged, file=file, guess_size=True) for n in names]
    return Calibration(cameras, world=WORLD)


def _folder(path: str | Path) -> Path:
    path = Path(path)
    return path.parent if path.name in (INTRI, EXTRI) else path


def read(path: str | Path) -> Calibration:
    """Read ``intri.yml`` and ``extri.yml`` from a folder (or given one of the two files), with
    the clocks of ``cascalib_time.json`` beside them."""
    folder = _folder(path)
    for name in (INTRI, EXTRI):
        if not (folder / name).is_file():
            raise CalibrationFileError(f"EasyMocap calibration needs {name} next to "
                                       f"{'extri.yml' if name == INTRI else 'intri.yml'}",
                                       file=str(folder / name))
    data = {"intri": read_nodes(folder / INTRI), "extri": read_nodes(folder / EXTRI)}
    return apply_time_sidecar(from_dict(data, file=str(folder)), folder, fmt="EasyMocap")


def write(calib: Calibration, path: str | Path) -> list[Path]:
    """Write ``intri.yml``, ``extri.yml`` and the clocks' ``cascalib_time.json`` into the folder
    ``path``; returns the three files."""
    folder = _folder(path)
    for name in calib.names:
        check_node_name(name, file=str(folder), fmt="EasyMocap")
    data = to_dict(calib)
    return [write_nodes(folder / INTRI, data["intri"]), write_nodes(folder / EXTRI, data["extri"]),
            write_time_sidecar(calib, folder)]
