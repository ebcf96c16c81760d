"""Reading a job's stored inputs: safe zip extraction and keypoint parsing.

Used twice with the same code: by the API to validate an upload before accepting it, and by the
worker to load the very same files for the calibration. Nothing here trusts a client-supplied
path: zip members are flattened to validated base names inside a server-made folder.
"""

from __future__ import annotations

import re
import stat
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from cascalib.errors import InputError

if TYPE_CHECKING:
    from cascalib.tracks import Tracks

from api_schemas import JobOptions

__all__ = ["ZipLimits", "is_zip", "safe_extract", "read_camera", "build_config",
           "check_session", "zip_limits"]

#: Names allowed for a member of an uploaded zip (after dropping its folders).
_MEMBER_NAME = re.compile(r"^[A-Za-z0-9_][A-Za-z0-9_.\-]{0,200}$")


@dataclass(frozen=True)
class ZipLimits:
    """Bounds on an upload: its zip (zip bombs, member floods) and the keypoints read from it."""

    max_members: int
    max_total_bytes: int
    max_ratio: float
    #: What the readers may build of one camera (see ``cascalib.formats.keypoints.ReadLimits``).
    max_frames: int | None = None
    max_persons: int | None = None
    max_keypoint_bytes: int | None = None


def zip_limits(settings: Any) -> ZipLimits:
    """The zip limits of the service settings."""
    return ZipLimits(settings.max_zip_members, settings.max_unzipped_bytes,
                     settings.max_zip_ratio, settings.max_frames, settings.max_persons,
                     settings.max_keypoint_bytes)


def is_zip(path: Path) -> bool:
    """Whether the upload is a zipped folder (of per-frame JSON files).

    NumPy ``.npz`` files are zip archives too: a ``.npz`` name, or members that are all
    ``.npy`` arrays, mean a keypoint file for the readers, not a folder.
    """
    with path.open("rb") as fh:
        if fh.read(4) != b"PK\x03\x04":
            return False
    if path.suffix.lower() == ".npz":
        return False
    try:
        with zipfile.ZipFile(path) as zf:
            names = [n for n in zf.namelist() if not n.endswith("/")]
    except (zipfile.BadZipFile, OSError):
        return True  # a damaged zip: safe_extract reports it
    return not (names and all(n.endswith(".npy") for n in names))


def _member_name(info: zipfile.ZipInfo, file: str) -> str | None:
    """Validated base name of a member, None for folders and macOS metadata."""
    raw = info.filename
    if raw.endswith("/") or raw.startswith("__MACOSX/"):
        return None
    parts = raw.replace("\\", "/").split("/")
    if raw.startswith(("/", "\\")) or ".." in parts or ":" in parts[0]:
        raise InputError(f"zip member {raw!r} has an absolute or parent path", file=file,
                         field="files")
    mode = info.external_attr >> 16
    if stat.S_ISLNK(mode):
        raise InputError(f"zip member {raw!r} is a symbolic link", file=file, field="files")
    name = parts[-1]
    if name.startswith("."):
        return None  # .DS_Store and friends: not data
    if not _MEMBER_NAME.match(name):
        raise InputError(f"zip member name {name!r} has characters other than letters, digits, "
                         "'_', '-', '.'", file=file, field="files")
    return name


def _check_members(zf: zipfile.ZipFile, file: str,
                   limits: ZipLimits) -> list[tuple[zipfile.ZipInfo, str]]:
    infos = zf.infolist()
    if len(infos) > limits.max_members:
        raise InputError(f"zip has {len(infos)} members, at most {limits.max_members} allowed",
                         file=file, field="files")
    members: list[tuple[zipfile.ZipInfo, str]] = []
    seen: set[str] = set()
    total = 0
    for info in infos:
        name = _member_name(info, file)
        if name is None:
            continue
        if info.flag_bits & 0x1:
            raise InputError(f"zip member {info.filename!r} is encrypted", file=file,
                             field="files")
        if name in seen:
            raise InputError(f"zip has two members named {name!r} (folders are flattened)",
                             file=file, field="files")
        seen.add(name)
        total += info.file_size
        ratio = info.file_size / max(info.compress_size, 1)
        if total > limits.max_total_bytes or ratio > limits.max_ratio:
            raise InputError("zip expands too much (zip bomb?): "
                             f"{total} bytes declared, member ratio {ratio:.0f}", file=file,
                             field="files")
        members.append((info, name))
    if not members:
        raise InputError("zip holds no files", file=file, field="files")
    return members


def safe_extract(archive: Path, dest: Path, limits: ZipLimits, *, file: str) -> Path:
    """Extract ``archive`` flat into the new folder ``dest``, enforcing ``limits``.

    Declared sizes can lie, so the bytes actually written are counted too.

    Raises
    ------
    InputError
        Not a valid zip, unsafe member names, too many members or too many bytes.
    """
    try:
        zf = zipfile.ZipFile(archive)
    except (zipfile.BadZipFile, OSError) as exc:
        raise InputError(f"not a readable zip archive ({exc})", file=file, field="files") from None
    dest.mkdir(parents=True)
    written = 0
    with zf:
        for info, name in _check_members(zf, file, limits):
            budget = min(limits.max_total_bytes - written, int(info.compress_size
                                                              * limits.max_ratio) + 1024)
            try:
                with zf.open(info) as src, (dest / name).open("wb") as out:
                    while block := src.read(2**16):
                        written += len(block)
                        budget -= len(block)
                        if budget < 0:
                            raise InputError("zip expands beyond its limits (zip bomb?)",
                                             file=file, field="files")
                        out.write(block)
            except (zipfile.BadZipFile, EOFError, OSError, ValueError) as exc:
                if isinstance(exc, InputError):
                    raise
                raise InputError(f"zip member {info.filename!r} is damaged ({exc})", file=file,
                                 field="files") from None
    return dest


def read_camera(path: Path, camera: str, options: JobOptions,
                limits: ZipLimits | None = None) -> tuple[Tracks, list[str]]:
    """Parse one camera's keypoints (any supported format) and fill in the job's image size
    and frame rate by the command line's rule (:class:`cascalib.session.GivenValues`).

    Returns
    -------
    tracks : Tracks
    warnings : list of str
        A given frame rate the file contradicts (this camera's beats the file's, one for every
        camera loses to it): the job reports it with its result.

    Raises
    ------
    LimitExceeded
        The keypoints exceed ``limits`` (frames, persons, bytes).
    InputError
        The file cannot be read as keypoints or contradicts the options (a given image size
        other than the one the file records is refused, naming ``options.image_size``).
    """
    from cascalib.formats import read_tracks
    from cascalib.formats.keypoints import ReadLimits, read_limits
    from cascalib.session import GivenValues

    bounds = ReadLimits() if limits is None else ReadLimits(
        limits.max_frames, limits.max_persons, limits.max_keypoint_bytes)
    with read_limits(bounds):
        raw = read_tracks(path, camera=camera, skeleton=options.skeleton)
    try:
        tracks, notes = GivenValues.parse(options.image_size, options.fps).apply(raw)
    except InputError as exc:
        if exc.field not in ("image_size", "fps"):
            raise
        raise InputError(exc.message, file=exc.file, camera=exc.camera, frame=exc.frame,
                         field=f"options.{exc.field}") from None
    if tracks.n_detections == 0:
        raise InputError("the file holds no detections", file=str(path), camera=camera)
    return tracks, notes


def check_session(tracks: list[Tracks]) -> None:
    """What the cascade needs of the whole session, checked before a job is accepted.

    Raises
    ------
    InputError
        Fewer than two cameras, or a camera without image size or frame rate.
    """
    if len(tracks) < 2:
        raise InputError(f"need at least two cameras, got {len(tracks)}", field="files")
    for t in tracks:
        if t.image_size is None:
            raise InputError("image size unknown: give image_size in the options",
                             camera=t.camera, field="options.image_size")
        if t.fps is None and t.timestamps is None:
            raise InputError("frame rate unknown: give fps in the options", camera=t.camera,
                             field="options.fps")


def build_config(options: JobOptions) -> Any:
    """The library's ``CalibrationConfig`` from the job options.

    Only options the client set are passed, so the library's defaults apply to the rest.
    """
    from cascalib.config import (  # type: ignore[import-not-found,unused-ignore]
        CalibrationConfig,
    )

    values: dict[str, Any] = dict(options.config or {})
    for name in ("height", "seed", "synchronized", "reference_camera"):
        if name in options.model_fields_set and getattr(options, name) is not None:
            values[name] = getattr(options, name)
    return CalibrationConfig.model_validate(values)
