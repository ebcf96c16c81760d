"""Embedded execution: a pool of worker processes inside ``cascalib serve``.

A dispatcher thread claims queued jobs (oldest first) while fewer than ``settings.workers`` run,
and starts one process per job. Processes come from a ``forkserver`` that has imported the
pipeline once (a job starts in milliseconds, not the seconds numpy/scipy/gtsam take to import),
and is itself a clean single-threaded process, so a crash or a kill cannot corrupt the server.
The thread watches them: a process that dies without recording an end (killed, out of memory,
segfault) gets its job re-queued, at most ``max_attempts`` times, then failed
with the reason; a cancelled job's process is terminated. On start-up, jobs a previous server
left running are treated the same way, so no job stays ``running`` after a crash.
"""

from __future__ import annotations

import logging
import multiprocessing
import os
import threading
import time
import uuid
from dataclasses import dataclass
from functools import partial
from multiprocessing.process import BaseProcess
from typing import Any

from cascalib.workers import die_with_parent
from service import store as st
from service.core.config import Settings
from service.core.proc import name_process, start_forkserver
from service.models import utcnow
from service.store import Store

__all__ = ["LocalPool"]

log = logging.getLogger(__name__)

_PREFIX = "local:"
#: Job processes run below the API and the upload validators, so polls stay fast under load.
JOB_NICENESS = 10
#: /readyz reports the pool unready when its rounds have failed for this many seconds.
_STALLED = 10.0


@dataclass
class _Running:
    process: BaseProcess
    attempt: int


def run_claimed_job(job_id: str, attempt: int, settings: Settings) -> None:
    """Body of a job process (embedded pool or Celery's supervised child): die with the parent,
    log, run the claimed job against the store, release the store."""
    from service.inputs import zip_limits
    from service.worker.runner import execute_claimed

    die_with_parent()
    name_process("cascalib-job")
    os.nice(JOB_NICENESS)
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    store = Store.from_settings(settings)
    try:
        execute_claimed(job_id, attempt, store, heartbeat=settings.heartbeat_seconds,
                        limits=zip_limits(settings))
    finally:
        store.dispose()


def _child_main(job_id: str, attempt: int, settings_values: dict[str, Any]) -> None:
    """Entry point of a worker process (runs one claimed job, then exits)."""
    run_claimed_job(job_id, attempt, Settings(**settings_values))


class LocalPool:
    """The embedded worker pool (one dispatcher thread, one process per running job)."""

    def __init__(self, settings: Settings, store: Store) -> None:
        self.settings = settings
        self.store = store
        self.instance = uuid.uuid4().hex[:10]
        self._ctx = multiprocessing.get_context("forkserver")
        self._running: dict[str, _Running] = {}
        self._last_round = time.monotonic()
        self._wake = threading.Event()
        self._stopping = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True, name="cascalib-pool")

    # -- life cycle ---------------------------------------------------------------------------
    def start(self) -> None:
        """Recover jobs a previous server left running, then start dispatching."""
        self._recover()
        start_forkserver()
        self._thread.start()

    def stop(self) -> None:
        """Stop dispatching; running jobs are stopped and queued again without an attempt lost."""
        self._stopping.set()
        self._wake.set()
        if self._thread.is_alive():
            self._thread.join(timeout=10)
        for job_id, run in list(self._running.items()):
            run.process.kill()
            run.process.join(timeout=5)
            self.store.retrying(f"release job {job_id}", partial(
                st.release_job, job_id=job_id, attempt=run.attempt))
        self._running.clear()

    def submit(self, job_id: str) -> None:
        """A job was queued: look for work now instead of at the next poll."""
        self._wake.set()

    def cancel(self, job_id: str) -> None:
        """A job was cancelled in the store: its process is terminated at the next look."""
        self._wake.set()

    def ready(self) -> str:
        """State for /readyz: the dispatcher runs and its last round went through."""
        if not self._thread.is_alive():
            return "worker pool not running"
        stalled = time.monotonic() - self._last_round
        return "ok" if stalled < _STALLED else f"worker pool stalled for {stalled:.0f} s"

    @property
    def running(self) -> dict[str, int]:
        """Job id -> process id of the jobs running now."""
        return {j: r.process.pid or 0 for j, r in self._running.items()}

    # -- internals ----------------------------------------------------------------------------
    def _recover(self) -> None:
        from datetime import timedelta

        with self.store.session() as session:
            dead = st.stale_jobs(session, now=utcnow(), stale_after=timedelta(days=3650),
                                 worker_prefix=_PREFIX)
            for job_id, attempt, _worker in dead:
                st.requeue_or_fail(session, job_id=job_id, attempt=attempt,
                                   reason="the server stopped while the job was running",
                                   max_attempts=self.settings.max_attempts)
                self.store.clean_work(job_id)

    def _loop(self) -> None:
        while not self._stopping.is_set():
            try:
                self._reap()
                self._check_cancelled()
                self._fill()
                self._last_round = time.monotonic()
            except st.TRANSIENT as exc:  # the database is briefly unavailable: next round
                log.warning("worker pool round: the job store is unavailable (%s)",
                            type(getattr(exc, "orig", exc)).__name__)
            except Exception:
                log.exception("worker pool round failed")
            self._wake.wait(0.5)
            self._wake.clear()

    def _reap(self) -> None:
        for job_id, run in list(self._running.items()):
            if run.process.is_alive():
                continue
            run.process.join()
            code = run.process.exitcode
            with self.store.session() as session:
                new = st.requeue_or_fail(
                    session, job_id=job_id, attempt=run.attempt,
                    reason=f"the worker process died (exit code {code})",
                    max_attempts=self.settings.max_attempts)
            del self._running[job_id]  # only once recorded: a failed write is retried
            self.store.clean_work(job_id)
            if new is not None:
                log.warning("job %s: worker died (exit code %s), now %s", job_id, code, new)

    def _check_cancelled(self) -> None:
        if not self._running:
            return
        with self.store.session() as session:
            for job_id, run in list(self._running.items()):
                job = st.find_job(session, job_id=job_id, owner=None)
                taken = job is not None and job.status == st.RUNNING and job.attempts != run.attempt
                if job is None or job.status == st.CANCELLED or taken:
                    log.info("job %s cancelled: stopping its process", job_id)
                    run.process.kill()
                    run.process.join(timeout=5)
                    del self._running[job_id]

    def _fill(self) -> None:
        free = self.settings.workers - len(self._running)
        if free <= 0 or self._stopping.is_set():
            return
        with self.store.session() as session:
            for job_id in st.queued_job_ids(session, limit=free):
                worker = f"{_PREFIX}{self.instance}:{os.getpid()}"
                attempt = st.claim_job(session, job_id=job_id, worker=worker)
                if attempt is None:
                    continue
                proc = self._ctx.Process(
                    target=_child_main, name=f"cascalib-job-{job_id}", daemon=False,
                    args=(job_id, attempt, self.settings.model_dump(mode="json")))
                proc.start()
                self._running[job_id] = _Running(proc, attempt)
                log.info("job %s attempt %d started in process %s", job_id, attempt, proc.pid)
