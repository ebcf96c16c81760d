"""How a submission's body arrives: written once into staging, a client that hangs up or
sends less than it announced is handled without a 500, a traceback or a stuck connection."""

from __future__ import annotations

import os
import socket
import time
from collections.abc import Iterator
from pathlib import Path

import pytest
from service_helpers import TOKENS, Deployment, build_deployment

BOUNDARY = "cascalibtestboundary"


@pytest.fixture(scope="module")
def streamed(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Deployment]:
    """A SQLite deployment with its own system temp folder and a 1 s body timeout."""
    tmp = tmp_path_factory.mktemp("streamed")
    (tmp / "systemp").mkdir()
    dep, _ = build_deployment("sqlite", tmp, TMPDIR=str(tmp / "systemp"),
                              CASCALIB_BODY_TIMEOUT_SECONDS="1")
    yield dep
    dep.stop()


def _open_upload(dep: Deployment, content_length: int) -> socket.socket:
    """A connection that has sent a POST /v1/jobs head and the start of one file part."""
    sock = socket.create_connection(("127.0.0.1", dep.port), timeout=10)
    sock.sendall((f"POST /v1/jobs HTTP/1.1\r\nHost: x\r\nAuthorization: Bearer {TOKENS[0]}\r\n"
                  f"Content-Type: multipart/form-data; boundary={BOUNDARY}\r\n"
                  f"Content-Length: {content_length}\r\n\r\n--{BOUNDARY}\r\n"
                  'Content-Disposition: form-data; name="files"; filename="cam0.json"\r\n\r\n'
                  ).encode())
    return sock


def _open_files(pid: int) -> list[str]:
    out = []
    for fd in Path(f"/proc/{pid}/fd").iterdir():
        try:
            out.append(os.readlink(fd))
        except OSError:
            pass
    return out


def _metric(dep: Deployment, prefix: str) -> list[str]:
    import httpx

    text = httpx.get(dep.url + "/metrics").text
    return [line for line in text.splitlines() if line.startswith(prefix)]


def test_upload_written_once_into_staging(streamed: Deployment) -> None:
    assert streamed.server is not None
    sock = _open_upload(streamed, 5 * 2**19)
    try:
        sock.sendall(b" " * (2 * 2**20))  # past Starlette's 1 MB in-memory spool
        deadline = time.monotonic() + 10
        staged: list[str] = []
        while not staged and time.monotonic() < deadline:
            files = _open_files(streamed.server.popen.pid)
            staged = [f for f in files if "/staging/" in f]
            time.sleep(0.05)
        assert staged and staged[0].endswith("/inputs/cam_0.json"), files
        assert not [f for f in files if "/systemp/" in f], files
    finally:
        sock.close()


def test_client_hanging_up_mid_upload_is_no_500(streamed: Deployment) -> None:
    assert streamed.server is not None
    sock = _open_upload(streamed, 5 * 2**19)
    sock.sendall(b" " * 2**20)
    time.sleep(0.3)
    sock.close()
    time.sleep(1.0)
    posts = _metric(streamed, 'cascalib_http_requests_total{method="POST"')
    assert posts and all('status="499"' in line for line in posts), posts
    log = streamed.server.tail()
    assert "Traceback" not in log and "Exception in ASGI application" not in log, log
    assert not list((streamed.data_dir / "staging").iterdir())


def test_body_shorter_than_its_length_times_out(streamed: Deployment) -> None:
    sock = _open_upload(streamed, 2**20)
    sock.sendall(b"0123456789")
    t0 = time.monotonic()
    answer = sock.recv(65536).decode("latin-1")
    sock.close()
    assert answer.startswith("HTTP/1.1 408"), answer
    assert time.monotonic() - t0 < 5
    assert "application/problem+json" in answer
