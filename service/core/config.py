"""Settings of the service, read from ``CASCALIB_*`` environment variables.

Only the service reads the environment; the library never does. ``Settings()`` builds a fresh
object each time (no module-level singleton), so tests and ``create_app(settings)`` can pass
their own.
"""

from __future__ import annotations

import hashlib
from pathlib import Path
from typing import Annotated

from pydantic import Field, field_validator, model_validator
from pydantic_settings import BaseSettings, NoDecode, SettingsConfigDict

__all__ = ["Settings", "ConfigurationError", "token_owner"]


class ConfigurationError(RuntimeError):
    """The service is configured in a way it must refuse to start with."""


def _split(value: object) -> object:
    if isinstance(value, str):
        return [v.strip() for v in value.split(",") if v.strip()]
    return value


def token_owner(token: str) -> str:
    """Owner id of a bearer token: its SHA-256 (the token itself is never stored)."""
    return hashlib.sha256(token.encode("utf-8")).hexdigest()


class Settings(BaseSettings):
    """Every setting of ``cascalib serve`` and of the Celery workers."""

    model_config = SettingsConfigDict(env_prefix="CASCALIB_", extra="ignore")

    data_dir: Path = Field(
        default=Path("cascalib-data"),
        description="Folder of the uploaded inputs, results and the default SQLite database.",
    )
    database_url: str | None = Field(
        default=None,
        description="SQLAlchemy URL; default sqlite:///<data_dir>/cascalib.db. "
        "postgresql://user:pass@host/db selects PostgreSQL (psycopg 3).",
    )
    broker_url: str | None = Field(
        default=None,
        description="Celery broker (redis://...). Unset: the embedded worker pool runs jobs.",
    )
    api_tokens: Annotated[list[str], NoDecode] = Field(
        default_factory=list, description="Comma-separated bearer tokens accepted by the API."
    )
    development: bool = Field(
        default=False, description="Local development mode: no token needed when none is set."
    )
    insecure_no_auth: bool = Field(
        default=False, description="Run without authentication (explicit opt-in)."
    )
    workers: int = Field(default=2, ge=1, le=64, description="Embedded pool: parallel jobs.")
    max_attempts: int = Field(
        default=3, ge=1, le=20, description="A job whose worker died is retried this many times."
    )
    heartbeat_seconds: float = Field(default=5.0, gt=0, description="Worker heartbeat period.")
    stale_after_seconds: float = Field(
        default=60.0, gt=0,
        description="A running job without heartbeat for this long is presumed dead.",
    )
    max_upload_bytes: int = Field(default=512 * 2**20, ge=1024, description="Whole request.")
    db_busy_timeout_seconds: float = Field(
        default=5.0, gt=0,
        description="SQLite: how long a write waits for another writer's lock per try.",
    )
    db_retry_seconds: float = Field(
        default=60.0, ge=0,
        description="How long a write is retried while the database is locked or unreachable; "
        "then the API answers 503 with Retry-After and a worker leaves the job to recovery.",
    )
    body_timeout_seconds: float = Field(
        default=60.0, gt=0,
        description="A request body that stops arriving for this long is answered 408.",
    )
    max_files: int = Field(default=64, ge=1, description="Files (cameras) per job.")
    max_unzipped_bytes: int = Field(
        default=2 * 2**30, ge=1024, description="Total size of one zip's extracted members."
    )
    max_zip_members: int = Field(default=200_000, ge=1, description="Members of one zip.")
    max_frames: int = Field(
        default=1_000_000, ge=1,
        description="Frames of one camera: the span of its frame ids, 0 to the last (413).",
    )
    max_persons: int = Field(
        default=100, ge=1, description="People detected in one frame of one camera (413)."
    )
    max_keypoint_bytes: int = Field(
        default=2**30, ge=2**20,
        description="Memory of one camera's keypoints, frames x persons x joints x 3 x 8 (413).",
    )
    max_zip_ratio: float = Field(
        default=200.0, gt=1, description="Largest compression ratio of a zip member (zip bombs)."
    )
    cors_origins: Annotated[list[str], NoDecode] = Field(
        default_factory=list, description="Comma-separated origins allowed by CORS."
    )
    page_limit: int = Field(default=100, ge=1, description="Largest page of GET /v1/jobs.")
    retention_hours: float = Field(
        default=720.0, ge=0,
        description="Finished jobs are deleted with their files this long after they ended "
        "(0: kept until deleted by hand).",
    )
    sweep_interval_seconds: float = Field(
        default=600.0, gt=0, description="How often the retention sweep runs."
    )
    validation_workers: int = Field(
        default=1, ge=1, le=64,
        description="Processes that parse uploads before a job is accepted (off the API's "
        "event loop); further submissions wait for one.",
    )
    max_pending_submissions: int = Field(
        default=16, ge=1,
        description="Submissions being received or validated at once; beyond, 503 with "
        "Retry-After.",
    )

    @field_validator("api_tokens", "cors_origins", mode="before")
    @classmethod
    def _comma_list(cls, value: object) -> object:
        return _split(value)

    @model_validator(mode="after")
    def _normalise(self) -> Settings:
        self.data_dir = self.data_dir.expanduser().resolve()
        return self

    @property
    def sqlalchemy_url(self) -> str:
        """Database URL with the psycopg 3 driver made explicit for PostgreSQL."""
        url = self.database_url or f"sqlite:///{self.data_dir / 'cascalib.db'}"
        for prefix in ("postgresql://", "postgres://"):
            if url.startswith(prefix):
                url = "postgresql+psycopg://" + url[len(prefix):]
        return url

    @property
    def auth_enabled(self) -> bool:
        """Whether requests need a bearer token."""
        if self.insecure_no_auth:
            return False
        return bool(self.api_tokens) or not self.development

    @property
    def token_owners(self) -> frozenset[str]:
        """Owner ids of the configured tokens."""
        return frozenset(token_owner(t) for t in self.api_tokens)

    def check_startable(self, *, n_stored_tokens: int) -> None:
        """Refuse to run open to anyone unless asked to explicitly.

        Raises
        ------
        ConfigurationError
            When no token is configured (neither in CASCALIB_API_TOKENS nor in the store)
            outside development mode and without ``--insecure-no-auth``.
        """
        if self.api_tokens or n_stored_tokens or self.development or self.insecure_no_auth:
            return
        raise ConfigurationError(
            "no API token configured: set CASCALIB_API_TOKENS (comma-separated bearer tokens), "
            "or CASCALIB_DEVELOPMENT=1 for local development, or pass --insecure-no-auth"
        )
