"""The CasCalib reference implementation's detection layout (one camera per file)::

    {"Info": [{"frame": 12, "track_id": 3, "bbox": [x1, y1, x2, y2],
               "keypoints": [[u, v, c], ...17 COCO joints...]}, ...]}

One entry per detection. ``frame`` is the row; ``track_id`` the track id (negative = unknown);
``bbox`` is not kept (it is rewritten around the present joints). ``0, 0, 0`` is a missing joint.
The reference code works with COCO-17; other joint counts are read with the skeleton inferred
from the count, and :func:`write_cascalib_ref` converts any skeleton to COCO-17 through the
canonical joints. No image size, frame rate or timestamps; frames after the last detection are
not represented.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from cascalib.errors import InputError
from cascalib.formats.keypoints import _common as c
from cascalib.skeletons import Skeleton
from cascalib.tracks import Tracks

__all__ = ["read_cascalib_ref", "write_cascalib_ref", "from_json", "looks_like"]


def looks_like(obj: Any) -> bool:
    """True for ``{"Info": [...]}``."""
    return isinstance(obj, dict) and "Info" in obj


def read_cascalib_ref(path: str | Path, *, camera: str | None = None,
                      skeleton: str | Skeleton | None = None, image_size: c.SizeArg = None,
                      fps: c.FpsArg = None) -> Tracks:
    """Read a CasCalib reference detection file into Tracks.

    Returns
    -------
    Tracks
        keypoints of shape (last frame + 1, max detections per frame, J, 3).

    Raises
    ------
    InputError
        Naming file, camera, frame and field for every malformed record.
    """
    path = Path(path)
    camera = camera or c.default_camera(path)
    return from_json(c.load_json(path, camera=camera), path, camera=camera, skeleton=skeleton,
                     image_size=image_size, fps=fps)


def from_json(obj: Any, path: Path, *, camera: str, skeleton: str | Skeleton | None = None,
              image_size: c.SizeArg = None, fps: c.FpsArg = None) -> Tracks:
    """Build Tracks from a parsed ``{"Info": [...]}`` object."""
    info = obj.get("Info") if isinstance(obj, dict) else None
    if not isinstance(info, list):
        raise InputError("expected {'Info': [detections]}", file=str(path), camera=camera,
                         field="Info")
    c.require_records(len(info), file=path, camera=camera, field="Info")
    for k, rec in enumerate(info):
        if not isinstance(rec, dict) or "frame" not in rec or "keypoints" not in rec:
            raise InputError(f"detection {k} needs 'frame' and 'keypoints'", file=str(path),
                             camera=camera, field="Info")
    frames = c.frame_numbers([r["frame"] for r in info], file=path, camera=camera,
                             field="frame")
    kp = c.as_records([r["keypoints"] for r in info], frames,
                      n_joints=c.given_joints(skeleton, file=path, camera=camera), width=3,
                      flat=False, file=path, camera=camera, field="keypoints")
    c.check_values(kp, frames, file=path, camera=camera)
    kp = c.zeros_to_nan(kp)
    tid = c.track_numbers([r.get("track_id") for r in info], frames, file=path, camera=camera,
                          field="track_id")
    sk = c.pick_skeleton(skeleton, kp, file=path, camera=camera)
    dense, track_ids = c.pack(frames, kp, tid, file=path, camera=camera)
    return Tracks(camera=camera, keypoints=dense, skeleton=sk,
                  image_size=c.resolve_image_size(None, image_size, camera=camera, file=path),
                  fps=c.resolve_fps(None, fps, camera=camera, file=path),
                  track_ids=track_ids, source=str(path))


def write_cascalib_ref(tracks: Tracks, path: str | Path) -> Path:
    """Write ``{"Info": [...]}`` with COCO-17 keypoints, one entry per detection."""
    path = Path(path)
    tracks = c.convert_skeleton(tracks, "coco17", "cascalib-ref")
    frames, slots, _ = c.unpack(tracks)
    kp = c.nan_to_zeros(tracks.keypoints[frames, slots]).tolist()
    boxes = c.bbox(tracks.keypoints[frames, slots]).tolist()
    tid = (np.full(frames.size, -1) if tracks.track_ids is None
           else tracks.track_ids[frames, slots]).tolist()
    info = [{"frame": f, "track_id": t, "bbox": b, "keypoints": k}
            for f, t, b, k in zip(frames.tolist(), tid, boxes, kp, strict=True)]
    c.write_json({"Info": info}, path)
    return path
