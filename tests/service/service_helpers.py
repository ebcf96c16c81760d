"""Helpers of the service tests: real servers (uvicorn on a loopback port), real databases
(SQLite file, PostgreSQL), a real broker (Redis) with real Celery workers.

The ``deployment`` fixture (conftest.py) runs over the three set-ups; PostgreSQL and Redis
come from ``.ci/services.sh`` (or CASCALIB_TEST_POSTGRES_URL / CASCALIB_TEST_REDIS_URL) and
the tests that need them skip, saying why, only where they cannot be reached.
"""

from __future__ import annotations

import io
import itertools
import json
import os
import signal
import socket
import subprocess
import sys
import time
import uuid
import zipfile
from dataclasses import dataclass, field
from pathlib import Path

import httpx
import numpy as np
import pytest

PG_ADMIN_URL = os.environ.get("CASCALIB_TEST_POSTGRES_URL",
                              "postgresql://cascalib:cascalib@127.0.0.1:5432/postgres")
REDIS_URL = os.environ.get("CASCALIB_TEST_REDIS_URL", "redis://127.0.0.1:6379")
TOKENS = [f"token-{i:02d}-{uuid.uuid4().hex[:8]}" for i in range(60)]
_token_counter = itertools.count()
#: Small limits so the "too large" cases stay cheap.
MAX_UPLOAD = 3 * 2**20
MAX_FILES = 8


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def postgres_reason() -> str | None:
    """Why PostgreSQL cannot be used here (None when it can)."""
    try:
        import psycopg

        with psycopg.connect(PG_ADMIN_URL, connect_timeout=3) as conn:
            conn.execute("SELECT 1")
    except Exception as exc:
        return (f"PostgreSQL not reachable at {PG_ADMIN_URL} ({type(exc).__name__}); "
                "run .ci/services.sh")
    return None


def redis_reason() -> str | None:
    """Why Redis cannot be used here (None when it can)."""
    try:
        import redis

        redis.Redis.from_url(REDIS_URL, socket_connect_timeout=2).ping()
    except Exception as exc:
        return f"Redis not reachable at {REDIS_URL} ({type(exc).__name__}); run .ci/services.sh"
    return None


#: Redis databases held by live deployments. Each Celery deployment gets its own, emptied
#: first: two live deployments on one database (the session's and a test's own, picked at
#: random before) steal each other's messages, and a worker then answers "no such job" for
#: the other's jobs (seen once in CI: a re-queued job never ran).
_redis_dbs_in_use: set[int] = set()


def take_redis_db() -> int:
    """A Redis database no live deployment uses, emptied (leftovers of earlier runs)."""
    import redis

    free = [db for db in range(1, 16) if db not in _redis_dbs_in_use]
    if not free:
        raise RuntimeError("more than 15 live Celery deployments: Redis has 16 databases")
    db = free[0]
    redis.Redis.from_url(f"{REDIS_URL}/{db}", socket_connect_timeout=2).flushdb()
    _redis_dbs_in_use.add(db)
    return db


@dataclass
class Postgres:
    """A throw-away PostgreSQL database."""

    name: str = field(default_factory=lambda: f"cascalib_test_{uuid.uuid4().hex[:10]}")

    @property
    def url(self) -> str:
        return PG_ADMIN_URL.rsplit("/", 1)[0] + "/" + self.name

    def create(self) -> Postgres:
        import psycopg

        with psycopg.connect(PG_ADMIN_URL, autocommit=True) as conn:
            conn.execute(f'CREATE DATABASE "{self.name}"')
        return self

    def drop(self) -> None:
        import psycopg

        with psycopg.connect(PG_ADMIN_URL, autocommit=True) as conn:
            conn.execute(f'DROP DATABASE IF EXISTS "{self.name}" WITH (FORCE)')


@dataclass
class Proc:
    """A child process whose output goes to a log file."""

    popen: subprocess.Popen[bytes]
    log: Path

    def kill(self) -> None:
        """SIGKILL the process and everything it started (its process group)."""
        try:
            os.killpg(self.popen.pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
        self.popen.wait(timeout=10)

    def stop(self) -> None:
        """SIGTERM (orderly shutdown), SIGKILL after 15 s."""
        if self.popen.poll() is None:
            os.killpg(self.popen.pid, signal.SIGTERM)
            try:
                self.popen.wait(timeout=15)
            except subprocess.TimeoutExpired:
                self.kill()

    def tail(self) -> str:
        return self.log.read_text(errors="replace")[-3000:] if self.log.exists() else ""


def children(pid: int) -> list[int]:
    """Process ids of the children of ``pid`` (Linux /proc)."""
    pids = []
    try:
        for task in Path(f"/proc/{pid}/task").iterdir():
            pids += [int(p) for p in (task / "children").read_text().split()]
    except OSError:
        pass
    return pids


def descendants(pid: int) -> list[int]:
    """Children, grandchildren... of ``pid``."""
    out = []
    for child in children(pid):
        out += [child, *descendants(child)]
    return out


def _comm(pid: int) -> str:
    try:
        return Path(f"/proc/{pid}/comm").read_text().strip()
    except OSError:
        return ""


def forked_processes(server_pid: int, name: str = "cascalib-job") -> list[int]:
    """Job processes of a server (or upload validators, ``name="cascalib-valid"``): the
    children of its multiprocessing fork server, by process name."""
    out = []
    for pid in children(server_pid):
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes()
        except OSError:
            continue
        if b"forkserver" in cmd:
            out += [p for p in children(pid) if _comm(p) == name]
    return out


def spawn(args: list[str], env: dict[str, str], log: Path) -> Proc:
    fh = log.open("ab")
    popen = subprocess.Popen(args, env=env, stdout=fh, stderr=subprocess.STDOUT,
                             start_new_session=True)
    return Proc(popen, log)


@dataclass
class Deployment:
    """One running service: its URL, environment, data folder and processes."""

    name: str
    env: dict[str, str]
    data_dir: Path
    tmp: Path
    port: int = 0
    server: Proc | None = None
    workers: list[Proc] = field(default_factory=list)
    redis_db: int | None = None

    @property
    def url(self) -> str:
        return f"http://127.0.0.1:{self.port}"

    @property
    def database_url(self) -> str:
        return self.env.get("CASCALIB_DATABASE_URL") or f"sqlite:///{self.data_dir / 'cascalib.db'}"

    def start_server(self, timeout: float = 40.0, extra: tuple[str, ...] = ()) -> None:
        self.port = free_port()
        args = [sys.executable, "-m", "service", "-v", "--port", str(self.port),
                *extra]
        self.server = spawn(args, self.env, self.tmp / f"server-{self.port}.log")
        deadline = time.monotonic() + timeout
        while time.monotonic() < deadline:
            if self.server.popen.poll() is not None:
                raise RuntimeError(f"server exited:\n{self.server.tail()}")
            try:
                if httpx.get(self.url + "/readyz", timeout=2).status_code == 200:
                    return
            except httpx.TransportError:
                pass
            time.sleep(0.2)
        raise RuntimeError(f"server not ready after {timeout} s:\n{self.server.tail()}")

    def start_worker(self, concurrency: int = 1) -> None:
        args = [sys.executable, "-m", "celery", "-A", "service.worker", "worker",
                "--concurrency", str(concurrency), "--loglevel", "INFO", "-Q", "cascalib",
                "--hostname", f"w{uuid.uuid4().hex[:6]}@%h", "--without-gossip",
                "--without-mingle", "--without-heartbeat"]
        self.workers.append(spawn(args, self.env, self.tmp / f"worker-{len(self.workers)}.log"))

    def client(self, token: str | None) -> httpx.Client:
        headers = {"Authorization": f"Bearer {token}"} if token else {}
        return httpx.Client(base_url=self.url, headers=headers, timeout=30)

    def stop(self) -> None:
        for w in self.workers:
            w.stop()
        self.workers.clear()
        if self.server is not None:
            self.server.stop()
        if self.redis_db is not None:
            _redis_dbs_in_use.discard(self.redis_db)
            self.redis_db = None

    def logs(self) -> str:
        parts = [self.server.tail()] if self.server else []
        return "\n".join(parts + [w.tail() for w in self.workers])


def make_env(data_dir: Path, **extra: str) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if not k.startswith("CASCALIB_")}
    env.update({
        "CASCALIB_DATA_DIR": str(data_dir),
        "CASCALIB_API_TOKENS": ",".join(TOKENS),
        "CASCALIB_MAX_UPLOAD_BYTES": str(MAX_UPLOAD),
        "CASCALIB_MAX_FILES": str(MAX_FILES),
        "CASCALIB_WORKERS": "2",
        "CASCALIB_HEARTBEAT_SECONDS": "0.5",
        "CASCALIB_STALE_AFTER_SECONDS": "4",
        "PYTHONUNBUFFERED": "1",
    })
    env.update(extra)
    return env


def build_deployment(kind: str, tmp: Path, concurrency: int = 1,
                     **extra: str) -> tuple[Deployment, Postgres | None]:
    """Start a deployment of ``kind`` (sqlite | postgres | celery); skip if impossible."""
    pg = None
    if kind in ("postgres", "celery"):
        reason = postgres_reason()
        if reason:
            pytest.skip(reason)
        pg = Postgres().create()
        extra = {"CASCALIB_DATABASE_URL": pg.url, **extra}
    redis_db = None
    if kind == "celery":
        reason = redis_reason()
        if reason:
            pg.drop() if pg else None
            pytest.skip(reason)
        redis_db = take_redis_db()
        extra = {"CASCALIB_BROKER_URL": f"{REDIS_URL}/{redis_db}", **extra}
    data_dir = tmp / "data"
    dep = Deployment(kind, make_env(data_dir, **extra), data_dir, tmp, redis_db=redis_db)
    try:
        dep.start_server()
        if kind == "celery":
            dep.start_worker(concurrency)
    except BaseException:
        dep.stop()
        if pg:
            pg.drop()
        raise
    return dep, pg


# --- inputs ------------------------------------------------------------------------------------

def openpose_frames(n_frames: int = 40, seed: int = 0, width: int = 1920,
                    height: int = 1080) -> list[bytes]:
    """Per-frame OpenPose JSON files (BODY_25) of one walking person, as bytes."""
    rng = np.random.default_rng(seed)
    base = np.column_stack([rng.uniform(-60, 60, 25), np.linspace(-300, 300, 25)])
    frames = []
    for f in range(n_frames):
        xy = base + [width / 2 + 8 * f - 160, height / 2] + rng.normal(0, 1.5, (25, 2))
        kp = np.column_stack([xy, np.full(25, 0.9)]).ravel().round(2).tolist()
        frames.append(json.dumps({"version": 1.3, "people": [{"pose_keypoints_2d": kp}]}).encode())
    return frames


def zip_bytes(members: dict[str, bytes], compression: int = zipfile.ZIP_DEFLATED) -> bytes:
    buf = io.BytesIO()
    with zipfile.ZipFile(buf, "w", compression) as zf:
        for name, data in members.items():
            zf.writestr(name, data)
    return buf.getvalue()


def camera_zip(seed: int = 0, n_frames: int = 40) -> bytes:
    """A zip of a folder of per-frame OpenPose JSON files."""
    return zip_bytes({f"cam/frame_{i:012d}_keypoints.json": data
                      for i, data in enumerate(openpose_frames(n_frames, seed))})


OPTIONS = {"image_size": "1920x1080", "fps": 30, "skeleton": "body25"}


def submit(client: httpx.Client, files: list[tuple[str, bytes]] | None = None,
           options: dict[str, object] | str | None = None,
           headers: dict[str, str] | None = None) -> httpx.Response:
    """POST /v1/jobs with (name, content) camera files and options."""
    if files is None:
        files = [(f"cam{i}.zip", camera_zip(i)) for i in range(2)]
    opts = OPTIONS if options is None else options
    text = opts if isinstance(opts, str) else json.dumps(opts)
    # The options travel as a plain part (no file name) so the body is multipart even without
    # files.
    parts: list[tuple[str, tuple[str | None, bytes | str, str]]] = [
        ("options", (None, text, "application/json"))]
    parts += [("files", (name, content, "application/octet-stream")) for name, content in files]
    return client.post("/v1/jobs", files=parts, headers=headers or {})


def wait_finished(client: httpx.Client, job_id: str, timeout: float = 60.0) -> dict[str, object]:
    """Poll a job until it is succeeded, failed or cancelled."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        job = client.get(f"/v1/jobs/{job_id}").json()
        if job["status"] in ("succeeded", "failed", "cancelled"):
            return dict(job)
        time.sleep(0.2)
    raise AssertionError(f"job {job_id} not finished after {timeout} s: {job}")


def pipeline_available() -> bool:
    import importlib.util

    return importlib.util.find_spec("cascalib.pipeline") is not None


needs_pipeline = pytest.mark.skipif(
    not pipeline_available(),
    reason="cascalib.pipeline (calibrate) is not importable yet: a job cannot succeed")


def next_token() -> str:
    """A token no other test of this session has used yet (wraps after 60)."""
    return TOKENS[next(_token_counter) % len(TOKENS)]


def sim_files(tmp: Path) -> list[tuple[str, bytes]]:
    """The cameras of the simulator's "terrace" scene as native .npz keypoint files."""
    from cascalib.formats import write_tracks
    from cascalib.simulate import simulate

    files = []
    for tr in simulate("terrace", seed=0).tracks:
        path = tmp / f"{tr.camera}.npz"
        write_tracks(tr, path, format="native-npz")
        files.append((path.name, path.read_bytes()))
    return files


def start_sim_job(client: httpx.Client, tmp: Path, timeout: float = 120.0) -> str:
    """Submit the simulated "terrace" rig and wait until its calibration is under way (past
    loading its inputs); returns the job id. The deployment needs uploads of ~100 MB."""
    job_id = str(submit(client, sim_files(tmp), {"seed": 0}).json()["id"])
    deadline = time.monotonic() + timeout
    while client.get(f"/v1/jobs/{job_id}").json()["stage"] in (None, "loading"):
        assert time.monotonic() < deadline, f"job {job_id} did not start in {timeout} s"
        time.sleep(0.1)
    return job_id
