"""Fixtures of the service tests (helpers in service_helpers.py)."""

from __future__ import annotations

from collections.abc import Iterator

import httpx
import pytest
from service_helpers import Deployment, build_deployment, next_token


@pytest.fixture(scope="session", params=["sqlite", "postgres", "celery"])
def deployment(request: pytest.FixtureRequest,
               tmp_path_factory: pytest.TempPathFactory) -> Iterator[Deployment]:
    """A running service on each back-end (shared by the tests of a session)."""
    dep, pg = build_deployment(request.param, tmp_path_factory.mktemp(request.param),
                               concurrency=2)
    yield dep
    dep.stop()
    if pg:
        pg.drop()


@pytest.fixture
def token() -> str:
    """A token no other test uses (so each test sees only its own jobs)."""
    return next_token()


@pytest.fixture
def client(deployment: Deployment, token: str) -> Iterator[httpx.Client]:
    with deployment.client(token) as c:
        yield c


