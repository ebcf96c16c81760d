"""Format detection and the format-independent entry points ``read_tracks`` / ``write_tracks``.

Formats and how they are recognised (content first, never the file name alone):

==================  =========================================================================
``native-json``     JSON object with ``"schema": "cascalib/tracks@1"``
``native-npz``      zip (NPZ) with arrays ``header`` and ``keypoints``
``openpose``        folder of per-frame JSON files, or one ``{"people": [...]}`` file
``mmpose``          JSON list of ``{"frame_id", "instances"}`` or ``{"meta_info", "instance_info"}``
``cascalib-ref``    JSON object ``{"Info": [...]}``
``coco``            JSON list of ``{"image_id", "keypoints", ...}``
``mediapipe-csv``   CSV whose header has ``port, frame_index, frame_time, point_id, img_loc_x/y``
==================  =========================================================================
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

from cascalib.errors import InputError
from cascalib.formats.keypoints import (
    _common as c,
)
from cascalib.formats.keypoints import (
    cascalib_ref,
    coco,
    mediapipe_csv,
    mmpose,
    native,
    openpose,
)
from cascalib.skeletons import Skeleton
from cascalib.tracks import Tracks

__all__ = ["FORMATS", "detect_format", "read_tracks", "read_tracks_many", "read_session",
           "write_tracks"]

logger = logging.getLogger(__name__)

#: Every supported format name.
FORMATS: tuple[str, ...] = ("native-json", "native-npz", "openpose", "mmpose", "cascalib-ref",
                            "coco", "mediapipe-csv")
_ALIASES = {"native": "native", "json": "native-json", "npz": "native-npz",
            "rtmlib": "mmpose", "caliscope": "mediapipe-csv", "mediapipe": "mediapipe-csv",
            "csv": "mediapipe-csv", "cascalib": "cascalib-ref"}
_JSON_FORMATS: dict[str, Any] = {"native-json": native, "mmpose": mmpose,
                                 "cascalib-ref": cascalib_ref, "coco": coco}


def _format_name(name: str) -> str:
    key = name.lower().replace("_", "-")
    key = _ALIASES.get(key, key)
    if key not in FORMATS and key != "native":
        raise InputError(f"unknown keypoint format {name!r}; known: {', '.join(FORMATS)}",
                         field="format")
    return key


def _classify_json(obj: Any, path: Path) -> str:
    if isinstance(obj, list) and not obj:
        raise InputError("no detections: the JSON list is empty", file=str(path),
                         field="keypoints")
    if isinstance(obj, dict) and "people" in obj:
        return "openpose"
    for name in ("native-json", "cascalib-ref", "coco", "mmpose"):
        if _JSON_FORMATS[name].looks_like(obj):
            return name
    kind = f"object with keys {sorted(obj)[:8]}" if isinstance(obj, dict) else type(obj).__name__
    raise InputError(f"unknown keypoint format: a JSON {kind}; known formats: "
                     f"{', '.join(FORMATS)}", file=str(path), field="format")


def _sniff(path: Path, camera: Any = None) -> tuple[str, Any]:
    """(format, parsed JSON or None) of a path, from its content."""
    if not path.exists():
        raise InputError("no such file or folder", file=str(path))
    if path.is_dir():
        return "openpose", None
    try:
        with open(path, "rb") as fh:
            head = fh.read(4096)
    except OSError as exc:
        raise InputError(f"cannot read: {exc.strerror}", file=str(path)) from None
    if head.startswith(b"PK"):
        return "native-npz", None
    text = head.lstrip(b"\xef\xbb\xbf \t\r\n")
    if text[:1] in (b"{", b"["):
        # JSON formats hold one camera: name it in a syntax error as the reader would.
        obj = c.load_json(path, camera=camera if isinstance(camera, str)
                          else c.default_camera(path))
        return _classify_json(obj, path), obj
    if not text:
        raise InputError("the file is empty", file=str(path))
    first = text.split(b"\n", 1)[0].decode("utf-8", "replace")
    if mediapipe_csv.looks_like(first):
        return "mediapipe-csv", None
    raise InputError(f"unknown keypoint format (starts with {first[:40]!r}); known formats: "
                     f"{', '.join(FORMATS)}", file=str(path), field="format")


def detect_format(path: str | Path) -> str:
    """The format of a keypoint file or folder, from its content (see the module docstring).

    Raises
    ------
    InputError
        For a missing path, unparseable JSON or content no reader understands.
    """
    return _sniff(Path(path))[0]


def read_tracks_many(path: str | Path, *, camera: Any = None,
                     skeleton: str | Skeleton | None = None, image_size: c.SizeArg = None,
                     fps: c.FpsArg = None, format: str | None = None) -> list[Tracks]:
    """Read every camera of a keypoint file or folder.

    Parameters
    ----------
    path : path
        Keypoint file or OpenPose folder.
    camera : str, optional
        Camera name (default: the file or folder stem). For multi-camera files (caliscope CSV) a
        template with ``{port}``, a mapping port -> name or a list of names (default
        ``port_N``, or the file stem for a single port).
    skeleton : str or Skeleton, optional
        Joint layout; default from the file or inferred from the joint count and content.
    image_size : "WxH", (W, H) or {camera: size}, optional
        Used where the file does not store the image size.
    fps : float or {camera: fps}, optional
        Used where the file does not store the frame rate.
    format : str, optional
        One of :data:`FORMATS`; default detected from the content.

    Returns
    -------
    list of Tracks
        One per camera, in the file's order.
    """
    with c.gc_paused():  # the parsed JSON is freed by reference counting once read
        return _read_tracks_many(Path(path), camera, format, skeleton=skeleton,
                                 image_size=image_size, fps=fps)


def _read_tracks_many(path: Path, camera: Any, format: str | None, **kw: Any) -> list[Tracks]:
    sniffed, obj = _sniff(path, camera) if format is None else (None, None)
    fmt = _format_name(format) if format is not None else sniffed
    if fmt == "native":
        fmt = "native-npz" if (sniffed or _sniff(path)[0]) == "native-npz" else "native-json"
    if fmt == "mediapipe-csv":
        return mediapipe_csv.read_mediapipe_csv(path, camera=camera, **kw)
    if camera is not None and not isinstance(camera, str):
        raise InputError(f"a {fmt} file holds one camera: give one name", file=str(path),
                         field="camera")
    if fmt == "native-npz":
        return [native.read_native_npz(path, camera=camera, **kw)]
    if fmt == "openpose":
        return [openpose.read_openpose(path, camera=camera, **kw)]
    if obj is None:
        obj = c.load_json(path, camera=camera)
    cam = camera if fmt == "native-json" else camera or c.default_camera(path)
    return [_JSON_FORMATS[str(fmt)].from_json(obj, path, camera=cam, **kw)]


def read_tracks(path: str | Path, *, camera: str | None = None,
                skeleton: str | Skeleton | None = None, image_size: c.SizeArg = None,
                fps: c.FpsArg = None, format: str | None = None) -> Tracks:
    """Read the tracks of one camera (see :func:`read_tracks_many` for the parameters).

    Raises
    ------
    InputError
        For unreadable or invalid input (naming file, camera, frame and field), and for a file
        holding several cameras (use :func:`read_tracks_many`).
    """
    tracks = read_tracks_many(path, camera=camera, skeleton=skeleton, image_size=image_size,
                              fps=fps, format=format)
    if len(tracks) != 1:
        raise InputError(f"the file holds {len(tracks)} cameras "
                         f"({', '.join(t.camera for t in tracks)}): use read_tracks_many",
                         file=str(path), field="camera")
    return tracks[0]


def read_session(paths: Sequence[str | Path], *, cameras: Sequence[str] | None = None,
                 skeleton: str | Skeleton | None = None, image_size: c.SizeArg = None,
                 fps: c.FpsArg = None, format: str | None = None) -> list[Tracks]:
    """Read the cameras of several files or folders, rejecting duplicate camera names.

    Parameters
    ----------
    paths : sequence of path
        Keypoint files or folders (multi-camera files contribute all their cameras).
    cameras : sequence of str, optional
        One name per path (for single-camera files), instead of the file stems.

    Returns
    -------
    list of Tracks
        In the order of ``paths``.

    Raises
    ------
    InputError
        Naming the camera and both files when two inputs give the same camera name.
    """
    if not paths:
        raise InputError("no input given: name one keypoint file or folder per camera")
    if cameras is not None and len(cameras) != len(paths):
        raise InputError(f"{len(cameras)} camera names for {len(paths)} paths", field="camera")
    out: list[Tracks] = []
    seen: dict[str, str | None] = {}
    for i, p in enumerate(paths):
        for t in read_tracks_many(p, camera=None if cameras is None else cameras[i],
                                  skeleton=skeleton, image_size=image_size, fps=fps,
                                  format=format):
            if t.camera in seen:
                raise InputError(f"duplicate camera name: {seen[t.camera]} and {t.source} both "
                                 "give it; name the cameras explicitly", file=t.source,
                                 camera=t.camera, field="camera")
            seen[t.camera] = t.source
            out.append(t)
    return out


_WRITERS: dict[str, Callable[..., Any]] = {
    "native-json": native.write_native_json, "native-npz": native.write_native_npz,
    "openpose": openpose.write_openpose, "mmpose": mmpose.write_mmpose,
    "cascalib-ref": cascalib_ref.write_cascalib_ref, "coco": coco.write_coco,
    "mediapipe-csv": mediapipe_csv.write_mediapipe_csv}


def write_tracks(tracks: Tracks | Sequence[Tracks], path: str | Path,
                 format: str | None = None) -> Path:
    """Write tracks in any supported format.

    Parameters
    ----------
    tracks : Tracks, or a list of Tracks for ``mediapipe-csv`` (several cameras, one file)
    path : path
        File to write (a folder for ``openpose``).
    format : str, optional
        One of :data:`FORMATS`; default from the suffix: ``.npz`` native-npz, ``.csv``
        mediapipe-csv, else native-json.

    Returns
    -------
    Path
        The file or folder written.
    """
    path = Path(path)
    if format is None:
        fmt = {".npz": "native-npz", ".csv": "mediapipe-csv"}.get(path.suffix.lower(),
                                                                 "native-json")
    else:
        fmt = _format_name(format)
        if fmt == "native":
            fmt = "native-npz" if path.suffix.lower() == ".npz" else "native-json"
    if fmt == "mediapipe-csv":
        return mediapipe_csv.write_mediapipe_csv(tracks, path)
    if not isinstance(tracks, Tracks):
        if len(tracks) != 1:
            raise InputError(f"{fmt} holds one camera per file; got {len(tracks)} cameras",
                             file=str(path), field="format")
        tracks = tracks[0]
    _WRITERS[fmt](tracks, path)
    return path
