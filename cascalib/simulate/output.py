"""Writing a simulated scene: detections in any keypoint format plus the ground truth."""

from __future__ import annotations

import json
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

if TYPE_CHECKING:
    from cascalib.simulate.scene import Scene

__all__ = ["save_scene", "TRACK_SUFFIX"]

#: File name suffix per keypoint format ("" = a folder, e.g. one OpenPose JSON per frame).
TRACK_SUFFIX: dict[str, str] = {
    "native-json": ".json", "native-npz": ".npz", "openpose": "", "mmpose": ".json",
    "cascalib-ref": ".json", "coco": ".json", "mediapipe-csv": ".csv",
}


def save_scene(scene: Scene, outdir: Path, fmt: str = "native-json") -> Path:
    """Write ``tracks/<camera><suffix>``, ``calibration.json`` and ``truth.npz`` to ``outdir``.

    ``truth.npz`` holds ``heights`` (P,), ``ground_normal`` (3,), ``ground_offset``, and per
    camera ``<cam>/joints3d`` (F_c, P, 26, 3), ``<cam>/frame_times`` (F_c,) world seconds and
    ``<cam>/slot_to_person`` (F_c, S_c).
    """
    from cascalib.formats import save_calibration, write_tracks

    fmt = "native-json" if fmt == "native" else fmt
    if fmt not in TRACK_SUFFIX:
        from cascalib.errors import InputError

        raise InputError(f"unknown keypoint format {fmt!r}; formats: {', '.join(TRACK_SUFFIX)}",
                         field="format")
    outdir.mkdir(parents=True, exist_ok=True)
    (outdir / "tracks").mkdir(exist_ok=True)
    for tr in scene.tracks:
        write_tracks(tr, outdir / "tracks" / f"{tr.camera}{TRACK_SUFFIX[fmt]}", format=fmt)
    save_calibration(scene.truth, outdir / "calibration.json", format="json")
    normal, offset = scene.ground_plane
    arrays: dict[str, Any] = {"heights": scene.heights, "ground_normal": normal,
                              "ground_offset": offset}
    for name in scene.camera_names:
        arrays[f"{name}/joints3d"] = scene.joints3d(name)
        arrays[f"{name}/frame_times"] = scene.frame_times(name)
        arrays[f"{name}/slot_to_person"] = scene.slot_to_person(name)
    np.savez_compressed(outdir / "truth.npz", allow_pickle=False, **arrays)
    info = {"seed": scene.seed, "config": scene.config.model_dump(mode="json"),
            "format": fmt, "cameras": scene.camera_names,
            "actions": [[list(a) for a in p.actions] for p in scene.people]}
    (outdir / "scene.json").write_text(json.dumps(info, indent=1))
    return outdir
