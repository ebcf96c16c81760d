"""A job that succeeds with something left undetermined says so in its status."""

from __future__ import annotations

from pathlib import Path

import pytest
from service_helpers import (
    build_deployment,
    needs_pipeline,
    next_token,
    sim_files,
    submit,
    wait_finished,
    zip_bytes,
)

DATA = Path(__file__).resolve().parents[3] / "shared" / "data" / "pose2sim_demo"


def _camera_zip(folder: Path) -> bytes:
    return zip_bytes({f"{folder.name}/{p.name}": p.read_bytes()
                      for p in sorted(folder.glob(f"{folder.name[:5]}.*.json"))})


@needs_pipeline
@pytest.mark.slow
@pytest.mark.skipif(not DATA.is_dir(), reason=f"real recordings not found at {DATA}")
def test_job_on_a_recording_stage_i_refuses_succeeds_with_its_warnings(tmp_path: Path) -> None:
    dep, _ = build_deployment("sqlite", tmp_path)
    try:
        with dep.client(next_token()) as client:
            folders = [DATA / "multi_person" / "pose" / f"cam0{i}_json" for i in range(1, 5)]
            r = submit(client, files=[(f"cam0{i + 1}.zip", _camera_zip(f))
                                      for i, f in enumerate(folders)],
                       options={"image_size": "1088x1920", "fps": 60, "synchronized": True})
            assert r.status_code == 202, r.text
            job = wait_finished(client, r.json()["id"], timeout=600)
            assert job["status"] == "succeeded", job
            assert any("stage I could not decide" in w for w in job["warnings"]), job
    finally:
        dep.stop()


@needs_pipeline
@pytest.mark.slow
def test_a_given_frame_rate_the_files_contradict_is_in_the_jobs_warnings(tmp_path: Path) -> None:
    """REST used to drop a given fps with a log line only: the simulated rig records 25 fps,
    the client says 30 for every camera; the files win (as on the command line) and the job
    says so, camera by camera."""
    dep, _ = build_deployment("sqlite", tmp_path, CASCALIB_MAX_UPLOAD_BYTES=str(200 * 2**20))
    try:
        with dep.client(next_token()) as client:
            r = submit(client, files=sim_files(tmp_path), options={"fps": 30, "seed": 0})
            assert r.status_code == 202, r.text
            job = wait_finished(client, r.json()["id"], timeout=1800)
            assert job["status"] == "succeeded", job
            notes = [w for w in job["warnings"] if "fps given for every camera" in w]
            assert len(notes) == 4 and notes[0] == ("camera cam0: its file records 25 fps; the "
                                                    "30 fps given for every camera is not "
                                                    "used for it"), job["warnings"]
    finally:
        dep.stop()
