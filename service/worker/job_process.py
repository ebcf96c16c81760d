"""``python -m service.worker.job_process JOB_ID ATTEMPT``: run one claimed job in its own process.

A Celery task starts this process and supervises it (heartbeat, cancellation, exit code), so a
calibration that holds the GIL for minutes cannot starve the heartbeat, a cancelled job is
stopped at once, and a crash of the calibration (segfault, out of memory) is a reported,
retried failure instead of a lost Celery worker.
"""

from __future__ import annotations

import sys

from service.core.config import Settings
from service.worker.local_pool import run_claimed_job


def main(argv: list[str] | None = None) -> int:
    """Run the job; exit code 0 whatever the job's outcome (it is recorded in the store)."""
    args = sys.argv[1:] if argv is None else argv
    run_claimed_job(args[0], int(args[1]), Settings())
    return 0


if __name__ == "__main__":
    sys.exit(main())
