"""Writing a simulated scene: detections in any keypoint format plus the ground truth."""

from __future__ import annotations

import json
import logging
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from cascalib.tracks import Tracks

if TYPE_CHECKING:
    from cascalib.simulate.scene import Scene

__all__ = ["save_scene", "TRACK_SUFFIX"]

logger = logging.getLogger(__name__)

#: File name suffix per keypoint format ("" = a folder, e.g. one OpenPose JSON per frame).
TRACK_SUFFIX: dict[str, str] = {
    "native-json": ".json", "native-npz": ".npz", "openpose": "", "mmpose": ".json",
    "cascalib-ref": ".json", "coco": ".json", "mediapipe-csv": ".csv",
}


def _write_tracks(tracks: Tracks, path: Path, fmt: str) -> None:
    try:
        from cascalib.formats import write_tracks  # type: ignore[attr-defined]
    except ImportError:
        write_tracks = None
    if write_tracks is not None:
        write_tracks(tracks, path, format=fmt)
        return
    # The keypoint writers are not available yet: keep the data in a plain npz.
    logger.warning("cascalib.formats.write_tracks not available: writing %s as npz", path)
    np.savez_compressed(path.with_suffix(".npz"), keypoints=tracks.keypoints,
                        track_ids=(tracks.track_ids if tracks.track_ids is not None
                                   else np.zeros((0, 0), int)),
                        skeleton=tracks.skeleton.name, camera=tracks.camera,
                        image_size=np.asarray(tracks.image_size), fps=tracks.fps or 0.0)


def save_scene(scene: Scene, outdir: Path, fmt: str = "native-json") -> Path:
    """Write ``tracks/<camera><suffix>``, ``calibration.json`` and ``truth.npz`` to ``outdir``.

    ``truth.npz`` holds ``heights`` (P,), ``ground_normal`` (3,), ``ground_offset``, and per
    camera ``<cam>/joints3d`` (F_c, P, 26, 3), ``<cam>/frame_times`` (F_c,) world seconds and
    ``<cam>/slot_to_person`` (F_c, S_c).
    """
    from cascalib.formats import save_calibration

    if fmt not in TRACK_SUFFIX:
        from cascalib.errors import InputError

        raise InputError(f"unknown keypoint format {fmt!r}; formats: {', '.join(TRACK_SUFFIX)}",
                         field="format")
    outdir.mkdir(parents=True, exist_ok=True)
    (outdir / "tracks").mkdir(exist_ok=True)
    for tr in scene.tracks:
        _write_tracks(tr, outdir / "tracks" / f"{tr.camera}{TRACK_SUFFIX[fmt]}", fmt)
    save_calibration(scene.truth, outdir / "calibration.json", format="json")
    normal, offset = scene.ground_plane
    arrays = {"heights": scene.heights, "ground_normal": normal, "ground_offset": offset}
    for name in scene.camera_names:
        arrays[f"{name}/joints3d"] = scene.joints3d(name)
        arrays[f"{name}/frame_times"] = scene.frame_times(name)
        arrays[f"{name}/slot_to_person"] = scene.slot_to_person(name)
    np.savez_compressed(outdir / "truth.npz", **arrays)
    info = {"seed": scene.seed, "config": scene.config.model_dump(mode="json"),
            "format": fmt, "cameras": scene.camera_names,
            "actions": [[list(a) for a in p.actions] for p in scene.people]}
    (outdir / "scene.json").write_text(json.dumps(info, indent=1))
    return outdir
