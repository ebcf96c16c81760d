"""Transient database faults: a SQLite write lock held by someone else is waited out and
retried; past the retry budget the API answers 503 with Retry-After (no SQL shown), /readyz
says the store is not writable, and running jobs are not failed because of it."""

from __future__ import annotations

import sqlite3
import threading
import time
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path

import httpx
import pytest
from service_helpers import (
    Deployment,
    build_deployment,
    needs_pipeline,
    next_token,
    start_sim_job,
    submit,
    wait_finished,
)


@contextmanager
def write_lock(dep: Deployment, seconds: float) -> Iterator[threading.Thread]:
    """Hold the SQLite write lock for ``seconds`` from another connection (in a thread)."""
    taken = threading.Event()

    def hold() -> None:
        conn = sqlite3.connect(dep.data_dir / "cascalib.db", timeout=30)
        conn.execute("BEGIN IMMEDIATE")
        taken.set()
        time.sleep(seconds)
        conn.rollback()
        conn.close()

    holder = threading.Thread(target=hold)
    holder.start()
    assert taken.wait(30)
    try:
        yield holder
    finally:
        holder.join()


@pytest.fixture(scope="module")
def impatient(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Deployment]:
    """SQLite with a 0.2 s busy timeout and a 3 s retry budget."""
    dep, _ = build_deployment("sqlite", tmp_path_factory.mktemp("impatient"),
                              CASCALIB_DB_BUSY_TIMEOUT_SECONDS="0.2",
                              CASCALIB_DB_RETRY_SECONDS="3")
    yield dep
    dep.stop()


def test_short_lock_is_retried(impatient: Deployment) -> None:
    with impatient.client(next_token()) as c, write_lock(impatient, 1.5):
        r = submit(c)
    assert r.status_code == 202, r.text


def test_long_lock_is_503_and_not_ready(impatient: Deployment) -> None:
    with impatient.client(next_token()) as c, write_lock(impatient, 6.0):
        t0 = time.monotonic()
        r = submit(c)
        waited = time.monotonic() - t0
        ready = c.get("/readyz")
    assert r.status_code == 503, r.text
    assert r.headers["retry-after"].isdigit() and r.headers["content-type"].startswith(
        "application/problem+json")
    assert waited < 5.5
    for leak in ("INSERT", "SELECT", "OperationalError", "locked", "sqlite"):
        assert leak not in r.text, r.text
    assert ready.status_code == 503 and ready.json()["checks"]["database"].startswith(
        "not writable"), ready.text
    assert not list((impatient.data_dir / "staging").iterdir())
    with impatient.client(None) as c:
        assert c.get("/readyz").status_code == 200


@needs_pipeline
@pytest.mark.slow
def test_running_job_survives_a_40_s_lock(tmp_path: Path) -> None:
    """The report's case: a write lock held 40 s (defaults: 5 s busy timeout, 60 s of
    retries) must not fail the running job nor its submission."""
    dep, _ = build_deployment("sqlite", tmp_path, CASCALIB_MAX_UPLOAD_BYTES=str(200 * 2**20),
                              CASCALIB_WORKERS="1")
    try:
        with dep.client(next_token()) as c:
            job_id = start_sim_job(c, tmp_path)
            c.timeout = httpx.Timeout(120)  # the submission waits the lock out
            with write_lock(dep, 40.0):
                late = submit(c)
            job = wait_finished(c, job_id, timeout=1800)
        assert late.status_code == 202, late.text
        assert job["status"] == "succeeded", job
    finally:
        dep.stop()


def test_retention_deletes_finished_jobs_and_their_files(tmp_path: Path) -> None:
    dep, _ = build_deployment("sqlite", tmp_path, CASCALIB_RETENTION_HOURS=str(2 / 3600),
                              CASCALIB_SWEEP_INTERVAL_SECONDS="0.5", CASCALIB_WORKERS="1")
    try:
        with dep.client(next_token()) as c:
            done = wait_finished(c, submit(c).json()["id"])["id"]
            assert (dep.data_dir / "jobs" / done).is_dir()
            deadline = time.monotonic() + 10
            while c.get(f"/v1/jobs/{done}").status_code != 404:
                assert time.monotonic() < deadline, "not deleted after its retention"
                time.sleep(0.2)
        assert not (dep.data_dir / "jobs" / done).exists()
    finally:
        dep.stop()
