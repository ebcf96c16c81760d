"""Turning a staged submission into a queued job (idempotency, validation, atomic commit)."""

from __future__ import annotations

import logging
import uuid

from sqlalchemy.exc import IntegrityError
from starlette.concurrency import run_in_threadpool
from starlette.requests import ClientDisconnect, Request

from api_schemas import InvalidParam, JobLinks
from service import store as st
from service.api.deps import AppState
from service.core.problems import ProblemError
from service.models import Job
from service.uploads import Submission, receive_submission

__all__ = ["submit_job", "links"]

log = logging.getLogger(__name__)

_MAX_KEY = 255
#: Seconds a client is asked to wait when too many submissions are in progress.
_RETRY_AFTER = 5


def links(job_id: str) -> JobLinks:
    """Relative links to a job and its outputs."""
    base = f"/v1/jobs/{job_id}"
    return JobLinks(self=base, result=f"{base}/result", report=f"{base}/report",
                    poses=f"{base}/poses")


def _replay(existing: Job, sub: Submission) -> tuple[Job, bool]:
    if existing.request_hash != sub.request_hash:
        raise ProblemError(422, "Idempotency-Key was already used for a different request",
                           title="Idempotency key reused",
                           errors=[InvalidParam(message="key reused with other content",
                                                field="Idempotency-Key")])
    return existing, True


def _by_key(state: AppState, owner: str, key: str) -> Job | None:
    with state.store.session() as session:
        return st.find_job_by_key(session, owner=owner, idempotency_key=key)


def _commit(state: AppState, sub: Submission, owner: str, key: str | None) -> Job:
    """Move the staged files under the job id and insert the row; undo the move on failure."""
    job_id = uuid.uuid4().hex
    job_dir = state.store.job_dir(job_id)
    sub.folder.rename(job_dir)
    sub.folder = job_dir
    try:
        return state.store.retrying("store the job", lambda session: st.create_job(
            session, job_id=job_id, owner=owner, options=sub.options_json, cameras=sub.cameras,
            inputs=sub.files, idempotency_key=key, request_hash=sub.request_hash))
    except BaseException:
        sub.discard()
        raise


async def submit_job(request: Request, state: AppState, owner: str,
                     idempotency_key: str | None) -> tuple[Job, bool]:
    """Validate and store a submission; returns the job and whether it is a replay.

    Nothing is left on disk or in the database when this raises.
    """
    if idempotency_key is not None and not 0 < len(idempotency_key) <= _MAX_KEY:
        raise ProblemError(422, f"Idempotency-Key must be 1-{_MAX_KEY} characters",
                           errors=[InvalidParam(message="bad length", field="Idempotency-Key")])
    if state.pending >= state.settings.max_pending_submissions:
        raise ProblemError(503, f"{state.pending} submissions in progress; retry later",
                           headers={"Retry-After": str(_RETRY_AFTER)})
    state.pending += 1
    try:
        return await _receive_and_commit(request, state, owner, idempotency_key)
    except ClientDisconnect:
        # Nobody to answer; 499 (nginx's "client closed request") is what the metrics count.
        log.info("client disconnected during its upload: nothing stored")
        raise ProblemError(499, "the client closed the connection during the upload") from None
    finally:
        state.pending -= 1


async def _receive_and_commit(request: Request, state: AppState, owner: str,
                              idempotency_key: str | None) -> tuple[Job, bool]:
    sub = await receive_submission(request, state.settings, state.store.staging_dir)
    try:
        if idempotency_key is not None:
            existing = await run_in_threadpool(_by_key, state, owner, idempotency_key)
            if existing is not None:
                return _replay(existing, sub)
        await state.validator.validate(sub)
        try:
            job = await run_in_threadpool(_commit, state, sub, owner, idempotency_key)
        except IntegrityError:
            # A concurrent retry with the same key won the race: answer with its job.
            existing = await run_in_threadpool(_by_key, state, owner, idempotency_key or "")
            if existing is None:
                raise
            return _replay(existing, sub)
    except ProblemError:
        state.metrics.rejected.inc()
        raise
    finally:
        if sub.folder.parent == state.store.staging_dir:
            sub.discard()
    state.metrics.submitted.inc()
    state.dispatcher.submit(job.id)
    return job, False
