"""cascalib's own keypoint files: every :class:`~cascalib.tracks.Tracks` field, losslessly.

JSON (``*.json``), schema tag ``cascalib/tracks@1``::

    {
      "schema": "cascalib/tracks@1",
      "camera": "cam0",
      "skeleton": {"name": "coco17", "joint_names": [...], "canonical": [... or null]},
      "image_size": [1920, 1080] | null,           # (width, height) pixels
      "fps": 30.0 | null,
      "shape": [n_frames, n_persons, n_joints],
      "keypoints": [[[[x, y, c] | null, ...joints], ...persons], ...frames],
      "timestamps": [t0, t1 | null, ...] | null,   # seconds, null where unknown
      "track_ids": [[id, ...persons], ...frames] | null,   # -1 unknown
      "meta": {...}                                # free JSON object
    }

``null`` in ``keypoints`` is a missing joint (NaN in all three of x, y, confidence). Floats are
written with Python's shortest round-trip repr, so values read back bit-identical.

NPZ (``*.npz``): arrays ``keypoints`` (F, P, J, 3) float64 with NaN, optional ``timestamps``
(F,) and ``track_ids`` (F, P) int64, and ``header``: a 0-d string array holding the JSON object
above without its three array fields. ``meta`` must be JSON-serialisable (numpy arrays in it
are written as lists). ``source`` is not stored: it is the path the tracks are read from.
"""

from __future__ import annotations

import itertools
import json
import zipfile
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cascalib.errors import InputError
from cascalib.formats.keypoints import _common as c
from cascalib.skeletons import SKELETONS, Skeleton
from cascalib.tracks import Tracks

__all__ = ["SCHEMA", "read_native_json", "write_native_json", "read_native_npz",
           "write_native_npz", "from_json", "looks_like"]

SCHEMA = "cascalib/tracks@1"


def looks_like(obj: Any) -> bool:
    """True for a JSON object carrying a ``cascalib/tracks@...`` schema tag."""
    return isinstance(obj, dict) and str(obj.get("schema", "")).startswith("cascalib/tracks@")


def _header(tracks: Tracks) -> dict[str, Any]:
    sk = tracks.skeleton
    return {"schema": SCHEMA, "camera": tracks.camera,
            "skeleton": {"name": sk.name, "joint_names": list(sk.joint_names),
                         "canonical": list(sk.canonical)},
            "image_size": None if tracks.image_size is None else list(tracks.image_size),
            "fps": tracks.fps, "shape": list(tracks.keypoints.shape[:3]),
            "meta": json.loads(json.dumps(tracks.meta, default=c.json_default))}


def _skeleton(spec: Any, path: Path, camera: str) -> Skeleton:
    """A known skeleton when the name and joints match, else the custom one as stored."""
    if isinstance(spec, str):
        return c.named_skeleton(spec, file=path, camera=camera)
    try:
        names = tuple(spec["joint_names"])
        canonical = tuple(spec["canonical"])
        known = SKELETONS.get(spec["name"])
        if known is not None and known.joint_names == names and known.canonical == canonical:
            return known
        return Skeleton(str(spec["name"]), names, canonical)
    except (KeyError, TypeError, AssertionError):
        raise InputError("skeleton must be {name, joint_names, canonical} with one canonical "
                         "name (or null) per joint", file=str(path), camera=camera,
                         field="skeleton") from None


def _array(value: Any, shape: tuple[int, ...], dtype: Any, *, path: Path, camera: str,
           name: str) -> NDArray[Any]:
    try:
        arr = np.array(value, dtype=dtype)
    except (TypeError, ValueError):
        raise InputError("not an array of numbers (null for missing)", file=str(path),
                         camera=camera, field=name) from None
    if arr.shape != shape:
        raise InputError(f"shape {arr.shape} does not match {shape} ('shape' field)",
                         file=str(path), camera=camera, field=name)
    return arr


def from_json(obj: Any, path: Path, *, camera: str | None = None, skeleton: Any = None,
              image_size: c.SizeArg = None, fps: c.FpsArg = None,
              arrays: dict[str, NDArray[Any]] | None = None) -> Tracks:
    """Build Tracks from the parsed JSON object (or an NPZ header plus its ``arrays``)."""
    if not looks_like(obj) or obj["schema"] != SCHEMA:
        got = obj.get("schema") if isinstance(obj, dict) else None
        raise InputError(f"unsupported schema {got!r}; this version reads {SCHEMA!r}",
                         file=str(path), field="schema")
    cam = camera or obj.get("camera") or c.default_camera(path)
    try:
        shape = tuple(int(v) for v in obj["shape"])
        if len(shape) != 3:
            raise ValueError
    except (KeyError, TypeError, ValueError):
        raise InputError("'shape' must be [n_frames, n_persons, n_joints]", file=str(path),
                         camera=cam, field="shape") from None
    c.check_dense(*shape, n_detections=None, file=path, camera=cam)
    src = arrays if arrays is not None else obj
    kp = _array(src.get("keypoints"), shape + (3,), np.float64, path=path, camera=cam,
                name="keypoints") if arrays is not None else _keypoints(obj, shape, path, cam)
    ts = src.get("timestamps")
    ts = None if ts is None else _array(ts, shape[:1], np.float64, path=path, camera=cam,
                                        name="timestamps")
    tid = src.get("track_ids")
    tid = None if tid is None else _array(tid, shape[:2], np.int64, path=path, camera=cam,
                                          name="track_ids")
    sk = _skeleton(obj.get("skeleton"), path, cam)
    if skeleton is not None and c.named_skeleton(skeleton, file=path, camera=cam) != sk:
        raise InputError(f"the file says skeleton {sk.name}, not {skeleton}", file=str(path),
                         camera=cam, field="skeleton")
    meta = obj.get("meta") or {}
    if not isinstance(meta, dict):
        raise InputError("'meta' must be an object", file=str(path), camera=cam, field="meta")
    return Tracks(camera=cam, keypoints=kp, skeleton=sk,
                  image_size=c.resolve_image_size(obj.get("image_size"), image_size,
                                                  camera=cam, file=path),
                  fps=c.resolve_fps(obj.get("fps"), fps, camera=cam, file=path),
                  timestamps=ts, track_ids=tid, source=str(path), meta=meta)


def _keypoints(obj: dict[str, Any], shape: tuple[int, ...], path: Path, camera: str
               ) -> NDArray[np.float64]:
    """Nested lists with ``null`` joints -> (F, P, J, 3) with NaN."""
    raw: Any = obj.get("keypoints")
    n_f, n_p, n_j = shape
    nan3 = (np.nan, np.nan, np.nan)
    bad = InputError(f"'keypoints' must be nested lists of {n_f} frames x {n_p} persons x "
                     f"{n_j} joints, each [x, y, c] or null ('shape' field)", file=str(path),
                     camera=camera, field="keypoints")
    try:
        ok = len(raw) == n_f and all(len(fr) == n_p and all(len(pe) == n_j for pe in fr)
                                     for fr in raw)
        joints: list[Any] = [nan3 if j is None else j for fr in raw for pe in fr for j in pe]
        ok = ok and all(len(j) == 3 for j in joints)
        if not ok:
            raise bad
        flat = np.fromiter(itertools.chain.from_iterable(joints), np.float64, n_f * n_p * n_j * 3)
    except (TypeError, ValueError):
        raise bad from None
    return flat.reshape(shape + (3,))


def read_native_json(path: str | Path, *, camera: str | None = None, skeleton: Any = None,
                     image_size: c.SizeArg = None, fps: c.FpsArg = None) -> Tracks:
    """Read a ``cascalib/tracks@1`` JSON file (see the module docstring for the layout)."""
    path = Path(path)
    return from_json(c.load_json(path, camera=camera), path, camera=camera, skeleton=skeleton,
                     image_size=image_size, fps=fps)


def write_native_json(tracks: Tracks, path: str | Path) -> Path:
    """Write every field of ``tracks`` to a ``cascalib/tracks@1`` JSON file."""
    path = Path(path)
    obj = _header(tracks)
    kp = tracks.keypoints
    missing = np.isnan(kp[..., 0]).ravel().tolist()
    joints: list[Any] = [None if m else j for j, m in
                         zip(kp.reshape(-1, 3).tolist(), missing, strict=True)]
    n_f, n_p, n_j = kp.shape[:3]
    obj["keypoints"] = [[joints[(f * n_p + p) * n_j:(f * n_p + p + 1) * n_j]
                         for p in range(n_p)] for f in range(n_f)]
    obj["timestamps"] = None if tracks.timestamps is None else [
        None if np.isnan(t) else t for t in tracks.timestamps.tolist()]
    obj["track_ids"] = None if tracks.track_ids is None else tracks.track_ids.tolist()
    c.write_json(obj, path)
    return path


def read_native_npz(path: str | Path, *, camera: str | None = None, skeleton: Any = None,
                    image_size: c.SizeArg = None, fps: c.FpsArg = None) -> Tracks:
    """Read a cascalib NPZ file (see the module docstring for the layout)."""
    path = Path(path)
    try:
        with np.load(path, allow_pickle=False) as z:
            c.check_unpacked(sum(i.file_size for i in z.zip.infolist()), file=path,
                             camera=camera)
            arrays = {k: z[k] for k in z.files}
    except InputError:
        raise
    except (OSError, ValueError, zipfile.BadZipFile) as exc:
        raise InputError(f"not a readable NPZ file: {exc}", file=str(path),
                         camera=camera) from None
    if "header" not in arrays or "keypoints" not in arrays:
        raise InputError("not a cascalib NPZ: needs arrays 'header' and 'keypoints' (has "
                         f"{sorted(arrays)})", file=str(path), camera=camera, field="header")
    try:
        obj = json.loads(str(arrays.pop("header")))
    except json.JSONDecodeError as exc:
        raise InputError(f"header is not valid JSON: {exc.msg}", file=str(path), camera=camera,
                         field="header") from None
    return from_json(obj, path, camera=camera, skeleton=skeleton, image_size=image_size,
                     fps=fps, arrays=arrays)


def write_native_npz(tracks: Tracks, path: str | Path) -> Path:
    """Write every field of ``tracks`` to a compressed NPZ file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    arrays: dict[str, NDArray[Any]] = {
        "header": np.array(json.dumps(_header(tracks), allow_nan=False)),
        "keypoints": tracks.keypoints}
    if tracks.timestamps is not None:
        arrays["timestamps"] = tracks.timestamps
    if tracks.track_ids is not None:
        arrays["track_ids"] = tracks.track_ids
    with open(path, "wb") as fh:  # a file object: np.savez would append ".npz" to other names
        np.savez_compressed(fh, **arrays)  # type: ignore[arg-type]
    return path
