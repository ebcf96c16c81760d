"""The whole cascade: tracks -> single view -> sync and ground alignment -> bundle adjustment.

:func:`calibrate` calls one typed function per stage, in cascade order, and keeps every stage's
result on the returned :class:`CalibrationResult` for inspection. Expected failures are
:class:`~cascalib.errors.EstimationFailed` / :class:`~cascalib.errors.RefinementFailed` with a
message that says which camera and why; progress is reported through an injected callback
(``progress(stage, fraction)``), the library owns no progress bar.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np

from cascalib import calibration_formats
from cascalib.calibration import Calibration
from cascalib.camera import Camera
from cascalib.config import CalibrationConfig
from cascalib.errors import EstimationFailed, InputError
from cascalib.poses import Poses3D
from cascalib.stages.align import AlignmentResult, align_cameras
from cascalib.stages.joint_clocks import checked_clocks, pair_starts
from cascalib.stages.multiview_path import (
    MultiviewInitial,
    known_clocks,
    multiview_initial,
    rebase_clocks,
    refine_or_start,
    scan_clock,
    synchronized_rates,
)
from cascalib.stages.multiview_start import focal_range
from cascalib.stages.refine import RefineResult, refine
from cascalib.stages.single_view import calibrate_single_view
from cascalib.stages.single_view_result import SingleViewResult
from cascalib.tracks import Tracks

__all__ = ["calibrate", "CalibrationResult", "STAGES", "Progress"]

log = logging.getLogger(__name__)

Progress = Callable[[str, float], None]

#: Stage names reported to ``progress``, in order, with their rough share of the run time.
STAGES: tuple[tuple[str, float], ...] = (
    ("single_view", 0.15), ("sync", 0.25), ("refine", 0.55), ("triangulate", 0.05),
)


@dataclass(eq=False)
class CalibrationResult:
    """Everything a calibration run produced.

    Attributes
    ----------
    calibration : Calibration
        The final cameras (world z up, ground z = 0, metres) with time offsets and rates, and
        the quality report in ``calibration.quality``.
    poses : Poses3D
        3D poses of every reference frame where a person is seen by two cameras.
    single_view : dict of str to SingleViewResult
        Stage I per camera.
    alignment : AlignmentResult or MultiviewInitial
        Stages II-IV (sync cost curves, ground trajectories, pairwise results), or the
        multi-view start where stage I could not decide every camera.
    refinement : RefineResult
        Stage V (solver statistics, association, per-camera quality).
    config : CalibrationConfig
        The configuration used.
    timings : dict of str to float
        Seconds spent per stage.
    left_out : dict of str to str
        Cameras that could not be placed, with the reason (also in ``calibration.quality``).
    stage_i_advice : dict of str to str
        Why stage I could not decide a camera (the multi-view start replaced it).
    save_timings : dict of str to float
        Seconds :meth:`save` spent on the calibration files, the poses and the report.
    """

    calibration: Calibration
    poses: Poses3D
    single_view: dict[str, SingleViewResult]
    alignment: AlignmentResult | MultiviewInitial
    refinement: RefineResult
    config: CalibrationConfig
    tracks: list[Tracks] = field(repr=False, default_factory=list)
    timings: dict[str, float] = field(default_factory=dict)
    left_out: dict[str, str] = field(default_factory=dict)
    stage_i_advice: dict[str, str] = field(default_factory=dict)
    save_timings: dict[str, float] = field(default_factory=dict)

    @property
    def accepted(self) -> bool:
        """True when no camera's verdict is ``failed``."""
        return all(q.verdict != "failed" for q in self.refinement.quality.values())

    def warnings(self) -> list[str]:
        """What the user should know about this result that the verdicts do not say."""
        out = [f"camera {n} left out: {why}" for n, why in self.left_out.items()]
        if self.stage_i_advice:
            out.append("stage I could not decide " + ", ".join(self.stage_i_advice)
                       + ": the cameras were started from the people's joints seen together")
        if "ground z=0" not in self.calibration.world:
            out.append(f"no feet seen by two cameras: the world is {self.calibration.world}")
        return out

    def summary(self) -> dict[str, Any]:
        """Machine-readable summary (the CLI's ``--json``)."""
        cams = []
        for cam in self.calibration:
            q = self.refinement.quality.get(cam.name)
            cams.append({
                "name": cam.name, "focal_px": cam.focal,
                "principal_point": cam.principal_point.tolist(),
                "center_m": cam.center.tolist(), "time_offset": cam.time_offset,
                "time_rate": cam.time_rate,
                "time_offset_sd_frames": (q.sigma_time_offset_frames
                                          if q and np.isfinite(q.sigma_time_offset_frames)
                                          else None),
                "verdict": q.verdict if q else None, "reason": q.reason if q else None,
                "reprojection_median_px": q.reprojection_median_px if q else None,
            })
        return {"ok": self.accepted, "reference_camera": self.calibration.reference_camera,
                "cameras": cams, "left_out": self.left_out, "warnings": self.warnings(),
                "timings_s": self.timings, "save_timings_s": self.save_timings}

    def save(self, outdir: str | Path, formats: Sequence[str] = ("json",),
             report: bool = True) -> dict[str, Path]:
        """Write ``calibration.json`` (+ the other requested calibration formats), the 3D poses
        and ``report.html`` with its PNG plots into ``outdir``.

        Returns
        -------
        dict of str to Path
            What was written, by kind.
        """
        from cascalib.formats import save_calibration

        outdir = Path(outdir)
        outdir.mkdir(parents=True, exist_ok=True)
        written: dict[str, Path] = {}
        t0 = time.perf_counter()
        for fmt in dict.fromkeys(["json", *formats]):
            paths = save_calibration(self.calibration, _calibration_path(outdir, fmt), fmt)
            written[f"calibration:{fmt}"] = Path(paths[0])
        self.save_timings["calibration"] = (t1 := time.perf_counter()) - t0
        for p in self.poses.save(outdir / "poses"):
            written[f"poses:{p.name}"] = p
        self.save_timings["poses"] = (t0 := time.perf_counter()) - t1
        if report:
            from cascalib.report import write_report

            written["report"] = write_report(self, outdir)
            self.save_timings["report"] = time.perf_counter() - t0
        return written


def _calibration_path(outdir: Path, fmt: str) -> Path:
    known = calibration_formats.FORMATS.get(fmt)
    if known is None or not known.writable:
        return outdir / f"calibration.{fmt}"  # save_calibration names the problem
    return outdir / known.output_name


def _check_inputs(tracks: Sequence[Tracks], cfg: CalibrationConfig) -> None:
    if len(tracks) < 2:
        raise InputError(f"need at least two cameras, got {len(tracks)}", field="cameras")
    names = [t.camera for t in tracks]
    for t in tracks:
        t.require_image_size()
        if t.fps is None and t.timestamps is None:
            raise InputError("frame rate unknown: give --fps (or fps in the options)",
                             file=t.source, camera=t.camera, field="fps")
    if cfg.reference_camera is not None and cfg.reference_camera not in names:
        raise InputError(f"reference camera {cfg.reference_camera!r} is not one of {names}",
                         field="reference_camera")
    unknown = sorted(set(cfg.known_intrinsics) - set(names))
    if unknown:
        raise InputError(f"known intrinsics given for unknown cameras {unknown}",
                         field="known_intrinsics")


@dataclass(frozen=True)
class _StageI:
    """Stage I over all cameras: the cameras it decided, why it could not decide the others,
    and its best (untrustworthy) estimate of those where it had one: advice, not a verdict."""

    results: dict[str, SingleViewResult]
    failures: dict[str, str]
    advice: dict[str, SingleViewResult]


def _single_view(tracks: Sequence[Tracks], cfg: CalibrationConfig, rng: np.random.Generator,
                 progress: Progress) -> _StageI:
    out = _StageI({}, {}, {})
    for i, t in enumerate(tracks):
        try:
            k = cfg.known_intrinsics.get(t.camera)
            known = None if k is None else (np.array(k.K), np.array(k.dist))
            out.results[t.camera] = calibrate_single_view(t, cfg.single_view, height=cfg.height,
                                                          rng=rng, known_intrinsics=known)
            log.info("stage I %s", out.results[t.camera].summary())
        except EstimationFailed as exc:
            out.failures[t.camera] = str(exc)
            partial = getattr(exc, "partial", None)
            if isinstance(partial, SingleViewResult):
                out.advice[t.camera] = partial
            log.info("stage I %s: %s", t.camera, exc)
        progress("single_view", (i + 1) / len(tracks))
    return out


def _stage_i_failed(failures: dict[str, str], n: int, why: str) -> EstimationFailed:
    """Stage I's refusals, when nothing can stand in for them."""
    return EstimationFailed(f"single-view calibration failed for {len(failures)} of {n} cameras "
                            f"and {why}:\n  " + "\n  ".join(failures.values()),
                            field="single_view")


def _apply_known(cameras: list[Camera], cfg: CalibrationConfig) -> list[Camera]:
    out = []
    for cam in cameras:
        k = cfg.known_intrinsics.get(cam.name)
        out.append(cam if k is None else cam.with_(K=np.array(k.K), dist=np.array(k.dist)))
    return out


def _synchronized(calib: Calibration, tracks: Sequence[Tracks]) -> Calibration:
    """Known synchronisation: offset 0, rate = reference fps / camera fps."""
    ref = next(t for t in tracks if t.camera == calib.reference_camera)
    cams = [c.with_(time_offset=0.0, time_rate=rate)
            for c, rate in zip(calib.cameras, synchronized_rates(tracks, ref), strict=True)]
    return Calibration(cams, calib.reference_camera, dict(calib.quality), calib.world)


def plane_camera(result: SingleViewResult) -> Camera:
    """Stage I's camera in its plane frame, its focal length kept within the field-of-view
    prior (an undecided camera's estimate can be anywhere: 29686 px on a 1088 px image)."""
    cam = result.to_camera()
    lo, hi = focal_range(cam.image_size)
    f = float(np.clip(cam.focal, lo, hi))
    K = cam.K.copy()
    K[0, 0] *= f / cam.focal
    K[1, 1] *= f / cam.focal
    return cam.with_(K=K)


def _stages_ii_iv(tracks: Sequence[Tracks], cfg: CalibrationConfig, stage_i: _StageI,
                  rng: np.random.Generator, progress: Callable[[float], None]) -> AlignmentResult:
    """Stages II-IV from stage I's cameras, its advice standing in for the undecided ones."""
    plane_cams = _apply_known([stage_i.results[t.camera].to_camera() if t.camera in stage_i.results
                               else plane_camera(stage_i.advice[t.camera]) for t in tracks], cfg)
    return align_cameras(list(tracks), plane_cams, cfg.align, reference=0, rng=rng,
                         progress=progress, height=cfg.height,
                         fixed_intrinsics=tuple(cfg.known_intrinsics))


def _start(tracks: Sequence[Tracks], cfg: CalibrationConfig, stage_i: _StageI,
           rng: np.random.Generator, progress: Callable[[float], None]
           ) -> AlignmentResult | MultiviewInitial:
    """Stage V's start: stages II-IV where stage I decided every camera; else, or where stages
    II-IV cannot tie the cameras together (nobody walks), the multi-view start, on the known
    clocks or on the clocks of stages II-IV run from stage I's advice."""
    hints = {n: r.to_camera().focal for n, r in stage_i.results.items()}
    clocks = known_clocks(tracks, cfg.synchronized)
    if not stage_i.failures:
        try:
            aligned = _stages_ii_iv(tracks, cfg, stage_i, rng, progress)
        except EstimationFailed as exc:
            if clocks is None:
                raise
            log.warning("stages II-IV: %s; the cameras are placed from the people's joints "
                        "instead", exc)
            return multiview_initial(tracks, cfg, hints, clocks, rng)
        if clocks is not None:
            return aligned
        return _joint_checked(tracks, cfg, aligned, hints, rng)
    if clocks is not None:
        return multiview_initial(tracks, cfg, hints, clocks, rng)
    found, hints, unclocked = _advised_clocks(tracks, cfg, stage_i, rng, progress)
    clocked = [t for t in tracks if t.camera in found]
    if len(clocked) < 2:
        raise _stage_i_failed(stage_i.failures, len(tracks), "the clocks are unknown (give "
                              "--synchronized, or timestamps on one clock, so that the "
                              "multi-view start can replace it)")
    start = multiview_initial(clocked, cfg, hints,
                              rebase_clocks([found[t.camera] for t in clocked]), rng)
    start.left_out.update(unclocked)
    return start


def _joint_clocks(tracks: Sequence[Tracks], aligned: AlignmentResult, cfg: CalibrationConfig
                  ) -> tuple[list[tuple[float, float]], list[str]]:
    """Stages II-IV's clocks, with those the people's joints put elsewhere replaced
    (:func:`~cascalib.stages.joint_clocks.checked_clocks`), and the cameras so moved. The
    check draws from its own random stream: where it moves nothing, the run is as without it."""
    clocks = [(c.time_offset, c.time_rate) for c in aligned.calibration]
    moved = checked_clocks(tracks, clocks, aligned.flags, aligned.confidence,
                           pair_starts(aligned.pairs, [t.camera for t in tracks]),
                           np.random.default_rng(cfg.seed))
    return [(moved.get(t.camera, o), r) for t, (o, r) in zip(tracks, clocks, strict=True)], \
        list(moved)


def _joint_checked(tracks: Sequence[Tracks], cfg: CalibrationConfig, aligned: AlignmentResult,
                   hints: dict[str, float], rng: np.random.Generator
                   ) -> AlignmentResult | MultiviewInitial:
    """Stages II-IV's result, or the multi-view start on the joints' clocks where the joints
    put a camera's clock elsewhere: its ground alignment was made at the wrong one."""
    clocks, moved = _joint_clocks(tracks, aligned, cfg)
    if not moved:
        return aligned
    log.warning("the people's joints put the clock of %s away from stage IV's: the cameras "
                "are placed from the joints on their clocks", ", ".join(moved))
    try:
        return multiview_initial(tracks, cfg, hints, rebase_clocks(clocks), rng)
    except EstimationFailed as exc:
        log.warning("multi-view start: %s; stages II-IV's result is kept", exc)
        return aligned


def _advised_clocks(tracks: Sequence[Tracks], cfg: CalibrationConfig, stage_i: _StageI,
                    rng: np.random.Generator, progress: Callable[[float], None]
                    ) -> tuple[dict[str, tuple[float, float]], dict[str, float], dict[str, str]]:
    """Clocks and focal lengths by camera from stages II-IV run on the cameras stage I
    estimated, decided or not; a camera it could not estimate at all gets its clock from the
    people's joints against the first of those, or a reason why not."""
    with_plane = [t for t in tracks if t.camera not in stage_i.failures
                  or t.camera in stage_i.advice]
    if len(with_plane) < 2:
        return {}, {}, {}
    rough = _stages_ii_iv(with_plane, cfg, stage_i, rng, progress)
    found = dict(zip([c.name for c in rough.calibration], _joint_clocks(with_plane, rough,
                                                                        cfg)[0], strict=True))
    unclocked = {}
    for t in tracks:
        if t.camera in found:
            continue
        clock = scan_clock(with_plane[0], (0.0, 1.0), t, rng)
        if clock is None:
            unclocked[t.camera] = (f"no clock: {stage_i.failures[t.camera]}; and its people's "
                                   f"joints fit no two-view geometry with {with_plane[0].camera}"
                                   " at any time offset")
        else:
            found[t.camera] = clock
            log.info("clock of %s from the people's joints: offset %.1f frames", t.camera,
                     clock[0])
    return found, {c.name: c.focal for c in rough.calibration}, unclocked


def calibrate(tracks: Sequence[Tracks], config: CalibrationConfig | None = None,
              progress: Progress | None = None) -> CalibrationResult:
    """Calibrate and synchronise a multi-camera rig from the people it sees.

    Parameters
    ----------
    tracks : sequence of Tracks
        One per camera, with image size and frame rate (or timestamps) known.
    config : CalibrationConfig, optional
        Every parameter; defaults throughout.
    progress : callable, optional
        ``progress(stage, fraction)`` with ``stage`` one of :data:`STAGES`' names.

    Returns
    -------
    CalibrationResult

    Raises
    ------
    InputError
        Unusable input (fewer than two cameras, unknown image size or frame rate ...).
    EstimationFailed, RefinementFailed
        A stage could not produce a trustworthy result; the message names the camera and why.
    """
    cfg = config or CalibrationConfig()
    report = progress or (lambda stage, fraction: None)
    tracks = list(tracks)
    if cfg.reference_camera is not None:  # the reference camera goes first
        tracks.sort(key=lambda t: t.camera != cfg.reference_camera)
    _check_inputs(tracks, cfg)
    rng = np.random.default_rng(cfg.seed)
    timings: dict[str, float] = {}

    t0 = time.perf_counter()
    stage_i = _single_view(tracks, cfg, rng, report)
    timings["single_view"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    report("sync", 0.0)
    aligned = _start(tracks, cfg, stage_i, rng, lambda f: report("sync", f))
    left_out: dict[str, str] = {}
    if isinstance(aligned, MultiviewInitial):
        left_out = aligned.left_out
        tracks = [t for t in tracks if t.camera in aligned.calibration.names]
        initial = aligned.calibration
    else:
        initial = _synchronized(aligned.calibration, tracks) if cfg.synchronized else \
            aligned.calibration
    report("sync", 1.0)
    timings["sync"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    report("refine", 0.0)
    if isinstance(aligned, MultiviewInitial):
        refined = refine_or_start(tracks, aligned, cfg, rng, lambda f: report("refine", f))
    else:
        rcfg = (cfg.refine.model_copy(update={"refine_time": False}) if cfg.synchronized
                else cfg.refine)
        refined = refine(tracks, initial, rcfg, height=cfg.height, rng=rng,
                         progress=lambda f: report("refine", f),
                         fixed_intrinsics=tuple(cfg.known_intrinsics),
                         rate_measured=aligned.rate_measured)
    report("refine", 1.0)
    timings["refine"] = time.perf_counter() - t0

    t0 = time.perf_counter()
    fps_ref = tracks[0].frame_rate() or 1.0
    poses = Poses3D(refined.poses3d, refined.times, fps_ref, refined.track_ids,
                    refined.residuals)
    report("triangulate", 1.0)
    timings["triangulate"] = time.perf_counter() - t0
    calibration = refined.calibration
    if left_out:
        calibration.quality["left_out"] = dict(left_out)
    return CalibrationResult(calibration, poses, stage_i.results, aligned, refined, cfg, tracks,
                             timings, left_out=left_out, stage_i_advice=stage_i.failures)
