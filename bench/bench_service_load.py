"""Load test of the calibration service: N jobs submitted by C concurrent clients.

Starts a real server (uvicorn on a loopback port; SQLite + embedded pool by default, or
PostgreSQL, or Celery + Redis + PostgreSQL), then C client threads, each with its own token,
submit their share of the jobs (each with an Idempotency-Key, retried on transport errors) and
poll them until they end, while every request's latency is recorded. Checks that every job
finished and none was lost or duplicated, then prints throughput and API latency percentiles.

The jobs are real calibration jobs on small synthetic OpenPose inputs that the cascade rejects
quickly (single-view stage): the benchmark measures the service (upload validation, store,
queue, workers, polling), not the calibration itself.

    python bench/bench_service_load.py                    # 100 jobs, 20 clients, SQLite
    python bench/bench_service_load.py --backend postgres --workers 2
    python bench/bench_service_load.py --backend celery
"""

from __future__ import annotations

import argparse
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
from service_helpers import TOKENS, build_deployment, camera_zip, submit  # noqa: E402

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


def client_run(url: str, token: str, n_jobs: int, files: list[tuple[str, bytes]],
               rec: Recorder, out: dict[str, list[str]], timeout: float) -> None:
    ids: list[str] = []
    with httpx.Client(base_url=url, headers={"Authorization": f"Bearer {token}"},
                      timeout=60) as c:
        for _ in range(n_jobs):
            key = {"Idempotency-Key": uuid.uuid4().hex}
            for _attempt in range(5):  # a retry re-sends the same key: never a second job
                try:
                    r = rec.timed("POST /v1/jobs", submit, c, files, None, key)
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
    p.add_argument("--jobs", type=int, default=100)
    p.add_argument("--clients", type=int, default=20)
    p.add_argument("--backend", choices=["sqlite", "postgres", "celery"], default="sqlite")
    p.add_argument("--workers", type=int, default=2,
                   help="embedded pool size, or Celery worker concurrency")
    p.add_argument("--timeout", type=float, default=600)
    args = p.parse_args()
    assert args.clients <= len(TOKENS)
    files = [(f"cam{i}.zip", camera_zip(i)) for i in range(2)]
    with tempfile.TemporaryDirectory() as tmp:
        dep, pg = build_deployment(args.backend, Path(tmp), concurrency=args.workers,
                                   CASCALIB_WORKERS=str(args.workers),
                                   CASCALIB_HEARTBEAT_SECONDS="2",
                                   CASCALIB_STALE_AFTER_SECONDS="60")
        try:
            rec, out = Recorder(), {}
            shares = [args.jobs // args.clients + (i < args.jobs % args.clients)
                      for i in range(args.clients)]
            threads = [threading.Thread(target=client_run, args=(
                dep.url, TOKENS[i], shares[i], files, rec, out, args.timeout))
                for i in range(args.clients)]
            t0 = time.perf_counter()
            for t in threads:
                t.start()
            for t in threads:
                t.join()
            elapsed = time.perf_counter() - t0
            print(f"backend {args.backend}, {args.clients} clients, {args.jobs} jobs, "
                  f"{args.workers} embedded workers" if args.backend != "celery"
                  else f"backend celery (1 worker, concurrency {args.workers}), "
                  f"{args.clients} clients, {args.jobs} jobs")
            return report(rec, out, dep.url, elapsed, args.jobs)
        finally:
            dep.stop()
            if pg:
                pg.drop()


if __name__ == "__main__":
    sys.exit(main())
