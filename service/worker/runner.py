"""Running one job: the code both execution back-ends share.

:func:`run_job` is the calibration itself (inputs -> ``calibrate`` -> saved outputs).
:func:`execute_claimed` wraps it for a worker that has claimed the job: a heartbeat thread,
throttled progress writes, cancellation, and the final state with a reason. The embedded pool
(``local_pool.py``) and Celery (``celery_app.py``) are thin adapters around these two.
"""

from __future__ import annotations

import json
import logging
import shutil
import tempfile
import threading
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from api_schemas import RESULT_FORMATS, JobOptions
from cascalib import calibration_formats
from cascalib.errors import CascalibError
from service import store as st
from service.inputs import (
    ZipLimits,
    build_config,
    check_session,
    is_zip,
    read_camera,
    safe_extract,
    zip_limits,
)
from service.store import Store, StoredFile, sha256_file

__all__ = ["JobCancelled", "run_job", "execute_claimed"]

log = logging.getLogger(__name__)

Progress = Callable[[str, float], None]


class JobCancelled(Exception):
    """The job was cancelled (or taken away from this worker) while it ran."""


class _Names:
    """Server paths of a job's inputs -> the client's file names (for error messages)."""

    def __init__(self, job_dir: Path) -> None:
        self.job_dir = job_dir
        self.paths: dict[str, str] = {}

    def clean(self, text: str) -> str:
        for server, client in sorted(self.paths.items(), key=lambda kv: -len(kv[0])):
            text = text.replace(server, client)
        return text.replace(str(self.job_dir) + "/", "")


def _load_tracks(job: Any, job_dir: Path, work: Path, limits: ZipLimits,
                 names: _Names) -> tuple[list[Any], list[str]]:
    """The cameras' tracks with the options filled in, and the warnings that raised."""
    options = JobOptions.model_validate(job.options)
    tracks: list[Any] = []
    notes: list[str] = []
    for f in (f for f in job.files if f.kind == "input"):
        path = job_dir / f.path
        names.paths[str(path)] = f.client_name or f.role
        if sha256_file(path) != f.sha256:
            raise CascalibError("stored input changed on disk (checksum mismatch)",
                                file=f.client_name, camera=f.role)
        if is_zip(path):
            path = safe_extract(path, work / f"cam_{len(tracks)}", limits,
                                file=f.client_name or f.role)
            names.paths[str(path)] = f.client_name or f.role
        camera, why = read_camera(path, f.role, options, limits)
        tracks.append(camera)
        notes += why
    check_session(tracks)
    return tracks, notes


EXPORT_ERRORS = "export_errors.json"


def _export(result: Any, tmp: Path) -> dict[str, Path]:
    """The native JSON, poses and report, then each other format on its own: a format that
    cannot hold these cameras (e.g. COLMAP and a skewed K) is reported, not fatal."""
    from cascalib.formats import save_calibration

    saved: dict[str, Path] = dict(result.save(tmp, formats=("json",)))
    errors: dict[str, str] = {}
    for fmt in RESULT_FORMATS:
        if fmt == "json":
            continue
        try:
            out = tmp / calibration_formats.get_format(fmt).output_name
            paths = save_calibration(result.calibration, out, fmt)
            saved[f"calibration:{fmt}"] = Path(paths[0])
        except CascalibError as exc:
            log.warning("export to %s failed: %s", fmt, exc)
            errors[fmt] = str(exc)
    if errors:
        (tmp / EXPORT_ERRORS).write_text(json.dumps(errors, indent=1))
        saved["export_errors"] = tmp / EXPORT_ERRORS
    return saved


def _save_outputs(result: Any, job_dir: Path) -> list[StoredFile]:
    tmp = job_dir / "outputs.partial"
    shutil.rmtree(tmp, ignore_errors=True)
    saved = _export(result, tmp)
    # Roles are the library's names for what it wrote ("calibration:json", "report", ...);
    # files it did not name (the rest of a COLMAP folder, report plots) get "file:<path>".
    roles = {Path(p).resolve().relative_to(tmp.resolve()): str(role)
             for role, p in dict(saved).items()}
    final = job_dir / "outputs"
    shutil.rmtree(final, ignore_errors=True)
    tmp.rename(final)
    outputs = []
    for path in sorted(p for p in final.rglob("*") if p.is_file()):
        rel = path.relative_to(final)
        role = roles.get(rel, f"file:{rel}")
        outputs.append(StoredFile(role=role[:64], path=str(Path("outputs") / rel),
                                  size=path.stat().st_size, sha256=sha256_file(path)))
    return outputs


def run_job(job_id: str, store: Store, progress: Progress, *,
            limits: ZipLimits | None = None, names: _Names | None = None
            ) -> tuple[list[StoredFile], list[str]]:
    """Calibrate one job from its stored inputs; returns the output files written and the
    result's warnings (what could not be determined).

    Raises
    ------
    CascalibError
        Bad input or a calibration that failed (the message says why).
    ImportError
        The calibration pipeline is not installed.
    JobCancelled
        Raised by ``progress`` when the job was cancelled meanwhile.
    """
    from service.core.config import Settings

    limits = limits or zip_limits(Settings())
    with store.session() as session:
        job = st.find_job(session, job_id=job_id, owner=None)
        if job is None:
            raise JobCancelled(f"job {job_id} no longer exists")
        options = JobOptions.model_validate(job.options)
        job_dir = store.job_dir(job_id)
        names = names or _Names(job_dir)
        progress("loading", 0.0)
    store.clean_work(job_id)  # an earlier attempt may have been killed mid-way
    config = build_config(options)
    from cascalib.pipeline import (  # type: ignore[import-not-found,unused-ignore]
        calibrate,
    )

    with tempfile.TemporaryDirectory(dir=job_dir) as tmp:
        tracks, notes = _load_tracks(job, job_dir, Path(tmp), limits, names)
        result = calibrate(tracks, config, progress=progress)
    progress("saving", 1.0)
    return _save_outputs(result, job_dir), [names.clean(w) for w in notes + result.warnings()]


class _Reporter:
    """Progress callback + heartbeat thread, fenced by the attempt number."""

    def __init__(self, store: Store, job_id: str, attempt: int, period: float) -> None:
        self.store, self.job_id, self.attempt, self.period = store, job_id, attempt, period
        self.lost = threading.Event()
        self._stop = threading.Event()
        self._last = 0.0
        self._stage: str | None = None
        self._thread = threading.Thread(target=self._beat, daemon=True, name=f"hb-{job_id}")

    def _write(self, stage: str | None, fraction: float | None) -> None:
        with self.store.session() as session:
            ok = st.update_progress(session, job_id=self.job_id, attempt=self.attempt,
                                    stage=stage, progress=fraction)
        if not ok:
            self.lost.set()

    def _beat(self) -> None:
        while not self._stop.wait(self.period):
            try:
                self._write(None, None)
            except Exception:  # a database hiccup must not kill the heartbeat for good
                log.warning("heartbeat of job %s failed", self.job_id, exc_info=True)

    def __call__(self, stage: str, fraction: float) -> None:
        now = time.monotonic()
        if stage != self._stage or now - self._last > 0.5:
            self._stage, self._last = stage, now
            try:
                self._write(stage, fraction)
            except st.TRANSIENT as exc:  # progress can wait: the job goes on
                log.warning("job %s: progress not recorded, the job store is unavailable (%s)",
                            self.job_id, type(getattr(exc, "orig", exc)).__name__)
        if self.lost.is_set():
            raise JobCancelled(f"job {self.job_id} was cancelled")

    def __enter__(self) -> _Reporter:
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


def _internal_error(exc: Exception, names: _Names) -> str:
    """What a client is told of an unexpected error: its kind and message, never SQL."""
    from sqlalchemy.exc import SQLAlchemyError

    if isinstance(exc, (SQLAlchemyError, st.StoreUnavailable)):
        return "internal error: the job store was unavailable"
    return names.clean(f"internal error: {type(exc).__name__}: {exc}")[:2000]


def execute_claimed(job_id: str, attempt: int, store: Store, *, heartbeat: float,
                    limits: ZipLimits | None = None) -> str:
    """Run a job this worker has claimed and record how it ended; returns the final status.

    A cancelled job stops at its next progress report; the back-ends also kill its process at
    once (it runs in a process of its own in both).
    """
    status, error = st.FAILED, None
    outputs: list[StoredFile] = []
    warnings: list[str] = []
    names = _Names(store.job_dir(job_id))
    with _Reporter(store, job_id, attempt, heartbeat) as reporter:
        try:
            outputs, warnings = run_job(job_id, store, reporter, limits=limits, names=names)
            status = st.SUCCEEDED
        except JobCancelled:
            status = st.CANCELLED
        except CascalibError as exc:
            error = names.clean(str(exc))
        except ImportError as exc:
            error = f"the calibration pipeline is not available in this installation ({exc})"
        except Exception as exc:
            log.exception("job %s attempt %d crashed", job_id, attempt)
            error = _internal_error(exc, names)
    if status == st.CANCELLED:
        log.info("job %s attempt %d stopped: cancelled or taken over by another worker",
                 job_id, attempt)
        return status
    if not store.retrying(f"record the end of job {job_id}", lambda session: st.finish_job(
            session, job_id=job_id, attempt=attempt, status=status, error=error,
            outputs=outputs, warnings=warnings)):
        log.info("job %s attempt %d finished but was cancelled meanwhile", job_id, attempt)
        return st.CANCELLED
    log.info("job %s attempt %d: %s%s", job_id, attempt, status, f" ({error})" if error else "")
    return status
