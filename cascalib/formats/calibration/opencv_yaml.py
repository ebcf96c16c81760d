"""One OpenCV FileStorage file (``.yml``/``.yaml``/``.xml``) holding the whole rig.

Node names follow the multi-camera convention of EasyMocap's ``intri.yml``/``extri.yml`` (itself
the one of OpenCV's stereo samples: a ``names`` list and per-camera ``<FIELD>_<name>`` nodes), in
one file:

==========================  ===================================================================
``names``                   sequence of camera names, in rig order
``K_<name>``                3x3 intrinsic matrix
``dist_<name>``             1x5 distortion ``k1 k2 p1 p2 k3`` (``D_<name>`` accepted on read)
``Rot_<name>``              3x3 rotation cam_from_world
``R_<name>``                the same rotation as a 3x1 Rodrigues vector (EasyMocap's node;
                            used on read only when ``Rot_<name>`` is absent)
``T_<name>``                3x1 translation cam_from_world, metres
``W_<name>``, ``H_<name>``  image width and height, pixels (int)
``fps_<name>``              frame rate (absent when unknown)
``time_offset_<name>``,     time mapping to the reference camera: frame ``k`` shows reference
``time_rate_<name>``        frame ``time_rate * k + time_offset`` (absent: 0 and 1)
``reference_camera``        name of the reference camera (optional)
``world``                   description of the world frame (optional)
==========================  ===================================================================

Camera names must be usable in node names (letters, digits, ``_``, ``-``). ``quality`` is not
kept.
"""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

import numpy as np

from cascalib.calibration import Calibration
from cascalib.camera import Camera
from cascalib.errors import CalibrationFileError
from cascalib.formats.calibration._filestorage import read_nodes, write_nodes
from cascalib.formats.calibration._validate import build_camera, check_node_name, matrix, require
from cascalib.geometry import matrix_to_rodrigues, rodrigues_to_matrix

__all__ = ["camera_from_nodes", "camera_nodes", "from_dict", "read", "to_dict", "write"]

logger = logging.getLogger(__name__)

UNKNOWN_WORLD = "unknown (from OpenCV FileStorage)"


def camera_nodes(cam: Camera, *, time: bool = True) -> dict[str, Any]:
    """The per-camera nodes of one camera (intrinsics, then extrinsics, then time)."""
    n = cam.name
    nodes: dict[str, Any] = {
        f"K_{n}": cam.K.copy(),
        f"dist_{n}": cam.dist[None, :].copy(),
        f"W_{n}": int(cam.image_size[0]),
        f"H_{n}": int(cam.image_size[1]),
        f"R_{n}": matrix_to_rodrigues(cam.R)[:, None],
        f"Rot_{n}": cam.R.copy(),
        f"T_{n}": cam.t[:, None].copy(),
    }
    if time:
        if cam.fps is not None:
            nodes[f"fps_{n}"] = float(cam.fps)
        nodes[f"time_offset_{n}"] = float(cam.time_offset)
        nodes[f"time_rate_{n}"] = float(cam.time_rate)
    return nodes


def camera_from_nodes(name: str, nodes: dict[str, Any], *, file: str | None,
                      guess_size: bool = False) -> Camera:
    """Build one camera from ``<FIELD>_<name>`` nodes (see the module table).

    ``guess_size`` (EasyMocap files often have no ``H_``/``W_``): take the image size as twice
    the principal point, with a warning, instead of failing.
    """
    K = require(nodes, f"K_{name}", file=file, camera=name, field=f"K_{name}")
    dist = nodes.get(f"dist_{name}", nodes.get(f"D_{name}"))
    if dist is None:
        raise CalibrationFileError(f"missing node 'dist_{name}'", file=file, camera=name,
                                   field=f"dist_{name}")
    r_field = f"Rot_{name}" if f"Rot_{name}" in nodes else f"R_{name}"
    if f"Rot_{name}" in nodes:
        R = nodes[f"Rot_{name}"]
    else:
        rvec = require(nodes, f"R_{name}", file=file, camera=name, field=f"R_{name}")
        rvec = np.asarray(rvec, dtype=np.float64)
        R = rvec if rvec.shape == (3, 3) else rodrigues_to_matrix(
            matrix(rvec.ravel(), (3,), file=file, camera=name, field=f"R_{name}"))
    t = require(nodes, f"T_{name}", file=file, camera=name, field=f"T_{name}")
    size = _image_size(name, nodes, K, file=file, guess=guess_size)
    return build_camera(
        name, file=file, image_size=size, K=K, dist=dist, R=R, t=t,
        fps=nodes.get(f"fps_{name}"), time_offset=nodes.get(f"time_offset_{name}", 0.0),
        time_rate=nodes.get(f"time_rate_{name}", 1.0),
        fields={"image_size": f"W_{name}", "K": f"K_{name}", "dist": f"dist_{name}",
                "R": r_field, "t": f"T_{name}"})


def _image_size(name: str, nodes: dict[str, Any], K: Any, *, file: str | None,
                guess: bool) -> Any:
    if f"W_{name}" in nodes and f"H_{name}" in nodes:
        return [nodes[f"W_{name}"], nodes[f"H_{name}"]]
    if not guess:
        raise CalibrationFileError(f"missing nodes 'W_{name}'/'H_{name}' (image size)",
                                   file=file, camera=name, field=f"W_{name}")
    K = matrix(K, (3, 3), file=file, camera=name, field=f"K_{name}")
    # Even sizes around the principal point: right for both the (W-1)/2 and the W/2 conventions.
    size = [int(2 * np.floor(K[0, 2] + 0.5)), int(2 * np.floor(K[1, 2] + 0.5))]
    logger.warning("%s: camera %s has no H_/W_ nodes; assuming image size %dx%d from the "
                   "principal point", file, name, *size)
    return size


def to_dict(calib: Calibration) -> dict[str, Any]:
    """The FileStorage nodes of a calibration, in writing order."""
    out: dict[str, Any] = {"names": list(calib.names)}
    for cam in calib.cameras:
        out.update(camera_nodes(cam))
    out["reference_camera"] = str(calib.reference_camera)
    out["world"] = calib.world
    return out


def camera_names(nodes: dict[str, Any], *, file: str | None) -> list[str]:
    """The ``names`` sequence, checked."""
    names = require(nodes, "names", file=file, field="names")
    if not isinstance(names, list) or not names or not all(isinstance(n, str) for n in names):
        raise CalibrationFileError("'names' must be a non-empty sequence of strings",
                                   file=file, field="names")
    return names


def from_dict(nodes: dict[str, Any], *, file: str | None = None,
              guess_size: bool = False) -> Calibration:
    """Build a :class:`Calibration` from FileStorage nodes (see the module table)."""
    names = camera_names(nodes, file=file)
    cameras = [camera_from_nodes(n, nodes, file=file, guess_size=guess_size) for n in names]
    try:
        return Calibration(cameras, reference_camera=nodes.get("reference_camera"),
                           world=str(nodes.get("world", UNKNOWN_WORLD)))
    except CalibrationFileError as exc:
        raise CalibrationFileError(exc.message, file=file, field=exc.field) from None


def read(path: str | Path) -> Calibration:
    """Read a rig from one OpenCV FileStorage file."""
    return from_dict(read_nodes(path), file=str(path))


def write(calib: Calibration, path: str | Path) -> list[Path]:
    """Write ``calib`` to one FileStorage file (format from the suffix: .yml, .yaml, .xml)."""
    for name in calib.names:
        check_node_name(name, file=str(path), fmt="OpenCV FileStorage")
    return [write_nodes(path, to_dict(calib))]
