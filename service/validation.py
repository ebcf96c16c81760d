"""Validating submissions in worker processes, off the API's event loop.

Parsing a keypoint file holds the GIL for as long as ``json.load`` or numpy run (seconds for a
large file): in a thread of the API it stalled ``/healthz`` and every poll. The validators are
processes from the fork server (the readers already imported), a little below the API's
priority, and die with it; a submission waits for a free one without blocking the event loop.
"""

from __future__ import annotations

import asyncio
import logging
import multiprocessing
import os
import threading
from concurrent.futures import ProcessPoolExecutor
from concurrent.futures.process import BrokenProcessPool
from typing import Any

from starlette.concurrency import run_in_threadpool

from service.core.config import Settings
from service.core.problems import ProblemError
from service.core.proc import name_process
from service.uploads import Submission, validate_submission

__all__ = ["Validator", "VALIDATOR_NICENESS"]

log = logging.getLogger(__name__)

#: Validators yield the CPU to the API (niceness 0) and run before jobs (JOB_NICENESS).
VALIDATOR_NICENESS = 5


def _init_validator() -> None:
    from cascalib.workers import die_with_parent

    die_with_parent()
    name_process("cascalib-valid")
    os.nice(VALIDATOR_NICENESS)


def _validate(sub: Submission, settings_values: dict[str, Any]) -> None:
    validate_submission(sub, Settings(**settings_values))


class Validator:
    """A pool of ``settings.validation_workers`` processes running ``validate_submission``."""

    def __init__(self, settings: Settings) -> None:
        self.settings = settings
        self._values = settings.model_dump(mode="json")
        self._pool = self._new_pool()

    def _new_pool(self) -> ProcessPoolExecutor:
        return ProcessPoolExecutor(self.settings.validation_workers,
                                   mp_context=multiprocessing.get_context("forkserver"),
                                   initializer=_init_validator)

    async def validate(self, sub: Submission) -> None:
        """Validate ``sub`` in a worker process; its 4xx problem is raised here.

        Raises
        ------
        ProblemError
            The submission's fault (4xx), or 503 when the validating process died (out of
            memory, killed): the pool is renewed and the client may retry.
        """
        try:
            # submit() may start a process and wait for the fork server: not in the event loop
            future = await run_in_threadpool(self._pool.submit, _validate, sub, self._values)
            await asyncio.wrap_future(future)
        except BrokenProcessPool:
            log.error("a validation process died; starting new ones")
            self._pool.shutdown(wait=False, cancel_futures=True)
            self._pool = self._new_pool()
            raise ProblemError(503, "the upload could not be validated (the validating "
                               "process died); retry later", headers={"Retry-After": "10"}
                               ) from None

    def warm_up(self) -> None:
        """Start the processes in the background (the fork server imports the readers first),
        so that the first submissions do not wait for them."""
        def start() -> None:
            try:
                for f in [self._pool.submit(os.getpid) for _ in range(
                        self.settings.validation_workers)]:
                    f.result()
            except Exception:  # the first submission reports it
                log.warning("upload validators did not start", exc_info=True)

        threading.Thread(target=start, daemon=True, name="cascalib-validators").start()

    def stop(self) -> None:
        """Stop the processes (validations in progress are abandoned)."""
        self._pool.shutdown(wait=False, cancel_futures=True)
