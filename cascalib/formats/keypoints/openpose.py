"""OpenPose JSON: one file per frame, ``{"people": [{"pose_keypoints_2d": [x, y, c] * J}]}``.

Layout read and written::

    cam01_json/                         # one folder per camera
        cam01_000000000000_keypoints.json    # OpenPose's own naming, or cam01.0000.json (Pose2Sim)
        ...

Each file holds ``{"version": 1.3, "people": [{"person_id": [id], "pose_keypoints_2d": [...]},
...]}``. ``0, 0, 0`` marks a missing joint. The frame (row) of a file is the *last* number in its
name (``cam01.0005.json`` -> 5, ``x_000000000005_keypoints.json`` -> 5). Files whose name does
not follow the folder's dominant pattern (e.g. Pose2Sim's stray ``del_*.json``) are skipped with
a warning. ``person_id`` becomes the track id when it is >= 0. People without a single detected
joint (all ``0, 0, 0``, or an empty list when OpenPose found only a face or hands) are empty
slots, not detections, and are dropped. The skeleton follows from the joint count
(BODY_25 vs BODY_25B from the content) unless given. OpenPose stores neither image size, frame
rate nor timestamps.
"""

from __future__ import annotations

import json
import logging
import re
from collections import Counter
from pathlib import Path
from typing import Any

import numpy as np

from cascalib.errors import InputError
from cascalib.formats.keypoints import _common as c
from cascalib.skeletons import Skeleton
from cascalib.tracks import Tracks

__all__ = ["read_openpose", "write_openpose", "frame_files"]

logger = logging.getLogger(__name__)

_NUMBER = re.compile(r"^(.*?)(\d+)(\D*)$")


def frame_files(folder: Path, *, camera: str | None = None) -> list[tuple[int, Path]]:
    """The frame files of an OpenPose folder with their frame numbers, in frame order.

    Raises
    ------
    InputError
        If the folder holds no frame file, or two files claim the same frame.
    """
    pattern: dict[Path, tuple[str, int]] = {}
    for p in sorted(folder.glob("*.json")):
        m = _NUMBER.match(p.stem)
        if m is None:
            logger.warning("%s: skipping %s: no frame number in its name", folder, p.name)
            continue
        pattern[p] = (f"{m.group(1)}#{m.group(3)}", int(m.group(2)))
    if not pattern:
        raise InputError("no OpenPose frame files (*.json with a frame number in the name)",
                         file=str(folder), camera=camera)
    counts = Counter(t for t, _ in pattern.values()).most_common()
    if len(counts) > 1 and counts[0][1] == counts[1][1]:
        raise InputError(f"cannot tell the frame files apart: as many files named like "
                         f"{counts[0][0]!r} as like {counts[1][0]!r}", file=str(folder),
                         camera=camera)
    main = counts[0][0]
    files: dict[int, Path] = {}
    for p, (template, number) in pattern.items():
        if template != main:
            logger.warning("%s: skipping %s: not a frame file (frames are named like %r)",
                           folder, p.name, main.replace("#", "N"))
        elif number in files:
            raise InputError(f"two files for frame {number}: {files[number].name} and {p.name}",
                             file=str(folder), camera=camera, frame=number)
        else:
            files[number] = p
    return sorted(files.items())


def _people(obj: Any, path: Path, frame: int, camera: str) -> list[Any]:
    if not isinstance(obj, dict) or not isinstance(obj.get("people"), list):
        raise InputError("an OpenPose frame must be an object with a 'people' list",
                         file=str(path), camera=camera, frame=frame, field="people")
    return obj["people"]


def _person_id(person: Any) -> Any:
    pid = person.get("person_id", -1)
    if isinstance(pid, list):
        pid = pid[0] if pid else -1
    return pid


def read_openpose(path: str | Path, *, camera: str | None = None,
                  skeleton: str | Skeleton | None = None, image_size: c.SizeArg = None,
                  fps: c.FpsArg = None) -> Tracks:
    """Read an OpenPose folder (or one frame file) into Tracks.

    Parameters
    ----------
    path : path
        Folder of per-frame JSON files, or a single frame file.
    camera : str, optional
        Camera name; default the folder name without a ``_json`` suffix.
    skeleton : str or Skeleton, optional
        Joint layout; default inferred from the joint count and content.
    image_size, fps : optional
        Not stored by OpenPose: the caller's values are used.

    Returns
    -------
    Tracks
        keypoints of shape (last frame + 1, max persons, J, 3).

    Raises
    ------
    InputError
        Unparseable JSON, missing ``people``, wrong joint counts, non-finite values, negative
        confidences, no detections; naming file, camera, frame and field.
    """
    path = Path(path)
    camera = camera or c.default_camera(path)
    files = frame_files(path, camera=camera) if path.is_dir() else [(_frame_of(path), path)]
    rows: list[Any] = []
    frames: list[int] = []
    ids: list[Any] = []
    where: list[Path] = []
    for frame, fp in files:
        for person in _people(c.load_json(fp, camera=camera), fp, frame, camera):
            if not isinstance(person, dict) or "pose_keypoints_2d" not in person:
                raise InputError("each person needs 'pose_keypoints_2d'", file=str(fp),
                                 camera=camera, frame=frame, field="pose_keypoints_2d")
            if person["pose_keypoints_2d"] == []:
                continue  # a person with no body joints (face or hands only): an empty slot
            rows.append(person["pose_keypoints_2d"])
            frames.append(frame)
            ids.append(_person_id(person))
            where.append(fp)
    return _build(rows, np.array(frames, np.int64), ids, where, path=path, camera=camera,
                  skeleton=skeleton, image_size=image_size, fps=fps,
                  n_frames=files[-1][0] + 1)


def _frame_of(path: Path) -> int:
    m = _NUMBER.match(path.stem)
    return int(m.group(2)) if m else 0


def _build(rows: list[Any], frames: np.ndarray, ids: list[Any], where: list[Path], *,
           path: Path, camera: str, skeleton: str | Skeleton | None, image_size: c.SizeArg,
           fps: c.FpsArg, n_frames: int) -> Tracks:
    c.require_records(len(rows), file=path, camera=camera, field="people")
    sk_joints = c.given_joints(skeleton, file=path, camera=camera)
    try:
        kp = c.as_records(rows, frames, n_joints=sk_joints, width=3, flat=True, file=path,
                          camera=camera, field="pose_keypoints_2d")
        c.check_values(kp, frames, file=path, camera=camera, field="pose_keypoints_2d")
    except InputError as exc:
        # Name the very file of the bad record rather than the folder.
        i = int(np.flatnonzero(frames == exc.frame)[0]) if exc.frame is not None else 0
        raise InputError(exc.message, file=str(where[i]), camera=camera, frame=exc.frame,
                         field=exc.field) from None
    kp = c.zeros_to_nan(kp)
    keep = np.isfinite(kp[..., 0]).any(-1)
    tid = c.track_numbers([i if isinstance(i, int) and i >= 0 else None for i in ids], frames,
                          file=path, camera=camera, field="person_id")
    sk = c.pick_skeleton(skeleton, kp[keep], file=path, camera=camera)
    dense, track_ids = c.pack(frames[keep], kp[keep], None if tid is None else tid[keep],
                              n_frames=n_frames, file=path, camera=camera)
    return Tracks(camera=camera, keypoints=dense, skeleton=sk,
                  image_size=c.resolve_image_size(None, image_size, camera=camera, file=path),
                  fps=c.resolve_fps(None, fps, camera=camera, file=path),
                  track_ids=track_ids, source=str(path))


def write_openpose(tracks: Tracks, folder: str | Path) -> list[Path]:
    """Write one OpenPose JSON file per frame (every row, empty frames too).

    Files are named ``{camera}_{frame:012d}_keypoints.json`` as OpenPose names them. Missing
    joints become ``0, 0, 0``; image size, fps and timestamps are not stored.

    Returns
    -------
    list of Path
        The files written, in frame order.
    """
    folder = Path(folder)
    folder.mkdir(parents=True, exist_ok=True)
    kp = c.nan_to_zeros(tracks.keypoints)
    _, _, present = c.unpack(tracks)
    tid = tracks.track_ids
    out = []
    for f in range(tracks.n_frames):
        people = [{"person_id": [int(tid[f, p]) if tid is not None else -1],
                   "pose_keypoints_2d": kp[f, p].ravel().tolist()}
                  for p in np.flatnonzero(present[f])]
        fp = folder / f"{tracks.camera}_{f:012d}_keypoints.json"
        fp.write_text(json.dumps({"version": 1.3, "people": people}, allow_nan=False),
                      encoding="utf-8")
        out.append(fp)
    return out
