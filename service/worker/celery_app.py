"""Scale-out execution: Celery workers with a Redis broker sharing the job store.

Start a worker with ``celery -A service.worker worker`` (same ``CASCALIB_*`` environment as
the API, with CASCALIB_BROKER_URL and a shared CASCALIB_DATABASE_URL / CASCALIB_DATA_DIR).
Each task runs its job in a child process (``job_process.py``) that it supervises.
The broker only carries job ids; the job itself lives in the store, so a lost or duplicated
message is harmless: the API re-sends queued jobs, and only one worker can claim a job.
"""

from __future__ import annotations

import logging
import os
import socket
import subprocess
import sys
import threading
import time
from datetime import timedelta

from celery import Celery  # type: ignore[import-untyped]

from service import store as st
from service.core.config import Settings
from service.models import utcnow
from service.store import Store

__all__ = ["TASK_NAME", "create_celery", "CeleryDispatcher", "app"]

log = logging.getLogger(__name__)

TASK_NAME = "cascalib.run_job"
QUEUE = "cascalib"

_store: Store | None = None
_store_lock = threading.Lock()


def _worker_store(settings: Settings) -> Store:
    """This worker process's store, created on first use (after Celery forked the process).

    The API owns the migrations; a worker waits until the schema is there.
    """
    global _store
    with _store_lock:
        if _store is None:
            from service.db import current_revision, head_revision

            store = Store.from_settings(settings)
            deadline = time.monotonic() + 120
            while current_revision(store.engine) != head_revision():
                if time.monotonic() > deadline:
                    raise RuntimeError("database schema not migrated: start the API first")
                time.sleep(1)
            _store = store
        return _store


def create_celery(settings: Settings) -> Celery:
    """The Celery application (no connection is made until it is used)."""
    celery = Celery("cascalib", broker=settings.broker_url or "redis://127.0.0.1:6379/0")
    celery.conf.update(
        task_acks_late=True,  # a worker killed mid-job leaves the message for another one
        task_reject_on_worker_lost=True,
        worker_prefetch_multiplier=1,  # jobs are long: do not hoard them
        task_default_queue=QUEUE,
        task_ignore_result=True,  # results live in the job store
        broker_connection_retry_on_startup=True,
        worker_hijack_root_logger=False,
    )

    @celery.task(name=TASK_NAME)  # type: ignore[untyped-decorator]
    def run_job_task(job_id: str) -> str | None:
        store = _worker_store(settings)
        worker = f"celery:{socket.gethostname()}:{os.getpid()}"
        with store.session() as session:
            attempt = st.claim_job(session, job_id=job_id, worker=worker)
            unknown = attempt is None and st.find_job(session, job_id=job_id, owner=None) is None
        if unknown:
            # Deleted since, or another deployment's job: a broker database shared by two
            # deployments makes their workers take (and drop) each other's messages.
            log.warning("job %s is not in this worker's database (deleted, or is the broker "
                        "at CASCALIB_BROKER_URL shared with another deployment?)", job_id)
        if attempt is None:
            return None  # duplicate message, or the job was cancelled meanwhile
        new = supervise(job_id, attempt, store, settings)
        if new == st.QUEUED:
            run_job_task.apply_async(args=[job_id], queue=QUEUE)
        return new

    return celery


def supervise(job_id: str, attempt: int, store: Store, settings: Settings) -> str | None:
    """Run a claimed job in a child process, heartbeat for it, stop it when cancelled.

    Returns the job's state when the child died without recording an end (re-queued or
    failed), else None.
    """
    try:
        proc = subprocess.Popen([sys.executable, "-m", "service.worker.job_process", job_id,
                                 str(attempt)])
    except OSError as exc:
        with store.session() as session:
            return st.requeue_or_fail(session, job_id=job_id, attempt=attempt,
                                      reason=f"cannot start the job process ({exc})",
                                      max_attempts=settings.max_attempts)
    try:
        while True:
            try:
                code = proc.wait(timeout=settings.heartbeat_seconds)
                break
            except subprocess.TimeoutExpired:
                with store.session() as session:
                    ours = st.update_progress(session, job_id=job_id, attempt=attempt,
                                              stage=None, progress=None)
                if not ours:  # cancelled, or re-queued after a missed heartbeat
                    log.info("job %s is no longer this worker's: stopping it", job_id)
                    proc.kill()
                    proc.wait()
                    return None
    except BaseException:
        proc.kill()  # the worker is shutting down: the job goes back to the queue
        proc.wait()
        with store.session() as session:
            st.release_job(session, job_id=job_id, attempt=attempt)
        raise
    if code == 0:
        return None
    store.clean_work(job_id)
    with store.session() as session:
        return st.requeue_or_fail(session, job_id=job_id, attempt=attempt,
                                  reason=f"the job process died (exit code {code})",
                                  max_attempts=settings.max_attempts)


class CeleryDispatcher:
    """API side of the Celery back-end: sends job ids, re-queues jobs of dead workers."""

    def __init__(self, settings: Settings, store: Store) -> None:
        self.settings = settings
        self.store = store
        self.celery = create_celery(settings)
        self._stopping = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True, name="cascalib-reaper")

    def start(self) -> None:
        """Re-send queued jobs (a message may have been lost) and start the reaper."""
        self._resend_queued()
        self._thread.start()

    def stop(self) -> None:
        """Stop the reaper (workers keep running their jobs)."""
        self._stopping.set()
        self._thread.join(timeout=10)

    def submit(self, job_id: str) -> None:
        """Hand the job to the workers; a broker outage is retried by the reaper."""
        try:
            self.celery.send_task(TASK_NAME, args=[job_id], queue=QUEUE)
        except Exception:
            log.warning("could not send job %s to the broker; will retry", job_id, exc_info=True)

    def cancel(self, job_id: str) -> None:
        """Nothing to send: the worker sees the cancellation at its next heartbeat."""

    def ready(self) -> str:
        """Broker reachable?"""
        try:
            with self.celery.connection_for_write() as conn:
                conn.ensure_connection(max_retries=1, timeout=2)
            return "ok"
        except Exception as exc:
            return f"broker unreachable: {type(exc).__name__}"

    def _resend_queued(self) -> None:
        with self.store.session() as session:
            ids = st.queued_job_ids(session, limit=10_000)
        for job_id in ids:
            self.submit(job_id)

    def _reap(self) -> None:
        stale = timedelta(seconds=self.settings.stale_after_seconds)
        with self.store.session() as session:
            for job_id, attempt, worker in st.stale_jobs(session, now=utcnow(), stale_after=stale):
                new = st.requeue_or_fail(
                    session, job_id=job_id, attempt=attempt,
                    reason=f"worker {worker} stopped responding (no heartbeat for "
                    f"{self.settings.stale_after_seconds:g} s)",
                    max_attempts=self.settings.max_attempts)
                if new == st.QUEUED:
                    self.submit(job_id)

    def _loop(self) -> None:
        last_resend = time.monotonic()
        while not self._stopping.wait(min(self.settings.heartbeat_seconds, 5.0)):
            try:
                self._reap()
                if time.monotonic() - last_resend > self.settings.stale_after_seconds:
                    self._resend_queued()
                    last_resend = time.monotonic()
            except Exception:
                log.exception("reaper round failed")


#: The application ``celery -A service.worker worker`` runs (settings from the environment;
#: building it opens no connection).
app = create_celery(Settings())
