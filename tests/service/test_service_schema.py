"""Property-based fuzzing of every operation in the OpenAPI schema (schemathesis): whatever a
client sends, the service answers without a 5xx and without a stack trace.

The schema is loaded eagerly from the application (``schemathesis.pytest.from_fixture`` reaches
into pytest's private ``Node._nodeid``, gone since pytest 9.1); the fixture checks that the
running server serves this very schema."""

from __future__ import annotations

from collections.abc import Iterator
from pathlib import Path

import pytest

schemathesis = pytest.importorskip("schemathesis", reason="schemathesis not installed (dev extra)")
from hypothesis import HealthCheck, settings  # noqa: E402
from schemathesis.checks import not_a_server_error  # noqa: E402
from schemathesis.specs.openapi.checks import (  # noqa: E402
    allow_header_conformance,
    content_type_conformance,
    negative_data_rejection,
    response_headers_conformance,
    response_schema_conformance,
    status_code_conformance,
)
from service_helpers import Deployment, build_deployment, next_token  # noqa: E402

from service.core.config import Settings  # noqa: E402
from service.main import create_app  # noqa: E402

#: Response-conformance checks: a client generated from the schema must work with the server.
CONFORMANCE = [not_a_server_error, status_code_conformance, content_type_conformance,
               response_schema_conformance, response_headers_conformance,
               allow_header_conformance, negative_data_rejection]
OPENAPI = create_app(Settings(api_tokens=["unused"])).openapi()
schema = schemathesis.openapi.from_dict(OPENAPI)
TOKEN = next_token()


@pytest.fixture(scope="module")
def fuzzed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Deployment]:
    import httpx

    dep, _ = build_deployment("sqlite", tmp_path_factory.mktemp("fuzz"))
    try:
        assert httpx.get(dep.url + "/openapi.json").json() == OPENAPI, \
            "the server serves another schema than the one fuzzed"
        yield dep
    finally:
        dep.stop()


@schema.parametrize()
@settings(max_examples=12, deadline=None, derandomize=True,
          suppress_health_check=list(HealthCheck))
def test_no_server_error(case, fuzzed: Deployment) -> None:  # type: ignore[no-untyped-def]
    """No 5xx, and every answer is what the document says: status code, media type, body
    schema, headers, and an ``Allow`` header listing the documented methods."""
    response = case.call(base_url=fuzzed.url, headers={"Authorization": f"Bearer {TOKEN}"},
                         timeout=30)
    assert response.status_code < 500, (case.method, case.path, response.text)
    case.validate_response(response, checks=CONFORMANCE)
    assert "Traceback" not in response.text
    if response.status_code >= 400:
        ctype = response.headers.get("content-type") or [""]
        assert ctype[0].startswith("application/problem+json"), ctype


def test_unauthenticated_fuzz_is_401(fuzzed: Deployment) -> None:
    import httpx

    for path in ("/v1/jobs", "/v1/jobs/0123", "/v1/jobs/x/result", "/v1/jobs/x/report"):
        assert httpx.get(fuzzed.url + path).status_code == 401
    assert Path(fuzzed.data_dir / "jobs").is_dir()
