"""Retention: a thread of the API deletes finished jobs older than the retention time, with
their files, and what crashed submissions left in staging.

Without it every job's inputs and outputs stayed until deleted by hand (100 jobs of a
4-camera scene: 3.5 GB). Several API replicas may sweep at once: deleting is idempotent.
"""

from __future__ import annotations

import logging
import threading
from datetime import timedelta

from service import store as st
from service.core.config import Settings
from service.models import utcnow
from service.store import Store

__all__ = ["Sweeper"]

log = logging.getLogger(__name__)

#: Jobs deleted per transaction (a large backlog is swept in several).
_BATCH = 100


class Sweeper:
    """Deletes expired jobs every ``settings.sweep_interval_seconds`` (none when retention is
    0)."""

    def __init__(self, settings: Settings, store: Store) -> None:
        self.settings, self.store = settings, store
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._loop, daemon=True, name="cascalib-sweeper")

    def start(self) -> None:
        """Sweep now and then periodically."""
        self._thread.start()

    def stop(self) -> None:
        """Stop after the sweep in progress."""
        self._stop.set()
        if self._thread.is_alive():
            self._thread.join(timeout=10)

    def _loop(self) -> None:
        while not self._stop.is_set():
            try:
                self.sweep()
            except st.TRANSIENT:  # the store is briefly unavailable: next round
                log.warning("retention sweep postponed: the job store is unavailable")
            except Exception:
                log.exception("retention sweep failed")
            self._stop.wait(self.settings.sweep_interval_seconds)

    def sweep(self) -> int:
        """Delete the expired jobs now; returns how many."""
        removed = self.store.sweep_orphans()
        if removed:
            log.warning("removed %d half-stored submission(s)", removed)
        hours = self.settings.retention_hours
        if not hours:
            return 0
        before = utcnow() - timedelta(hours=hours)
        deleted = 0
        while True:
            with self.store.session() as session:
                ids = st.expired_jobs(session, before=before, limit=_BATCH)
                gone = [i for i in ids if st.delete_job(session, job_id=i)]
            for job_id in gone:
                self.store.remove_files(job_id)
            deleted += len(gone)
            if len(ids) < _BATCH:
                break
        if deleted:
            log.info("retention: deleted %d job(s) finished before %s", deleted,
                     before.isoformat(timespec="seconds"))
        return deleted
