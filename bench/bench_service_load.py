"""Load test of the calibration service: a burst of N jobs from C concurrent clients, then the
API's peak memory on two hostile-but-small and large-but-valid uploads.

Starts a real server (uvicorn on a loopback port; SQLite + embedded pool by default, or
PostgreSQL, or Celery + Redis + PostgreSQL), then C client threads, each with its own token,
submit their share of the jobs (each with an Idempotency-Key, retried on transport errors) and
poll them until they end, while every request's latency is recorded and another thread polls
/healthz as a liveness probe would. Checks that every job finished and none was lost or
duplicated, then prints throughput and latency percentiles (submit, job GET, /healthz).

The jobs are real calibration jobs on synthetic inputs that the cascade rejects quickly
(single-view stage): the benchmark measures the service (upload, validation, store, queue,
workers, polling), not the calibration itself. Each upload is two mmpose files of
``--upload-mb`` MB in all (0: two small zipped OpenPose folders).

The memory cases (``--memory-cases``) submit, one at a time, a 1.3 MB mmpose file whose last
frame id is 1,000,000 and a valid 300 MB mmpose file, and print the answer, its time and the
peak resident memory of the API process and of the upload validators while it was handled.

    python bench/bench_service_load.py                    # 20 jobs of 6 MB, 20 clients, SQLite
    python bench/bench_service_load.py --memory-cases     # then the two memory cases
    python bench/bench_service_load.py --jobs 100 --upload-mb 0 --backend postgres
    python bench/bench_service_load.py --backend celery
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import threading
import time
import uuid
from collections import defaultdict
from pathlib import Path

import httpx
import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "service"))
from service_helpers import (  # noqa: E402
    TOKENS,
    build_deployment,
    camera_zip,
    forked_processes,
    submit,
)

#: Seconds between two /healthz probes, and between two memory samples.
PROBE_PERIOD = 0.05
MEMORY_PERIOD = 0.02
TERMINAL = {"succeeded", "failed", "cancelled"}


class Recorder:
    """Thread-safe latency log per endpoint."""

    def __init__(self) -> None:
        self.lock = threading.Lock()
        self.latency: dict[str, list[float]] = defaultdict(list)
        self.errors: dict[str, int] = defaultdict(int)

    def timed(self, name: str, fn, *args, **kwargs):  # type: ignore[no-untyped-def]
        t0 = time.perf_counter()
        r = fn(*args, **kwargs)
        dt = time.perf_counter() - t0
        with self.lock:
            self.latency[name].append(dt)
            if r.status_code >= 500:
                self.errors[name] += 1
        return r


def mmpose_file(n_bytes: int, seed: int = 0, last_frame: int | None = None) -> bytes:
    """A synthetic mmpose file (COCO-17, three people a frame) of about ``n_bytes``; with
    ``last_frame``, the last frame's id is that number instead of the next one."""
    rng = np.random.default_rng(seed)
    people = [{"keypoints": rng.uniform(100, 500, (17, 2)).round(1).tolist(),
               "keypoint_scores": [0.9] * 17} for _ in range(3)]
    frame = json.dumps({"frame_id": 0, "instances": people})
    n_frames = max(2, n_bytes // (len(frame) + 2))
    ids = list(range(n_frames))
    if last_frame is not None:
        ids[-1] = last_frame
    body = ",".join(frame.replace('"frame_id": 0', f'"frame_id": {i}', 1) for i in ids)
    return f"[{body}]".encode()


def _rss(pid: int) -> int:
    """Resident memory of a process in bytes (0 once it is gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    except OSError:
        pass
    return 0


class MemoryWatch:
    """Samples the resident memory of the API process and of its upload validators."""

    def __init__(self, server_pid: int) -> None:
        self.pid = server_pid
        self.peak_api = self.peak_validators = 0
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        while not self._stop.wait(MEMORY_PERIOD):
            self.peak_api = max(self.peak_api, _rss(self.pid))
            validators = forked_processes(self.pid, "cascalib-valid")
            self.peak_validators = max([self.peak_validators, *map(_rss, validators)])

    def __enter__(self) -> MemoryWatch:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join()


def probe_health(url: str, rec: Recorder, stop: threading.Event) -> None:
    """Poll /healthz as a liveness probe would, until ``stop``."""
    with httpx.Client(base_url=url, timeout=60) as c:
        while not stop.wait(PROBE_PERIOD):
            try:
                rec.timed("GET /healthz", c.get, "/healthz")
            except httpx.TransportError:
                with rec.lock:
                    rec.errors["GET /healthz"] += 1


def memory_cases(url: str, server_pid: int) -> None:
    """Submit the huge-frame-id and the 300 MB case; print answer, time and peak memory."""
    small = [("cam1.json", mmpose_file(2**20, seed=1))]
    cases = [("mmpose 1.3 MB, frame_id 1,000,000",
              [("cam0.json", mmpose_file(13 * 2**20 // 10, last_frame=1_000_000))]),
             ("mmpose 300 MB, valid", [("cam0.json", mmpose_file(300 * 2**20))])]
    print(f"\n{'memory case':36s} {'answer':>6s} {'seconds':>8s} {'API peak MB':>12s} "
          f"{'validator peak MB':>18s}")
    with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {TOKENS[-1]}"},
                      timeout=600) as c:
        for name, files in cases:
            with MemoryWatch(server_pid) as mem:
                t0 = time.perf_counter()
                r = submit(c, files + small, {"image_size": "640x480", "fps": 30})
                dt = time.perf_counter() - t0
            if r.status_code == 202:
                c.delete(f"/v1/jobs/{r.json()['id']}")  # only the submission is measured
            print(f"{name:36s} {r.status_code:6d} {dt:8.1f} {mem.peak_api / 2**20:12.0f} "
                  f"{mem.peak_validators / 2**20:18.0f}")


def client_run(url: str, token: str, n_jobs: int, files: list[tuple[str, bytes]],
               options: dict[str, object] | None, rec: Recorder, out: dict[str, list[str]],
               timeout: float) -> None:
    ids: list[str] = []
    with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {token}"},
                      timeout=60) as c:
        for _ in range(n_jobs):
            key = {"Idempotency-Key": uuid.uuid4().hex}
            for _attempt in range(5):  # a retry re-sends the same key: never a second job
                try:
                    r = rec.timed("POST /v1/jobs", submit, c, files, options, key)
                    break
                except httpx.TransportError:
                    time.sleep(0.5)
            else:
                raise RuntimeError("submission failed 5 times")
            assert r.status_code == 202, r.text
            ids.append(r.json()["id"])
        pending = set(ids)
        deadline = time.monotonic() + timeout
        while pending and time.monotonic() < deadline:
            for job_id in list(pending):
                r = rec.timed("GET /v1/jobs/{id}", c.get, f"/v1/jobs/{job_id}")
                if r.json()["status"] in TERMINAL:
                    pending.discard(job_id)
            rec.timed("GET /v1/jobs", c.get, "/v1/jobs", params={"limit": 20})
            time.sleep(0.2)
    out[token] = ids


def report(rec: Recorder, out: dict[str, list[str]], url: str, elapsed: float,
           n_expected: int) -> int:
    all_ids = [i for ids in out.values() for i in ids]
    statuses: dict[str, int] = defaultdict(int)
    listed = 0
    for token, ids in out.items():
        with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {token}"}) as c:
            page = c.get("/v1/jobs", params={"limit": 100}).json()
            listed += page["count"]
            assert {j["id"] for j in page["data"]} == set(ids), "a job lost or duplicated"
            for j in page["data"]:
                statuses[j["status"]] += 1
    print(f"\njobs submitted {len(all_ids)} (expected {n_expected}), unique {len(set(all_ids))}, "
          f"listed by their owners {listed}; final states {dict(statuses)}")
    print(f"wall time {elapsed:.1f} s, throughput {len(all_ids) / elapsed:.2f} jobs/s\n")
    print(f"{'endpoint':22s} {'requests':>8s} {'p50 ms':>8s} {'p90 ms':>8s} {'p99 ms':>8s} "
          f"{'max ms':>8s} {'5xx':>4s}")
    for name, lat in sorted(rec.latency.items()):
        a = np.array(lat) * 1000
        print(f"{name:22s} {a.size:8d} {np.percentile(a, 50):8.1f} {np.percentile(a, 90):8.1f} "
              f"{np.percentile(a, 99):8.1f} {a.max():8.1f} {rec.errors[name]:4d}")
    ok = (len(all_ids) == len(set(all_ids)) == listed == n_expected
          and sum(statuses[s] for s in TERMINAL) == n_expected and not any(rec.errors.values()))
    print("\nOK: every job finished, none lost or duplicated" if ok else "\nFAILED")
    return 0 if ok else 1


def main() -> int:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--jobs", type=int, default=20)
    p.add_argument("--clients", type=int, default=20)
    p.add_argument("--backend", choices=["sqlite", "postgres", "celery"], default="sqlite")
    p.add_argument("--workers", type=int, default=2,
                   help="embedded pool size, or Celery worker concurrency")
    p.add_argument("--validators", type=int, default=1,
                   help="upload validator processes (CASCALIB_VALIDATION_WORKERS)")
    p.add_argument("--timeout", type=float, default=600)
    p.add_argument("--upload-mb", type=float, default=6.0,
                   help="size of each submission (two mmpose files); 0: small OpenPose zips")
    p.add_argument("--memory-cases", action="store_true",
                   help="then submit the huge-frame-id and the 300 MB file")
    args = p.parse_args()
    assert args.clients < len(TOKENS)
    half = int(args.upload_mb * 2**19)
    files = ([(f"cam{i}.json", mmpose_file(half, seed=i)) for i in range(2)] if half
             else [(f"cam{i}.zip", camera_zip(i)) for i in range(2)])
    options = {"image_size": "640x480", "fps": 30} if half else None
    with tempfile.TemporaryDirectory() as tmp:
        dep, pg = build_deployment(args.backend, Path(tmp), concurrency=args.workers,
                                   CASCALIB_WORKERS=str(args.workers),
                                   CASCALIB_HEARTBEAT_SECONDS="2",
                                   CASCALIB_STALE_AFTER_SECONDS="60",
                                   CASCALIB_MAX_UPLOAD_BYTES=str(512 * 2**20),
                                   CASCALIB_MAX_PENDING_SUBMISSIONS=str(args.clients),
                                   CASCALIB_VALIDATION_WORKERS=str(args.validators))
        try:
            rec, out = Recorder(), {}
            shares = [args.jobs // args.clients + (i < args.jobs % args.clients)
                      for i in range(args.clients)]
            threads = [threading.Thread(target=client_run, args=(
                dep.url, TOKENS[i], shares[i], files, options, rec, out, args.timeout))
                for i in range(args.clients)]
            stop = threading.Event()
            prober = threading.Thread(target=probe_health, args=(dep.url, rec, stop))
            t0 = time.perf_counter()
            prober.start()
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            stop.set()
            prober.join()
            elapsed = time.perf_counter() - t0
            print(f"backend {args.backend}, {args.clients} clients, {args.jobs} jobs, "
                  f"{args.workers} embedded workers" if args.backend != "celery"
                  else f"backend celery (1 worker, concurrency {args.workers}), "
                  f"{args.clients} clients, {args.jobs} jobs")
            print((f"uploads of {args.upload_mb:g} MB" if half else "uploads: small zips")
                  + f", {args.validators} validator process(es)")
            code = report(rec, out, dep.url, elapsed, args.jobs)
            if args.memory_cases:
                assert dep.server is not None
                memory_cases(dep.url, dep.server.popen.pid)
            return code
        finally:
            dep.stop()
            if pg:
                pg.drop()


if __name__ == "__main__":
    sys.exit(main())
