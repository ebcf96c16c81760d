"""Every calibration format the library writes can be downloaded from a succeeded job (the
format registry is read by the worker's export and by the result route alike)."""

from __future__ import annotations

import hashlib
import io
import uuid
import zipfile
from pathlib import Path
from typing import Any

import httpx
from service_helpers import Deployment

from api_schemas import RESULT_FORMATS
from cascalib.calibration import Calibration
from cascalib.formats import load_calibration, save_calibration
from service.models import Job, JobFile
from service.store import Store
from service.worker.runner import _save_outputs

RIG = Path(__file__).resolve().parents[1] / "data" / "calibration" / "rig.json"


class _Result:
    """What the export needs of a ``CalibrationResult``: the calibration and its ``save``."""

    def __init__(self, calibration: Calibration) -> None:
        self.calibration = calibration

    def save(self, outdir: Path, formats: Any = ("json",)) -> dict[str, Path]:
        outdir.mkdir(parents=True, exist_ok=True)
        return {"calibration:json": save_calibration(self.calibration,
                                                     outdir / "calibration.json")[0]}


def _succeeded_job(dep: Deployment, token: str, calib: Calibration) -> str:
    """A succeeded job of ``token`` whose outputs the worker's export wrote."""
    store = Store(dep.database_url, dep.data_dir)
    try:
        job_id = uuid.uuid4().hex
        outputs = _save_outputs(_Result(calib), store.job_dir(job_id))
        with store.session() as session:
            job = Job(id=job_id, owner=hashlib.sha256(token.encode()).hexdigest(),
                      status="succeeded", stage="done", progress=1.0, options={},
                      cameras=calib.names, request_hash="0" * 64, attempts=1)
            job.files = [JobFile(kind="output", role=f.role, path=f.path, size=f.size,
                                 sha256=f.sha256) for f in outputs]
            session.add(job)
            session.commit()
    finally:
        store.dispose()
    return job_id


def test_every_result_format_downloads(deployment: Deployment, client: httpx.Client,
                                       token: str, tmp_path: Path) -> None:
    calib = load_calibration(RIG)
    job_id = _succeeded_job(deployment, token, calib)
    spec = client.get("/openapi.json").json()
    params = spec["paths"]["/v1/jobs/{job_id}/result"]["get"]["parameters"]
    offered = next(p for p in params if p["name"] == "format")["schema"]["enum"]
    assert offered == list(RESULT_FORMATS) and "caliscope" in offered
    for fmt in RESULT_FORMATS:
        r = client.get(f"/v1/jobs/{job_id}/result", params={"format": fmt})
        assert r.status_code == 200, (fmt, r.text)
        if r.headers["content-type"] == "application/zip":
            folder = tmp_path / fmt
            zipfile.ZipFile(io.BytesIO(r.content)).extractall(folder)
            got = load_calibration(folder, format=fmt)
        else:
            name = r.headers["content-disposition"].split('filename="', 1)[1].rstrip('"')
            (tmp_path / name).write_bytes(r.content)
            got = load_calibration(tmp_path / name, format=fmt)
        assert got.names == calib.names, fmt
    caliscope = client.get(f"/v1/jobs/{job_id}/result", params={"format": "caliscope"})
    assert caliscope.headers["content-type"].startswith("application/toml")
    assert b"[cameras." in caliscope.content
