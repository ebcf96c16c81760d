"""MMPose / rtmlib inferencer JSON for one video.

Accepted layouts (one camera per file)::

    [{"frame_id": k, "instances": [{"keypoints": [[x, y], ...], "keypoint_scores": [s, ...],
                                    "bbox": [[x1, y1, x2, y2]], "track_id": 3}, ...]}, ...]
    {"meta_info": {...dataset meta...}, "instance_info": [ ...the list above... ]}
    [{"keypoints": [[x, y], ...], "keypoint_scores": [...]}, ...]       # one image: frame 0

``frame_id`` is the row as stored (mmpose's demo scripts count from 1, leaving row 0 empty; the
offset is the same for every camera processed alike, so synchronisation is unaffected).
``keypoint_scores`` is the confidence (1.0 where absent; ``keypoints`` may also carry it as a
third value). ``track_id`` (when a tracker ran) is the track id. ``bbox`` is not kept. A joint
stored as ``[0, 0]`` with score 0 is missing (what :func:`write_mmpose` writes for NaN joints).
The skeleton comes from ``meta_info.dataset_name`` when it names a known skeleton with the right
joint count, else from the joint count. Image size comes from ``meta_info.image_size`` ``[W, H]``
(or ``img_shape`` ``[H, W]``) when present; ``meta_info.fps`` likewise. These two meta keys are
cascalib's extension: mmpose itself stores neither.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from cascalib.errors import InputError
from cascalib.formats.keypoints import _common as c
from cascalib.skeletons import Skeleton, get_skeleton
from cascalib.tracks import Tracks

__all__ = ["read_mmpose", "write_mmpose", "from_json", "looks_like"]


def looks_like(obj: Any) -> bool:
    """True for the JSON structures this module reads."""
    if isinstance(obj, dict):
        return "instance_info" in obj
    if isinstance(obj, list) and obj and isinstance(obj[0], dict):
        return "instances" in obj[0] or ("keypoints" in obj[0] and "image_id" not in obj[0])
    return False


def read_mmpose(path: str | Path, *, camera: str | None = None,
                skeleton: str | Skeleton | None = None, image_size: c.SizeArg = None,
                fps: c.FpsArg = None) -> Tracks:
    """Read an mmpose / rtmlib prediction file into Tracks.

    Returns
    -------
    Tracks
        keypoints of shape (last frame_id + 1, max instances, J, 3).

    Raises
    ------
    InputError
        Bad JSON, missing fields, wrong joint counts, non-finite values, negative scores, no
        detections; naming file, camera, frame and field.
    """
    path = Path(path)
    camera = camera or c.default_camera(path)
    return from_json(c.load_json(path, camera=camera), path, camera=camera, skeleton=skeleton,
                     image_size=image_size, fps=fps)


def _frames(obj: Any, path: Path, camera: str) -> tuple[list[Any], dict[str, Any]]:
    meta: dict[str, Any] = {}
    if isinstance(obj, dict):
        meta = obj.get("meta_info") or {}
        obj = obj.get("instance_info")
    if not isinstance(obj, list):
        raise InputError("expected a list of frames ('instance_info')", file=str(path),
                         camera=camera, field="instance_info")
    if obj and isinstance(obj[0], dict) and "instances" not in obj[0]:
        obj = [{"frame_id": 0, "instances": obj}]  # a single image's instance list
    if not isinstance(meta, dict):
        raise InputError("'meta_info' must be an object", file=str(path), camera=camera,
                         field="meta_info")
    return obj, meta


def _records(frames_in: list[Any], path: Path, camera: str
             ) -> tuple[list[Any], list[Any], list[int], list[Any]]:
    kps, scores, frames, ids = [], [], [], []
    for k, fr in enumerate(frames_in):
        if not isinstance(fr, dict) or not isinstance(fr.get("instances"), list):
            raise InputError(f"frame entry {k} needs an 'instances' list", file=str(path),
                             camera=camera, field="instances")
        fid = fr.get("frame_id", k)
        if not isinstance(fid, int) or isinstance(fid, bool) or fid < 0:
            raise InputError(f"frame_id must be an integer >= 0, got {fid!r}", file=str(path),
                             camera=camera, field="frame_id")
        for inst in fr["instances"]:
            if not isinstance(inst, dict) or "keypoints" not in inst:
                raise InputError("each instance needs 'keypoints'", file=str(path),
                                 camera=camera, frame=fid, field="keypoints")
            kps.append(inst["keypoints"])
            scores.append(inst.get("keypoint_scores"))
            frames.append(fid)
            ids.append(inst.get("track_id"))
    return kps, scores, frames, ids


def _scores(scores: list[Any], frames: np.ndarray, n: int, path: Path, camera: str
            ) -> np.ndarray:
    if all(s is None for s in scores):
        return np.ones((len(scores), n))
    return c.as_records(scores, frames, n_joints=n, width=1, flat=True, file=path,
                        camera=camera, field="keypoint_scores")[..., 0]


def from_json(obj: Any, path: Path, *, camera: str, skeleton: str | Skeleton | None = None,
              image_size: c.SizeArg = None, fps: c.FpsArg = None) -> Tracks:
    """Build Tracks from parsed mmpose JSON (see :func:`read_mmpose`)."""
    frames_in, meta = _frames(obj, path, camera)
    kps, scores, frame_list, ids = _records(frames_in, path, camera)
    c.require_records(len(kps), file=path, camera=camera, field="instances")
    frames = np.array(frame_list, np.int64)
    first = kps[0][0] if kps[0] else None
    width = len(first) if isinstance(first, list) and len(first) in (2, 3) else 2
    n_given = c.given_joints(skeleton, file=path, camera=camera)
    xy = c.as_records(kps, frames, n_joints=n_given, width=width, flat=False, file=path,
                      camera=camera, field="keypoints")
    kp = np.empty(xy.shape[:2] + (3,))
    kp[..., :2] = xy[..., :2]
    kp[..., 2] = xy[..., 2] if width == 3 else _scores(scores, frames, xy.shape[1], path, camera)
    c.check_values(kp, frames, file=path, camera=camera, conf_field="keypoint_scores")
    kp = c.zeros_to_nan(kp)
    tid = c.track_numbers(ids, frames, file=path, camera=camera, field="track_id")
    sk = c.pick_skeleton(skeleton or _meta_skeleton(meta, int(xy.shape[1])), kp, file=path,
                         camera=camera)
    n_frames = max((f.get("frame_id", k) for k, f in enumerate(frames_in)), default=0) + 1
    dense, track_ids = c.pack(frames, kp, tid, n_frames=n_frames, file=path, camera=camera)
    return Tracks(camera=camera, keypoints=dense, skeleton=sk,
                  image_size=c.resolve_image_size(_meta_size(meta), image_size, camera=camera,
                                                  file=path),
                  fps=c.resolve_fps(meta.get("fps"), fps, camera=camera, file=path),
                  track_ids=track_ids, source=str(path))


def _meta_skeleton(meta: dict[str, Any], n_joints: int) -> Skeleton | None:
    name = meta.get("dataset_name")
    if not isinstance(name, str):
        return None
    try:
        sk = get_skeleton(name)
    except InputError:
        return None
    return sk if sk.n_joints == n_joints else None


def _meta_size(meta: dict[str, Any]) -> Any:
    if "image_size" in meta:
        return meta["image_size"]
    shape = meta.get("img_shape")
    return None if shape is None else (shape[1], shape[0])


def write_mmpose(tracks: Tracks, path: str | Path) -> Path:
    """Write the ``{"meta_info", "instance_info"}`` form, one frame entry per row.

    Missing joints become ``[0, 0]`` with score 0; ``bbox`` is the box around the present
    joints. Image size and fps go to ``meta_info`` when known; timestamps are not stored.
    """
    path = Path(path)
    sk = tracks.skeleton
    meta: dict[str, Any] = {"dataset_name": sk.name, "num_keypoints": sk.n_joints,
                            "keypoint_id2name": {str(i): n for i, n in
                                                 enumerate(sk.joint_names)}}
    if tracks.image_size is not None:
        meta["image_size"] = list(tracks.image_size)
    if tracks.fps is not None:
        meta["fps"] = tracks.fps
    kp = c.nan_to_zeros(tracks.keypoints)
    frames, slots, present = c.unpack(tracks)
    boxes = c.bbox(tracks.keypoints[frames, slots]).tolist()
    xy = kp[frames, slots, :, :2].tolist()
    sc = kp[frames, slots, :, 2].tolist()
    info: list[dict[str, Any]] = [{"frame_id": f, "instances": []}
                                  for f in range(tracks.n_frames)]
    for i, (f, p) in enumerate(zip(frames.tolist(), slots.tolist(), strict=True)):
        inst: dict[str, Any] = {"keypoints": xy[i], "keypoint_scores": sc[i],
                                "bbox": [boxes[i]], "bbox_score": 1.0}
        if tracks.track_ids is not None and tracks.track_ids[f, p] >= 0:
            inst["track_id"] = int(tracks.track_ids[f, p])
        info[f]["instances"].append(inst)
    c.write_json({"meta_info": meta, "instance_info": info}, path)
    return path
