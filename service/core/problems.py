"""Problem-details answers (``application/problem+json``) and the exception handlers.

Every error leaves the service as a :class:`api_schemas.Problem`; cascalib's own errors keep
their location (camera, file, frame, field); anything unexpected becomes a bare 500 with a
request id to find the traceback in the log (never the traceback itself).
"""

from __future__ import annotations

import logging
import uuid
from collections.abc import Sequence
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from starlette.exceptions import HTTPException as StarletteHTTPException

from api_schemas import PROBLEM_MEDIA_TYPE, InvalidParam, Problem
from cascalib.errors import CascalibError
from service.store import TRANSIENT, StoreUnavailable

__all__ = ["ProblemError", "install_handlers", "problem_response", "from_cascalib"]

log = logging.getLogger(__name__)

#: Seconds a client is told to wait when the job store is unavailable.
_STORE_RETRY_AFTER = 5

_TITLES = {400: "Bad request", 401: "Unauthorized", 404: "Not found", 405: "Method not allowed",
           408: "Request timeout", 409: "Conflict", 413: "Payload too large",
           415: "Unsupported media type",
           422: "Invalid input", 499: "Client closed request", 500: "Internal error",
           503: "Service unavailable"}


class ProblemError(Exception):
    """Raised by routes and helpers to answer with a problem body."""

    def __init__(self, status: int, detail: str, *, title: str | None = None,
                 errors: Sequence[InvalidParam] = (), headers: dict[str, str] | None = None):
        super().__init__(detail)
        self.status = status
        self.detail = detail
        self.title = title or _TITLES.get(status, "Error")
        self.errors = list(errors)
        self.headers = headers

    def __reduce__(self) -> tuple[Any, ...]:
        """Pickle with every attribute (validation runs in another process and raises these)."""
        return (_rebuild, (self.status, self.detail, self.title, self.errors, self.headers))


def _rebuild(status: int, detail: str, title: str, errors: list[InvalidParam],
             headers: dict[str, str] | None) -> ProblemError:
    return ProblemError(status, detail, title=title, errors=errors, headers=headers)


def from_cascalib(exc: CascalibError, status: int = 422) -> ProblemError:
    """A cascalib error (located by camera/file/frame/field) as a 4xx problem (413 for a
    stated size limit)."""
    from cascalib.formats.keypoints import LimitExceeded

    if isinstance(exc, LimitExceeded):
        status = 413
    param = InvalidParam(message=exc.message, camera=exc.camera, file=exc.file, frame=exc.frame,
                         field=exc.field)
    return ProblemError(status, str(exc), title=type(exc).__name__, errors=[param])


def problem_response(request: Request, status: int, detail: str | None, *, title: str | None = None,
                     errors: Sequence[InvalidParam] = (),
                     headers: dict[str, str] | None = None) -> JSONResponse:
    """A JSON response with a problem body."""
    body = Problem(title=title or _TITLES.get(status, "Error"), status=status, detail=detail,
                   instance=request.url.path, errors=list(errors))
    return JSONResponse(body.model_dump(mode="json", exclude_none=True), status_code=status,
                        media_type=PROBLEM_MEDIA_TYPE, headers=headers)


def _validation_params(errors: Sequence[Any]) -> list[InvalidParam]:
    out = []
    for err in errors:
        loc = [str(p) for p in err.get("loc", ()) if p not in ("body", "query", "path", "header")]
        out.append(InvalidParam(message=str(err.get("msg", "invalid")),
                                field=".".join(loc) or None))
    return out


def allowed_methods(request: Request) -> list[str]:
    """The methods the API documents at this path (Starlette's 405 names only the first route
    that matched the path, e.g. GET and not DELETE for ``/v1/jobs/{id}``)."""
    from starlette.routing import compile_path

    for template, operations in request.app.openapi().get("paths", {}).items():
        if compile_path(template)[0].match(request.url.path):
            return sorted(m.upper() for m in operations)
    return []


def problem_openapi(schema: dict[str, Any]) -> dict[str, Any]:
    """Document every error answer as what it is: ``application/problem+json`` with the
    Problem schema (FastAPI lists a model's schema under ``application/json``)."""
    ref = {"$ref": "#/components/schemas/Problem"}
    for operations in schema.get("paths", {}).values():
        for operation in operations.values():
            for status, answer in operation.get("responses", {}).items():
                if str(status)[0] in "45":
                    answer["content"] = {PROBLEM_MEDIA_TYPE: {"schema": ref}}
    return schema


def install_handlers(app: FastAPI) -> None:
    """Register the handlers that turn every exception into a problem body."""

    @app.exception_handler(ProblemError)
    async def _problem(request: Request, exc: ProblemError) -> JSONResponse:
        return problem_response(request, exc.status, exc.detail, title=exc.title,
                                errors=exc.errors, headers=exc.headers)

    @app.exception_handler(CascalibError)
    async def _cascalib(request: Request, exc: CascalibError) -> JSONResponse:
        p = from_cascalib(exc)
        return problem_response(request, p.status, p.detail, title=p.title, errors=p.errors)

    @app.exception_handler(RequestValidationError)
    async def _validation(request: Request, exc: RequestValidationError) -> JSONResponse:
        return problem_response(request, 422, "the request does not match the API schema",
                                errors=_validation_params(exc.errors()))

    @app.exception_handler(StarletteHTTPException)
    async def _http(request: Request, exc: StarletteHTTPException) -> JSONResponse:
        headers = getattr(exc, "headers", None)
        if exc.status_code == 405:
            headers = {**(headers or {}), "Allow": ", ".join(allowed_methods(request))}
        return problem_response(request, exc.status_code, str(exc.detail), headers=headers)

    async def _unavailable(request: Request, exc: Exception) -> JSONResponse:
        log.warning("%s %s: %s", request.method, request.url.path,
                    exc if isinstance(exc, StoreUnavailable) else type(exc).__name__)
        return problem_response(request, 503, "the job store is unavailable for now; retry "
                                "later", headers={"Retry-After": str(_STORE_RETRY_AFTER)})

    for kind in (StoreUnavailable, *TRANSIENT):
        app.add_exception_handler(kind, _unavailable)

    @app.exception_handler(Exception)
    async def _unexpected(request: Request, exc: Exception) -> JSONResponse:
        ref = uuid.uuid4().hex[:12]
        log.error("unhandled error %s on %s %s", ref, request.method, request.url.path,
                  exc_info=exc)
        return problem_response(request, 500, f"internal error (reference {ref})")
