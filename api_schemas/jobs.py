"""Request and response bodies of the ``/v1/jobs`` API (plain pydantic, no ORM).

The families follow the FastAPI full-stack template: ``JobOptions`` (the client's input, with
limits and ``extra="forbid"`` so a misspelt option is an error rather than silently ignored),
``JobPublic`` (one job as a client sees it), ``JobsPublic`` (a page of jobs) and ``JobCreated``
(the 202 answer to a submission).
"""

from __future__ import annotations

import enum
from datetime import datetime
from typing import TYPE_CHECKING, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator

from cascalib.calibration_formats import WRITABLE

__all__ = [
    "JobCreated",
    "JobLinks",
    "JobOptions",
    "JobPublic",
    "JobStatus",
    "JobsPublic",
    "RESULT_FORMATS",
    "ResultFormat",
]

#: Calibration file formats ``GET /v1/jobs/{id}/result?format=`` can return: every format the
#: library writes (its registry, :mod:`cascalib.calibration_formats`).
RESULT_FORMATS: tuple[str, ...] = WRITABLE

if TYPE_CHECKING:
    ResultFormat = str
else:
    #: The ``?format=`` values, as a type (an enum in the OpenAPI schema).
    ResultFormat = Literal[RESULT_FORMATS]

_SIZE_PATTERN = r"^\s*[0-9]{1,6}\s*[xX]\s*[0-9]{1,6}\s*$"
_CAMERA_PATTERN = r"^[A-Za-z0-9][A-Za-z0-9_.-]{0,63}$"


class JobStatus(enum.StrEnum):
    """Life cycle of a job: queued -> running -> succeeded | failed | cancelled."""

    queued = "queued"
    running = "running"
    succeeded = "succeeded"
    failed = "failed"
    cancelled = "cancelled"

    @property
    def finished(self) -> bool:
        """True for the three terminal states."""
        return self in (JobStatus.succeeded, JobStatus.failed, JobStatus.cancelled)


class JobOptions(BaseModel):
    """Options of one calibration: the ``options`` part of ``POST /v1/jobs``.

    The keys mirror the ``cascalib calibrate`` flags with the same value syntax
    (``--image-size 1920x1080`` becomes ``"image_size": "1920x1080"``). Per-camera values are
    objects keyed by camera name (the uploaded file name without its extension).
    """

    model_config = ConfigDict(
        extra="forbid",
        json_schema_extra={
            "examples": [
                {"image_size": "1920x1080", "fps": {"cam2": 25, "cam0": 30}, "height": 1.7},
                {"image_size": {"cam0": "1920x1080", "cam1": "1280x720"}, "skeleton": "coco17"},
            ]
        },
    )

    image_size: str | dict[str, str] | None = Field(
        default=None,
        description="Image size WIDTHxHEIGHT of every camera, or an object camera -> size. "
        "Needed when the keypoint files do not carry it; a size other than the one a file "
        "records is refused.",
        examples=["1920x1080"],
    )
    fps: float | dict[str, float] | None = Field(
        default=None,
        description="Nominal frame rate of every camera, or an object camera -> rate. As on "
        "the command line, a rate given for a camera beats the one its file records, a rate "
        "for every camera does not; a disagreement is listed in the job's warnings.",
        examples=[30, {"cam0": 30, "cam2": 25}],
    )
    skeleton: str | None = Field(
        default=None,
        max_length=32,
        description="Keypoint layout (coco17, halpe26, body25, body25b, coco18, blazepose33, "
        "h36m17); inferred from the data when omitted.",
    )
    height: float | None = Field(
        default=None, gt=0.5, lt=2.5,
        description="Average height of the people in the scene, metres (default 1.70).",
    )
    seed: int | None = Field(
        default=None, ge=0, le=2**32 - 1,
        description="Seed of the random number generator (RANSAC); results are reproducible.",
    )
    synchronized: bool | None = Field(
        default=None,
        description="The cameras are hardware-synchronised: skip the time-offset search.",
    )
    reference_camera: str | None = Field(
        default=None, pattern=_CAMERA_PATTERN,
        description="Camera whose frame and clock define the world; the first one by default.",
    )
    config: dict[str, Any] | None = Field(
        default=None,
        description="Further calibration settings, nested by stage exactly like the "
        "`--config` file of `cascalib calibrate` (see CalibrationConfig).",
    )

    @field_validator("image_size")
    @classmethod
    def _check_sizes(cls, value: str | dict[str, str] | None) -> str | dict[str, str] | None:
        import re

        values = value.values() if isinstance(value, dict) else [] if value is None else [value]
        for v in values:
            if not re.match(_SIZE_PATTERN, v):
                raise ValueError(f"image size must look like 1920x1080, got {v!r}")
        return value

    @field_validator("fps")
    @classmethod
    def _check_fps(cls, value: float | dict[str, float] | None) -> float | dict[str, float] | None:
        values = value.values() if isinstance(value, dict) else [] if value is None else [value]
        for v in values:
            if not 0.0 < v <= 10_000.0:
                raise ValueError(f"frame rate must be in (0, 10000], got {v}")
        return value

    def per_camera_keys(self) -> dict[str, list[str]]:
        """Camera names used as keys of per-camera options, by option name."""
        out: dict[str, list[str]] = {}
        for name in ("image_size", "fps"):
            value = getattr(self, name)
            if isinstance(value, dict):
                out[name] = list(value)
        return out


class JobLinks(BaseModel):
    """Where to find a job and its outputs."""

    self: str = Field(description="This job.")
    result: str = Field(description="The calibration (native JSON; ?format= for others).")
    report: str = Field(description="The HTML report.")
    poses: str = Field(description="The 3D poses.")


class JobPublic(BaseModel):
    """One job as its owner sees it."""

    id: str = Field(description="Job id.")
    status: JobStatus
    stage: str | None = Field(default=None, description="Current stage of the cascade.")
    progress: float = Field(ge=0.0, le=1.0, description="Fraction done, 0-1.")
    cameras: list[str] = Field(description="Camera names, in upload order.")
    attempts: int = Field(ge=0, description="How many times a worker started this job.")
    created_at: datetime
    started_at: datetime | None = None
    finished_at: datetime | None = None
    error: str | None = Field(default=None, description="Why the job failed.")
    warnings: list[str] = Field(
        default_factory=list, description="What a succeeded job could not determine or "
        "decided against the client: a given frame rate its file contradicts, cameras left out "
        "(with the reason), stage I replaced by the multi-view start, no ground seen.")
    links: JobLinks


class JobCreated(BaseModel):
    """Answer to an accepted submission (202)."""

    id: str
    status: JobStatus
    links: JobLinks


class JobsPublic(BaseModel):
    """A page of jobs, newest first."""

    data: list[JobPublic]
    count: int = Field(ge=0, description="Number of jobs matching the filter (all pages).")
    limit: int
    offset: int
