"""Public request/response models of the cascalib calibration service (pydantic, and the
library's format registry :mod:`cascalib.calibration_formats`)."""

from api_schemas.health import Health, Readiness
from api_schemas.jobs import (
    RESULT_FORMATS,
    JobCreated,
    JobLinks,
    JobOptions,
    JobPublic,
    JobsPublic,
    JobStatus,
    ResultFormat,
)
from api_schemas.problems import PROBLEM_MEDIA_TYPE, InvalidParam, Problem

__all__ = [
    "Health",
    "InvalidParam",
    "JobCreated",
    "JobLinks",
    "JobOptions",
    "JobPublic",
    "JobStatus",
    "JobsPublic",
    "PROBLEM_MEDIA_TYPE",
    "Problem",
    "RESULT_FORMATS",
    "Readiness",
    "ResultFormat",
]
