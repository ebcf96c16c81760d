"""The job store: the only code that commits to the database.

Functions take the ``Session`` first and everything else by keyword (the template's
``crud.py``). Worker-side updates are *fenced* by the attempt number: a worker whose job was
cancelled, or re-queued after it was presumed dead, can no longer write to it (the update
matches no row and the function returns False).

:class:`Store` bundles the engine, the session factory and the on-disk layout
(``<data_dir>/jobs/<job id>/{inputs,outputs}/``: server-generated names only).
"""

from __future__ import annotations

import hashlib
import logging
import shutil
import time
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from dataclasses import dataclass
from datetime import datetime, timedelta
from pathlib import Path
from typing import Any, TypeVar

from sqlalchemy import Engine, func, select, text, update
from sqlalchemy.exc import IntegrityError, InterfaceError, OperationalError
from sqlalchemy.orm import Session, selectinload, sessionmaker

from service.db import make_engine, migrate
from service.models import ApiToken, Job, JobEvent, JobFile, utcnow

__all__ = [
    "StoredFile",
    "Store",
    "StoreUnavailable",
    "TRANSIENT",
    "JOB_BUCKETS",
    "add_api_token",
    "read_events",
    "cancel_job",
    "claim_job",
    "count_api_tokens",
    "count_by_status",
    "create_job",
    "delete_job",
    "expired_jobs",
    "find_job",
    "find_job_by_key",
    "finish_job",
    "list_jobs",
    "queued_job_ids",
    "release_job",
    "requeue_or_fail",
    "stale_jobs",
    "token_known",
    "update_progress",
    "sha256_file",
]

log = logging.getLogger(__name__)

T = TypeVar("T")
#: Database errors that pass: a lock held by another writer, a dropped connection, a restart.
TRANSIENT = (OperationalError, InterfaceError)
_FIRST_WAIT = 0.05  # s, first pause before retrying; doubles up to _LONGEST_WAIT
_LONGEST_WAIT = 2.0
_READY_TIMEOUT = 1.0  # s a readiness probe waits for the write lock


class StoreUnavailable(RuntimeError):
    """The database stayed unavailable through every retry (the API answers 503)."""


#: Upper bounds (s) of the job histograms (time queued, time running).
JOB_BUCKETS = (1.0, 5.0, 15.0, 60.0, 300.0, 900.0, 3600.0, 14400.0)

QUEUED, RUNNING, SUCCEEDED, FAILED, CANCELLED = (
    "queued", "running", "succeeded", "failed", "cancelled")
FINISHED = (SUCCEEDED, FAILED, CANCELLED)


def sha256_file(path: Path) -> str:
    """SHA-256 hex digest of a file, read in 1 MiB blocks."""
    h = hashlib.sha256()
    with path.open("rb") as fh:
        for block in iter(lambda: fh.read(2**20), b""):
            h.update(block)
    return h.hexdigest()


@dataclass(frozen=True)
class StoredFile:
    """A file of a job: ``path`` relative to the job folder, ``role`` camera or output name."""

    role: str
    path: str
    size: int
    sha256: str
    client_name: str | None = None


class Store:
    """Engine, sessions and file layout of one service installation."""

    def __init__(self, database_url: str, data_dir: Path, *, busy_timeout: float = 30.0,
                 retry_seconds: float = 60.0) -> None:
        self.engine: Engine = make_engine(database_url, busy_timeout)
        self.sessions = sessionmaker(self.engine, expire_on_commit=False)
        self.busy_timeout = busy_timeout
        self.retry_seconds = retry_seconds
        self.data_dir = data_dir
        self.jobs_dir = data_dir / "jobs"
        self.staging_dir = data_dir / "staging"

    def prepare(self) -> None:
        """Create the folders and bring the schema to the newest migration."""
        self.jobs_dir.mkdir(parents=True, exist_ok=True)
        self.staging_dir.mkdir(parents=True, exist_ok=True)
        migrate(self.engine)

    @contextmanager
    def session(self) -> Iterator[Session]:
        """A session closed on exit (callers commit through the functions below)."""
        with self.sessions() as session:
            yield session

    @classmethod
    def from_settings(cls, settings: Any) -> Store:
        """The store of the service settings (database, data folder, timeouts)."""
        return cls(settings.sqlalchemy_url, settings.data_dir,
                   busy_timeout=settings.db_busy_timeout_seconds,
                   retry_seconds=settings.db_retry_seconds)

    def retrying(self, what: str, fn: Callable[[Session], T]) -> T:
        """``fn(session)`` in a fresh session, again after a transient database error, with
        growing pauses, for up to ``retry_seconds``.

        Raises
        ------
        StoreUnavailable
            The database stayed unavailable (the message names ``what``, never the SQL).
        """
        deadline = time.monotonic() + self.retry_seconds
        wait = _FIRST_WAIT
        while True:
            try:
                with self.session() as session:
                    return fn(session)
            except TRANSIENT as exc:
                cause = type(getattr(exc, "orig", exc)).__name__
                if time.monotonic() + wait > deadline:
                    raise StoreUnavailable(f"{what}: the job store is unavailable ({cause})"
                                           ) from exc
                log.warning("%s: the job store is unavailable (%s), retrying in %.2f s", what,
                            cause, wait)
                time.sleep(wait)
                wait = min(2 * wait, _LONGEST_WAIT)

    def check_writable(self) -> str:
        """"ok" when a write would go through within ``_READY_TIMEOUT`` (nothing is changed),
        else why not."""
        try:
            with self.engine.connect() as conn:
                if conn.dialect.name == "sqlite":
                    conn.exec_driver_sql(f"PRAGMA busy_timeout={int(_READY_TIMEOUT * 1000)}")
                else:
                    conn.execute(text(f"SET LOCAL lock_timeout = '{int(_READY_TIMEOUT * 1000)}ms'"))
                try:
                    conn.execute(text("UPDATE alembic_version SET version_num = version_num"))
                finally:
                    conn.rollback()
                    if conn.dialect.name == "sqlite":
                        conn.exec_driver_sql(
                            f"PRAGMA busy_timeout={int(self.busy_timeout * 1000)}")
        except TRANSIENT as exc:
            return f"not writable: {type(getattr(exc, 'orig', exc)).__name__}"
        return "ok"

    def job_dir(self, job_id: str) -> Path:
        """Folder of one job (job ids are server-generated hex strings)."""
        if not job_id.isalnum():
            raise ValueError(f"invalid job id {job_id!r}")
        return self.jobs_dir / job_id

    def clean_work(self, job_id: str) -> None:
        """Delete what a killed attempt left in the job's folder: its scratch folders
        (``tmp*``) and half-written outputs (``outputs.partial``)."""
        folder = self.job_dir(job_id)
        for leftover in [*folder.glob("tmp*"), folder / "outputs.partial"]:
            shutil.rmtree(leftover, ignore_errors=True)

    def remove_files(self, job_id: str) -> None:
        """Delete a job's folder (after its row is gone)."""
        shutil.rmtree(self.job_dir(job_id), ignore_errors=True)

    def sweep_orphans(self, min_age: float = 900.0) -> int:
        """Remove what a crash mid-submission left: staging folders and job folders without a
        row, older than ``min_age`` seconds (younger ones may be another API replica's
        submission in progress)."""
        import time

        cutoff = time.time() - min_age
        with self.session() as session:
            known = set(session.scalars(select(Job.id)))
        removed = 0
        for parent, keep in ((self.staging_dir, set()), (self.jobs_dir, known)):
            for d in parent.iterdir():
                if d.name not in keep and d.stat().st_mtime < cutoff:
                    shutil.rmtree(d, ignore_errors=True) if d.is_dir() else d.unlink()
                    removed += 1
        return removed

    def dispose(self) -> None:
        """Close every pooled connection."""
        self.engine.dispose()


# --- API side ----------------------------------------------------------------------------------

def create_job(session: Session, *, job_id: str, owner: str, options: dict[str, object],
               cameras: Sequence[str], inputs: Sequence[StoredFile],
               idempotency_key: str | None, request_hash: str) -> Job:
    """Insert a queued job with its input files.

    Raises
    ------
    sqlalchemy.exc.IntegrityError
        When the owner already has a job with this idempotency key (after rolling back).
    """
    job = Job(id=job_id, owner=owner, status=QUEUED, stage=None, progress=0.0,
              options=options, cameras=list(cameras), idempotency_key=idempotency_key,
              request_hash=request_hash, attempts=0)
    job.files = [JobFile(kind="input", role=f.role, path=f.path, client_name=f.client_name,
                         size=f.size, sha256=f.sha256) for f in inputs]
    session.add(job)
    try:
        session.commit()
    except IntegrityError:
        session.rollback()
        raise
    return job


def find_job(session: Session, *, job_id: str, owner: str | None) -> Job | None:
    """The job, if it exists and belongs to ``owner`` (any owner when None)."""
    stmt = select(Job).where(Job.id == job_id).options(selectinload(Job.files))
    if owner is not None:
        stmt = stmt.where(Job.owner == owner)
    return session.scalars(stmt).first()


def find_job_by_key(session: Session, *, owner: str, idempotency_key: str) -> Job | None:
    """The owner's job submitted with this idempotency key."""
    stmt = select(Job).where(Job.owner == owner, Job.idempotency_key == idempotency_key)
    return session.scalars(stmt).first()


def list_jobs(session: Session, *, owner: str, status: str | None, limit: int,
              offset: int) -> tuple[list[Job], int]:
    """One page of the owner's jobs, newest first, and the total matching count."""
    where = [Job.owner == owner] + ([Job.status == status] if status else [])
    count = session.scalar(select(func.count()).select_from(Job).where(*where)) or 0
    stmt = (select(Job).where(*where).order_by(Job.created_at.desc(), Job.id)
            .limit(limit).offset(offset))
    return list(session.scalars(stmt)), int(count)


def cancel_job(session: Session, *, job_id: str) -> str:
    """Cancel a queued or running job; returns its status afterwards."""
    now = utcnow()
    session.execute(update(Job).where(Job.id == job_id, Job.status.in_((QUEUED, RUNNING)))
                    .values(status=CANCELLED, finished_at=now, worker=None))
    session.commit()
    return session.scalars(select(Job.status).where(Job.id == job_id)).one()


def delete_job(session: Session, *, job_id: str) -> bool:
    """Delete a finished job's row (its files are removed by ``Store.remove_files``)."""
    job = session.get(Job, job_id)
    if job is None or job.status not in FINISHED:
        return False
    session.delete(job)
    session.commit()
    return True


def expired_jobs(session: Session, *, before: datetime, limit: int) -> list[str]:
    """Finished jobs that ended before ``before`` (oldest first), for the retention sweep."""
    stmt = (select(Job.id).where(Job.status.in_(FINISHED), Job.finished_at < before)
            .order_by(Job.finished_at).limit(limit))
    return list(session.scalars(stmt))


def count_by_status(session: Session) -> dict[str, int]:
    """Number of jobs in each state (all owners), for the metrics."""
    rows = session.execute(select(Job.status, func.count()).group_by(Job.status))
    return {status: int(n) for status, n in rows}


def add_api_token(session: Session, *, name: str, token: str) -> None:
    """Keep a bearer token in the store (only its SHA-256)."""
    session.add(ApiToken(name=name, token_sha256=hashlib.sha256(token.encode()).hexdigest()))
    session.commit()


def count_api_tokens(session: Session) -> int:
    """How many tokens the store holds."""
    return int(session.scalar(select(func.count()).select_from(ApiToken)) or 0)


def token_known(session: Session, *, token_sha256: str) -> bool:
    """Whether the store holds a token with this hash."""
    stmt = select(ApiToken.id).where(ApiToken.token_sha256 == token_sha256)
    return session.scalars(stmt).first() is not None


# --- metrics: running totals in the store (every process adds to the same) -----------------

def _add_events(session: Session, rows: Sequence[tuple[str, str, float]]) -> None:
    """Add to running totals (created at their first use); the caller commits."""
    from sqlalchemy.dialects import postgresql, sqlite

    dialect = sqlite if session.get_bind().dialect.name == "sqlite" else postgresql
    stmt: Any = dialect.insert(JobEvent).values(
        [{"name": n, "bucket": b, "value": v} for n, b, v in rows])
    session.execute(stmt.on_conflict_do_update(
        index_elements=["name", "bucket"], set_={"value": JobEvent.value + stmt.excluded.value}))


def _observe(session: Session, name: str, seconds: float) -> None:
    """One observation of a histogram (cumulative buckets, like Prometheus's)."""
    seconds = max(seconds, 0.0)
    _add_events(session, [(name, f"{b:g}", 1.0) for b in JOB_BUCKETS if seconds <= b]
                + [(name, "+Inf", 1.0), (name, "sum", seconds)])


def _count(session: Session, name: str) -> None:
    _add_events(session, [(name, "", 1.0)])


def read_events(session: Session) -> dict[tuple[str, str], float]:
    """Every running total: ``(name, bucket) -> value``."""
    return {(e.name, e.bucket): e.value for e in session.scalars(select(JobEvent))}


# --- worker side -------------------------------------------------------------------------------

def queued_job_ids(session: Session, *, limit: int) -> list[str]:
    """Oldest queued jobs first."""
    stmt = select(Job.id).where(Job.status == QUEUED).order_by(Job.created_at).limit(limit)
    return list(session.scalars(stmt))


def claim_job(session: Session, *, job_id: str, worker: str) -> int | None:
    """Atomically move a queued job to running; returns the attempt number, None if not queued.

    Two workers claiming the same job (a duplicated broker message) cannot both win: the
    update matches ``status='queued'`` and only one of them changes the row.
    """
    now = utcnow()
    res = session.execute(
        update(Job).where(Job.id == job_id, Job.status == QUEUED)
        .values(status=RUNNING, attempts=Job.attempts + 1, worker=worker, heartbeat_at=now,
                started_at=now, stage="loading", progress=0.0, error=None))
    if getattr(res, "rowcount", 0) != 1:
        session.commit()
        return None
    attempt, created = session.execute(
        select(Job.attempts, Job.created_at).where(Job.id == job_id)).one()
    if attempt == 1:  # a retry's wait is not the client's wait for its job to start
        _observe(session, "queue_wait", (now - created).total_seconds())
    session.commit()
    return int(attempt)


def _fenced(job_id: str, attempt: int):  # type: ignore[no-untyped-def]
    return update(Job).where(Job.id == job_id, Job.status == RUNNING, Job.attempts == attempt)


def update_progress(session: Session, *, job_id: str, attempt: int, stage: str | None,
                    progress: float | None) -> bool:
    """Record progress and a heartbeat; False when the job is no longer this attempt's."""
    values: dict[str, object] = {"heartbeat_at": utcnow()}
    if stage is not None:
        values["stage"] = stage[:64]
    if progress is not None:
        values["progress"] = min(max(float(progress), 0.0), 1.0)
    res = session.execute(_fenced(job_id, attempt).values(**values))
    session.commit()
    return getattr(res, "rowcount", 0) == 1


def finish_job(session: Session, *, job_id: str, attempt: int, status: str,
               error: str | None = None, outputs: Sequence[StoredFile] = (),
               warnings: Sequence[str] = ()) -> bool:
    """Move a running job to a terminal state and record its outputs and warnings, in one
    transaction."""
    res = session.execute(_fenced(job_id, attempt).values(
        status=status, error=error, finished_at=utcnow(), worker=None,
        warnings=list(warnings) or None,
        progress=1.0 if status == SUCCEEDED else Job.progress,
        stage="done" if status == SUCCEEDED else Job.stage))
    if getattr(res, "rowcount", 0) != 1:
        session.rollback()
        return False
    session.add_all([JobFile(job_id=job_id, kind="output", role=f.role, path=f.path,
                             size=f.size, sha256=f.sha256) for f in outputs])
    started = session.scalars(select(Job.started_at).where(Job.id == job_id)).one()
    if started is not None:
        _observe(session, f"duration:{status}", (utcnow() - started).total_seconds())
    if status == FAILED:
        _count(session, "failed")
    session.commit()
    return True


def release_job(session: Session, *, job_id: str, attempt: int) -> bool:
    """Put a running job back in the queue without counting the attempt (orderly shutdown)."""
    res = session.execute(_fenced(job_id, attempt).values(
        status=QUEUED, attempts=Job.attempts - 1, worker=None, stage=None, progress=0.0))
    session.commit()
    return getattr(res, "rowcount", 0) == 1


def requeue_or_fail(session: Session, *, job_id: str, attempt: int, reason: str,
                    max_attempts: int) -> str | None:
    """A worker died during ``attempt``: queue the job again, or fail it after max_attempts.

    Returns the new status, or None when the job had already moved on.
    """
    job = session.get(Job, job_id)
    if job is None or job.status != RUNNING or job.attempts != attempt:
        return None
    if attempt >= max_attempts:
        new = FAILED
        values: dict[str, object] = {
            "status": FAILED, "finished_at": utcnow(), "worker": None,
            "error": f"{reason}; gave up after {attempt} attempt(s)"}
    else:
        new = QUEUED
        values = {"status": QUEUED, "worker": None, "stage": None, "progress": 0.0,
                  "error": None}
    res = session.execute(_fenced(job_id, attempt).values(**values))
    if getattr(res, "rowcount", 0) == 1:
        _count(session, "failed" if new == FAILED else "retried")
    session.commit()
    if getattr(res, "rowcount", 0) != 1:
        return None
    log.warning("job %s attempt %d: %s -> %s", job_id, attempt, reason, new)
    return new


def stale_jobs(session: Session, *, now: datetime, stale_after: timedelta,
               worker_prefix: str | None = None) -> list[tuple[str, int, str | None]]:
    """Running jobs whose heartbeat is older than ``stale_after`` (or whose worker belongs to
    ``worker_prefix``, a previous instance): ``(id, attempt, worker)`` each."""
    cond = Job.heartbeat_at < now - stale_after
    if worker_prefix is not None:
        cond = cond | Job.worker.startswith(worker_prefix)
    stmt = select(Job.id, Job.attempts, Job.worker).where(Job.status == RUNNING, cond)
    return [(i, int(a), w) for i, a, w in session.execute(stmt)]
