"""A recording session: the keypoint files of all cameras, with per-camera overrides.

Users give cameras as files or folders (one camera each; the camera name is the file or folder
name), or as one session manifest (TOML or JSON) listing them. Image size and frame rate are not
stored by most detector formats, so they can be given for every camera at once (``"1920x1080"``,
``30``) or per camera (``{"cam2": "1280x720"}``). :class:`GivenValues` holds the one rule the
command line, the Python API and the REST service share: a value found in the file wins over
none; a frame rate given for this camera beats the file's, one given for every camera loses to
it, and either disagreement becomes a warning; a given image size that differs from the file's
is refused (docs/decisions/image-size-precedence.md).
"""

from __future__ import annotations

import json
import logging
import tomllib
from collections.abc import Mapping, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from cascalib.errors import InputError
from cascalib.tracks import Tracks, parse_image_size

__all__ = ["GivenValues", "load_session", "resolve_session", "parse_camera_values",
           "apply_overrides", "resolve_camera_values", "read_manifest"]

log = logging.getLogger(__name__)

PerCamera = str | float | Mapping[str, Any] | Sequence[str] | None


def parse_camera_values(values: PerCamera, parse: Any, *, field: str
                        ) -> tuple[Any | None, dict[str, Any]]:
    """Split a command-line style value into (value for every camera, {camera: value}).

    Accepts ``None``; one value (``"1920x1080"`` or ``30``); a mapping ``{"cam2": 25}``; or a list
    of strings each either ``VALUE`` or ``NAME=VALUE`` (the repeated ``--fps cam2=25`` flag).

    Raises
    ------
    InputError
        Naming the field (and the camera) when a value cannot be parsed or is given twice.
    """
    default: Any | None = None
    per: dict[str, Any] = {}
    if values is None:
        return None, {}
    if isinstance(values, Mapping):
        items: list[tuple[str | None, Any]] = [(str(k), v) for k, v in values.items()]
    elif isinstance(values, (str, int, float)):
        items = [_split(values)]
    else:
        items = [_split(v) for v in values]
    for cam, raw in items:
        try:
            value = parse(raw)
        except InputError as exc:
            raise InputError(exc.message, camera=cam, field=field) from None
        except (TypeError, ValueError):
            raise InputError(f"cannot parse {raw!r}", camera=cam, field=field) from None
        if cam is None:
            if default is not None:
                raise InputError("given twice for every camera", field=field)
            default = value
        else:
            if cam in per:
                raise InputError("given twice for this camera", camera=cam, field=field)
            per[cam] = value
    return default, per


def _split(value: Any) -> tuple[str | None, Any]:
    if isinstance(value, str) and "=" in value:
        name, _, v = value.partition("=")
        return name.strip(), v.strip()
    return None, value


def _parse_fps(v: Any) -> float:
    fps = float(v)
    if not fps > 0:
        raise InputError(f"frame rate must be positive, got {v!r}")
    return fps


@dataclass(frozen=True)
class GivenValues:
    """Image sizes and frame rates a caller gives, for every camera and per camera."""

    size_all: tuple[int, int] | None = None
    size_per: dict[str, tuple[int, int]] = field(default_factory=dict)
    fps_all: float | None = None
    fps_per: dict[str, float] = field(default_factory=dict)

    @classmethod
    def parse(cls, image_size: PerCamera = None, fps: PerCamera = None) -> GivenValues:
        """From command-line style values (see :func:`parse_camera_values`)."""
        size_all, size_per = parse_camera_values(image_size, parse_image_size, field="image_size")
        fps_all, fps_per = parse_camera_values(fps, _parse_fps, field="fps")
        return cls(size_all, size_per, fps_all, fps_per)

    def check_cameras(self, names: Sequence[str]) -> None:
        """Refuse a per-camera value for a camera that is not in the session."""
        for cam in list(self.size_per) + list(self.fps_per):
            if cam not in names:
                raise InputError(f"no camera named {cam!r} in this session (cameras: "
                                 f"{', '.join(names)})", camera=cam,
                                 field="image_size" if cam in self.size_per else "fps")

    def apply(self, t: Tracks) -> tuple[Tracks, list[str]]:
        """One camera's tracks with the given values filled in, and the warnings.

        Frame rate: this camera's given value > the file's > the value for every camera; a
        given value the file contradicts is a warning (whichever wins). Image size: the file's,
        else the given one; a given size that differs from the file's is refused.

        Raises
        ------
        InputError
            A given image size other than the one the file records (``field="image_size"``).
        """
        from cascalib.formats.keypoints._common import resolve_image_size

        given = self.size_per.get(t.camera, self.size_all)
        size = resolve_image_size(t.image_size, given, camera=t.camera, file=t.source)
        rate, notes = t.fps, []
        if t.camera in self.fps_per:
            rate = self.fps_per[t.camera]
            if t.fps is not None and t.fps != rate:
                notes.append(f"camera {t.camera}: the given {rate:g} fps replaces the "
                             f"{t.fps:g} fps its file records")
        elif t.fps is None:
            rate = self.fps_all
        elif self.fps_all is not None and self.fps_all != t.fps:
            notes.append(f"camera {t.camera}: its file records {t.fps:g} fps; the "
                         f"{self.fps_all:g} fps given for every camera is not used for it")
        if (size, rate) == (t.image_size, t.fps):
            return t, notes
        return t.with_(image_size=size, fps=rate), notes


def resolve_camera_values(tracks: Sequence[Tracks], *, image_size: PerCamera = None,
                          fps: PerCamera = None) -> tuple[list[Tracks], list[str]]:
    """Fill in image sizes and frame rates by the rule of :meth:`GivenValues.apply`.

    Returns
    -------
    tracks : list of Tracks
    warnings : list of str
        Each given frame rate a file contradicts, naming the camera and both rates.

    Raises
    ------
    InputError
        If a per-camera value names a camera that is not in the session, or a given image
        size differs from the one a file records.
    """
    given = GivenValues.parse(image_size, fps)
    given.check_cameras([t.camera for t in tracks])
    out, notes = [], []
    for t in tracks:
        resolved, why = given.apply(t)
        out.append(resolved)
        notes += why
    return out, notes


def apply_overrides(tracks: list[Tracks], *, image_size: PerCamera = None, fps: PerCamera = None
                    ) -> list[Tracks]:
    """:func:`resolve_camera_values`, its warnings logged."""
    out, notes = resolve_camera_values(tracks, image_size=image_size, fps=fps)
    for note in notes:
        log.warning("%s", note)
    return out


def read_manifest(path: Path) -> dict[str, Any]:
    """Read a session manifest (TOML or JSON).

    Layout::

        image_size = "1920x1080"          # optional, every camera
        fps = 30                          # optional, every camera
        skeleton = "coco17"               # optional
        [cameras.cam0]                    # one table per camera, in order
        file = "cam0.json"                # relative to the manifest
        image_size = "1280x720"           # optional override
        fps = 25                          # optional override
    """
    try:
        text = path.read_text()
        data = tomllib.loads(text) if path.suffix.lower() == ".toml" else json.loads(text)
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, tomllib.TOMLDecodeError) as exc:
        raise InputError(f"cannot read session manifest: {exc}", file=str(path)) from None
    cams = data.get("cameras")
    if not isinstance(cams, dict) or not cams:
        raise InputError("a session manifest needs a non-empty [cameras] table",
                         file=str(path), field="cameras")
    for name, spec in cams.items():
        if not isinstance(spec, dict) or "file" not in spec:
            raise InputError("each camera needs a 'file'", file=str(path), camera=name,
                             field="file")
    return data


def is_manifest(path: Path) -> bool:
    """True for a TOML file, or a JSON object with a ``cameras`` table and no keypoints.

    A keypoint file (megabytes) is only parsed here when its bytes could name a ``cameras`` key:
    literally, or through a backslash escape; otherwise its reader parses it once.
    """
    if path.is_dir() or path.suffix.lower() not in (".toml", ".json"):
        return False
    if path.suffix.lower() == ".toml":
        return True
    try:
        raw = path.read_bytes()
        if not raw[:4096].lstrip().startswith(b"{"):
            return False
        if b'"cameras"' not in raw and b"\\" not in raw:
            return False
        data = json.loads(raw)
    except (OSError, ValueError):
        return False
    return isinstance(data, dict) and isinstance(data.get("cameras"), dict) and "schema" not in data


def load_session(paths: Sequence[str | Path], *, image_size: PerCamera = None,
                 fps: PerCamera = None, skeleton: str | None = None) -> list[Tracks]:
    """:func:`resolve_session`'s tracks, its warnings logged."""
    tracks, notes = resolve_session(paths, image_size=image_size, fps=fps, skeleton=skeleton)
    for note in notes:
        log.warning("%s", note)
    return tracks


def resolve_session(paths: Sequence[str | Path], *, image_size: PerCamera = None,
                    fps: PerCamera = None, skeleton: str | None = None
                    ) -> tuple[list[Tracks], list[str]]:
    """Read the keypoint tracks of every camera of a session, with the warnings of
    :func:`resolve_camera_values`.

    Parameters
    ----------
    paths : sequence of path
        One path per camera (keypoint file or folder of per-frame JSON files; the camera name is
        the file or folder stem), a multi-camera file (caliscope CSV), or one session manifest.
    image_size, fps : optional
        See :func:`parse_camera_values`. They win over a manifest's values.
    skeleton : str, optional
        Skeleton name where the format is ambiguous.

    Returns
    -------
    tracks : list of Tracks
        In the order given.
    warnings : list of str
        Given frame rates the files contradict.

    Raises
    ------
    InputError
        Unreadable input, duplicate camera names, unknown camera in an override.
    """
    from cascalib.formats import read_session

    given = [Path(p) for p in paths]
    if not given:
        raise InputError("no input given: name one keypoint file or folder per camera")
    files: list[Path] = []
    names: list[str | None] = []
    manifest_sizes: dict[str, Any] = {}
    manifest_fps: dict[str, Any] = {}
    for p in given:
        if not p.exists():
            raise InputError("no such file or folder", file=str(p))
        if not is_manifest(p):
            files.append(p)
            names.append(None)
            continue
        data = read_manifest(p)
        skeleton = data.get("skeleton", skeleton)
        for name, spec in data["cameras"].items():
            f = (p.parent / spec["file"]).resolve()
            if not f.exists():
                raise InputError("no such file or folder", file=str(f), camera=name, field="file")
            files.append(f)
            names.append(name)
            for key, store in (("image_size", manifest_sizes), ("fps", manifest_fps)):
                if key in spec or key in data:
                    store[name] = spec.get(key, data.get(key))
    tracks = read_session(files, cameras=names, skeleton=skeleton)  # type: ignore[arg-type]
    notes: list[str] = []
    if manifest_sizes or manifest_fps:
        tracks, notes = resolve_camera_values(tracks, image_size=manifest_sizes or None,
                                              fps=manifest_fps or None)
    tracks, more = resolve_camera_values(tracks, image_size=image_size, fps=fps)
    return tracks, notes + more
