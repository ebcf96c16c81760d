"""``python -m service.worker.job_process JOB_ID ATTEMPT``: run one claimed job in its own process.

A Celery task starts this process and supervises it (heartbeat, cancellation, exit code), so a
calibration that holds the GIL for minutes cannot starve the heartbeat, a cancelled job is
stopped at once, and a crash of the calibration (segfault, out of memory) is a reported,
retried failure instead of a lost Celery worker.
"""

from __future__ import annotations

import logging
import sys

from service.core.config import Settings
from service.inputs import zip_limits
from service.store import Store
from service.worker.local_pool import die_with_parent
from service.worker.runner import execute_claimed


def main(argv: list[str] | None = None) -> int:
    """Run the job; exit code 0 whatever the job's outcome (it is recorded in the store)."""
    args = sys.argv[1:] if argv is None else argv
    job_id, attempt = args[0], int(args[1])
    die_with_parent()
    logging.basicConfig(level=logging.INFO, format="%(levelname)s %(name)s: %(message)s")
    settings = Settings()
    store = Store(settings.sqlalchemy_url, settings.data_dir)
    try:
        execute_claimed(job_id, attempt, store, heartbeat=settings.heartbeat_seconds,
                        limits=zip_limits(settings))
    finally:
        store.dispose()
    return 0


if __name__ == "__main__":
    sys.exit(main())
