"""Stage V: joint refinement of all cameras and the people's 3D joints.

The paper (sec. "Joint Camera Refinement" and supplement "Bundle Adjustment - Details") minimises
ray-to-ray distances with gradient descent. Here the same terms -- multi-view agreement, left/right
symmetry, feet on the ground, the height prior -- form a nonlinear least-squares problem in a GTSAM
factor graph (key table and factors in :mod:`cascalib.stages.refine_graph`, one solve's problem
in :mod:`cascalib.stages.refine_problem`, the intrinsics passes and their checks in
:mod:`cascalib.stages.refine_passes`), minimising the *reprojection* error with robust kernels
and reporting marginal uncertainties.

Cascade of one call to :func:`refine`::

    tracks --interpolate to reference times--> views
    views --associate (ground position, Hungarian, triangulation check)--> groups
    groups --select (coverage of time, floor, image)--> graph --LM--> cameras
    cameras --refine time offsets, re-associate--> (repeat n_rounds, more while they still move)
    [lens-distortion pass, kept if it helps on held-out frames: the later solves hold its lens]
    [principal-point pass (upright torsos added), kept if it helps on held-out frames, then
     solved again with bone targets from its own cameras; if that moved the cameras far, one
     more round and pass at its principal points; where a lens was found, the lens pass
     again at them, kept unless it reprojects held-out frames worse]
    cameras --triangulate every frame--> poses3d, quality report
"""

from __future__ import annotations

import logging
import time
from collections.abc import Callable, Collection, Mapping
from dataclasses import dataclass, field, replace

import gtsam
import numpy as np
from numpy.typing import NDArray

from cascalib.blas import one_blas_thread
from cascalib.calibration import Calibration
from cascalib.camera import Camera
from cascalib.errors import InputError, RefinementFailed
from cascalib.geometry import rotation_angle_deg
from cascalib.skeletons import CANONICAL_INDEX
from cascalib.stages.association import Association, associate, ground_velocity
from cascalib.stages.frame_selection import select_groups, usable_groups
from cascalib.stages.quality import CameraQuality, assess_camera, unit_weight_sigma
from cascalib.stages.reconstruct import (
    SessionData,
    clock_check_times,
    persons_per_time,
    poses_by_slot,
    prepare,
    reconstruct,
    triangulate_groups,
    views_at,
)
from cascalib.stages.refine_config import DEFAULT_JOINTS, RefineConfig
from cascalib.stages.refine_graph import (
    GraphProblem,
    SolveInfo,
    marginal_sigmas,
)
from cascalib.stages.refine_passes import (
    heldout_gain,
    intrinsics_pass,
    principal_point_spread,
    rounds_size_graph,
    settle_principal_points,
)
from cascalib.stages.refine_problem import (
    make_problem,
    solve,
    track_targets,
)
from cascalib.stages.refine_result import RefineResult, with_failed_camera
from cascalib.stages.stature import rescale_to_statures
from cascalib.stages.time_refine import refine_offsets, regroup
from cascalib.step_seconds import account, timed
from cascalib.tracks import Tracks

__all__ = ["DEFAULT_JOINTS", "RefineConfig", "RefineResult", "refine", "refine_clocks"]

log = logging.getLogger(__name__)

#: Prior sd of a camera's rate around one stage III measured (its pair fits' rates are good to
#: about this, unlike a declared frame rate's ratio, which is exact unless mislabelled).
MEASURED_RATE_SD = 1e-3


def _select(assoc: Association, sizes: list[tuple[int, int]], n: int,
            joints: NDArray[np.int64], cfg: RefineConfig) -> NDArray[np.int64]:
    """``n`` well-spread person-frames of ``assoc`` (:func:`select_groups` with the frame
    selection settings of ``cfg``)."""
    return select_groups(assoc, sizes, n, joints, n_time_bins=cfg.n_time_bins,
                         floor_cell_m=cfg.floor_cell_m, image_grid=cfg.image_grid)


def _pass_groups(assoc: Association, sel: NDArray[np.int64], sizes: list[tuple[int, int]],
                joints: NDArray[np.int64], cfg: RefineConfig, n: int) -> NDArray[np.int64]:
    """Person-frames of an intrinsics pass of budget ``n``: the last round's selection ``sel``
    at the rounds' size, else a new selection that leaves at least a fifth of the usable groups
    out (for the held-out check of mode "auto")."""
    n = min(n, max(cfg.max_groups, 4 * usable_groups(assoc, joints).size // 5))
    if n == cfg.max_groups:
        return sel
    return _select(assoc, sizes, n, joints, cfg)


def _intrinsics_budget(assoc: Association, cfg: RefineConfig) -> int:
    """Person-frames asked of the principal-point pass: ``cfg.intrinsics_groups_per_person``
    per person in view at a reference time of ``assoc`` (on average), at least
    ``cfg.intrinsics_groups`` and at most ``cfg.intrinsics_groups_max``."""
    in_view = assoc.n_groups / max(np.unique(assoc.times).size, 1)
    want = int(cfg.intrinsics_groups_per_person * in_view)
    return max(cfg.intrinsics_groups, min(want, cfg.intrinsics_groups_max))


def _report(assoc: Association, err: NDArray[np.float64], cameras: list[Camera],
            sigmas: list[dict[str, float]], cfg: RefineConfig) -> dict[str, CameraQuality]:
    """Per-camera quality from the reprojection errors (G, C, 26) of the final triangulation."""
    conf = assoc.obs[..., 2]
    sig = cfg.sigma_px / np.sqrt(np.clip(np.nan_to_num(conf), cfg.min_confidence, 1.0))
    used = np.array([CANONICAL_INDEX[n] for n in cfg.joints])
    e_used, s_used = err[:, :, used], sig[:, :, used]
    inl = np.isfinite(e_used) & (e_used < cfg.inlier_px)
    s0 = unit_weight_sigma(e_used[inl], s_used[inl])
    scale = (s0 if np.isfinite(s0) else 1.0) * cfg.uncertainty_inflation
    quality = {cam.name: assess_camera(cam, e_used[:, c].ravel(), sigmas[c], scale, cfg)
               for c, cam in enumerate(cameras)}
    for q in quality.values():
        log.info("camera %s: %s (%s)", q.camera, q.verdict, q.reason)
    return quality


def _clock_check_groups(data: SessionData, cameras: list[Camera], cfg: RefineConfig,
                        height: float) -> tuple[Association, Association]:
    """All persons at the reference times of ``data`` (see
    :func:`~cascalib.stages.reconstruct.clock_check_times`) associated across the cameras at
    these clocks, and an even subset of about 2000 of them on which clocks are compared."""
    # the refined ground gate with the first round's (looser) triangulation check
    gates = cfg.association_gates(refined=True) | {"consistency": cfg.consistency}
    assoc = associate(views_at(data, cameras), cameras, data.times, height=height, link=False,
                      **gates)  # type: ignore[arg-type]  # no tracks needed
    return assoc, assoc.subset(np.arange(0, assoc.n_groups, max(1, assoc.n_groups // 2000)))


def _clock_costs(data: SessionData, groups: Association, cameras: list[Camera],
                 new: list[Camera], joints: NDArray[np.int64]) -> tuple[float, float]:
    """Median reprojection error of ``groups`` (associated at the clocks of ``cameras``)
    triangulated by all cameras at those clocks, and of the same persons at the clocks of
    ``new``, over the joints seen at both."""
    _, err = triangulate_groups(groups, cameras, joints)
    _, err_new = triangulate_groups(regroup(data.keypoints, data.links, new, groups), new,
                                    joints)
    both = np.isfinite(err) & np.isfinite(err_new)
    if not both.any():
        return np.inf, np.inf
    return float(np.median(err[both])), float(np.median(err_new[both]))


def refine_clocks(data: SessionData, cameras: list[Camera], cfg: RefineConfig,
                  joints: NDArray[np.int64], height: float, rng: np.random.Generator,
                  anchor_rates: Collection[float] | None = None,
                  sd: NDArray[np.float64] | None = None,
                  declared: Collection[int] = (), measured: Collection[int] = ()
                  ) -> list[Camera]:
    """Sub-frame time offsets (and rates, ``cfg.time_rates``) of every non-reference camera,
    geometry fixed, re-associating with the new clocks between updates (``cfg.time_iterations``
    at most).

    An update is kept only if it lowers the joint triangulation error of all cameras: the
    leave-one-out estimate of one clock can be biased by the rest of the rig's geometry errors.
    The error is compared on the same persons at the same times, seen through both clocks
    (:func:`~cascalib.stages.time_refine.regroup`): between two associations made anew, which
    persons each keeps moves the median by more than a tenth of a frame of one clock does. A
    kept update that moved no offset by ``cfg.time_settle_frames`` ends the updates.
    ``anchor_rates`` (stage III's rates) centre the rates' prior; default the cameras' own.
    ``declared``: the cameras whose anchor is their declared frame rate's ratio, which may be
    a mislabel; ``measured``: those whose anchor stage III measured, their prior
    :data:`MEASURED_RATE_SD` wide. ``sd`` (C,), if given, is filled with the standard error
    of each offset from the last update's measurement (both: see
    :func:`~cascalib.stages.time_refine.refine_offsets`).
    """
    data = clock_check_times(data, cfg.time_check_frames)  # one set for every cost
    for _ in range(cfg.time_iterations):
        # the persons as the current (kept) clocks associate them
        assoc, groups = _clock_check_groups(data, cameras, cfg, height)
        new = refine_offsets(data.keypoints, data.links, cameras, assoc, data.reference,
                             joints, search=cfg.time_search_frames,
                             max_groups=cfg.time_groups, rates=cfg.time_rates,
                             rate_sd=[MEASURED_RATE_SD if c in measured else cfg.time_rate_sd
                                      for c in range(len(cameras))],
                             anchor_rates=anchor_rates,  # type: ignore[arg-type]
                             declared=tuple(declared), rng=rng, sd=sd)
        cost, new_cost = _clock_costs(data, groups, cameras, new, joints)
        kept = new_cost < cost * (1.0 + cfg.time_tie_tolerance)
        log.info("time offsets: joint reprojection %.4f -> %.4f px (%s)", cost, new_cost,
                 "kept" if kept else "rejected")
        if not kept:
            break
        moved = max(abs(a.time_offset - b.time_offset) for a, b in zip(new, cameras,
                                                                         strict=True))
        cameras = new
        if moved < cfg.time_settle_frames:
            break
    return cameras


def _round_association(rounds: SessionData, cameras: list[Camera], cfg: RefineConfig,
                       height: float, reference: int, *, refined: bool) -> Association:
    """The persons of the rounds' reference times associated across the cameras: with the
    first round's wide gates and ground warps, or ``refined`` (cameras out of a solve)."""
    return associate(views_at(rounds, cameras), cameras, rounds.times, height=height,
                     reference=reference, **cfg.association_gates(refined=refined))  # type: ignore[arg-type]


def _reassociate(rounds: SessionData, cameras: list[Camera], cfg: RefineConfig, height: float,
                 reference: int, sizes: list[tuple[int, int]], joints: NDArray[np.int64],
                 budget: int, fitted_times: NDArray[np.float64]
                 ) -> tuple[Association, NDArray[np.int64], NDArray[np.int64], NDArray[np.int64]]:
    """The rounds' association and person-frame choices made again with the principal-point
    pass's ``cameras`` (see ``RefineConfig.principal_point_reassociate``).

    Returns the association (with walking velocities), the rounds-size selection, the pass-size
    selection, and the groups the held-out checks must not use: those chosen here and every
    group at a time of ``fitted_times`` (the person-frames earlier solves saw, which the new
    association numbers differently).
    """
    assoc = _round_association(rounds, cameras, cfg, height, reference, refined=True)
    assoc = replace(assoc, velocity=ground_velocity(assoc))
    sel = _select(assoc, sizes, cfg.max_groups, joints, cfg)
    chosen = _pass_groups(assoc, sel, sizes, joints, cfg, budget)
    seen = np.flatnonzero(np.isin(assoc.times, fitted_times))
    return assoc, sel, chosen, np.union1d(np.union1d(sel, chosen), seen)


def camera_change(before: list[Camera], after: list[Camera]) -> tuple[float, float]:
    """Largest rotation (deg, geodesic) and relative focal change of any camera between two
    versions of a rig in one world frame."""
    rot = max(rotation_angle_deg(b.R @ a.R.T) for a, b in zip(before, after, strict=True))
    focal = max(abs(b.focal / a.focal - 1) for a, b in zip(before, after, strict=True))
    return rot, focal


def _round_limits(cfg: RefineConfig) -> tuple[int, int]:
    """Least and most solve / re-associate rounds (see ``RefineConfig.n_rounds``)."""
    if cfg.n_rounds is not None:
        return cfg.n_rounds, cfg.n_rounds
    least = 2 if cfg.principal_point != "never" else 3
    return least, max(least, cfg.max_rounds)


@dataclass
class _Progress:
    """Progress fractions of ``total`` roughly equal steps, to ``callback``; steps may be added
    on the way (more rounds) and the fraction never goes back."""

    callback: Callable[[float], None] | None
    total: int
    done: int = 0
    shown: float = 0.0

    def step(self) -> None:
        self.done += 1
        self.shown = max(self.shown, min(self.done / self.total, 1.0))
        if self.callback is not None:
            self.callback(self.shown)


@dataclass
class _Run:
    """What the steps of one :func:`refine` call share; ``solves`` collects their records."""

    data: SessionData
    rounds: SessionData  # the reference times the rounds associate
    cfg: RefineConfig
    height: float
    joints: NDArray[np.int64]
    fixed: frozenset[int]
    anchor_rates: list[float]  # stage III's rates: the clock search's anchors
    rng: np.random.Generator
    progress: _Progress
    solves: list[SolveInfo] = field(default_factory=list)
    clock_sd: NDArray[np.float64] | None = None  # of the last clock update's offsets (frames)
    declared: frozenset[int] = frozenset()  # cameras at their declared rate (stage III)
    measured: frozenset[int] = frozenset()  # cameras whose rate stage III measured

    def clocks(self, cameras: list[Camera]) -> list[Camera]:
        """:func:`refine_clocks` of ``cameras`` (or them unchanged with ``refine_time`` off)."""
        if not self.cfg.refine_time:
            return cameras
        self.clock_sd = np.full(len(cameras), np.nan)
        with timed("clock_updates"):
            return refine_clocks(self.data, cameras, self.cfg, self.joints, self.height,
                                 self.rng, anchor_rates=self.anchor_rates, sd=self.clock_sd,
                                 declared=self.declared, measured=self.measured)


@dataclass
class _Fit:
    """The current cameras and what they were solved on, from step to step of :func:`refine`."""

    cameras: list[Camera]
    assoc: Association  # the association of the last solve's person-frames
    sel: NDArray[np.int64]  # its selection at the rounds' size (marginals at that size)
    fitted: NDArray[np.int64]  # person-frames solves saw: never held out
    kw: dict  # problem keywords, with the bone targets of ``assoc``'s tracks
    graph: gtsam.NonlinearFactorGraph
    values: gtsam.Values
    prob: GraphProblem


def _solve_rounds(run: _Run, cameras: list[Camera], *, least: int, most: int,
                  refined: bool) -> _Fit:
    """Associate, select, solve and update the clocks, ``least`` to ``most`` rounds: more
    while the last round still moved the cameras (``RefineConfig.round_tolerance_deg``).

    ``refined``: ``cameras`` come out of a solve (the association's narrow gates, the size noise
    model fitted from the start). Each round beyond ``least`` adds three progress steps.
    """
    cfg, data = run.cfg, run.data
    targets: dict[int, NDArray] | None = None
    r = 0
    while True:
        refined = refined or r > 0
        assoc = _round_association(run.rounds, cameras, cfg, run.height, data.reference,
                                   refined=refined)
        if assoc.n_groups < 5:
            raise RefinementFailed(f"only {assoc.n_groups} person-frames are seen by two cameras"
                                   " at the same time: check the time offsets and overlap")
        run.progress.step()
        if cfg.use_bones and refined:
            # track numbers are this association's own: the targets must come from it too
            assoc, targets = track_targets(assoc, cameras, cfg, run.joints, run.height)
        sel = _select(assoc, data.sizes, cfg.max_groups, run.joints, cfg)
        kw = dict(height=run.height, n_persons=persons_per_time(assoc),
                  reference=data.reference, targets=targets, fixed=run.fixed)
        prob = make_problem(assoc.subset(sel), cameras, cfg, solved=refined, **kw)  # type: ignore[arg-type]
        before = cameras
        cameras, _, info, graph, values = solve(prob, cfg)
        run.solves.append(info)
        run.progress.step()
        r += 1
        moved_deg, moved_focal = camera_change(before, cameras)
        log.info("round %d moved the cameras by up to %.3f deg, focal %.2f %%", r, moved_deg,
                 100 * moved_focal)
        last = r >= most or (r >= least and moved_deg <= cfg.round_tolerance_deg
                             and moved_focal <= cfg.round_tolerance_focal)
        if last or cfg.time_each_round:
            # after the last round too: the passes and the final association use them
            cameras = run.clocks(cameras)
        run.progress.step()
        if last:
            break
        run.progress.total += 3 * (r >= least)  # one more round than planned
    if cfg.use_bones:  # for the intrinsics passes (same association; clocks do not enter)
        assoc, targets = track_targets(assoc, cameras, cfg, run.joints, run.height)
    assoc = replace(assoc, velocity=ground_velocity(assoc))  # the passes' walking lean
    return _Fit(cameras, assoc, sel, sel, kw | {"targets": targets}, graph, values, prob)


@dataclass
class _PrincipalPoint:
    """The principal-point pass's outcome (:func:`_principal_point_pass`)."""

    fit: _Fit
    moved_deg: float  # how far its update moved any camera from the pass (deg)
    start: _Fit  # where the pass started, and its person-frames: for the split halves
    chosen: NDArray[np.int64]


def _principal_point_pass(run: _Run, fit: _Fit) -> tuple[_Fit, _PrincipalPoint | None]:
    """The principal-point pass from ``fit`` (``RefineConfig.principal_point``), and its
    updates on persons associated anew with its cameras.

    Returns ``fit`` with the pass's person-frames counted as seen, and the outcome if the pass
    was run and kept (else None).
    """
    cfg = run.cfg
    if cfg.principal_point == "never":
        return fit, None
    budget = _intrinsics_budget(fit.assoc, cfg)
    chosen = _pass_groups(fit.assoc, fit.sel, run.data.sizes, run.joints, cfg, budget)
    updates = cfg.use_bones and cfg.principal_point_updates > 0
    min_gain = -0.005
    res = intrinsics_pass(fit.assoc, chosen, fit.cameras, cfg, fit.kw, run.rng, model="s2",
                          mode="always")  # judged here: a second look may follow the updates
    kept = True
    if res is not None and cfg.principal_point == "auto":
        gain = heldout_gain(fit.assoc, np.union1d(chosen, fit.fitted), fit.cameras, res[0],
                            cfg, run.rng, "s2 pass")
        kept = gain is not None and gain >= min_gain
    fit = replace(fit, fitted=np.union1d(fit.fitted, chosen))
    if res is None or not (kept or updates):
        return fit, None
    picks = (fit.assoc, fit.sel, chosen, fit.fitted)
    if cfg.principal_point_reassociate and updates:
        picks = _reassociate(run.rounds, res[0], cfg, run.height, run.data.reference,
                             run.data.sizes, run.joints, budget,
                             fit.assoc.times[fit.fitted])
    assoc, sel, fitted, kw, moved = fit.assoc, fit.sel, fit.fitted, fit.kw, 0.0
    settled = settle_principal_points(picks[0], picks[2], res, cfg, kw, run.joints, run.height)
    if settled[2] is not res:  # solved (on the new association, if any)
        moved = camera_change(res[0], settled[2][0])[0]
        log.info("principal-point update moved the cameras by up to %.3f deg", moved)
        _, sel, _, fitted = picks
        assoc, kw, res = settled
    if not kept:
        # a second look, after the updates: the pass's first solve is one iteration from the
        # rounds' cameras with their bone targets; on precise detections it reprojected
        # held-out persons worse than the rounds' rig 2 deg off (0.164 against 0.147 px)
        # although it was 0.18 deg off the truth, and its updates 0.03. On the rounds'
        # association, like the first look, not on the one made with the pass's cameras: an
        # association keeps the views its own rig finds consistent (there the rounds' rig
        # reprojected held-out persons to 0.89 px, on its own to 0.15); without the
        # person-frames any solve saw, nor the frames of the updates' person-frames (numbered
        # differently in the new association)
        seen = np.union1d(picks[1], picks[2])
        unseen = np.union1d(fit.fitted, np.flatnonzero(np.isin(fit.assoc.times,
                                                                picks[0].times[seen])))
        gain = heldout_gain(fit.assoc, unseen, fit.cameras, res[0], cfg, run.rng,
                            "s2 pass after its updates")
        if gain is None or gain < min_gain:
            return fit, None
    cameras, _, info, graph, values, prob = res
    run.solves.append(info)
    return fit, _PrincipalPoint(_Fit(cameras, assoc, sel, fitted, kw, graph, values, prob),
                                moved, fit, chosen)


def _lens_pass(run: _Run, fit: _Fit, rng: np.random.Generator, held: bool
               ) -> tuple[_Fit, bool]:
    """The lens-distortion pass from ``fit`` on ``cfg.distortion_groups`` person-frames
    (``RefineConfig.distortion``): ``fit`` with its cameras, lens included, if the pass is kept,
    and whether it was. In mode "auto" held-out person-frames must reproject
    ``distortion_min_gain`` better, or, where the cameras already ``held`` a lens, no worse."""
    cfg = run.cfg
    min_gain = 0.0 if held else cfg.distortion_min_gain
    chosen = _pass_groups(fit.assoc, fit.sel, run.data.sizes, run.joints, cfg,
                          cfg.distortion_groups)
    res = intrinsics_pass(fit.assoc, chosen, fit.cameras, cfg, fit.kw, rng, model="ds2",
                          mode=cfg.distortion, min_gain=min_gain, fitted=fit.fitted)
    if res is None:
        return fit, False
    cameras, _, info, graph, values, prob = res
    run.solves.append(info)
    return replace(fit, cameras=cameras, graph=graph, values=values, prob=prob), True


def _crowded(assoc: Association, cfg: RefineConfig) -> bool:
    """Whether the rounds associated as many persons at a reference time (median over the
    times) as ``RefineConfig.principal_point_rerun_persons``: a crowd, which gets one rerun of
    the rounds and the principal-point pass whatever the update moved."""
    limit = cfg.principal_point_rerun_persons
    if limit is None or assoc.n_groups == 0:
        return False
    _, counts = np.unique(assoc.times, return_counts=True)
    crowd = bool(np.median(counts) >= limit)
    if crowd:
        log.info("a crowd (%.0f persons at a time): the rounds and the pass run again once "
                 "whatever the update moves", np.median(counts))
    return crowd


def _prior_spread(cameras: list[Camera], fixed: Collection[int], cfg: RefineConfig
                  ) -> NDArray[np.float64]:
    """The principal-point prior's sd (px, (C,)): how far real principal points lie from the
    image centre (``principal_point_sigma`` of the image width); 0 for known intrinsics
    (``fixed``)."""
    sd = np.array([cfg.principal_point_sigma * cam.image_size[0] for cam in cameras])
    sd[list(fixed)] = 0.0
    return sd


def _lens_floor(pp_se: NDArray[np.float64], cameras: list[Camera], fixed: Collection[int],
                cfg: RefineConfig) -> NDArray[np.float64]:
    """The principal points' uncertainty (px, (C,)) once the lens pass is kept: at least the
    prior's sd (``principal_point_sigma`` of the image width).

    Without ``lens_first`` the principal-point pass, and the split halves that measure its
    spread, solve without a lens model, which the held-out person-frames then ask for: the
    radial terms they lacked went partly into the principal points (the lens pass then holds
    them), and both halves lack them alike, so their spread misses that error. Measured on the
    simulator's phones and security rigs (60 s whole-cascade scenes): at seed 0, principal
    points 11-68 px off, split-half standard errors 0.8-10.5 px, rotations 1.0-3.3 deg off
    (relative to the reference camera) with a reported 1-sigma of 0.13-0.42 deg, every camera
    "accepted" (up to 17 combined sigmas); with this floor, at seeds 0-2 (the 5 of 6 rigs
    Stage V solved: principal points 6-91 px off, rotations up to 6.5 deg), 1-sigma 1.0-2.5
    deg, every camera "suspicious", the largest error 2.2 combined sigmas.

    With ``lens_first`` they hold a lens found at principal points at the image centre, and
    their spread still falls short: on the same rigs at seed 0, split-half errors 0.4-6.8 px
    with the principal points 1.7-23.5 px off, rotation 1-sigmas 0.14-1.04 deg with relative
    rotations up to 0.84-1.73 deg off (phones camera 0: 0.4 px apart, 23.5 px off). Known
    intrinsics (``fixed``) keep theirs.
    """
    out = np.maximum(pp_se, _prior_spread(cameras, fixed, cfg))  # known: 0, theirs kept
    log.info("lens model kept: the principal points are as uncertain as their prior (%s px)",
             ", ".join(f"{v:.0f}" for v in out))
    return out


@one_blas_thread
def refine(tracks: list[Tracks], initial: Calibration, config: RefineConfig | None = None, *,
           height: float = 1.70, rng: np.random.Generator | int | None = None,
           progress: Callable[[float], None] | None = None,
           fixed_intrinsics: Collection[str] = (),
           rate_measured: Mapping[str, bool] | None = None) -> RefineResult:
    """Refine all cameras (intrinsics, extrinsics, time offsets) and triangulate every frame.

    Parameters
    ----------
    tracks : list of Tracks
        One per camera of ``initial`` (matched by name), 2D detections.
    initial : Calibration
        Cameras from stages I-IV in one world frame (z up, ground z = 0, metres) with time offsets
        and rates per cascalib's TIME CONVENTION.
    config : RefineConfig, optional
    height : float
        Mean person height (m): the metric scale.
    rng : Generator or seed, optional
        For the subsets of the time and distortion checks.
    progress : callable, optional
        ``progress(fraction)`` after each step (association, solve and clock update of every
        round, the intrinsics passes, the final reconstruction); fractions rise to 1.
    fixed_intrinsics : collection of str
        Cameras whose intrinsics in ``initial`` (K and distortion) are known: they are held in
        every solve and returned exactly as given.
    rate_measured : mapping of str to bool, optional
        Per camera, whether stage III measured its rate in ``initial`` (True) or kept its
        declared frame rate's ratio (False; ``AlignmentResult.rate_measured``). The clock
        search holds a declared ratio close (``time_rate_sd``) but lets it go to a mislabelled
        rate (29.97 fps declared as 30) where the data ask, and a measured one only loosely
        (:data:`MEASURED_RATE_SD`): stage III's pair fits measure a rate to no better than
        that. Cameras not named: held close, no mislabel.

    Returns
    -------
    RefineResult

    Raises
    ------
    InputError
        If a camera of ``initial`` has no tracks.
    RefinementFailed
        If too few people are seen by two cameras, the reference camera sees none of the
        person-frames, or the solve fails. A non-reference camera that sees none of them (its
        time offset or pose from stages II-IV is wrong) does not stop the rest: they are refined
        without it, and it comes back as stages I-IV left it, with the verdict "failed" and
        the reason.
    """
    cfg = config or RefineConfig()
    rng = np.random.default_rng(rng)
    shown = [0.0]  # a retry starts its steps again: progress never goes back

    def monotone(fraction: float) -> None:
        shown[0] = max(shown[0], fraction)
        if progress is not None:
            progress(shown[0])

    t0 = time.perf_counter()
    with account() as spent:
        res = _refine_or_retry(tracks, initial, cfg, height, rng, monotone, fixed_intrinsics,
                               rate_measured or {})
    if spent is None:  # a retry inside refine(): the caller's tally has its seconds
        return res
    total = time.perf_counter() - t0
    spent["other"] = max(total - sum(spent.values()), 0.0)  # timed blocks never overlap
    spent["total"] = total
    return replace(res, step_seconds=spent)


def _refine_or_retry(tracks: list[Tracks], initial: Calibration, cfg: RefineConfig,
                     height: float, rng: np.random.Generator,
                     monotone: Callable[[float], None], fixed_intrinsics: Collection[str],
                     rate_measured: Mapping[str, bool]
                     ) -> RefineResult:
    """:func:`refine`'s work: the rig, or, where a non-reference camera sees none of the
    person-frames, the rig without it."""
    try:
        return _refine_rig(tracks, initial, cfg, height, rng, monotone, fixed_intrinsics,
                           rate_measured)
    except RefinementFailed as exc:
        bad = exc.camera
        if bad not in initial.names or bad == initial.reference_camera or len(initial) <= 2:
            raise
        log.warning("camera %s: %s; the other cameras are refined without it", bad, exc.message)
        rest = Calibration([c for c in initial.cameras if c.name != bad],
                           reference_camera=initial.reference_camera,
                           quality=dict(initial.quality), world=initial.world)
        res = refine([t for t in tracks if t.camera != bad], rest, cfg, height=height, rng=rng,
                     progress=monotone,
                     fixed_intrinsics=[n for n in fixed_intrinsics if n != bad],
                     rate_measured=rate_measured)
        return with_failed_camera(res, initial, bad, f"left out of the refinement (kept as "
                                  f"stages I-IV left it): it {exc.message}; check its time "
                                  "offset and pose from stages II-IV")


def _refine_rig(tracks: list[Tracks], initial: Calibration, cfg: RefineConfig, height: float,
                rng: np.random.Generator, progress: Callable[[float], None],
                fixed_intrinsics: Collection[str], rate_measured: Mapping[str, bool]
                ) -> RefineResult:
    """:func:`refine` of every camera of ``initial``, or RefinementFailed."""
    min_rounds, max_rounds = _round_limits(cfg)
    # steps: 3 per round, the two intrinsics passes, the reconstruction
    prog = _Progress(progress, 3 * min_rounds + 3)
    data = prepare(tracks, initial)
    unknown = sorted(set(fixed_intrinsics) - set(initial.names))
    if unknown:
        raise InputError(f"known intrinsics given for cameras {unknown} that the calibration "
                         f"lacks ({initial.names})", camera=unknown[0], field="known_intrinsics")
    # the rounds need enough person-frames to choose max_groups from, not every frame
    rounds = replace(data, times=data.times[::max(1, -(-len(data.times) // cfg.round_frames))])
    run = _Run(data, rounds, cfg, height, np.array([CANONICAL_INDEX[n] for n in cfg.joints]),
               frozenset(initial.names.index(n) for n in fixed_intrinsics),
               [c.time_rate for c in initial.cameras], rng, prog,
               declared=frozenset(i for i, n in enumerate(initial.names)
                                  if n in rate_measured and not rate_measured[n]),
               measured=frozenset(i for i, n in enumerate(initial.names)
                                  if rate_measured.get(n, False)))
    fit = _solve_rounds(run, list(initial.cameras), least=min_rounds, most=max_rounds,
                        refined=False)
    # a lens the start cameras carry (a calibration with distortion given back) was held by
    # the rounds: estimated again, and kept unless held-out persons reproject worse
    lens = any(c.has_distortion for i, c in enumerate(initial.cameras) if i not in run.fixed)
    if cfg.lens_first and cfg.distortion != "never":
        # its own random stream: a rig where no lens is found goes on as without it
        fit, kept = _lens_pass(run, fit, rng.spawn(1)[0], held=lens)
        lens = lens or kept
    fit, pp = _principal_point_pass(run, fit)
    estimated = pp  # the last kept pass: the principal points the cameras carry
    crowd = _crowded(fit.assoc, cfg)
    for k in range(cfg.principal_point_reruns):
        if pp is None or (pp.moved_deg <= cfg.principal_point_rerun_deg
                          and not (crowd and k == 0)):
            break
        # the rounds' association, clocks and bone targets were made at a geometry about that
        # far off (principal points at the image centre): once more at the pass's
        log.info("one more round and pass at the principal-point pass's principal points")
        prog.total += 3
        fit = _solve_rounds(run, pp.fit.cameras, least=1, most=1, refined=True)
        fit, pp = _principal_point_pass(run, fit)
        estimated = pp or estimated
    prog.step()
    pp_se = None
    if estimated is not None:
        # the split halves start where the pass did (their spread is the pass's, not the
        # update's); nothing after them depends on the pass having run first. A rerun whose
        # own pass was not kept leaves the cameras at the earlier pass's principal points
        # (its round held them there): their spread is that pass's
        pp_se = principal_point_spread(estimated.start.assoc, estimated.chosen,
                                       estimated.start.cameras, cfg, estimated.start.kw,
                                       max_groups=cfg.spread_groups)
    if pp is not None:
        fit = pp.fit
    if pp_se is None:
        # no principal-point pass ran or was kept (or its spread could not be measured): the
        # principal points sit where the rounds held them, at the image centre, as uncertain
        # as real ones lie from it. Reported as unknown (NaN) instead, the rotation's sigma
        # left that error out: on the simulator's phones (principal points 1-4 % of the width
        # off, principal_point "never") rotations 0.9-2.1 deg off reported a 1-sigma of
        # 0.10-0.13 deg, every camera "accepted"; now 0.96-1.88 deg, three "suspicious"
        pp_se = _prior_spread(fit.cameras, run.fixed, cfg)
        log.info("principal points not estimated: assumed at the image centre (sd %s px)",
                 ", ".join(f"{v:.0f}" for v in pp_se))
    if cfg.distortion != "never" and (lens or not cfg.lens_first):
        # a lens found after the rounds is estimated again at the final principal points, kept
        # unless it reprojects held-out persons worse; none found there: none is looked for
        fit, kept = _lens_pass(run, fit, rng, held=lens)
        lens = lens or kept
    if lens:
        pp_se = _lens_floor(pp_se, fit.cameras, run.fixed, cfg)
    prog.step()
    cameras, graph, values, prob = fit.cameras, fit.graph, fit.values, fit.prob
    with timed("solves"):  # a graph built and factored, as a solve's
        if prob.obs.shape[0] > cfg.max_groups:
            graph, values, prob = rounds_size_graph(fit.assoc, fit.sel, cameras, cfg, fit.kw,
                                                    prob.model)
        sigmas = marginal_sigmas(graph, values, prob)
    sigmas = [s | {"principal_point": float(v)} for s, v in zip(sigmas, pp_se, strict=True)]
    if cfg.time_final_update and (pp is not None or lens):
        # the passes moved the geometry after the rounds' last clock update
        cameras = run.clocks(cameras)
    if run.clock_sd is not None:  # the reference's clock is exact by definition
        clock_sd = np.hypot(cfg.time_uncertainty_inflation * run.clock_sd,
                            cfg.time_uncertainty_floor_frames)
        clock_sd[data.reference] = 0.0
        sigmas = [s | {"time_offset": float(v)} for s, v in zip(sigmas, clock_sd, strict=True)]
    with timed("reconstruction"):
        final, points, err = reconstruct(data, cameras, cfg, height)
        cameras, points, factor = rescale_to_statures(cameras, points, height)
        final = replace(final, ground=factor * final.ground,
                        velocity=None if final.velocity is None else factor * final.velocity)
        log.info("metric scale from the people's leg-and-trunk chains: x%.3f", factor)
        sigmas = [s | {"position": factor * s["position"]} for s in sigmas]
        prog.step()
        quality = _report(final, err, cameras, sigmas, cfg)
        poses, ids, resid = poses_by_slot(final, points, data.times, err)
    calib = Calibration(cameras, reference_camera=initial.reference_camera,
                        quality={n: q.to_dict() for n, q in quality.items()},
                        world=initial.world)
    return RefineResult(calib, poses, data.times, ids, quality, final, run.solves, lens,
                        fit.prob.obs.shape[0], resid)
