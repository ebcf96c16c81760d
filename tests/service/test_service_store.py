"""The job store on a real database (SQLite file and PostgreSQL): migrations, atomic claims,
fencing, bounded retries, idempotency, and the settings' refusal to run open."""

from __future__ import annotations

import threading
from collections.abc import Iterator
from datetime import timedelta
from pathlib import Path

import pytest
from service_helpers import Postgres, postgres_reason
from sqlalchemy.exc import IntegrityError

from service import store as st
from service.core.config import ConfigurationError, Settings
from service.db import current_revision, head_revision
from service.models import Base, utcnow
from service.store import Store, StoredFile


@pytest.fixture(params=["sqlite", "postgres"])
def store(request: pytest.FixtureRequest, tmp_path: Path) -> Iterator[Store]:
    pg = None
    if request.param == "sqlite":
        url = f"sqlite:///{tmp_path / 'jobs.db'}"
    else:
        reason = postgres_reason()
        if reason:
            pytest.skip(reason)
        pg = Postgres().create()
        url = pg.url.replace("postgresql://", "postgresql+psycopg://")
    s = Store(url, tmp_path / "data")
    s.prepare()
    yield s
    s.dispose()
    if pg:
        pg.drop()


def new_job(store: Store, job_id: str, *, owner: str = "o1", key: str | None = None) -> None:
    with store.session() as session:
        st.create_job(session, job_id=job_id, owner=owner, options={}, cameras=["a", "b"],
                      inputs=[StoredFile("a", "inputs/cam_0.json", 3, "0" * 64, "a.json")],
                      idempotency_key=key, request_hash="h")


def test_migrations_match_models(store: Store) -> None:
    from alembic.autogenerate import compare_metadata
    from alembic.runtime.migration import MigrationContext

    assert current_revision(store.engine) == head_revision() == "0003"
    store.prepare()  # idempotent
    with store.engine.connect() as conn:
        diff = compare_metadata(MigrationContext.configure(conn), Base.metadata)
    assert diff == []


def test_claim_is_atomic(store: Store) -> None:
    new_job(store, "j1")
    wins: list[int | None] = []

    def claim(i: int) -> None:
        with store.session() as session:
            wins.append(st.claim_job(session, job_id="j1", worker=f"w{i}"))

    threads = [threading.Thread(target=claim, args=(i,)) for i in range(8)]
    for t in threads:
        t.start()
    for t in threads:
        t.join()
    assert sorted(wins, key=str) == [1] + [None] * 7


def test_fenced_updates_and_bounded_retries(store: Store) -> None:
    new_job(store, "j2")
    with store.session() as s:
        a1 = st.claim_job(s, job_id="j2", worker="w")
        assert a1 == 1
        assert st.update_progress(s, job_id="j2", attempt=1, stage="sync", progress=0.4)
        assert st.requeue_or_fail(s, job_id="j2", attempt=1, reason="died",
                                  max_attempts=2) == "queued"
        # The first attempt's worker is fenced off now.
        assert not st.update_progress(s, job_id="j2", attempt=1, stage="x", progress=0.9)
        assert st.claim_job(s, job_id="j2", worker="w") == 2
        assert not st.finish_job(s, job_id="j2", attempt=1, status="succeeded")
        assert st.requeue_or_fail(s, job_id="j2", attempt=2, reason="died again",
                                  max_attempts=2) == "failed"
        job = st.find_job(s, job_id="j2", owner="o1")
        assert job is not None and job.status == "failed"
        assert job.error == "died again; gave up after 2 attempt(s)"


def test_cancel_wins_over_worker(store: Store) -> None:
    new_job(store, "j3")
    with store.session() as s:
        assert st.claim_job(s, job_id="j3", worker="w") == 1
        assert st.cancel_job(s, job_id="j3") == "cancelled"
        assert not st.update_progress(s, job_id="j3", attempt=1, stage="refine", progress=0.5)
        out = [StoredFile("calibration:json", "outputs/calibration.json", 2, "1" * 64)]
        assert not st.finish_job(s, job_id="j3", attempt=1, status="succeeded", outputs=out)
        job = st.find_job(s, job_id="j3", owner=None)
        assert job is not None and job.status == "cancelled"
        assert [f.kind for f in job.files] == ["input"]
        assert st.delete_job(s, job_id="j3") and st.find_job(s, job_id="j3", owner=None) is None


def test_idempotency_key_unique_per_owner(store: Store) -> None:
    new_job(store, "k1", key="same")
    new_job(store, "k2", owner="o2", key="same")  # another owner may reuse a key
    with pytest.raises(IntegrityError):
        new_job(store, "k3", key="same")
    with store.session() as s:
        found = st.find_job_by_key(s, owner="o1", idempotency_key="same")
        assert found is not None and found.id == "k1"


def test_stale_jobs_and_paging(store: Store) -> None:
    for i in range(5):
        new_job(store, f"p{i}")
    with store.session() as s:
        st.claim_job(s, job_id="p0", worker="local:old:1")
        assert st.stale_jobs(s, now=utcnow(), stale_after=timedelta(minutes=5)) == []
        got = st.stale_jobs(s, now=utcnow() + timedelta(minutes=6),
                            stale_after=timedelta(minutes=5))
        assert got == [("p0", 1, "local:old:1")]
        assert st.stale_jobs(s, now=utcnow(), stale_after=timedelta(minutes=5),
                             worker_prefix="local:")[0][0] == "p0"
        page, count = st.list_jobs(s, owner="o1", status="queued", limit=2, offset=0)
        assert count == 4 and len(page) == 2
        assert st.count_by_status(s) == {"queued": 4, "running": 1}


def test_stored_tokens(store: Store) -> None:
    import hashlib

    with store.session() as s:
        st.add_api_token(s, name="lab", token="s3cret")
        assert st.count_api_tokens(s) == 1
        assert st.token_known(s, token_sha256=hashlib.sha256(b"s3cret").hexdigest())
        assert not st.token_known(s, token_sha256=hashlib.sha256(b"other").hexdigest())


def test_settings_refuse_to_run_open(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    for k in ("CASCALIB_API_TOKENS", "CASCALIB_DEVELOPMENT", "CASCALIB_INSECURE_NO_AUTH",
              "CASCALIB_DATABASE_URL"):
        monkeypatch.delenv(k, raising=False)
    s = Settings(data_dir=tmp_path)
    with pytest.raises(ConfigurationError, match="no API token configured"):
        s.check_startable(n_stored_tokens=0)
    s.check_startable(n_stored_tokens=1)
    assert s.auth_enabled
    assert not Settings(data_dir=tmp_path, development=True).auth_enabled
    Settings(data_dir=tmp_path, insecure_no_auth=True).check_startable(n_stored_tokens=0)
    assert Settings(data_dir=tmp_path).sqlalchemy_url == f"sqlite:///{tmp_path}/cascalib.db"
    monkeypatch.setenv("CASCALIB_API_TOKENS", "a, b,,c")
    monkeypatch.setenv("CASCALIB_DATABASE_URL", "postgresql://u:p@h/db")
    env = Settings()
    assert env.api_tokens == ["a", "b", "c"] and env.auth_enabled
    assert env.sqlalchemy_url == "postgresql+psycopg://u:p@h/db"
