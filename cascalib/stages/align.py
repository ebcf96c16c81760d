"""Stages II-IV: put all cameras on one ground plane and one clock.

``align_cameras`` ties the cascade together:

1. ground trajectories per camera (:mod:`~cascalib.stages.ground`);
2. for every camera pair: offset candidates from the joint offset/rotation vote
   (:mod:`~cascalib.stages.sync`), each verified by trimmed ICP (:mod:`~cascalib.stages.icp`,
   with the paper's brute-force rotation search of :mod:`~cascalib.stages.rotation` as fallback
   initialisation); the best is refined to a sub-frame offset, a rate ratio and a 2D similarity.
   An ambiguous pair gets more candidates from an ICP scan of all offsets, and the epipolar
   geometry of the people's joints decides among its best (:mod:`~cascalib.stages.ambiguous_pairs`);
3. globally consistent clocks from all pairs (robust L1 over the pair graph, so that one wrong
   pair is outvoted by the cycles through the other cameras) and globally consistent ground
   alignments (robust least squares over every accepted pair's matched points;
   :mod:`~cascalib.stages.align_global`);
4. the camera vote (:mod:`~cascalib.stages.consensus`): each doubtful camera (a rejected pair,
   only ambiguous pairs, or not placed) moves to the clock and heading that the ICP evidence
   summed over all of its pairs supports best, trying every candidate of every pair; its pairs
   are refitted there and step 3 runs again. Periodic walking needs it: the lap-off peak is a
   property of the scene, so two pairs of a camera can agree on it and outvote the right one;
5. each camera moved from its own plane frame into the reference camera's.
"""

from __future__ import annotations

import logging
import threading
from collections.abc import Callable, Sequence
from concurrent.futures import Future, ThreadPoolExecutor
from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from cascalib.blas import one_blas_thread
from cascalib.calibration import Calibration
from cascalib.camera import Camera
from cascalib.errors import EstimationFailed, InputError
from cascalib.stages.align_config import AlignConfig
from cascalib.stages.align_global import (
    PairAlignment,
    doubtful_cameras,
    global_alignment,
)
from cascalib.stages.ambiguous_pairs import PairJoints, epipolar_choice, scan_candidates
from cascalib.stages.consensus import CandidateEdge, vote_cameras
from cascalib.stages.epipolar_rig import RigRefinement, refine_rig
from cascalib.stages.epipolar_sync import EpipolarClocks, epipolar_clocks
from cascalib.stages.ground import GroundTracks, ground_trajectories
from cascalib.stages.icp import (
    IcpResult,
    Lanes,
    Similarity2D,
    SyncFit,
    dense_lanes,
    refine_sync,
)
from cascalib.stages.pair_evidence import (
    ByCamera,
    ambiguity_of,
    candidate_score,
    evidence,
    evidence_sigma,
    pair_icp,
    place_camera,
    plausible,
)
from cascalib.stages.reconstruct import SessionData, prepare
from cascalib.stages.rotation import rotation_search
from cascalib.stages.sync import GridTrack, resample_tracks, search_offsets
from cascalib.tracks import Tracks
from cascalib.workers import WorkerPool

__all__ = ["AlignConfig", "PairAlignment", "AlignmentResult", "align_cameras"]

logger = logging.getLogger(__name__)

#: A camera's clock rate within this of the declared frame rates' ratio is that ratio: the
#: pairs whose fits fell back to it give the global clock solve log rates of 1e-12.
RATE_ROUNDING = 1e-9


@dataclass(frozen=True)
class AlignmentResult:
    """Output of :func:`align_cameras`.

    Parameters
    ----------
    calibration : Calibration
        Cameras in the reference camera's plane frame (z up, ground z = 0, metres from the
        height prior) with ``time_offset`` / ``time_rate`` per the time convention.
    confidence : dict of str to float
        Per camera, in [0, 1]: 1 - ambiguity of its best accepted pair, times the share of its
        pairs that agree with the global clocks (reference: 1).
    flags : dict of str to list of str
        Per camera: ``"ambiguous"`` (runner-up offset nearly as good), ``"inconsistent"``
        (most of its pairs disagree with the global clocks), ``"not_aligned"``,
        ``"rejected_pair:<other>"``.
    pairs : list of PairAlignment
        Pairwise results incl. the sync cost curves (for plots).
    ground : list of GroundTracks
        Ground trajectories per camera in its own plane frame.
    transforms : list of Similarity2D
        Per camera, own plane frame -> reference plane frame.
    epipolar : EpipolarClocks, optional
        The sub-frame clock correction (``AlignConfig.epipolar_sync``), its pairwise cost
        curves included; ``calibration`` carries its clocks.
    rig : RigRefinement, optional
        The last step, the rig from the epipolar geometry (``AlignConfig.epipolar_rig``);
        ``calibration`` carries its cameras when it was kept.
    rate_measured : dict of str to bool
        Per camera: its frame-rate ratio was measured (pair fits moved it off the declared frame
        rates' ratio) or not (False, the reference too): stage V's clock search holds a measured
        rate loosely, a declared one close but lets it go to a mislabelled rate (29.97 fps
        declared as 30) where its data ask.
    """

    calibration: Calibration
    confidence: dict[str, float]
    flags: dict[str, list[str]]
    pairs: list[PairAlignment]
    ground: list[GroundTracks]
    transforms: list[Similarity2D]
    diagnostics: dict[str, object] = field(default_factory=dict)
    epipolar: EpipolarClocks | None = None
    rig: RigRefinement | None = None
    rate_measured: dict[str, bool] = field(default_factory=dict)


def _fps(tracks: Tracks, camera: Camera) -> float | None:
    rate = tracks.frame_rate()
    return rate if rate is not None else camera.fps


def _check_inputs(tracks: list[Tracks], cams: list[Camera], reference: str | int | None) -> int:
    if len(tracks) != len(cams):
        raise InputError(f"{len(tracks)} tracks for {len(cams)} plane cameras",
                         field="plane_cameras")
    if len(tracks) < 2:
        raise InputError("alignment needs at least two cameras", field="tracks")
    for t, c in zip(tracks, cams, strict=True):
        if t.camera != c.name:
            raise InputError(f"tracks of camera {t.camera!r} paired with plane camera "
                             f"{c.name!r}: give them in the same order", camera=t.camera)
    if reference is None:
        return 0
    if isinstance(reference, int):
        if not 0 <= reference < len(cams):
            raise InputError(f"reference index {reference} out of range", field="reference")
        return reference
    names = [c.name for c in cams]
    if reference not in names:
        raise InputError(f"reference camera {reference!r} is not one of {names}",
                         field="reference")
    return names.index(reference)


def _ground(tracks: Tracks, cam: Camera, fps: float | None, cfg: AlignConfig) -> GroundTracks:
    rate = fps or 30.0
    return ground_trajectories(
        tracks, cam, foot_height=cfg.foot_height, max_range=cfg.max_range,
        min_confidence=cfg.min_confidence, dbscan_eps=cfg.dbscan_eps,
        dbscan_min_samples=cfg.dbscan_min_samples,
        dbscan_min_cluster_fraction=cfg.dbscan_min_cluster_fraction,
        max_step=cfg.max_speed / rate, max_gap=max(1, int(round(cfg.max_gap_seconds * rate))),
        min_length=cfg.min_tracklet_frames, jump_threshold=cfg.jump_threshold,
        link_speed=cfg.link_speed / rate,
        stance_speed=cfg.stance_speed / rate if cfg.stance_speed > 0 else None,
        stance_smooth=cfg.stance_smooth_seconds * rate)


@dataclass(frozen=True)
class _CameraGround:
    """One camera's ground trajectories on the reference clock: as found, on the coarse grid
    of the offset search, and on the fine grid of ICP with its lanes."""

    ground: GroundTracks
    coarse: GridTrack
    fine: GridTrack
    lanes: Lanes


def _camera_ground(tracks: Tracks, cam: Camera, fps: float | None, rho: float, fps_ref: float,
                   cfg: AlignConfig) -> _CameraGround:
    ground = _ground(tracks, cam, fps, cfg)
    step = max(1, int(round(fps_ref / cfg.coarse_rate)))
    fine = resample_tracks(ground, rho, 1.0, smooth=cfg.smooth_seconds * (fps or fps_ref))
    return _CameraGround(ground, resample_tracks(ground, rho, float(step)), fine,
                         dense_lanes(fine))


@dataclass
class _AlignInputs:
    """What the tasks of :func:`align_cameras` read (worker processes inherit it)."""

    tracks: list[Tracks]
    cameras: list[Camera]  # plane frames
    fps: list[float | None]
    rho: list[float]
    fps_ref: float
    reference: int
    height: float
    noise: list[tuple[NDArray[np.float64], float]]
    pairs: list[tuple[int, int]]
    seeds: NDArray[np.int64]  # one stream per pair: the same result in any order or worker
    cfg: AlignConfig
    # the canonical tracks, made at most once per process: by the caller for the epipolar
    # clock step, and by a forked worker (forked before the caller made them) for its first
    # ambiguous pair; worker threads share the caller's
    _session: list[SessionData] = field(default_factory=list)
    _lock: threading.Lock = field(default_factory=threading.Lock)

    def session(self) -> SessionData:
        """The canonical tracks and frame links of the epipolar steps."""
        with self._lock:
            if not self._session:
                self._session.append(prepare(self.tracks, Calibration(
                    self.cameras, reference_camera=self.cameras[self.reference].name)))
            return self._session[0]

    def joints(self) -> PairJoints:
        d = self.session()
        return PairJoints(d.keypoints, d.links, self.cameras, self.rho, self.height,
                          self.fps_ref)


def _ground_task(s: _AlignInputs, c: int) -> _CameraGround:
    return _camera_ground(s.tracks[c], s.cameras[c], s.fps[c], s.rho[c], s.fps_ref, s.cfg)


def _pair_task(s: _AlignInputs, k: int, first: _CameraGround, second: _CameraGround
               ) -> PairAlignment:
    """Camera pair ``k`` from its two cameras' ground trajectories (the arguments: in worker
    processes only these 2 of the cameras cross, 1.7 MB each on 3000 frames x 5 persons)."""
    i, j = s.pairs[k]
    ready = {i: first, j: second}
    return _align_pair(i, j, {c: g.coarse for c, g in ready.items()},
                       {c: g.fine for c, g in ready.items()},
                       {c: g.lanes for c, g in ready.items()}, s.noise, s.fps_ref, s.cfg,
                       np.random.default_rng(s.seeds[k]),
                       s.joints if s.cfg.epipolar_candidates > 1 else None)


def _align_pair(i: int, j: int, coarse: ByCamera[GridTrack], fine: ByCamera[GridTrack],
                lanes: ByCamera[Lanes], noise: list[tuple[NDArray[np.float64], float]],
                fps_ref: float, cfg: AlignConfig, rng: np.random.Generator,
                joints: Callable[[], PairJoints] | None = None) -> PairAlignment:
    """Offset candidates, ICP verification and continuous refinement for one pair.

    An ambiguous pair (runner-up evidence above ``cfg.ambiguity_ratio`` of the best) with a
    plausible fit gets more candidates from an ICP scan of all offsets; with ``joints`` (made
    only then), it is
    decided by the epipolar geometry of the people's joints among its best candidates when
    that is decisive (cost ratio at most ``cfg.epipolar_decisive``), and the clock moves to
    where the joints fit best; it stays flagged ambiguous
    (:mod:`~cascalib.stages.ambiguous_pairs`)."""
    sr = cfg.scale_range if cfg.estimate_scale else 1.0
    longest = max(coarse[i].length, coarse[j].length) * coarse[i].step
    curve = search_offsets(
        coarse[i], coarse[j], max_offset=cfg.max_offset_fraction * longest,
        chunk_seconds_frames=int(cfg.chunk_seconds * fps_ref),
        min_overlap=max(5, int(cfg.min_overlap_seconds * fps_ref / coarse[i].step)),
        min_spread=cfg.min_spread, sigma=cfg.sigma, scale_range=sr,
        n_candidates=cfg.n_candidates, nms_frames=cfg.nms_seconds * fps_ref)
    offs = [int(round(c.offset)) for c in curve.candidates]
    # quick ICP of every candidate, then the full ICP of those within half of the best
    results = [pair_icp(i, j, o, c.angle, lanes, cfg, sr, quick=True)
               for o, c in zip(offs, curve.candidates, strict=True)]
    if not any(plausible(r, cfg) for r in results) and curve.candidates:
        # the vote's angle did not lead ICP to a tight fit: the paper's full rotation search
        results[0] = _rotation_fallback(i, j, offs[0], results[0], lanes, cfg, sr, rng)
    full = cfg.evidence_seconds * fps_ref
    scores = evidence(results, evidence_sigma(results, cfg), lanes[i], lanes[j], full)
    if (cfg.scan_seconds > 0 and ambiguity_of(scores) > cfg.ambiguity_ratio
            and any(plausible(r, cfg) for r in results)):
        curve, results = scan_candidates(i, j, curve, results, lanes, fps_ref, cfg, sr)
        offs = [int(round(c.offset)) for c in curve.candidates]
        scores = evidence(results, evidence_sigma(results, cfg), lanes[i], lanes[j], full)
    for k in np.argsort(scores)[::-1][:3]:
        r = results[k]
        if r is not None and scores[k] >= 0.5 * max(scores):
            results[k] = pair_icp(i, j, offs[k], r.transform.angle, lanes, cfg, sr)
    sig = evidence_sigma(results, cfg)
    scores = evidence(results, sig, lanes[i], lanes[j], full)
    angles = [r.transform.angle if r is not None else c.angle
              for r, c in zip(results, curve.candidates, strict=True)]
    if not scores or max(scores) <= 0:
        return PairAlignment(i, j, curve, scores, -1, None, 1.0, icp_angles=angles,
                             evidence_sigma=sig)
    k = int(np.argmax(scores))
    ambiguity = ambiguity_of(scores) if len(scores) > 1 else curve.peak_ratio
    best = results[k]
    assert best is not None
    fit = _refine_pair(i, j, int(round(curve.candidates[k].offset)), best, fine, lanes, noise,
                       fps_ref, cfg, sr, rng)
    if joints is not None and fit is not None and ambiguity > cfg.ambiguity_ratio:
        fits = {k: fit}
        # the runners-up by evidence, the chosen k aside (argsort may put another of a tie
        # first)
        runners = [int(m) for m in np.argsort(scores)[::-1] if m != k]
        for m in runners[:cfg.epipolar_candidates - 1]:
            r = results[m]
            if r is not None and scores[m] >= 0.5 * max(scores):
                alt = _refine_pair(i, j, int(round(curve.candidates[m].offset)), r, fine,
                                   lanes, noise, fps_ref, cfg, sr, rng)
                if alt is not None:
                    fits[m] = alt
        choice = epipolar_choice(i, j, fits, joints(), cfg, rng) if len(fits) > 1 else None
        if choice is not None and choice[1] <= cfg.epipolar_decisive:
            # the pair keeps its ambiguity (and its flag): the check only compares the
            # candidates it was given, and the true one may not be among them
            k = choice[0]
            # the clock where the joints fit best; the ground alignment stays the ICP's
            fit = replace(fits[k], offset=fits[k].offset + choice[2],
                          pivot_offset=fits[k].pivot_offset + choice[2])
    if fit is None:
        return PairAlignment(i, j, curve, scores, -1, None, 1.0, icp_angles=angles,
                             evidence_sigma=sig)
    logger.info("pair %s-%s: offset %.2f rate %.5f angle %.1f deg rms %.3f m ambiguity %.2f",
                fine[i].camera, fine[j].camera, fit.offset, fit.rate,
                np.degrees(fit.transform.angle), fit.rms, ambiguity)
    return PairAlignment(i, j, curve, scores, k, fit, float(ambiguity), icp_angles=angles,
                         evidence_sigma=sig)


def _refine_pair(i: int, j: int, offset: int, best: IcpResult, fine: ByCamera[GridTrack],
                 lanes: ByCamera[Lanes], noise: list[tuple[NDArray[np.float64], float]],
                 fps_ref: float, cfg: AlignConfig, sr: float, rng: np.random.Generator
                 ) -> SyncFit | None:
    """Sub-frame offset, rate and similarity from the ICP match at an integer offset."""
    kw = dict(sigma=cfg.refine_sigma, estimate_rate=cfg.estimate_rate, scale_range=sr,
              margin=max(3.0, 3 * cfg.smooth_seconds * fps_ref), noise_a=noise[i],
              noise_b=noise[j], rate_prior_sd=cfg.rate_prior_sd, corr_frames=0.5 * fps_ref)
    fit = refine_sync(fine[i], fine[j], lanes[i], lanes[j], best, offset, rng=rng, **kw)  # type: ignore[arg-type]
    for _ in range(3):
        # the coarse peak can sit a few frames off (broad peaks in crowds): when the fit runs
        # into its +-6 frame bound, re-associate at its offset and fit again
        if fit is None or abs(fit.pivot_offset - offset) < 4.0:
            break
        offset = int(round(fit.pivot_offset))
        moved = pair_icp(i, j, offset, fit.transform.angle, lanes, cfg, sr)
        if moved is None:
            break
        best = moved
        fit = refine_sync(fine[i], fine[j], lanes[i], lanes[j], best, offset, rng=rng, **kw)  # type: ignore[arg-type]
    return fit


def _fit_at(i: int, j: int, offset: int, angle: float, fine: list[GridTrack],
            lanes: list[Lanes], noise: list[tuple[NDArray[np.float64], float]], fps_ref: float,
            cfg: AlignConfig, sr: float, rng: np.random.Generator, quick: bool = False
            ) -> SyncFit | None:
    """ICP at an integer offset from a rotation, then the sub-frame fit (None if either fails)."""
    best = pair_icp(i, j, offset, angle, lanes, cfg, sr, quick=quick)
    return None if best is None else _refine_pair(i, j, offset, best, fine, lanes, noise,
                                                  fps_ref, cfg, sr, rng)


def _rotation_fallback(i: int, j: int, offset: int, res: IcpResult | None, lanes: ByCamera[Lanes],
                       cfg: AlignConfig, sr: float, rng: np.random.Generator
                       ) -> IcpResult | None:
    """Re-initialise the ICP by the brute-force rotation search (paper, "2D Rotation Search")."""
    pa = _xyt(lanes[i], 0)
    pb = _xyt(lanes[j], offset)
    if len(pa) < 10 or len(pb) < 10:
        return res
    rs = rotation_search(pa, pb, step_deg=cfg.rotation_step_deg, rng=rng)
    alt = pair_icp(i, j, offset, rs.angle, lanes, cfg, sr)
    if res is None or (alt is not None and alt.score > res.score):
        return alt
    return res


def _xyt(lanes: Lanes, offset: int) -> NDArray[np.float64]:
    """(x, y, synchronised time) of every lane point; time shifted by ``offset``."""
    g, k = np.nonzero(np.isfinite(lanes.pos[..., 0]))
    return np.c_[lanes.pos[g, k], g + offset]


def _vote(n: int, ref: int, pairs: list[PairAlignment], b: NDArray[np.float64],
          T: list[Similarity2D | None], lanes: list[Lanes], fine: list[GridTrack],
          noise: list[tuple[NDArray[np.float64], float]], fps_ref: float, cfg: AlignConfig,
          sr: float, rng: np.random.Generator) -> list[PairAlignment] | None:
    """Move cameras to the clock and heading that all their pairs support best
    (:func:`~cascalib.stages.consensus.vote_cameras`) and refit those cameras' pairs there.
    None when no camera moves."""
    by_ij = {(p.i, p.j): p for p in pairs}
    edges = [CandidateEdge(p.i, p.j, [c.offset for c in p.curve.candidates], p.icp_angles,
                           p.icp_scores) for p in pairs if len(p.icp_angles) == len(p.icp_scores)]
    cache: dict[tuple[int, int, int, int, bool], float] = {}

    def score(i: int, j: int, offset: float, angle: float, full: bool) -> float:
        o = int(round(offset))
        key = (i, j, o, int(round(np.degrees(angle) / 5.0)) % 72, full)
        if key not in cache:
            r = pair_icp(i, j, o, angle, lanes, cfg, sr, quick=not full)
            cache[key] = candidate_score(r, by_ij[(i, j)].evidence_sigma, lanes[i], lanes[j],
                                         cfg.evidence_seconds * fps_ref)
        return cache[key]

    settled: dict[tuple[int, int, int], tuple[float, float] | None] = {}
    base = int(rng.integers(2**32))  # one stream per settled candidate: threads keep results

    def settle(i: int, j: int, offset: float, angle: float) -> tuple[float, float] | None:
        o = int(round(offset))
        if (i, j, o) not in settled:
            fit = _fit_at(i, j, o, angle, fine, lanes, noise, fps_ref, cfg, sr,
                          np.random.default_rng([base, i, j, o + 2**20]), quick=True)
            settled[(i, j, o)] = None if fit is None else (fit.offset, fit.transform.angle)
        return settled[(i, j, o)]

    placed = np.array([t is not None for t in T])
    yaw = np.array([t.angle if t is not None else 0.0 for t in T])
    # ICP spends its time in numpy, which releases the GIL: hypotheses are scored in threads
    # (the caches may then compute an entry twice, never wrongly)
    with ThreadPoolExecutor(max_workers=cfg.n_workers) as pool:
        votes = vote_cameras(n, ref, edges, b, yaw, placed, score, settle,
                             movable=doubtful_cameras(n, ref, pairs, placed, cfg),
                             tolerance=cfg.offset_tolerance, mapper=pool.map)
    moved = {v.camera: v for v in votes if v.moved}
    if not moved:
        return None
    state_b, state_yaw = b.copy(), yaw.copy()
    for v in votes:
        state_b[v.camera], state_yaw[v.camera] = v.b, v.yaw
    out = []
    for p in pairs:
        if p.i not in moved and p.j not in moved:
            out.append(p)
            continue
        offset = int(round(state_b[p.j] - state_b[p.i]))
        logger.info("camera vote: pair %s-%s refitted at offset %d", fine[p.i].camera,
                    fine[p.j].camera, offset)
        fit = _fit_at(p.i, p.j, offset, float(state_yaw[p.j] - state_yaw[p.i]), fine, lanes,
                      noise, fps_ref, cfg, sr, rng)
        near = [k for k, c in enumerate(p.curve.candidates)
                if abs(c.offset - offset) <= cfg.offset_tolerance]
        amb = max(moved[c].ambiguity for c in (p.i, p.j) if c in moved)
        out.append(replace(p, chosen=near[0] if near else -1, fit=fit, ambiguity=amb))
    return out


@one_blas_thread
def align_cameras(tracks: list[Tracks], plane_cameras: list[Camera],
                  config: AlignConfig | None = None, *, reference: str | int | None = None,
                  rng: np.random.Generator | int | None = None,
                  progress: Callable[[float], None] | None = None,
                  height: float = 1.70, fixed_intrinsics: Sequence[str] = ()
                  ) -> AlignmentResult:
    """Synchronise all cameras and place them on the reference camera's ground plane.

    Parameters
    ----------
    tracks : list of Tracks
        One per camera.
    plane_cameras : list of Camera
        Same order; each camera in its own plane frame (stage I ``to_camera()``).
    config : AlignConfig, optional
    reference : str or int, optional
        Reference camera (name or index); default the first.
    rng : Generator or int, optional
    progress : callable, optional
        ``progress(fraction)`` when the ground trajectories are made and as each camera pair is
        aligned (pairs take most of the time).
    height : float
        Mean person height (m): the epipolar steps match persons across cameras by their
        ground positions, from the hips where the feet are not seen.
    fixed_intrinsics : sequence of str
        Cameras whose intrinsics are known: the rig refinement holds their focal length and
        principal point.

    Returns
    -------
    AlignmentResult

    Raises
    ------
    InputError
        Mismatched inputs.
    EstimationFailed
        No camera could be aligned with the reference.
    """
    cfg = config or AlignConfig()
    rng = np.random.default_rng(rng)
    ref = _check_inputs(tracks, plane_cameras, reference)
    n = len(tracks)
    fps = [_fps(t, c) for t, c in zip(tracks, plane_cameras, strict=True)]
    known = fps[ref] is not None and all(f is not None for f in fps)
    fps_ref = float(fps[ref]) if fps[ref] is not None else 30.0  # type: ignore[arg-type]
    rho = [fps_ref / f if known else 1.0 for f in fps]  # type: ignore[operator]
    # ground noise model per camera: one pixel moves a point at distance d by d^2 / (f h)
    noise = [(c.center[:2], cfg.pixel_noise / (c.focal * max(c.center[2], 0.3)))
             for c in plane_cameras]
    ij = [(i, j) for i in range(n) for j in range(i + 1, n)]
    seeds = rng.integers(0, 2**32, len(ij))
    report = progress or (lambda fraction: None)
    # every camera's ground trajectories, then each camera pair as soon as its two cameras
    # are ready, in forked worker processes (their Python loops hold the GIL), which inherit
    # the inputs; meanwhile the canonical tracks of the epipolar clock step, here
    shared = _AlignInputs(tracks, plane_cameras, fps, rho, fps_ref, ref, height, noise, ij,
                          seeds, cfg)
    with WorkerPool(cfg.n_workers, shared, processes=cfg.processes) as pool:
        per_cam = [pool.submit(_ground_task, c) for c in range(n)]
        data = shared.session() if cfg.epipolar_sync or cfg.epipolar_rig else None
        cams: list[_CameraGround] = []
        found: dict[int, Future[PairAlignment]] = {}
        for c, f in enumerate(per_cam):
            cams.append(f.result())  # a camera's error: the pairs not started are not run
            for i in range(c):
                k = ij.index((i, c))
                found[k] = pool.submit(_pair_task, k, cams[i], cams[c])
        report(0.2)
        pairs = []
        for k in range(len(ij)):
            pairs.append(found[k].result())
            report(0.2 + 0.75 * len(pairs) / len(ij))
    ground = [c.ground for c in cams]
    fine = [c.fine for c in cams]
    lanes = [c.lanes for c in cams]
    sr = cfg.scale_range if cfg.estimate_scale else 1.0
    pairs, a, b, T = global_alignment(n, ref, pairs, cfg, sr)
    if cfg.camera_vote and n > 2:
        revised = _vote(n, ref, pairs, b, T, lanes, fine, noise, fps_ref, cfg, sr, rng)
        if revised is not None:
            pairs, a, b, T = global_alignment(n, ref, revised, cfg, sr)
    if all(T[c] is None for c in range(n) if c != ref):
        raise EstimationFailed("no camera could be synchronised and aligned with the "
                               "reference: the cameras may not see the same people, or too "
                               "few walking people were detected", camera=tracks[ref].camera)
    result = _result(tracks, plane_cameras, ground, pairs, T, a, b, rho, fps, ref, cfg)
    report(0.95)
    if cfg.epipolar_sync:
        epi = epipolar_clocks(tracks, result.calibration, height=height,
                              window=cfg.epipolar_window_frames, n_times=cfg.epipolar_times,
                              max_points=cfg.epipolar_points,
                              iterations=cfg.epipolar_iterations, n_workers=cfg.n_workers,
                              rng=rng, data=data)
        result = replace(result, calibration=epi.calibration, epipolar=epi)
    if cfg.epipolar_rig and data is not None:
        rig = refine_rig(data, result.calibration, height=height,
                         fixed_intrinsics=fixed_intrinsics,
                         held=[n for n, fl in result.flags.items() if "not_aligned" in fl],
                         n_times=cfg.epipolar_times, max_points=cfg.rig_points,
                         tilt_sigma_deg=cfg.rig_tilt_sigma_deg, focal_sigma=cfg.rig_focal_sigma,
                         principal_point_sigma=cfg.rig_principal_point_sigma,
                         radial_sigma=cfg.rig_radial_sigma,
                         rounds=cfg.rig_rounds, rng=rng)
        result = replace(result, calibration=rig.calibration, rig=rig)
    return result


def _result(tracks: list[Tracks], cams: list[Camera], ground: list[GroundTracks],
            pairs: list[PairAlignment], T: list[Similarity2D | None], a: NDArray[np.float64],
            b: NDArray[np.float64], rho: list[float], fps: list[float | None], ref: int,
            cfg: AlignConfig) -> AlignmentResult:
    n = len(cams)
    out_cams, confidence, flags, measured = [], {}, {}, {}
    transforms = []
    for c in range(n):
        name = cams[c].name
        inc = [p for p in pairs if c in (p.i, p.j)]
        acc = [p for p in inc if p.accepted]
        fl = [f"rejected_pair:{cams[p.j if p.i == c else p.i].name}" for p in inc
              if p.fit is not None and not p.accepted]
        Tc = T[c]
        if Tc is None:
            fl.append("not_aligned")
            Tc = Similarity2D(0.0, np.zeros(2))
        # confidence: the best accepted pair's margin over its runner-up, scaled by the
        # share of the camera's pairs that agree with the global clocks (cycle consistency)
        fitted = [p for p in inc if p.fit is not None]
        agree = len(acc) / max(1, len(fitted))
        conf = 1.0 if c == ref else agree * max((1.0 - p.ambiguity for p in acc), default=0.0)
        if c != ref and acc and min(p.ambiguity for p in acc) > cfg.ambiguity_ratio:
            fl.append("ambiguous")
        if c != ref and acc and agree < 0.5:
            fl.append("inconsistent")
        cam = place_camera(cams[c], Tc).with_(fps=fps[c], time_offset=float(b[c]),
                                              time_rate=float(a[c] * rho[c]))
        if T[c] is None:
            cam = cam.with_(time_offset=0.0, time_rate=float(rho[c]))
        # the global clocks keep the declared ratio (to rounding) unless a pair's rate counted
        measured[name] = bool(c != ref and T[c] is not None and abs(a[c] - 1.0) > RATE_ROUNDING)
        out_cams.append(cam)
        transforms.append(Tc)
        confidence[name] = float(conf)
        flags[name] = fl
        if fl:
            logger.warning("camera %s: %s", name, ", ".join(fl))
    calib = Calibration(out_cams, reference_camera=cams[ref].name,
                        quality={"alignment": {"confidence": confidence, "flags": flags}})
    return AlignmentResult(calib, confidence, flags, pairs, ground, transforms,
                           rate_measured=measured)
