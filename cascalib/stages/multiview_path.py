"""The second way into the cascade: when stage I cannot decide a camera, start stage V from the
multi-view start (:mod:`~cascalib.stages.multiview_start`) instead of stages II-IV.

It needs the clocks: cameras known to be synchronised, or timestamps on one clock (the cameras of
one multi-camera file, such as caliscope's CSV). Stage I's focal lengths, where it found them,
and known intrinsics are used as the start; a camera that cannot be placed is left out with its
reason, and the others go on.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace

import cv2
import numpy as np
from numpy.typing import NDArray

from cascalib.calibration import Calibration
from cascalib.camera import Camera
from cascalib.config import CalibrationConfig
from cascalib.errors import EstimationFailed, RefinementFailed
from cascalib.skeletons import CANONICAL_INDEX
from cascalib.stages.multiview_pairs import RANSAC_THRESHOLD, _candidates, _points
from cascalib.stages.multiview_start import (
    MultiviewStart,
    WorldFrame,
    multiview_start,
    reprojection_fit,
    to_world,
    world_frame,
)
from cascalib.stages.quality import CameraQuality
from cascalib.stages.reconstruct import poses_by_slot, prepare, reconstruct, views_at
from cascalib.stages.refine import refine
from cascalib.stages.refine_result import RefineResult
from cascalib.stages.track_interpolation import frame_links, interpolate_views
from cascalib.tracks import Tracks

__all__ = ["MultiviewInitial", "known_clocks", "multiview_initial", "rebase_clocks",
           "refine_or_start", "start_result", "synchronized_rates", "WORLD_NOTE"]

log = logging.getLogger(__name__)

#: Joints used as point matches: every canonical joint (the detector's confidence gates them).
MATCH_JOINTS = np.arange(26)
#: What the world frame is when no feet are seen (written into the calibration's world field).
WORLD_NOTE = "z-up from the people's heads above their shoulders, z=0 at the lowest joint seen"


@dataclass(frozen=True)
class MultiviewInitial:
    """Stage V's start from the multi-view start.

    Attributes
    ----------
    calibration : Calibration
        The placed cameras in the world (z up, metres), with the known clocks.
    left_out : dict of str to str
        Cameras that could not be placed, with the reason.
    start : MultiviewStart
        The bundle it came from (pairs, groups, reprojection errors).
    frame : WorldFrame
        How the bundle's frame became the world.
    """

    calibration: Calibration
    left_out: dict[str, str]
    start: MultiviewStart
    frame: WorldFrame


def _linear_clock(times: NDArray[np.float64]) -> tuple[float, float]:
    """(start s, frame period s) of the line through a camera's frame timestamps."""
    k = np.arange(times.size, dtype=np.float64)
    ok = np.isfinite(times)
    period, start = np.polyfit(k[ok], times[ok], 1)
    return float(start), float(period)


def synchronized_rates(tracks: Sequence[Tracks], reference: Tracks) -> list[float]:
    """Each camera's clock rate on ``reference``'s frames when they start together: the ratio
    of frame rates (1 where a rate is unknown)."""
    fps_ref = reference.frame_rate() or 1.0
    return [fps_ref / (t.frame_rate() or fps_ref) for t in tracks]


def known_clocks(tracks: Sequence[Tracks], synchronized: bool
                 ) -> list[tuple[float, float]] | None:
    """Each camera's (time offset, rate) on the first camera's clock when it is known without
    searching: synchronised cameras, or timestamps that all cameras read from one multi-camera
    file share. None otherwise."""
    ref = tracks[0]
    if synchronized:
        return [(0.0, rate) for rate in synchronized_rates(tracks, ref)]
    one_file = len({t.source for t in tracks}) == 1 and ref.source is not None
    if not one_file or any(t.timestamps is None for t in tracks):
        return None
    lines = [_linear_clock(t.timestamps) for t in tracks]  # type: ignore[arg-type]
    start_ref, period_ref = lines[0]
    return [((start - start_ref) / period_ref, period / period_ref) for start, period in lines]


def _bases(tracks: Sequence[Tracks], cfg: CalibrationConfig,
           clocks: list[tuple[float, float]]) -> list[Camera]:
    """Per camera: image size, clock, known intrinsics or a centred principal point."""
    out = []
    for t, (offset, rate) in zip(tracks, clocks, strict=True):
        size = t.require_image_size()
        cam = Camera.from_params(t.camera, size, float(np.hypot(*size)), np.eye(3), np.zeros(3),
                                 fps=t.fps, time_offset=offset, time_rate=rate)
        k = cfg.known_intrinsics.get(t.camera)
        out.append(cam if k is None else cam.with_(K=np.array(k.K), dist=np.array(k.dist)))
    return out


def _rebase_clocks(cams: list[Camera]) -> list[Camera]:
    """Clocks on the first camera's (when the first input camera was left out)."""
    clocks = rebase_clocks([(c.time_offset, c.time_rate) for c in cams])
    return [c.with_(time_offset=o, time_rate=r) for c, (o, r) in zip(cams, clocks, strict=True)]


def rebase_clocks(clocks: list[tuple[float, float]]) -> list[tuple[float, float]]:
    """Clocks (time offset, rate) read on the first one's: that one becomes (0, 1)."""
    off0, rate0 = clocks[0]
    return [((off - off0) / rate0, rate / rate0) for off, rate in clocks]


def multiview_initial(tracks: Sequence[Tracks], cfg: CalibrationConfig,
                      focal_hints: dict[str, float], clocks: list[tuple[float, float]],
                      rng: np.random.Generator) -> MultiviewInitial:
    """Place the cameras from the people's joints and put them in a metric, z-up world.

    ``focal_hints`` (px, by camera) are tried as one more start beside the field-of-view sweep;
    ``clocks`` are each camera's (time offset, rate) on the first camera's clock.

    Raises
    ------
    EstimationFailed
        When fewer than two cameras can be placed, or neither the up direction nor the scale
        can be read from the people.
    """
    bases = _bases(tracks, cfg, clocks)
    data = prepare(list(tracks), Calibration(bases))
    views = views_at(data, bases)
    hints = [focal_hints.get(t.camera, bases[i].focal if t.camera in cfg.known_intrinsics
                             else None) for i, t in enumerate(tracks)]
    start = multiview_start(views, bases, rng, joints=MATCH_JOINTS, focal_hints=hints)
    placed = [c for c in start.cameras if c is not None]
    if len(placed) < 2:
        raise EstimationFailed("the multi-view start placed fewer than two cameras: "
                               + "; ".join(f"{k}: {v}" for k, v in start.reasons.items()),
                               field="multiview")
    try:
        frame = world_frame(start.points, MATCH_JOINTS, placed, height=cfg.height,
                            ankle_height=cfg.refine.ankle_height)
    except ValueError as exc:
        raise EstimationFailed(f"multi-view start: {exc}", field="multiview") from None
    world = "z-up, ground z=0" if frame.ground else WORLD_NOTE
    cams = _rebase_clocks([to_world(c, frame) for c in placed])
    log.info("multi-view start: %d of %d cameras placed (start fov %.0f deg), up from %s",
             len(cams), len(tracks), start.fov_start_deg, frame.up_from)
    return MultiviewInitial(Calibration(cams, world=world), dict(start.reasons), start, frame)


#: Widest ground gate (m) of stage V's association in the multi-view path.
WIDE_GATE_M = 3.0
#: Stage V's rig is kept unless it explains the start's matched joints this much worse.
START_TIE = 0.05
#: Reprojection error (px) under which an observation counts as an inlier in the start's report.
START_INLIER_PX = 15.0


def _start_quality(name: str, errors: NDArray[np.float64], reason: str) -> CameraQuality:
    e = errors[np.isfinite(errors)]
    return CameraQuality(
        camera=name, n_observations=int(e.size),
        reprojection_median_px=float(np.median(e)) if e.size else float("nan"),
        reprojection_p90_px=float(np.percentile(e, 90)) if e.size else float("nan"),
        inlier_rate=float(np.mean(e < START_INLIER_PX)) if e.size else 0.0,
        sigma_focal_px=float("nan"), sigma_focal_rel=float("nan"),
        sigma_rotation_deg=float("nan"), sigma_position_m=float("nan"), time_offset=0.0,
        verdict="suspicious", reason=reason)


def start_result(tracks: Sequence[Tracks], initial: MultiviewInitial, cfg: CalibrationConfig,
                 why: str) -> RefineResult:
    """The multi-view start as the final rig, when stage V could not refine it: every frame
    triangulated with it, each camera "suspicious" with ``why`` (no uncertainty is known)."""
    calib = initial.calibration
    data = prepare(list(tracks), calib)
    assoc, points, err = reconstruct(data, list(calib.cameras), cfg.refine, cfg.height)
    poses, ids, resid = poses_by_slot(assoc, points, data.times, err)
    reason = f"multi-view start only (bundle adjustment of the joints, no uncertainty): {why}"
    quality = {c.name: replace(_start_quality(c.name, err[:, k], reason),
                               time_offset=c.time_offset)
               for k, c in enumerate(calib.cameras)}
    calib = Calibration(list(calib.cameras), calib.reference_camera,
                        {k: q.to_dict() for k, q in quality.items()}, calib.world)
    return RefineResult(calib, poses, data.times, ids, quality, assoc, residuals=resid)


def association_gate(initial: MultiviewInitial, smallest: float) -> float:
    """Stage V's ground gate (m) for this scene: half the distance at which two people were
    ever seen at once (their hips), at least ``smallest``, at most :data:`WIDE_GATE_M`. Stage V
    sizes its gates for crowds; one person balancing on one leg moves the ground point of a
    raised ankle by a metre between cameras."""
    hips = (initial.start.points[:, MATCH_JOINTS == CANONICAL_INDEX["mid_hip"]][:, 0]
            @ initial.frame.R.T * initial.frame.scale)[:, :2]
    times = initial.start.groups.times
    gaps = [np.linalg.norm(hips[a] - hips[b]) for a in range(len(times))
            for b in range(a + 1, len(times)) if times[a] == times[b]]
    gaps = [g for g in gaps if np.isfinite(g)]
    if not gaps:
        return WIDE_GATE_M
    return float(np.clip(0.5 * np.percentile(gaps, 10), smallest, WIDE_GATE_M))


def refine_or_start(tracks: Sequence[Tracks], initial: MultiviewInitial, cfg: CalibrationConfig,
                    rng: np.random.Generator, progress: Callable[[float], None]) -> RefineResult:
    """Stage V from the multi-view start; the start itself where stage V fails, leaves a
    camera out, or explains the start's matched joints worse (stage V's body model assumes
    people standing on the ground: a seated or floating figure it bends)."""
    update: dict[str, object] = {
        "gate_m": association_gate(initial, cfg.refine.gate_m),
        "gate_refined_m": association_gate(initial, cfg.refine.gate_refined_m)}
    if cfg.synchronized:
        update["refine_time"] = False
    rcfg = cfg.refine.model_copy(update=update)
    try:
        refined = refine(list(tracks), initial.calibration, rcfg, height=cfg.height, rng=rng,
                         progress=progress, fixed_intrinsics=tuple(cfg.known_intrinsics))
    except (EstimationFailed, RefinementFailed) as exc:
        log.warning("stage V could not refine the multi-view start: %s", exc)
        return start_result(tracks, initial, cfg, f"stage V failed: {exc}")
    failed = [n for n, q in refined.quality.items() if q.verdict == "failed"]
    if failed:
        log.warning("stage V left %s out: the multi-view start is kept", ", ".join(failed))
        return start_result(tracks, initial, cfg,
                            f"stage V could not place {', '.join(failed)}: "
                            + refined.quality[failed[0]].reason)
    placed = [c for c in initial.start.cameras if c is not None]
    uv = initial.start.uv[[i for i, c in enumerate(initial.start.cameras) if c is not None]]
    before = reprojection_fit(list(initial.calibration.cameras), uv)
    after = reprojection_fit([refined.calibration[c.name] for c in placed], uv)
    log.info("matched joints reproject at %.2f px from the start, %.2f px from stage V",
             before, after)
    if after > before * (1.0 + START_TIE):
        return start_result(tracks, initial, cfg, f"stage V explained the matched joints worse "
                            f"({after:.2f} px against {before:.2f} px)")
    return refined


#: Reference instants the clock scan compares (evenly spread).
SCAN_INSTANTS = 240
#: Coarse step of the clock scan as a fraction of a second (a walker moves 0.2 m in it).
SCAN_STEP_S = 0.15
#: Least share of the possible person matches one two-view geometry must explain at the scan's
#: best offset.
SCAN_MIN_SUPPORT = 0.5
#: A person pair is explained when this share of its joints is within the geometry's threshold.
SCAN_GROUP_SHARE = 0.7
#: Least share of the reference recording two clocks must overlap by to be scanned.
SCAN_MIN_OVERLAP = 0.25


def _epipolar_support(va: NDArray[np.float64], vb: NDArray[np.float64], diagonal: float,
                      rng: np.random.Generator) -> tuple[int, int]:
    """Person matches whose joints one fundamental matrix explains (most joints within its
    threshold; at most the fewer persons of the two views per instant), and how many were
    possible: many only where the two clocks agree and overlap."""
    cand = _candidates(va, vb, rng)
    if cand is None or cand.t.size < SCAN_INSTANTS * SCAN_MIN_OVERLAP:
        return 0, 0
    xa, xb, g = _points(va, vb, cand)
    F, mask = cv2.findFundamentalMat(xa, xb, cv2.USAC_MAGSAC, RANSAC_THRESHOLD * diagonal,
                                     0.99, 2000)
    if F is None or mask is None:
        return 0, 0
    share = np.bincount(g, mask.ravel().astype(np.float64), cand.t.size) / np.bincount(
        g, minlength=cand.t.size).clip(1)
    instants, at = np.unique(cand.t, return_inverse=True)
    fits = np.bincount(at, share >= SCAN_GROUP_SHARE, instants.size)
    possible = np.array([min(np.unique(cand.pa[at == k]).size, np.unique(cand.pb[at == k]).size)
                         for k in range(instants.size)])
    return int(np.minimum(fits, possible).sum()), int(possible.sum())


def scan_clock(reference: Tracks, ref_clock: tuple[float, float], other: Tracks,
               rng: np.random.Generator) -> tuple[float, float] | None:
    """Clock (offset, rate) of ``other`` on the clock ``reference`` is read on, from the
    people's joints alone: the offset at which one two-view geometry explains most of their
    matches (coarse steps of :data:`SCAN_STEP_S`, then single frames); the rate is the frame
    rates' ratio. For a camera stage I cannot estimate at all, when the clocks are unknown;
    None where no offset gets :data:`SCAN_MIN_SUPPORT` of the matches explained."""
    fps_ref = reference.fps or 1.0 / float(np.nanmedian(np.diff(reference.frame_times())))
    fps = other.fps or 1.0 / float(np.nanmedian(np.diff(other.frame_times())))
    rate = fps_ref / fps
    kr, ko = reference.canonical(), other.canonical()
    lr, lo = frame_links(kr, reference.track_ids), frame_links(ko, other.track_ids)
    times = np.linspace(0, kr.shape[0] - 1, SCAN_INSTANTS)
    va = interpolate_views(kr, lr, (times - ref_clock[0]) / ref_clock[1])
    diagonal = float(max(np.hypot(*reference.require_image_size()),
                         np.hypot(*other.require_image_size())))
    margin = SCAN_MIN_OVERLAP * kr.shape[0]

    def support(offset: float) -> tuple[int, int]:
        vb = interpolate_views(ko, lo, (times - offset) / rate)
        return _epipolar_support(va, vb, diagonal, rng)

    step = max(1.0, round(SCAN_STEP_S * fps_ref))
    coarse = np.arange(-ko.shape[0] * rate + margin, kr.shape[0] - margin, step)
    best = float(max(coarse, key=lambda o: support(o)[0]))
    scored = [(support(o), float(o)) for o in np.arange(best - step, best + step + 1.0)]
    (fits, possible), offset = max(scored, key=lambda r: r[0][0])
    return (offset, rate) if fits >= SCAN_MIN_SUPPORT * max(1, possible) else None
