"""The HTTP API against a real server, on SQLite, PostgreSQL and Celery + Redis."""

from __future__ import annotations

import concurrent.futures
import io
import json
import time
import zipfile
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import httpx
import numpy as np
import pytest
from service_helpers import (
    MAX_FILES,
    MAX_UPLOAD,
    OPTIONS,
    TOKENS,
    Deployment,
    build_deployment,
    camera_zip,
    needs_pipeline,
    next_token,
    openpose_frames,
    sim_files,
    submit,
    wait_finished,
    zip_bytes,
)

from api_schemas import RESULT_FORMATS
from cascalib.calibration_formats import get_format

PROBLEM = "application/problem+json"


def stored_jobs(dep: Deployment) -> set[str]:
    jobs = dep.data_dir / "jobs"
    return {p.name for p in jobs.iterdir()} if jobs.exists() else set()


def test_health_ready_metrics_openapi(deployment: Deployment) -> None:
    with deployment.client(None) as c:
        assert c.get("/healthz").json()["status"] == "ok"
        ready = c.get("/readyz")
        assert ready.status_code == 200, ready.text
        assert ready.json()["checks"] == {"database": "ok", "workers": "ok"}
        text = c.get("/metrics").text
        assert 'cascalib_http_requests_total{method="GET",route="/readyz",status="200"}' in text
        assert 'cascalib_jobs{status="queued"}' in text
        spec = c.get("/openapi.json").json()
    assert {"/v1/jobs", "/v1/jobs/{job_id}", "/v1/jobs/{job_id}/result", "/v1/jobs/{job_id}/report",
            "/v1/jobs/{job_id}/poses"} <= set(spec["paths"])
    assert "multipart/form-data" in spec["paths"]["/v1/jobs"]["post"]["requestBody"]["content"]


def test_auth_required_and_jobs_private(deployment: Deployment, token: str) -> None:
    with deployment.client(None) as anon:
        r = anon.get("/v1/jobs")
        assert r.status_code == 401 and r.headers["content-type"] == PROBLEM
        assert r.headers["www-authenticate"] == "Bearer"
        assert submit(anon).status_code == 401
    with deployment.client("not-a-token") as bad:
        assert bad.get("/v1/jobs").status_code == 401
    with deployment.client(token) as owner:
        r = submit(owner)
        assert r.status_code == 202, r.text
        job_id = r.json()["id"]
        assert owner.get(f"/v1/jobs/{job_id}").status_code == 200
    other = TOKENS[(TOKENS.index(token) + 30) % len(TOKENS)]
    with deployment.client(other) as intruder:
        assert intruder.get(f"/v1/jobs/{job_id}").status_code == 404
        assert intruder.get(f"/v1/jobs/{job_id}/result").status_code == 404
        assert intruder.delete(f"/v1/jobs/{job_id}").status_code == 404
        assert job_id not in [j["id"] for j in intruder.get("/v1/jobs").json()["data"]]
    with deployment.client(token) as owner:
        assert owner.get(f"/v1/jobs/{job_id}").json()["status"] != "cancelled"


def _bomb() -> bytes:
    return zip_bytes({"frame_000000000000_keypoints.json": b"{" + b" " * (40 * 2**20) + b"}"})


def _sized_file(name: str, size: tuple[int, int] = (640, 480)) -> tuple[str, bytes]:
    """A native keypoint file that records its image size."""
    import tempfile

    import numpy as np

    from cascalib import Tracks
    from cascalib.formats import write_tracks

    kp = np.random.default_rng(0).uniform(10, 400, (6, 1, 17, 3))
    kp[..., 2] = 0.9
    with tempfile.TemporaryDirectory() as tmp:
        path = write_tracks(Tracks(name, kp, "coco17", image_size=size), Path(tmp) / f"{name}.json",
                            format="native-json")
        return f"{name}.json", Path(path).read_bytes()


def _truncated_zip() -> bytes:
    return camera_zip(0)[: len(camera_zip(0)) // 2]


BAD_UPLOADS = {
    # kind: (files, options, status, field that the problem must name)
    "wrong format": ([("cam0.json", b"\x89PNG\r\n\x1a\n" + b"\0" * 64)], OPTIONS, 422, None),
    "text not keypoints": ([("cam0.csv", b"hello,world\n1,2\n")], OPTIONS, 422, None),
    "truncated json": ([("cam0.json", openpose_frames(1)[0][:50])], OPTIONS, 422, None),
    "truncated zip": ([("cam0.zip", _truncated_zip())], OPTIONS, 422, "files"),
    "zip bomb": ([("cam0.zip", _bomb())], OPTIONS, 422, "files"),
    "path traversal name": ([("../../etc/cam0.json", camera_zip())], OPTIONS, 422, "files"),
    "backslash name": ([("..\\cam0.zip", camera_zip())], OPTIONS, 422, "files"),
    "hidden name": ([(".cam0.zip", camera_zip())], OPTIONS, 422, "files"),
    "traversal in zip": ([("cam0.zip", zip_bytes({"../evil.json": openpose_frames(1)[0]}))],
                         OPTIONS, 422, "files"),
    "absolute in zip": ([("cam0.zip", zip_bytes({"/tmp/evil.json": openpose_frames(1)[0]}))],
                        OPTIONS, 422, "files"),
    "empty file": ([("cam0.json", b"")], OPTIONS, 422, "files"),
    "duplicate camera": ([("cam0.zip", camera_zip()), ("cam0.json", b"{}")], OPTIONS, 422,
                         "files"),
    "unknown option": (None, {**OPTIONS, "imagesize": "1x1"}, 422, "options.imagesize"),
    "bad image size": (None, {**OPTIONS, "image_size": "big"}, 422, "options.image_size"),
    "negative fps": (None, {**OPTIONS, "fps": -3}, 422, "options.fps"),
    "options not json": (None, "{image_size: 1920x1080", 422, "options"),
    "options not object": (None, "[1, 2]", 422, "options"),
    "options nested 100k deep": (None, '{"config":' + '{"a":' * 100_000 + "1" + "}" * 100_001,
                                 422, "options"),
    "options nested 300k lists": (None, '{"config":{"a":' + "[" * 300_000 + "]" * 300_000
                                  + "}}", 422, "options"),
    "options nested 40 deep": (None, '{"config":' + '{"a":' * 40 + "1" + "}" * 41, 422,
                               "options"),
    "fps for unknown camera": (None, {**OPTIONS, "fps": {"camX": 30}}, 422, "options.fps.camX"),
    "unknown reference camera": (None, {**OPTIONS, "reference_camera": "camZ"}, 422,
                                 "options.reference_camera"),
    "unknown skeleton": (None, {**OPTIONS, "skeleton": "octopus8"}, 422, None),
    "unknown config key": (None, {**OPTIONS, "config": {"refine": {"bogus": 1}}}, 422,
                           "options.config.refine.bogus"),
    "one camera only": ([("cam0.zip", camera_zip(0))], OPTIONS, 422, "files"),
    "no image size": ([("cam0.zip", camera_zip(0)), ("cam1.zip", camera_zip(1))],
                      {"fps": 30, "skeleton": "body25"}, 422, "options.image_size"),
    "too large": ([("cam0.zip", b"PK\x03\x04" + b"\xff" * (MAX_UPLOAD + 10))], OPTIONS, 413,
                  None),
    "too many files": ([(f"cam{i}.zip", b"x") for i in range(MAX_FILES + 1)], OPTIONS, 413,
                       "files"),
    "no files": ([], OPTIONS, 422, "files"),
    "image size 1x1 against the file's": ([_sized_file("cam0"), _sized_file("cam1")],
                                          {"fps": 30, "image_size": "1x1"}, 422,
                                          "options.image_size"),
    "image size 999999x999999 for one camera": (
        [_sized_file("cam0"), _sized_file("cam1")],
        {"fps": 30, "image_size": {"cam1": "999999x999999"}}, 422, "options.image_size"),
}


@pytest.mark.parametrize("kind", list(BAD_UPLOADS))
def test_bad_upload_rejected_and_nothing_stored(deployment: Deployment, client: httpx.Client,
                                                kind: str) -> None:
    files, options, status, field = BAD_UPLOADS[kind]
    before = stored_jobs(deployment)
    r = submit(client, files, options)
    assert r.status_code == status, r.text
    assert r.headers["content-type"] == PROBLEM
    body = r.json()
    assert body["status"] == status and body["detail"]
    assert "Traceback" not in r.text and str(deployment.data_dir) not in r.text
    if field is not None:
        assert field in [e.get("field") for e in body["errors"]], body
    assert stored_jobs(deployment) == before
    assert not list((deployment.data_dir / "staging").iterdir())
    assert client.get("/v1/jobs").json()["count"] == 0


def test_error_names_camera_and_client_file(client: httpx.Client) -> None:
    good = ("cam0.zip", camera_zip(0))
    bad = ("side_left.json", b'{"people": [{"pose_keypoints_2d": [1, 2]}]}')
    r = submit(client, [good, bad], OPTIONS)
    assert r.status_code == 422, r.text
    err = r.json()["errors"][0]
    assert err["camera"] == "side_left"
    assert err["file"] is None or err["file"].startswith("side_left.json")


def test_streamed_body_over_limit(deployment: Deployment, client: httpx.Client) -> None:
    """No Content-Length (chunked): the limit is enforced while the body streams in."""
    before = stored_jobs(deployment)

    def body() -> Iterator[bytes]:
        yield (b'--xx\r\nContent-Disposition: form-data; name="files"; filename="cam0.json"'
               b"\r\n\r\n")
        for _ in range(MAX_UPLOAD // 2**16 + 2):
            yield b" " * 2**16
        yield b"\r\n--xx--\r\n"

    r = client.post("/v1/jobs", content=body(),
                    headers={"content-type": "multipart/form-data; boundary=xx"})
    assert r.status_code == 413 and r.headers["content-type"] == PROBLEM
    assert stored_jobs(deployment) == before


def test_not_multipart(client: httpx.Client) -> None:
    r = client.post("/v1/jobs", json={"options": {}})
    assert r.status_code == 415 and r.headers["content-type"] == PROBLEM


def test_idempotency_key(client: httpx.Client) -> None:
    files = [("cam0.zip", camera_zip(0)), ("cam1.zip", camera_zip(1))]
    key = {"Idempotency-Key": "retry-7f3a"}
    first = submit(client, files, OPTIONS, key)
    assert first.status_code == 202, first.text
    again = submit(client, files, OPTIONS, key)
    assert again.status_code == 202 and again.json()["id"] == first.json()["id"]
    assert again.headers["idempotent-replayed"] == "true"
    other = submit(client, files, {**OPTIONS, "height": 1.8}, key)
    assert other.status_code == 422 and other.json()["errors"][0]["field"] == "Idempotency-Key"
    # Concurrent retries of one new request: one job.
    key2 = {"Idempotency-Key": "burst-1"}
    with concurrent.futures.ThreadPoolExecutor(6) as pool:
        rs = list(pool.map(lambda _: submit(client, files, OPTIONS, key2), range(6)))
    assert {r.status_code for r in rs} == {202}
    assert len({r.json()["id"] for r in rs}) == 1
    assert client.get("/v1/jobs").json()["count"] == 2


def test_job_reaches_an_end_with_a_reason(deployment: Deployment, client: httpx.Client) -> None:
    r = submit(client)
    assert r.status_code == 202, r.text
    body = r.json()
    assert r.headers["location"] == body["links"]["self"] == f"/v1/jobs/{body['id']}"
    job = wait_finished(client, body["id"])
    assert job["status"] in ("succeeded", "failed")
    assert job["cameras"] == ["cam0", "cam1"] and job["attempts"] == 1
    assert job["created_at"] <= job["started_at"] <= job["finished_at"]
    if job["status"] == "failed":
        assert job["error"] and "Traceback" not in job["error"]
        assert str(deployment.data_dir) not in job["error"] and "/tmp" not in job["error"]
        assert "cam0.zip" in job["error"]  # named as the client named it
        r = client.get(f"/v1/jobs/{body['id']}/result")
        assert r.status_code == 409 and "failed" in r.json()["detail"]


def test_list_paging_and_filter(client: httpx.Client) -> None:
    ids = [submit(client).json()["id"] for _ in range(3)]
    page = client.get("/v1/jobs", params={"limit": 2}).json()
    assert page["count"] == 3 and len(page["data"]) == 2
    assert [j["id"] for j in page["data"]] == ids[::-1][:2]  # newest first
    rest = client.get("/v1/jobs", params={"limit": 2, "offset": 2}).json()
    assert [j["id"] for j in rest["data"]] == [ids[0]]
    final = {i: wait_finished(client, i)["status"] for i in ids}
    for status in ("succeeded", "failed", "queued"):
        got = client.get("/v1/jobs", params={"status": status}).json()
        assert got["count"] == sum(s == status for s in final.values())
    assert client.get("/v1/jobs", params={"status": "bogus"}).status_code == 422
    assert client.get("/v1/jobs", params={"limit": 0}).status_code == 422


def test_cancel_then_delete(deployment: Deployment, client: httpx.Client) -> None:
    job_id = submit(client).json()["id"]
    r = client.delete(f"/v1/jobs/{job_id}")
    if r.status_code == 200:  # was queued or running: cancelled
        assert r.json()["status"] == "cancelled"
        time.sleep(1.5)  # a worker that had started it must not resurrect it
        job = client.get(f"/v1/jobs/{job_id}").json()
        assert job["status"] == "cancelled" and job["finished_at"]
        assert client.get(f"/v1/jobs/{job_id}/result").status_code == 409
        r = client.delete(f"/v1/jobs/{job_id}")
    assert r.status_code == 204
    assert client.get(f"/v1/jobs/{job_id}").status_code == 404
    assert job_id not in stored_jobs(deployment)


def test_inputs_kept_with_checksums(deployment: Deployment, client: httpx.Client) -> None:
    import hashlib

    content = camera_zip(3)
    job_id = submit(client, [("cam0.zip", content), ("cam1.zip", camera_zip(4))]).json()["id"]
    stored = deployment.data_dir / "jobs" / job_id / "inputs" / "cam_0.zip"
    assert hashlib.sha256(stored.read_bytes()).digest() == hashlib.sha256(content).digest()
    wait_finished(client, job_id)
    assert stored.read_bytes() == content  # still there whatever the outcome


@needs_pipeline
@pytest.mark.slow
@pytest.mark.parametrize("kind", ["sqlite", "celery"])
def test_full_life_cycle(kind: str, tmp_path: Path) -> None:
    """Submit a simulated rig, poll to success, download every output."""
    from cascalib.formats import load_calibration

    dep, pg = build_deployment(kind, tmp_path, CASCALIB_MAX_UPLOAD_BYTES=str(200 * 2**20))
    try:
        with dep.client(next_token()) as client:
            _life_cycle(client, tmp_path, load_calibration)
    finally:
        dep.stop()
        if pg:
            pg.drop()


def assert_documented(client: httpx.Client, template: str, r: httpx.Response) -> None:
    """The answer's status and media type are the ones /openapi.json gives for the path."""
    spec = client.get("/openapi.json").json()
    answers = spec["paths"][template][r.request.method.lower()]["responses"]
    assert str(r.status_code) in answers, (template, r.status_code, list(answers))
    media = r.headers["content-type"].split(";")[0]
    assert media in answers[str(r.status_code)].get("content", {}), (template, media)


def test_downloads_of_an_unfinished_job_answer_as_documented(client: httpx.Client) -> None:
    job_id = submit(client).json()["id"]
    wait_finished(client, job_id)
    for what in ("result", "report", "poses"):
        r = client.get(f"/v1/jobs/{job_id}/{what}")
        assert r.status_code in (404, 409), r.text  # a failed job, or an output missing
        assert_documented(client, f"/v1/jobs/{{job_id}}/{what}", r)
    r = client.get("/v1/jobs/0123/result")
    assert r.status_code == 404
    assert_documented(client, "/v1/jobs/{job_id}/result", r)


def _life_cycle(client: httpx.Client, tmp_path: Path, load_calibration: Any) -> None:
    files = sim_files(tmp_path)
    r = submit(client, files, {"seed": 0})
    assert r.status_code == 202, r.text
    job = wait_finished(client, r.json()["id"], timeout=1800)
    assert job["status"] == "succeeded", job
    assert job["progress"] == 1.0 and job["stage"] == "done"
    result = client.get(f"/v1/jobs/{job['id']}/result")
    assert result.status_code == 200 and result.headers["etag"]
    (tmp_path / "calibration.json").write_bytes(result.content)
    calib = load_calibration(tmp_path / "calibration.json")
    assert calib.names == [name.rsplit(".", 1)[0] for name, _ in files]
    exported = 0
    for fmt in RESULT_FORMATS[1:]:  # every format the library writes, caliscope too
        r = client.get(f"/v1/jobs/{job['id']}/result", params={"format": fmt})
        if r.status_code == 404:  # the format cannot hold these cameras: the reason is given
            assert "produced no" in r.json()["detail"] and ": " in r.json()["detail"], r.text
            continue
        assert r.status_code == 200 and r.content, fmt
        assert_documented(client, "/v1/jobs/{job_id}/result", r)
        exported += 1
        if get_format(fmt).is_folder:
            assert zipfile.ZipFile(io.BytesIO(r.content)).namelist()
    assert exported >= 2
    report = client.get(f"/v1/jobs/{job['id']}/report")
    assert report.status_code == 200 and "<html" in report.text.lower()
    poses = client.get(f"/v1/jobs/{job['id']}/poses")
    assert poses.status_code == 200 and json.loads(poses.content)
    npz = client.get(f"/v1/jobs/{job['id']}/poses", params={"format": "npz"})
    assert npz.content[:2] == b"PK"
    for what, r in (("result", result), ("report", report), ("poses", poses), ("poses", npz)):
        assert_documented(client, f"/v1/jobs/{{job_id}}/{what}", r)
    assert client.delete(f"/v1/jobs/{job['id']}").status_code == 204


def mmpose_bytes(frame_ids: list[int], persons: int = 1, seed: int = 0) -> bytes:
    """An mmpose file (COCO-17, two values per joint) with ``persons`` people per frame id."""
    rng = np.random.default_rng(seed)

    def person() -> dict[str, object]:
        xy = rng.uniform(100, 500, (17, 2)).round(1)
        return {"keypoints": xy.tolist(), "keypoint_scores": [0.9] * 17}

    return json.dumps([{"frame_id": f, "instances": [person() for _ in range(persons)]}
                       for f in frame_ids]).encode()


MEMORY_CASES = {
    # kind: (frame ids, persons per frame, status, field)
    "frame id past the frame limit": ([*range(40), 1_000_000], 1, 413, "frames"),
    "frame ids spread far apart": ([*range(40), 300_000], 1, 422, "frames"),
    "too many people in a frame": ([0, 1, 2], 101, 413, "persons"),
}


@pytest.mark.parametrize("kind", list(MEMORY_CASES))
def test_keypoints_beyond_their_data_refused_early(client: httpx.Client, kind: str) -> None:
    """A small file must not make the API build a dense array for frames or people it does
    not hold: the stated limits answer 413, ids far apart 422, in well under a second."""
    frame_ids, persons, status, field = MEMORY_CASES[kind]
    files = [("cam0.json", mmpose_bytes(frame_ids, persons)),
             ("cam1.json", mmpose_bytes(list(range(40)), 1, seed=1))]
    t0 = time.monotonic()
    r = submit(client, files, {"image_size": "640x480", "fps": 30})
    assert r.status_code == status, r.text
    assert time.monotonic() - t0 < 5.0
    err = r.json()["errors"][0]
    assert (err["camera"], err["file"], err["field"]) == ("cam0", "cam0.json", field), err


def _series(text: str, name: str) -> float:
    """The value of one sample of a Prometheus text page (0 when absent)."""
    for line in text.splitlines():
        if line.startswith(name + " "):
            return float(line.rsplit(" ", 1)[1])
    return 0.0


def test_job_histograms_and_counters(deployment: Deployment, client: httpx.Client) -> None:
    """Queue wait and run time histograms, failure and retry counters in /metrics, summed
    over every process that runs jobs (they live in the store)."""
    with deployment.client(None) as anon:
        before = anon.get("/metrics").text
        job = wait_finished(client, submit(client).json()["id"])
        after = anon.get("/metrics").text
    assert job["status"] == "failed"  # the synthetic inputs fail in the single-view stage
    status = '{status="failed"}'
    for name, grew in [("cascalib_job_queue_wait_seconds_count", 1),
                       (f"cascalib_job_duration_seconds_count{status}", 1),
                       ("cascalib_jobs_failed_total", 1)]:
        assert _series(after, name) - _series(before, name) == grew, name
    waited = (_series(after, "cascalib_job_queue_wait_seconds_sum")
              - _series(before, "cascalib_job_queue_wait_seconds_sum"))
    assert 0 <= waited < 60
    assert 'cascalib_job_duration_seconds_bucket{le="+Inf",status="failed"}' in after
    assert "cascalib_job_retries_total" in after
