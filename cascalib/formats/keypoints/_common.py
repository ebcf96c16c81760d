"""Helpers shared by the keypoint readers and writers.

Every reader collects its detections as flat records (one per person and frame), checks them all
at once with numpy, and packs them into the dense ``(n_frames, n_persons, n_joints, 3)`` array of
:class:`~cascalib.tracks.Tracks`. Checking flat arrays keeps readers fast (no Python loop per
joint) and lets every error name the first offending frame.
"""

from __future__ import annotations

import gc
import itertools
import json
import logging
import re
from collections.abc import Callable, Iterator, Mapping
from contextlib import contextmanager
from contextvars import ContextVar
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cascalib.errors import InputError
from cascalib.skeletons import SKELETONS, Skeleton, get_skeleton, infer_skeleton, to_canonical
from cascalib.tracks import Tracks, parse_image_size

logger = logging.getLogger(__name__)

_fast_loads: Callable[[bytes], Any] | None
try:  # optional: parses a large keypoint file several times faster than the json module
    import orjson  # type: ignore[import-not-found, unused-ignore]

    _fast_loads = orjson.loads
except ImportError:  # pragma: no cover - depends on what is installed
    _fast_loads = None

#: Image size as a caller may give it: "1920x1080", (W, H), or per camera {name: size}.
SizeArg = str | tuple[int, int] | list[int] | Mapping[str, Any] | None
#: Frame rate as a caller may give it: one value or per camera {name: fps}.
FpsArg = float | Mapping[str, float] | None

#: The dense array may hold this many (frame, person) slots per detection read, beyond
#: ``_SLOTS_FREE``: frame ids spread far apart would otherwise turn a small file into gigabytes.
_SLOTS_PER_DETECTION = 32
_SLOTS_FREE = 100_000


class LimitExceeded(InputError):
    """The keypoints exceed a limit the caller set with :func:`read_limits`."""


@dataclass(frozen=True)
class ReadLimits:
    """Bounds on what a reader may build for one camera (None: no bound).

    Attributes
    ----------
    max_frames : int, optional
        Rows of the dense array: the span of frame ids, 0 to the last.
    max_persons : int, optional
        Person slots: the most detections in one frame.
    max_bytes : int, optional
        Size of the dense ``(frames, persons, joints, 3)`` array.
    """

    max_frames: int | None = None
    max_persons: int | None = None
    max_bytes: int | None = None


_LIMITS: ContextVar[ReadLimits] = ContextVar("cascalib_read_limits", default=ReadLimits())


@contextmanager
def read_limits(limits: ReadLimits) -> Iterator[None]:
    """Apply ``limits`` to the readers called inside the ``with`` block (this thread only)."""
    token = _LIMITS.set(limits)
    try:
        yield
    finally:
        _LIMITS.reset(token)


def check_unpacked(n_bytes: int, *, file: Path | str, camera: str | None) -> None:
    """Refuse an archive (NPZ) whose arrays unpack to more than twice the keypoints' limit
    (the keypoints dominate; ids and timestamps are smaller), before it is unpacked.

    Raises
    ------
    LimitExceeded
        Over the ``max_bytes`` of :func:`read_limits`.
    """
    limit = _LIMITS.get().max_bytes
    if limit is not None and n_bytes > 2 * limit:
        raise LimitExceeded(f"the arrays unpack to {n_bytes} bytes, at most {2 * limit} "
                            "allowed", file=str(file), camera=camera, field="keypoints")


def check_dense(n_frames: int, n_persons: int, n_joints: int, *, n_detections: int | None,
                file: Path | str, camera: str) -> None:
    """Refuse a dense array the data does not justify, before it is allocated.

    Raises
    ------
    LimitExceeded
        Over a limit of :func:`read_limits`.
    InputError
        More than ``_SLOTS_PER_DETECTION`` empty slots per detection (frame ids far apart).
    """
    lim = _LIMITS.get()
    where: dict[str, Any] = {"file": str(file), "camera": camera}
    n_bytes = n_frames * n_persons * n_joints * 3 * 8
    for value, limit, what, field in (
            (n_frames, lim.max_frames, f"frame ids span {n_frames} frames", "frames"),
            (n_persons, lim.max_persons, f"{n_persons} people in one frame", "persons"),
            (n_bytes, lim.max_bytes, f"the keypoints need {n_bytes} bytes", "keypoints")):
        if limit is not None and value > limit:
            raise LimitExceeded(f"{what}, at most {limit} allowed", field=field, **where)
    slots = n_frames * n_persons
    if n_detections is not None and slots > _SLOTS_PER_DETECTION * n_detections + _SLOTS_FREE:
        raise InputError(f"{n_detections} detections spread over frame ids 0-{n_frames - 1} "
                         f"and {n_persons} person slots ({slots} slots, mostly empty): frame "
                         "ids must be the video's frame numbers", field="frames", **where)


def load_json(path: Path, *, camera: str | None = None) -> Any:
    """Parse one JSON file, turning syntax errors into an :class:`InputError` with line/column.

    orjson parses when it is installed; whatever it refuses (NaN literals, other encodings than
    UTF-8, huge integers, real syntax errors) the json module parses or words the error as
    always. The garbage collector is paused meanwhile (see :func:`gc_paused`).
    """
    try:
        with open(path, "rb") as fh:
            data = fh.read()
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror}", file=str(path), camera=camera) from None
    with gc_paused():
        if _fast_loads is not None:
            try:
                return _fast_loads(data)
            except ValueError:  # orjson.JSONDecodeError; the json module decides below
                pass
        try:
            return json.loads(data)
        except json.JSONDecodeError as exc:
            raise InputError(f"not valid JSON: {exc.msg} at line {exc.lineno}, column "
                             f"{exc.colno}", file=str(path), camera=camera) from None
        except UnicodeDecodeError as exc:
            raise InputError(f"not valid JSON text: {exc}", file=str(path),
                             camera=camera) from None


@contextmanager
def gc_paused() -> Iterator[None]:
    """Pause Python's cyclic garbage collector (if it runs) for the ``with`` block.

    Parsing a keypoint file makes millions of lists and dicts at once; the collector would walk
    all of them again and again while none of them can be garbage (they are freed by reference
    counting once the arrays are built).
    """
    was_enabled = gc.isenabled()
    gc.disable()
    try:
        yield
    finally:
        if was_enabled:
            gc.enable()


def default_camera(path: Path) -> str:
    """Camera name from a file or folder name: its stem, without a Pose2Sim ``_json`` suffix."""
    name = path.name if path.is_dir() else path.stem
    return re.sub(r"_json$", "", name) or name


def for_camera(value: Any, camera: str) -> Any:
    """Pick a caller's value for one camera: a mapping is looked up by name (key ``"*"``: every
    other camera), anything else is used as is."""
    if isinstance(value, Mapping):
        return value.get(camera, value.get("*"))
    return value


def resolve_image_size(from_file: Any, given: SizeArg, *, camera: str, file: Path | str | None
                       ) -> tuple[int, int] | None:
    """The image size of a camera: the file's, else the caller's; a disagreement is refused.

    A size the caller gives (for every camera or for this one) that differs from the size the
    file records is an error, never silently dropped nor silently applied: keypoints are in the
    pixels of the image the file describes (see docs/decisions/image-size-precedence.md).

    Raises
    ------
    InputError
        A malformed size, or a given size other than the file's (naming file and camera).
    """
    caller = for_camera(given, camera)
    caller_size = None if caller is None else parse_image_size(caller, camera=camera)
    if from_file is None:
        return caller_size
    where: dict[str, Any] = {"file": None if file is None else str(file), "camera": camera,
                             "field": "image_size"}
    try:
        size = parse_image_size(from_file, camera=camera)
    except InputError as exc:
        raise InputError(exc.message, **where) from None
    if caller_size is not None and caller_size != size:
        raise InputError(f"the given image size {caller_size[0]}x{caller_size[1]} differs from "
                         f"the {size[0]}x{size[1]} the file records: give the file's size or "
                         "none for this camera", **where)
    return size


def _positive(value: Any, *, what: str, file: Path | None, camera: str) -> float:
    try:
        fps = float(value)
    except (TypeError, ValueError):
        fps = np.nan
    if not (np.isfinite(fps) and fps > 0):
        raise InputError(f"{what} must be a positive number, got {value!r}",
                         file=None if file is None else str(file), camera=camera, field="fps")
    return fps


def resolve_fps(from_file: Any, given: FpsArg, *, camera: str, file: Path) -> float | None:
    """The frame rate stored in the file wins; the caller's is used where the file has none."""
    caller = for_camera(given, camera)
    if caller is not None:
        caller = _positive(caller, what="the given frame rate", file=None, camera=camera)
    if from_file is None:
        return caller
    fps = _positive(from_file, what="the frame rate in the file", file=file, camera=camera)
    if caller is not None and caller != fps:
        logger.warning("%s: camera %s: the file says %g fps, ignoring the given %g", file,
                       camera, fps, caller)
    return fps


def as_records(rows: list[Any], frames: NDArray[np.int64], *, n_joints: int | None,
               width: int, flat: bool, file: Path, camera: str, field: str
               ) -> NDArray[np.float64]:
    """Stack per-detection keypoint lists into an (N, J, width) float array.

    Parameters
    ----------
    rows : list
        Per detection, a flat list of ``J * width`` numbers (``flat``, e.g. OpenPose's
        ``[x, y, c] * J``) or a nested ``(J, width)`` list (mmpose's ``[[x, y], ...]``).
    frames : ndarray of int, shape (N,)
        Frame of each detection, for messages.
    n_joints : int, optional
        Expected joint count (from a given skeleton); else the first detection's count.
    width : int
        Number of values per joint.

    Raises
    ------
    InputError
        Naming the first detection's frame whose joint count or joint width differs or whose
        values are not numbers. ``null`` values become NaN (rejected by :func:`check_values`).
    """
    lengths = np.fromiter((len(r) if isinstance(r, list) else -1 for r in rows), np.int64,
                          len(rows))
    if flat and width > 1:
        bad = lengths % width != 0
        if bad.any():
            i = int(np.argmax(bad))
            raise InputError(f"{lengths[i]} values is not a whole number of joints of {width}"
                             " values", file=str(file), camera=camera, frame=int(frames[i]),
                             field=field)
        lengths = np.where(lengths < 0, -1, lengths // width)
    expect = n_joints if n_joints is not None else int(lengths[0])
    bad = lengths != expect
    if bad.any():
        i = int(np.argmax(bad))
        got = "no keypoint list" if lengths[i] < 0 else f"{lengths[i]} joints"
        raise InputError(f"expected {expect} joints, got {got}", file=str(file), camera=camera,
                         frame=int(frames[i]), field=field)
    where = {"file": str(file), "camera": camera, "field": field}
    if not flat:
        try:  # joint widths, counted at C speed
            widths = np.fromiter(map(len, itertools.chain.from_iterable(rows)), np.int64,
                                 len(rows) * expect).reshape(len(rows), expect)
        except TypeError:  # a joint that is not a list
            widths = np.array([[len(j) if isinstance(j, list) else -1 for j in r]
                               for r in rows])
        bad = (widths != width).any(-1)
        if bad.any():
            raise InputError(f"each joint needs {width} values", frame=int(frames[np.argmax(bad)]),
                             **where)
        try:  # fast path: no nested-sequence discovery
            chain = itertools.chain.from_iterable(itertools.chain.from_iterable(rows))
            flat_values = np.fromiter(chain, np.float64, len(rows) * expect * width)
            return flat_values.reshape(len(rows), expect, width)
        except (TypeError, ValueError):
            pass  # null or text somewhere: the slow path below turns null into NaN or names it
    try:
        arr = np.array(rows, dtype=np.float64)
    except (TypeError, ValueError):
        i = _first_non_numeric(rows)
        raise InputError("keypoint values must be numbers", frame=int(frames[i]),
                         **where) from None
    return arr.reshape(len(rows), expect, width)


def _first_non_numeric(rows: list[Any]) -> int:
    for i, r in enumerate(rows):
        try:
            np.array(r, dtype=np.float64)
        except (TypeError, ValueError):
            return i
    return 0


def check_values(kp: NDArray[np.float64], frames: NDArray[np.int64], *, file: Path, camera: str,
                 field: str = "keypoints", conf_field: str | None = None) -> None:
    """Reject NaN/inf coordinates or confidences and negative confidences, naming the frame.

    Parameters
    ----------
    kp : ndarray, shape (N, J, 3)
        Records as read (no missing markers converted yet).
    frames : ndarray of int, shape (N,)
        Frame of each record.
    """
    bad = ~np.isfinite(kp)
    if bad.any():
        i, j, c = (int(v) for v in np.argwhere(bad)[0])
        what = ("x", "y", "confidence")[c]
        raise InputError(f"{what} of joint {j} is {kp[i, j, c]} (NaN, infinite or null): "
                         "detector output must be finite numbers", file=str(file), camera=camera,
                         frame=int(frames[i]), field=conf_field if c == 2 and conf_field
                         else field)
    neg = kp[..., 2] < 0
    if neg.any():
        i, j = (int(v) for v in np.argwhere(neg)[0])
        raise InputError(f"negative confidence {kp[i, j, 2]:g} of joint {j}", file=str(file),
                         camera=camera, frame=int(frames[i]), field=conf_field or field)


def zeros_to_nan(kp: NDArray[np.float64]) -> NDArray[np.float64]:
    """Mark joints stored as ``0, 0, 0`` missing (NaN): the detectors' "not found" marker."""
    kp = kp.copy()
    kp[(kp == 0).all(-1)] = np.nan
    return kp


def nan_to_zeros(kp: NDArray[np.float64]) -> NDArray[np.float64]:
    """Inverse of :func:`zeros_to_nan` for writing: missing joints become ``0, 0, 0``."""
    return np.where(np.isnan(kp), 0.0, kp)


def pick_skeleton(given: str | Skeleton | None, kp: NDArray[np.float64], *, file: Path,
                  camera: str) -> Skeleton:
    """The caller's skeleton (checked against the joint count) or one inferred from content.

    Parameters
    ----------
    kp : ndarray, shape (N, J, 3)
        All records, NaN where missing.
    """
    n_joints = kp.shape[1]
    # Checked here so that a file of all-missing joints says so, not "skeleton ambiguous".
    require_records(int(np.isfinite(kp[..., 0]).any()), file=file, camera=camera,
                    field="keypoints")
    try:
        if given is not None:
            sk = get_skeleton(given)
            if sk.n_joints != n_joints:
                raise InputError(f"skeleton {sk.name} has {sk.n_joints} joints, the file has "
                                 f"{n_joints}", field="skeleton")
            return sk
        return infer_skeleton(n_joints, kp)
    except InputError as exc:
        raise InputError(exc.message, file=str(file), camera=camera,
                         field=exc.field or "skeleton") from None


def pack(frames: NDArray[np.int64], kp: NDArray[np.float64], ids: NDArray[np.int64] | None,
         n_frames: int | None = None, *, file: Path | None = None, camera: str = ""
         ) -> tuple[NDArray[np.float64], NDArray[np.int64] | None]:
    """Pack flat records into dense arrays; person slots keep the file's order within a frame.

    Parameters
    ----------
    frames : ndarray of int, shape (N,)
        Frame (row) of each record, >= 0.
    kp : ndarray, shape (N, J, 3)
    ids : ndarray of int, shape (N,), optional
        Track id of each record (-1 unknown).
    n_frames : int, optional
        Number of rows (at least ``frames.max() + 1``).
    file, camera : optional
        For the error when the array would be too large (:func:`check_dense`).

    Returns
    -------
    keypoints : ndarray, shape (n_frames, n_persons, J, 3)
        NaN padded.
    track_ids : ndarray of int, shape (n_frames, n_persons), or None
        None when no record has an id.
    """
    n_rows = int(frames.max()) + 1 if frames.size else 0
    n_rows = max(n_rows, n_frames or 0)
    order = np.argsort(frames, kind="stable")
    f_sorted = frames[order]
    starts = np.searchsorted(f_sorted, f_sorted, side="left")
    slot = np.empty_like(frames)
    slot[order] = np.arange(frames.size) - starts
    n_persons = int(slot.max()) + 1 if frames.size else 1
    check_dense(n_rows, n_persons, kp.shape[1], n_detections=frames.size,
                file=file or Path("?"), camera=camera)
    out = np.full((n_rows, n_persons, kp.shape[1], 3), np.nan)
    out[frames, slot] = kp
    if ids is None or not (ids >= 0).any():
        return out, None
    tid = np.full((n_rows, n_persons), -1, dtype=np.int64)
    tid[frames, slot] = np.where(ids >= 0, ids, -1)  # any negative id means "unknown"
    return out, tid


def unpack(tracks: Tracks) -> tuple[NDArray[np.int64], NDArray[np.int64], NDArray[np.bool_]]:
    """Frame and slot of every detection (a slot with at least one joint), in frame order.

    Returns
    -------
    frames, slots : ndarray of int, shape (N,)
    present : ndarray of bool, shape (n_frames, n_persons)
    """
    present = np.asarray(np.isfinite(tracks.keypoints[..., 0]).any(-1), dtype=bool)
    frames, slots = np.nonzero(present)
    return frames.astype(np.int64), slots.astype(np.int64), present


def convert_skeleton(tracks: Tracks, target: str, fmt: str) -> Tracks:
    """Re-map tracks to a format's fixed skeleton (via the canonical joints), logging the loss."""
    sk = SKELETONS[target]
    if tracks.skeleton.name == sk.name:
        return tracks
    logger.info("%s stores %s only: converting camera %s from %s", fmt, sk.name, tracks.camera,
                tracks.skeleton.name)
    can = to_canonical(tracks.keypoints, tracks.skeleton)
    idx = sk.canonical_indices
    kp = np.full(tracks.keypoints.shape[:2] + (sk.n_joints, 3), np.nan)
    kp[..., idx >= 0, :] = can[..., idx[idx >= 0], :]
    return tracks.with_(keypoints=kp, skeleton=sk)


def bbox(kp: NDArray[np.float64]) -> NDArray[np.float64]:
    """Box ``[x1, y1, x2, y2]`` around the present joints of each detection, shape (N, 4)."""
    with np.errstate(all="ignore"):
        return np.stack([np.nanmin(kp[..., 0], -1), np.nanmin(kp[..., 1], -1),
                         np.nanmax(kp[..., 0], -1), np.nanmax(kp[..., 1], -1)], -1)


def json_default(obj: Any) -> Any:
    """``json.dump`` fallback for numpy values inside ``Tracks.meta``."""
    if isinstance(obj, np.ndarray):
        return obj.tolist()
    if isinstance(obj, np.generic):
        return obj.item()
    if isinstance(obj, Path):
        return str(obj)
    raise TypeError(f"meta value of type {type(obj).__name__} cannot be written to JSON")


def write_json(obj: Any, path: Path) -> None:
    """Write compact JSON (no NaN tokens: they are not JSON)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    # json.dumps, not json.dump: only the one-shot encoder uses the C accelerator.
    text = json.dumps(obj, allow_nan=False, default=json_default, separators=(",", ":"))
    path.write_text(text, encoding="utf-8")


def frame_numbers(values: list[Any], *, file: Path, camera: str, field: str
                  ) -> NDArray[np.int64]:
    """Integer frame numbers (>= 0) from a JSON field, naming the first bad record."""
    ok = [isinstance(v, int) and not isinstance(v, bool) and v >= 0 for v in values]
    if not all(ok):
        i = ok.index(False)
        raise InputError(f"frame number must be an integer >= 0, got {values[i]!r} (record {i})",
                         file=str(file), camera=camera, field=field)
    return np.array(values, dtype=np.int64).reshape(len(values))


def track_numbers(values: list[Any], frames: NDArray[np.int64], *, file: Path, camera: str,
                  field: str) -> NDArray[np.int64] | None:
    """Integer track ids (None entries -> -1); None when no record has one."""
    if all(v is None for v in values):
        return None
    ok = [v is None or (isinstance(v, int) and not isinstance(v, bool)) for v in values]
    if not all(ok):
        i = ok.index(False)
        raise InputError(f"track id must be an integer, got {values[i]!r}", file=str(file),
                         camera=camera, frame=int(frames[i]), field=field)
    return np.array([-1 if v is None else v for v in values], dtype=np.int64)


def require_records(n: int, *, file: Path, camera: str, field: str) -> None:
    """Reject a file without a single detection."""
    if n == 0:
        raise InputError("no detections: the sequence is empty", file=str(file), camera=camera,
                         field=field)


def named_skeleton(skeleton: str | Skeleton, *, file: Path, camera: str | None) -> Skeleton:
    """:func:`get_skeleton` with the file and camera in its error."""
    try:
        return get_skeleton(skeleton)
    except InputError as exc:
        raise InputError(exc.message, file=str(file), camera=camera, field="skeleton") from None


def given_joints(skeleton: str | Skeleton | None, *, file: Path, camera: str) -> int | None:
    """Joint count of the caller's skeleton, or None when the skeleton is to be inferred."""
    return None if skeleton is None else named_skeleton(skeleton, file=file,
                                                         camera=camera).n_joints
