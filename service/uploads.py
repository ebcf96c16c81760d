"""Accepting a submission: multipart parsing, limits, staging and full validation.

A submission is staged in ``<data_dir>/staging/<random>/`` under server-made names
(``cam_<i>.<ext>``), checksummed, validated exactly as the worker will read it, and only then
moved into ``<data_dir>/jobs/<job id>/inputs/``. Anything rejected is deleted whole: nothing is
stored half.
"""

from __future__ import annotations

import hashlib
import json
import logging
import re
import shutil
import tempfile
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from pydantic import ValidationError
from starlette.requests import Request

from api_schemas import InvalidParam, JobOptions
from cascalib.errors import CascalibError
from service.core.config import Settings
from service.core.problems import ProblemError, from_cascalib
from service.inputs import (
    build_config,
    check_session,
    is_zip,
    read_camera,
    safe_extract,
    zip_limits,
)
from service.multipart import FormParts, parse_multipart
from service.store import StoredFile

__all__ = ["Submission", "receive_submission", "validate_submission", "FILES_FIELD",
           "OPTIONS_FIELD"]

log = logging.getLogger(__name__)

FILES_FIELD = "files"
OPTIONS_FIELD = "options"
_CAMERA = re.compile(r"^[A-Za-z0-9][A-Za-z0-9_.\-]{0,63}$")
_EXT = re.compile(r"^[A-Za-z0-9]{1,8}$")
#: Deepest nesting of objects and lists accepted in ``options`` (the config has three levels).
MAX_OPTIONS_DEPTH = 32


@dataclass
class Submission:
    """A staged, checksummed upload (not yet validated as keypoints)."""

    folder: Path
    options: JobOptions
    options_json: dict[str, Any]
    cameras: list[str] = field(default_factory=list)
    files: list[StoredFile] = field(default_factory=list)

    @property
    def request_hash(self) -> str:
        """Fingerprint of what was asked (options and file contents) for idempotency."""
        h = hashlib.sha256(json.dumps(self.options_json, sort_keys=True).encode())
        for f in self.files:
            h.update(f"\0{f.role}\0{f.sha256}".encode())
        return h.hexdigest()

    def discard(self) -> None:
        """Delete the staged files."""
        shutil.rmtree(self.folder, ignore_errors=True)


def _bad(detail: str, *, field: str, file: str | None = None, camera: str | None = None,
         status: int = 422) -> ProblemError:
    return ProblemError(status, detail, errors=[InvalidParam(message=detail, field=field,
                                                            file=file, camera=camera)])


def camera_name(filename: str | None) -> tuple[str, str]:
    """Camera name and lower-case extension ('' if none) from an upload's file name."""
    if not filename:
        raise _bad("every camera file needs a file name (the camera name)", field=FILES_FIELD)
    if any(c in filename for c in "/\\\0") or filename.startswith("."):
        raise _bad(f"file name {filename!r} must be a plain name, not a path",
                   field=FILES_FIELD, file=filename)
    stem, dot, ext = filename.rpartition(".")
    if not dot or not _EXT.match(ext):
        stem, ext = filename, ""
    if not _CAMERA.match(stem):
        raise _bad(f"camera name {stem!r} (from file name {filename!r}) must be 1-64 letters, "
                   "digits, '_', '-' or '.', starting with a letter or digit",
                   field=FILES_FIELD, file=filename)
    return stem, ext.lower()


def _depth(value: Any) -> int:
    """Nesting depth of parsed JSON, counted without recursion."""
    deepest, stack = 0, [(value, 1)]
    while stack:
        item, level = stack.pop()
        if isinstance(item, (dict, list)):
            deepest = max(deepest, level)
            children = item.values() if isinstance(item, dict) else item
            stack.extend((child, level + 1) for child in children)
    return deepest


def parse_options(raw: str | None) -> tuple[JobOptions, dict[str, Any]]:
    """The ``options`` part as :class:`JobOptions` (422 naming the option on error)."""
    too_deep = _bad(f"options nest deeper than {MAX_OPTIONS_DEPTH} levels", field=OPTIONS_FIELD)
    try:
        data = json.loads(raw) if raw else {}
    except json.JSONDecodeError as exc:
        raise _bad(f"options is not valid JSON: {exc}", field=OPTIONS_FIELD) from None
    except RecursionError:  # the decoder recurses once per level of nesting
        raise too_deep from None
    if _depth(data) > MAX_OPTIONS_DEPTH:
        raise too_deep
    if not isinstance(data, dict):
        raise _bad("options must be a JSON object", field=OPTIONS_FIELD)
    try:
        return JobOptions.model_validate(data), data
    except ValidationError as exc:
        errors = [InvalidParam(message=e["msg"], field=".".join(
            [OPTIONS_FIELD, *(str(p) for p in e["loc"])])) for e in exc.errors()]
        raise ProblemError(422, "invalid options: " + "; ".join(
            f"{p.field}: {p.message}" for p in errors), errors=errors) from None


def _check_parts(sub: Submission, form: FormParts) -> str | None:
    """The options text; every part is a camera file or the one options field."""
    options: str | None = None
    for name, value in form.fields:
        if name != OPTIONS_FIELD or options is not None:
            raise _bad(f"unexpected form part {name!r} (expected '{FILES_FIELD}' files and one "
                       f"'{OPTIONS_FIELD}' JSON text)", field=name)
        options = value
    for part in form.files:
        if part.name != FILES_FIELD:
            raise _bad(f"unexpected form part {part.name!r} (expected '{FILES_FIELD}' files "
                       f"and one '{OPTIONS_FIELD}' JSON text)", field=part.name)
        camera = sub.cameras[len(sub.files)]
        if part.size == 0:
            raise _bad("the file is empty", field=FILES_FIELD, file=part.filename, camera=camera)
        sub.files.append(StoredFile(role=camera, path=str(part.path.relative_to(sub.folder)),
                                    size=part.size, sha256=part.sha256,
                                    client_name=part.filename))
    if not form.files:
        raise _bad("no camera file uploaded", field=FILES_FIELD)
    return options


async def receive_submission(request: Request, settings: Settings, staging: Path) -> Submission:
    """Stream a submission into a new staging folder: file parts are written once, under
    server-made names, and checksummed as they arrive (no keypoint parsing yet)."""
    staging.mkdir(parents=True, exist_ok=True)
    sub = Submission(Path(tempfile.mkdtemp(dir=staging)), JobOptions(), {})
    (sub.folder / "inputs").mkdir()

    def place(filename: str, index: int) -> Path:
        camera, ext = camera_name(filename)
        if camera in sub.cameras:
            raise _bad(f"two files for camera {camera!r}", field=FILES_FIELD, file=filename,
                       camera=camera)
        sub.cameras.append(camera)
        return sub.folder / "inputs" / (f"cam_{index}" + (f".{ext}" if ext else ""))

    try:
        form = await parse_multipart(request.headers.get("content-type", ""), request.stream(),
                                     place, max_files=settings.max_files)
        sub.options, sub.options_json = parse_options(_check_parts(sub, form))
    except BaseException:
        sub.discard()
        raise
    return sub


def _relocate(exc: CascalibError, sub: Submission, work: Path) -> ProblemError:
    """Replace server paths in a library error by the client's file names."""
    problem = from_cascalib(exc)
    for f in sub.files:
        for server in (str(work / f.role), str(sub.folder / f.path)):
            problem.detail = problem.detail.replace(server, f.client_name or f.role)
            for p in problem.errors:
                for attr in ("file", "message"):
                    val = getattr(p, attr)
                    if val and server in val:
                        setattr(p, attr, val.replace(server, f.client_name or f.role))
    return problem


def _check_option_cameras(sub: Submission) -> None:
    for option, keys in sub.options.per_camera_keys().items():
        for key in keys:
            if key not in sub.cameras:
                raise _bad(f"options.{option} names camera {key!r}, which was not uploaded "
                           f"(cameras: {', '.join(sub.cameras)})", field=f"options.{option}.{key}")
    ref = sub.options.reference_camera
    if ref is not None and ref not in sub.cameras:
        raise _bad(f"reference camera {ref!r} was not uploaded", field="options.reference_camera")


def validate_submission(sub: Submission, settings: Settings) -> None:
    """Read every camera exactly as the worker will; raise a 4xx problem on the first fault.

    Blocking (parses files): call it in a thread.
    """
    _check_option_cameras(sub)
    try:
        build_config(sub.options)
    except ImportError:
        pass  # the library's config is not installed: the job fails with that reason when run
    except ValidationError as exc:
        errors = [InvalidParam(message=e["msg"], field=".".join(
            ["options.config", *(str(p) for p in e["loc"])])) for e in exc.errors()]
        raise ProblemError(422, "invalid calibration settings", errors=errors) from None
    limits = zip_limits(settings)
    tracks = []
    with tempfile.TemporaryDirectory(dir=sub.folder) as tmp:
        work = Path(tmp)
        for f in sub.files:
            path = sub.folder / f.path
            try:
                if is_zip(path):
                    path = safe_extract(path, work / f.role, limits, file=f.client_name or f.role)
                tracks.append(read_camera(path, f.role, sub.options, limits)[0])
            except CascalibError as exc:
                raise _relocate(exc, sub, work) from None
            except ImportError as exc:
                raise ProblemError(503, f"keypoint readers unavailable: {exc}") from None
            except Exception as exc:  # a reader bug must not become a 500 for a bad upload
                log.warning("reader crashed on %s", f.client_name, exc_info=True)
                raise _bad(f"cannot read the file as keypoints ({type(exc).__name__})",
                           field=FILES_FIELD, file=f.client_name, camera=f.role) from None
    try:
        check_session(tracks)
    except CascalibError as exc:
        raise from_cascalib(exc) from None
