"""The API stays responsive while uploads are parsed and jobs run (2 cores): parsing happens in
validator processes and jobs in processes niced below the API."""

from __future__ import annotations

import json
import threading
import time
from collections.abc import Iterator
from pathlib import Path

import httpx
import numpy as np
import pytest
from service_helpers import Deployment, build_deployment, forked_processes, next_token, submit


@pytest.fixture(scope="module")
def roomy(tmp_path_factory: pytest.TempPathFactory) -> Iterator[Deployment]:
    """A SQLite deployment that takes uploads of 200 MB."""
    dep, _ = build_deployment("sqlite", tmp_path_factory.mktemp("roomy"),
                              CASCALIB_MAX_UPLOAD_BYTES=str(200 * 2**20))
    yield dep
    dep.stop()


def _niceness(pid: int) -> int:
    return int(Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()[16])


def big_mmpose(n_frames: int, persons: int = 3, seed: int = 0) -> bytes:
    """An mmpose file (COCO-17) of ``n_frames`` frames, about 1.2 kB per person and frame."""
    rng = np.random.default_rng(seed)
    xy = rng.uniform(100, 500, (persons, 17, 2)).round(1).tolist()
    frame = [{"keypoints": p, "keypoint_scores": [0.9] * 17} for p in xy]
    return json.dumps([{"frame_id": f, "instances": frame} for f in range(n_frames)]).encode()


def test_jobs_and_validators_run_below_the_api(roomy: Deployment) -> None:
    assert roomy.server is not None
    server = roomy.server.popen.pid
    seen: dict[str, int] = {}
    with roomy.client(next_token()) as c:
        deadline = time.monotonic() + 30
        while len(seen) < 2 and time.monotonic() < deadline:
            if not forked_processes(server):
                submit(c)
            for name in ("cascalib-job", "cascalib-valid"):
                for pid in forked_processes(server, name):
                    try:
                        seen.setdefault(name, _niceness(pid))
                    except OSError:
                        pass
            time.sleep(0.01)
    base = _niceness(server)  # the tests may run niced themselves
    assert seen == {"cascalib-job": min(base + 10, 19), "cascalib-valid": min(base + 5, 19)}


def test_health_and_polls_fast_while_a_large_upload_is_parsed(roomy: Deployment) -> None:
    """A 40 MB keypoint file: the API process only streams it to disk; json parsing (which
    holds the GIL for its whole duration) happens in a validator process."""
    files = [("cam0.json", big_mmpose(12_000)), ("cam1.json", big_mmpose(12_000, seed=1))]
    latencies: list[float] = []
    done = threading.Event()

    def poll() -> None:
        with httpx.Client(base_url=roomy.url, timeout=30) as h:
            while not done.is_set():
                t0 = time.perf_counter()
                h.get("/healthz")
                latencies.append(time.perf_counter() - t0)
                time.sleep(0.01)

    poller = threading.Thread(target=poll)
    with roomy.client(next_token()) as c:
        submit(c, [("cam0.json", b"{}"), ("cam1.json", b"{}")])  # validators started
        poller.start()
        t0 = time.perf_counter()
        try:
            r = submit(c, files, {"image_size": "640x480", "fps": 30})
        finally:
            upload = time.perf_counter() - t0
            done.set()
            poller.join()
    assert r.status_code == 202, r.text
    assert len(latencies) > 20
    # parsed in the API process, one health check would wait for most of the upload; relative
    # to the upload's own time, so that a loaded machine slows both alike
    assert max(latencies) < 0.3 * upload, (upload, sorted(latencies)[-5:])
