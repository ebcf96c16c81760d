"""``/v1/jobs``: submit, poll, download, list, cancel and delete calibration jobs."""

from __future__ import annotations

import io
import json
import zipfile
from pathlib import Path as FsPath
from typing import Annotated, Any, Literal

from fastapi import APIRouter, Header, Path, Query, Request, Response
from fastapi.responses import FileResponse

from api_schemas import (
    RESULT_FORMATS,
    JobCreated,
    JobOptions,
    JobPublic,
    JobsPublic,
    JobStatus,
    Problem,
    ResultFormat,
)
from cascalib.calibration_formats import get_format
from service import store as st
from service.api.deps import SessionDep, StateDep, TokenDep
from service.core.problems import ProblemError
from service.models import Job, JobFile
from service.store import sha256_file
from service.submit import links, submit_job

__all__ = ["router"]

router = APIRouter(prefix="/v1/jobs", tags=["jobs"])

JobId = Annotated[str, Path(description="Job id (32 hex digits).", max_length=64)]
_P = "application/problem+json"
_ERRORS: dict[int | str, dict[str, Any]] = {
    code: {"model": Problem, "description": text, "content": {_P: {}}}
    for code, text in [(401, "Missing or invalid token"), (404, "No such job (for this token)"),
                       (422, "Invalid input"),
                       (503, "The job store is unavailable for now (see Retry-After)")]}

_UPLOAD_DOC: dict[str, Any] = {"requestBody": {"required": True, "content": {
    "multipart/form-data": {
        "schema": {"type": "object", "required": ["files"], "properties": {
            "files": {"type": "array", "items": {"type": "string", "format": "binary"},
                      "minItems": 1,
                      "description": "One file per camera; the file name (without extension) "
                      "is the camera name. Any supported keypoint format; a folder of per-frame "
                      "JSON files as a zip."},
            "options": {"type": "string", "description": "JobOptions as JSON text.",
                        "contentMediaType": "application/json",
                        "x-schema": JobOptions.model_json_schema()}}},
        "encoding": {"options": {"contentType": "application/json"}},
        "example": {"options": '{"image_size": "1920x1080", "fps": {"cam2": 25, "cam0": 30}, '
                    '"height": 1.7}'}}}}}


def to_public(job: Job) -> JobPublic:
    """The API view of a job row."""
    return JobPublic(id=job.id, status=JobStatus(job.status), stage=job.stage,
                     progress=job.progress, cameras=list(job.cameras), attempts=job.attempts,
                     created_at=job.created_at, started_at=job.started_at,
                     finished_at=job.finished_at, error=job.error,
                     warnings=list(job.warnings or []), links=links(job.id))


def _job(session: SessionDep, owner: str, job_id: str) -> Job:
    job = st.find_job(session, job_id=job_id, owner=owner)
    if job is None:
        raise ProblemError(404, f"no job {job_id!r}")
    return job


@router.post("", status_code=202, response_model=JobCreated, openapi_extra=_UPLOAD_DOC,
             responses={**_ERRORS, 413: {"model": Problem, "description": "Upload too large"},
                        415: {"model": Problem, "description": "Not multipart/form-data"},
                        400: {"model": Problem, "description": "Malformed multipart body"},
                        408: {"model": Problem, "description": "The body stopped arriving"},
                        503: {"model": Problem, "description": "Too many submissions in "
                              "progress, or the job store unavailable (see Retry-After)"}})
async def create_job(request: Request, response: Response, state: StateDep, owner: TokenDep,
                     idempotency_key: Annotated[str | None, Header(
                         description="Retry-safe submission: the same key returns the same "
                         "job.")] = None) -> JobCreated:
    """Submit a calibration: one keypoint file per camera plus ``options`` (JSON).

    Everything is validated before the job is accepted.
    """
    job, replayed = await submit_job(request, state, owner, idempotency_key)
    response.headers["Location"] = f"/v1/jobs/{job.id}"
    if replayed:
        response.headers["Idempotent-Replayed"] = "true"
    return JobCreated(id=job.id, status=JobStatus(job.status), links=links(job.id))


@router.get("", response_model=JobsPublic, responses=_ERRORS)
def list_jobs(session: SessionDep, owner: TokenDep, state: StateDep,
              status: Annotated[JobStatus | None, Query(description="Only this state.")] = None,
              limit: Annotated[int, Query(ge=1, le=1000)] = 50,
              offset: Annotated[int, Query(ge=0, le=10**9)] = 0) -> JobsPublic:
    """Your jobs, newest first, one page at a time."""
    limit = min(limit, state.settings.page_limit)
    jobs, count = st.list_jobs(session, owner=owner, status=status.value if status else None,
                               limit=limit, offset=offset)
    return JobsPublic(data=[to_public(j) for j in jobs], count=count, limit=limit,
                      offset=offset)


@router.get("/{job_id}", response_model=JobPublic, responses=_ERRORS)
def read_job(job_id: JobId, session: SessionDep, owner: TokenDep) -> JobPublic:
    """State, stage, progress, timestamps and error of a job."""
    return to_public(_job(session, owner, job_id))


def _outputs(job: Job, what: str) -> list[JobFile]:
    if job.status != "succeeded":
        detail = f"job is {job.status}" + (f": {job.error}" if job.error else "")
        raise ProblemError(409, f"no {what}: {detail}")
    return [f for f in job.files if f.kind == "output"]


def _checked(state: StateDep, job: Job, f: JobFile, what: str) -> FsPath:
    path = state.store.job_dir(job.id) / f.path
    if not path.is_file() or sha256_file(path) != f.sha256:
        raise ProblemError(500, f"the stored {what} is damaged")
    return path


def _export_error(state: StateDep, job: Job, roles: tuple[str, ...]) -> str:
    """Why a calibration format could not be written (from export_errors.json), if known."""
    note = next((f for f in job.files if f.role == "export_errors"), None)
    if note is None:
        return ""
    errors = json.loads(_checked(state, job, note, "export notes").read_text())
    reasons = [errors[r.split(":", 1)[1]] for r in roles if r.split(":", 1)[-1] in errors]
    return f": {reasons[0]}" if reasons else ""


def _serve(state: StateDep, job: Job, roles: tuple[str, ...], media_type: str,
           what: str) -> Response:
    """One output file by role; or, for a format written as a folder, a zip of the folder."""
    outputs = _outputs(job, what)
    found = next((f for r in roles for f in outputs if f.role == r), None)
    if found is None:
        raise ProblemError(404, f"this job produced no {what}{_export_error(state, job, roles)}")
    path = _checked(state, job, found, what)
    folder = FsPath(found.path).parent
    if folder.name in FOLDER_FORMATS:  # colmap/, easymocap/: several files
        members = [f for f in outputs if FsPath(f.path).parent == folder]
        buf = io.BytesIO()
        with zipfile.ZipFile(buf, "w", zipfile.ZIP_DEFLATED) as zf:
            for f in members:
                zf.write(_checked(state, job, f, what), FsPath(f.path).name)
        return Response(buf.getvalue(), media_type="application/zip", headers={
            "Content-Disposition": f'attachment; filename="{job.id}-{folder.name}.zip"'})
    return FileResponse(path, media_type=media_type, filename=f"{job.id}-{path.name}",
                        headers={"ETag": f'"{found.sha256}"'})


#: Output folders of the formats written as several files (served as a zip).
FOLDER_FORMATS = tuple(get_format(f).output_name for f in RESULT_FORMATS
                       if get_format(f).is_folder)
_MEDIA = {f: get_format(f).served_media_type for f in RESULT_FORMATS}
_POSES_MEDIA = {"json": "application/json", "npz": "application/octet-stream"}
_BINARY = {"type": "string", "format": "binary"}


def _downloads(media: dict[str, dict[str, Any]], what: str) -> dict[int | str, dict[str, Any]]:
    """OpenAPI answers of a download: 200 in each media type, 404 and 409 as problems."""
    return {**_ERRORS,
            200: {"description": what, "content": media},
            404: {"model": Problem, "content": {_P: {}},
                  "description": "No such job (for this token), or the job produced no such "
                  "file (the reason is given)"},
            409: {"model": Problem, "content": {_P: {}},
                  "description": "The job has not succeeded (yet)"}}


_RESULT_DOC = _downloads({
    media: {"schema": {"type": "object"} if media == "application/json" else
            _BINARY if media == "application/zip" else {"type": "string"}}
    for media in dict.fromkeys(_MEDIA.values())}, "The calibration in the format asked for")
_REPORT_DOC = _downloads({"text/html": {"schema": {"type": "string"}}}, "The HTML report")
_POSES_DOC = _downloads({"application/json": {"schema": {"type": "object"}},
                         "application/octet-stream": {"schema": _BINARY}},
                        "3D poses: JSON, or NumPy .npz arrays")


_FORMAT_DOC = "Calibration file format ({}); {} come as a zip of their folder.".format(
    ", ".join(f"{f}: {get_format(f).description}" for f in RESULT_FORMATS),
    " and ".join(f for f in RESULT_FORMATS if get_format(f).is_folder))


@router.get("/{job_id}/result", response_class=Response, responses=_RESULT_DOC)
def read_result(job_id: JobId, session: SessionDep, owner: TokenDep, state: StateDep,
                format: Annotated[ResultFormat, Query(description=_FORMAT_DOC)] = "json",
                ) -> Response:
    """The calibration: native JSON, or another supported format."""
    assert format in RESULT_FORMATS
    return _serve(state, _job(session, owner, job_id), (f"calibration:{format}",),
                  _MEDIA[format], f"{format} calibration")


@router.get("/{job_id}/report", response_class=Response, responses=_REPORT_DOC)
def read_report(job_id: JobId, session: SessionDep, owner: TokenDep,
                state: StateDep) -> Response:
    """The HTML report of the calibration."""
    return _serve(state, _job(session, owner, job_id), ("report",), "text/html", "report")


@router.get("/{job_id}/poses", response_class=Response, responses=_POSES_DOC)
def read_poses(job_id: JobId, session: SessionDep, owner: TokenDep, state: StateDep,
               format: Annotated[Literal["json", "npz"], Query(
                   description="JSON, or NumPy .npz arrays.")] = "json") -> Response:
    """The 3D poses of the people (per reference frame, person and joint)."""
    return _serve(state, _job(session, owner, job_id), (f"poses:poses.{format}",),
                  _POSES_MEDIA[format], "poses")


@router.delete("/{job_id}", responses={**_ERRORS, 200: {"model": JobPublic},
                                       204: {"description": "Deleted with its files"}})
def delete_job(job_id: JobId, session: SessionDep, owner: TokenDep,
               state: StateDep) -> Response:
    """Cancel a queued or running job (200, the job); delete a finished one (204)."""
    job = _job(session, owner, job_id)
    if job.status in ("queued", "running"):
        st.cancel_job(session, job_id=job.id)
        state.dispatcher.cancel(job.id)
        session.refresh(job)
        return Response(to_public(job).model_dump_json(), media_type="application/json")
    if st.delete_job(session, job_id=job.id):
        state.store.remove_files(job.id)
    return Response(status_code=204)
