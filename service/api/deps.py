"""Dependencies of the routes: the app state, a database session and the caller's identity."""

from __future__ import annotations

import hashlib
from collections.abc import Iterator
from dataclasses import dataclass
from typing import Annotated, Protocol

from fastapi import Depends, Request
from fastapi.security import HTTPAuthorizationCredentials, HTTPBearer
from sqlalchemy.orm import Session
from starlette.concurrency import run_in_threadpool

from service import store as st
from service.core.config import Settings
from service.core.metrics import Metrics
from service.core.problems import ProblemError
from service.store import Store
from service.validation import Validator

__all__ = ["AppState", "Dispatcher", "SessionDep", "StateDep", "TokenDep", "ANONYMOUS"]

#: Owner of every job when authentication is off.
ANONYMOUS = "anonymous"


class Dispatcher(Protocol):
    """What the API needs from an execution back-end (embedded pool or Celery)."""

    def start(self) -> None: ...
    def stop(self) -> None: ...
    def submit(self, job_id: str) -> None: ...
    def cancel(self, job_id: str) -> None: ...
    def ready(self) -> str: ...


@dataclass
class AppState:
    """Everything one running app holds (set up by the lifespan of ``create_app``)."""

    settings: Settings
    store: Store
    dispatcher: Dispatcher
    metrics: Metrics
    validator: Validator
    #: Submissions being received or validated now (bounded by max_pending_submissions).
    pending: int = 0


async def _state(request: Request) -> AppState:
    # async: a plain attribute read need not hop to a worker thread (a sync dependency does)
    state: AppState = request.app.state.cascalib
    return state


StateDep = Annotated[AppState, Depends(_state)]


def _session(state: StateDep) -> Iterator[Session]:
    with state.store.session() as session:
        yield session


SessionDep = Annotated[Session, Depends(_session)]

_bearer = HTTPBearer(auto_error=False, description="An API token (CASCALIB_API_TOKENS).")


async def _owner(state: StateDep,
                 credentials: Annotated[HTTPAuthorizationCredentials | None, Depends(_bearer)]
                 ) -> str:
    """Owner id of the caller: SHA-256 of its token (jobs are visible to their owner only).

    A configured token is checked in memory; only a token kept in the store costs a query,
    run in a worker thread.
    """
    if not state.settings.auth_enabled:
        return ANONYMOUS
    challenge = {"WWW-Authenticate": "Bearer"}
    if credentials is None or credentials.scheme.lower() != "bearer":
        raise ProblemError(401, "missing bearer token (Authorization: Bearer <token>)",
                           headers=challenge)
    digest = hashlib.sha256(credentials.credentials.encode("utf-8")).hexdigest()
    # Comparing digests, not tokens: a timing difference reveals nothing usable about a token.
    if digest in state.settings.token_owners or await run_in_threadpool(_stored, state, digest):
        return digest
    raise ProblemError(401, "invalid bearer token", headers=challenge)


def _stored(state: AppState, digest: str) -> bool:
    with state.store.session() as session:
        return st.token_known(session, token_sha256=digest)


TokenDep = Annotated[str, Depends(_owner)]
