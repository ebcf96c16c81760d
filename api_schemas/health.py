"""Bodies of ``/healthz`` and ``/readyz``."""

from __future__ import annotations

from pydantic import BaseModel, Field

__all__ = ["Health", "Readiness"]


class Health(BaseModel):
    """The process is alive."""

    status: str = "ok"
    version: str


class Readiness(BaseModel):
    """The service can accept and run jobs: every check is ``"ok"``."""

    status: str = Field(description='"ok" or "unavailable".')
    checks: dict[str, str] = Field(description="Each dependency and its state.")
