"""``cascalib serve``: refuses to run open, starts with a token or --insecure-no-auth."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import httpx
from service_helpers import Deployment, make_env


def test_serve_refuses_to_start_without_tokens(tmp_path: Path) -> None:
    env = make_env(tmp_path / "data")
    del env["CASCALIB_API_TOKENS"]
    r = subprocess.run([sys.executable, "-m", "cascalib.cli", "serve", "--port", "1"], env=env,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 2, r.stderr
    assert "no API token configured" in r.stderr and "--insecure-no-auth" in r.stderr
    assert "Traceback" not in r.stderr


def test_serve_help_is_the_services_own() -> None:
    """``cascalib serve`` hands its arguments to the service's command (an entry point)."""
    for cmd in (["-m", "cascalib.cli", "serve", "--help"], ["-m", "service", "--help"]):
        r = subprocess.run([sys.executable, *cmd], capture_output=True, text=True, timeout=120)
        assert r.returncode == 0, r.stderr
        assert "--insecure-no-auth" in r.stdout and "--port" in r.stdout
    assert "usage: cascalib serve" in subprocess.run(
        [sys.executable, "-m", "cascalib.cli", "serve", "-h"], capture_output=True, text=True,
        timeout=120).stdout


def test_serve_insecure_no_auth_opens_the_api(tmp_path: Path) -> None:
    env = make_env(tmp_path / "data")
    del env["CASCALIB_API_TOKENS"]
    dep = Deployment("insecure", env, tmp_path / "data", tmp_path)
    dep.start_server(extra=("--insecure-no-auth",))
    try:
        r = httpx.get(dep.url + "/v1/jobs")
        assert r.status_code == 200 and r.json()["count"] == 0
    finally:
        dep.stop()
    assert (tmp_path / "data" / "cascalib.db").is_file()  # the default SQLite store


def test_stored_token_and_cors(tmp_path: Path) -> None:
    env = make_env(tmp_path / "data", CASCALIB_CORS_ORIGINS="https://app.example")
    del env["CASCALIB_API_TOKENS"]
    r = subprocess.run([sys.executable, "-m", "service.tokens", "add", "lab-1"], env=env,
                       capture_output=True, text=True, timeout=120)
    assert r.returncode == 0, r.stderr
    token = r.stdout.strip()
    assert len(token) >= 40
    db = (tmp_path / "data" / "cascalib.db").read_bytes()
    assert token.encode() not in db  # only the hash is stored
    dup = subprocess.run([sys.executable, "-m", "service.tokens", "add", "lab-1"], env=env,
                         capture_output=True, text=True, timeout=120)
    assert dup.returncode == 2 and "exists already" in dup.stderr
    dep = Deployment("stored-token", env, tmp_path / "data", tmp_path)
    dep.start_server()  # starts: a token is stored, although CASCALIB_API_TOKENS is unset
    try:
        assert httpx.get(dep.url + "/v1/jobs").status_code == 401
        ok = httpx.get(dep.url + "/v1/jobs", headers={"Authorization": f"Bearer {token}"})
        assert ok.status_code == 200
        pre = httpx.options(dep.url + "/v1/jobs", headers={
            "Origin": "https://app.example", "Access-Control-Request-Method": "POST",
            "Access-Control-Request-Headers": "authorization,idempotency-key"})
        assert pre.headers["access-control-allow-origin"] == "https://app.example"
        other = httpx.options(dep.url + "/v1/jobs", headers={
            "Origin": "https://evil.example", "Access-Control-Request-Method": "POST"})
        assert "access-control-allow-origin" not in other.headers
    finally:
        dep.stop()
