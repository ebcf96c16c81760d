"""Liveness, readiness and Prometheus metrics (no token needed)."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import JSONResponse, Response
from prometheus_client import CONTENT_TYPE_LATEST, generate_latest

from api_schemas import Health, Readiness
from cascalib import __version__
from service.api.deps import StateDep
from service.db import current_revision, head_revision

__all__ = ["router"]

router = APIRouter(tags=["health"])


@router.get("/healthz", response_model=Health)
def healthz() -> Health:
    """The process answers."""
    return Health(version=__version__)


@router.get("/readyz", response_model=Readiness,
            responses={503: {"model": Readiness, "description": "Not ready"}})
def readyz(state: StateDep) -> JSONResponse:
    """The database is migrated and writable, and the workers (or the broker) are alive."""
    checks: dict[str, str] = {}
    try:
        rev = current_revision(state.store.engine)
        checks["database"] = (state.store.check_writable() if rev == head_revision()
                              else f"schema at {rev}")
    except Exception as exc:
        checks["database"] = f"unreachable: {type(exc).__name__}"
    checks["workers"] = state.dispatcher.ready()
    ok = all(v == "ok" for v in checks.values())
    body = Readiness(status="ok" if ok else "unavailable", checks=checks)
    return JSONResponse(body.model_dump(), status_code=200 if ok else 503)


@router.get("/metrics", response_class=Response,
            responses={200: {"content": {"text/plain": {}}, "description": "Prometheus text"}})
def metrics(state: StateDep) -> Response:
    """Prometheus metrics: request counts and latencies, submissions, jobs by state."""
    return Response(generate_latest(state.metrics.registry), media_type=CONTENT_TYPE_LATEST)
