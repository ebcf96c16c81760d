"""A recording session: the keypoint files of all cameras, with per-camera overrides.

Users give cameras as files or folders (one camera each; the camera name is the file or folder
name), or as one session manifest (TOML or JSON) listing them. Image size and frame rate are not
stored by most detector formats, so they can be given for every camera at once (``"1920x1080"``,
``30``) or per camera (``{"cam2": "1280x720"}``). A value found in the file always wins over none;
an explicit per-camera value wins over the file.
"""

from __future__ import annotations

import json
import tomllib
from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

from cascalib.errors import InputError
from cascalib.tracks import Tracks, parse_image_size

__all__ = ["load_session", "parse_camera_values", "apply_overrides", "read_manifest"]

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


def apply_overrides(tracks: list[Tracks], *, image_size: PerCamera = None, fps: PerCamera = None
                    ) -> list[Tracks]:
    """Fill in image sizes and frame rates.

    Frame rates: per-camera value > value in the file > global value. Image sizes: the file's,
    else the given one; a given size that differs from the file's is refused (the rule of
    :func:`~cascalib.formats.keypoints._common.resolve_image_size`, the REST service's too).

    Raises
    ------
    InputError
        If a per-camera value names a camera that is not in the session, or a given image
        size differs from the one a file records.
    """
    from cascalib.formats.keypoints._common import resolve_image_size

    size_all, size_per = parse_camera_values(image_size, parse_image_size, field="image_size")
    fps_all, fps_per = parse_camera_values(fps, _parse_fps, field="fps")
    names = [t.camera for t in tracks]
    for cam in list(size_per) + list(fps_per):
        if cam not in names:
            raise InputError(f"no camera named {cam!r} in this session (cameras: "
                             f"{', '.join(names)})", camera=cam,
                             field="image_size" if cam in size_per else "fps")
    out = []
    for t in tracks:
        given = size_per.get(t.camera, size_all)
        size = resolve_image_size(t.image_size, given, camera=t.camera, file=t.source)
        rate = fps_per.get(t.camera, t.fps if t.fps is not None else fps_all)
        out.append(t.with_(image_size=size, fps=rate) if (size, rate) != (t.image_size, t.fps)
                   else t)
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
    """Read the keypoint tracks of every camera of a session.

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
    list of Tracks
        In the order given.

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
    if manifest_sizes or manifest_fps:
        tracks = apply_overrides(tracks, image_size=manifest_sizes or None,
                                 fps=manifest_fps or None)
    return apply_overrides(tracks, image_size=image_size, fps=fps)
