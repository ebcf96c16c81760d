"""Engine construction and migrations (alembic, shipped inside the package, run at start-up)."""

from __future__ import annotations

import logging
from pathlib import Path
from typing import Any

from sqlalchemy import Engine, create_engine, event, text

__all__ = ["make_engine", "migrate", "current_revision", "head_revision"]

log = logging.getLogger(__name__)

_ALEMBIC_DIR = Path(__file__).resolve().parent / "alembic"
#: Arbitrary constant of the PostgreSQL advisory lock that serialises concurrent migrations
#: (the API and several Celery workers may start at the same moment).
_MIGRATION_LOCK = 727_411_009


def make_engine(url: str, busy_timeout: float = 30.0) -> Engine:
    """Engine for ``url``; SQLite gets WAL, a busy timeout and foreign keys.

    Several processes (the API and its worker processes) write to one SQLite file, so writers
    wait for each other (``busy_timeout`` seconds) before failing with "database is locked"
    (then the store's callers retry, see ``Store.retrying``).
    """
    if url.startswith("sqlite"):
        engine = create_engine(url, connect_args={"timeout": busy_timeout,
                                                  "check_same_thread": False})

        @event.listens_for(engine, "connect")
        def _pragmas(dbapi_conn: Any, _record: Any) -> None:
            cur = dbapi_conn.cursor()
            cur.execute("PRAGMA journal_mode=WAL")
            cur.execute("PRAGMA foreign_keys=ON")
            cur.execute(f"PRAGMA busy_timeout={int(busy_timeout * 1000)}")
            cur.close()

        return engine
    return create_engine(url, pool_pre_ping=True, pool_size=10, max_overflow=20)


def _alembic_config(engine: Engine) -> Any:
    from alembic.config import Config

    cfg = Config()
    cfg.set_main_option("script_location", str(_ALEMBIC_DIR))
    cfg.set_main_option("sqlalchemy.url", engine.url.render_as_string(hide_password=False))
    return cfg


def migrate(engine: Engine) -> None:
    """Upgrade the database to the newest schema (idempotent, safe to call concurrently)."""
    from alembic import command

    cfg = _alembic_config(engine)
    with engine.begin() as conn:
        if conn.dialect.name == "postgresql":
            conn.execute(text("SELECT pg_advisory_xact_lock(:k)"), {"k": _MIGRATION_LOCK})
        cfg.attributes["connection"] = conn
        command.upgrade(cfg, "head")
    log.info("database schema at %s", head_revision())


def head_revision() -> str | None:
    """Newest migration shipped with this package."""
    from alembic.config import Config
    from alembic.script import ScriptDirectory

    cfg = Config()
    cfg.set_main_option("script_location", str(_ALEMBIC_DIR))
    return ScriptDirectory.from_config(cfg).get_current_head()


def current_revision(engine: Engine) -> str | None:
    """Schema revision the database is at (None before the first migration)."""
    from alembic.runtime.migration import MigrationContext

    with engine.connect() as conn:
        return MigrationContext.configure(conn).get_current_revision()
