"""COCO keypoint *results* (detector output), one camera per file::

    [{"image_id": 12, "category_id": 1, "keypoints": [x, y, v] * 17, "score": 0.93,
      "track_id": 3}, ...]

``image_id`` is the frame (row). The confidence of a joint is its third value ``v``: results files
(mmpose, detectron2) store the keypoint score there. Only when *every* ``v`` in the file is one of
the annotation visibility flags 0, 1, 2 is the file read as annotations: ``v > 0`` is a present
joint whose confidence is the instance ``score`` (1.0 without one). ``0, 0, 0`` (or ``v = 0`` in
annotation files) is missing. ``track_id`` (PoseTrack style) is kept when present;
``category_id`` is not checked (keypoint results are persons). COCO stores 17 joints:
:func:`write_coco` converts other skeletons through the canonical joints. No image size, frame
rate or timestamps.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from cascalib.errors import InputError
from cascalib.formats.keypoints import _common as c
from cascalib.skeletons import Skeleton
from cascalib.tracks import Tracks

__all__ = ["read_coco", "write_coco", "from_json", "looks_like"]


def looks_like(obj: Any) -> bool:
    """True for a list of records with ``image_id`` and ``keypoints``."""
    return (isinstance(obj, list) and bool(obj) and isinstance(obj[0], dict)
            and "image_id" in obj[0] and "keypoints" in obj[0])


def read_coco(path: str | Path, *, camera: str | None = None,
              skeleton: str | Skeleton | None = None, image_size: c.SizeArg = None,
              fps: c.FpsArg = None) -> Tracks:
    """Read a COCO keypoint results file into Tracks.

    Returns
    -------
    Tracks
        keypoints of shape (last image_id + 1, max detections per image, J, 3).

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
    """Build Tracks from a parsed COCO results list."""
    if not isinstance(obj, list):
        raise InputError("expected a list of COCO keypoint results", file=str(path),
                         camera=camera)
    c.require_records(len(obj), file=path, camera=camera, field="keypoints")
    for k, rec in enumerate(obj):
        if not isinstance(rec, dict) or "image_id" not in rec or "keypoints" not in rec:
            raise InputError(f"result {k} needs 'image_id' and 'keypoints'", file=str(path),
                             camera=camera, field="keypoints")
    frames = c.frame_numbers([r["image_id"] for r in obj], file=path, camera=camera,
                             field="image_id")
    kp = c.as_records([r["keypoints"] for r in obj], frames,
                      n_joints=c.given_joints(skeleton, file=path, camera=camera), width=3,
                      flat=True, file=path, camera=camera, field="keypoints")
    c.check_values(kp, frames, file=path, camera=camera)
    kp = _annotation_flags(kp, obj, frames, path, camera)
    tid = c.track_numbers([r.get("track_id") for r in obj], frames, file=path, camera=camera,
                          field="track_id")
    sk = c.pick_skeleton(skeleton, kp, file=path, camera=camera)
    dense, track_ids = c.pack(frames, kp, tid, file=path, camera=camera)
    return Tracks(camera=camera, keypoints=dense, skeleton=sk,
                  image_size=c.resolve_image_size(None, image_size, camera=camera, file=path),
                  fps=c.resolve_fps(None, fps, camera=camera, file=path),
                  track_ids=track_ids, source=str(path))


def _annotation_flags(kp: np.ndarray, obj: list[Any], frames: np.ndarray, path: Path,
                      camera: str) -> np.ndarray:
    """Missing joints to NaN; visibility flags to the instance score (see module docstring)."""
    v = kp[..., 2]
    if not np.isin(v, (0.0, 1.0, 2.0)).all():
        return c.zeros_to_nan(kp)
    scores = [r.get("score", 1.0) for r in obj]
    try:
        s = np.array(scores, dtype=np.float64).reshape(len(obj))
    except (TypeError, ValueError):
        s = np.full(len(obj), np.nan)
    bad = ~np.isfinite(s) | (s < 0)
    if bad.any():
        i = int(np.argmax(bad))
        raise InputError(f"instance score must be a number >= 0, got {scores[i]!r}",
                         file=str(path), camera=camera, frame=int(frames[i]), field="score")
    kp = kp.copy()
    kp[..., 2] = s[:, None]
    kp[v == 0] = np.nan
    return kp


def write_coco(tracks: Tracks, path: str | Path) -> Path:
    """Write COCO results: 17 joints, ``v`` = confidence, ``score`` = mean confidence."""
    path = Path(path)
    tracks = c.convert_skeleton(tracks, "coco17", "coco")
    frames, slots, _ = c.unpack(tracks)
    raw = tracks.keypoints[frames, slots]
    score = np.nanmean(raw[..., 2], axis=-1).tolist()
    kp = c.nan_to_zeros(raw).reshape(len(frames), -1).tolist()
    tid = None if tracks.track_ids is None else tracks.track_ids[frames, slots].tolist()
    out: list[dict[str, Any]] = []
    for i, f in enumerate(frames.tolist()):
        rec: dict[str, Any] = {"image_id": f, "category_id": 1, "keypoints": kp[i],
                               "score": score[i]}
        if tid is not None and tid[i] >= 0:
            rec["track_id"] = tid[i]
        out.append(rec)
    c.write_json(out, path)
    return path
