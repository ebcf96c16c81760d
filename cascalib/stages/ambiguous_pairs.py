"""What stage III does with an ambiguous camera pair: more candidates, and the joints decide.

A pair is ambiguous when its second-best clock candidate's ICP evidence is close to its best
(``AlignConfig.ambiguity_ratio``). On people walking circles that is the rule, not the
exception: a time shift along a circle looks like a turn about its centre, so

* the vote's peaks (:mod:`~cascalib.stages.sync`) are the longest overlaps rather than the
  truth, and :func:`scan_candidates` adds candidates from quick ICP over the whole range of
  offsets, which fits one similarity to the whole overlap, where the path's lap-to-lap
  differences show;
* the ground evidence of a lap-off candidate can equal the truth's, and
  :func:`epipolar_choice` lets the epipolar geometry of the people's joints decide among the
  best candidates, each at its best clock nearby.

Measured on bench_sync.py's table 2b (the paper's sync experiment in the full simulator: one
walker on a wobbly circle, 2 cameras, offsets 0-200 frames, 7 subjects): 28/35 -> 33/35 clocks
within half a frame (one of the five from the epipolar clock search's widening), the worst
error 294 -> 0.53 frame; at offset 200 (the paper's failure) 3/7 -> 6/7. The two left (one
subject at offsets 150 and 200, 0.52 and 0.53 frame off) came from the epipolar clock search's
Huber loss, which let swapped joints pull the clock; with its Cauchy loss all 35 are within
0.08 frame.
"""

from __future__ import annotations

import logging
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from cascalib.camera import Camera
from cascalib.stages.align_config import AlignConfig
from cascalib.stages.epipolar_sync import pair_cost, quadratic_minimum
from cascalib.stages.icp import IcpResult, Lanes, SyncFit
from cascalib.stages.pair_evidence import (
    ByCamera,
    evidence,
    evidence_sigma,
    pair_icp,
    place_camera,
)
from cascalib.stages.sync import SyncCandidate, SyncCurve

__all__ = ["PairJoints", "epipolar_choice", "scan_candidates"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class PairJoints:
    """What the epipolar check of ambiguous pairs needs: every camera's canonical detections
    and frame links, its plane-frame camera, its frame-rate ratio to the reference, the
    person height prior and the reference frame rate."""

    keypoints: list[NDArray[np.float64]]
    links: list[NDArray[np.int64]]
    cameras: list[Camera]
    rho: list[float]
    height: float
    fps_ref: float


def epipolar_choice(i: int, j: int, fits: dict[int, SyncFit], joints: PairJoints,
                    cfg: AlignConfig, rng: np.random.Generator
                    ) -> tuple[int, float, float] | None:
    """The candidate whose clock and ground alignment give the lowest epipolar cost of the
    pair's joints (:func:`~cascalib.stages.epipolar_sync.pair_cost`).

    Each candidate's cost is the lowest over clocks within ``cfg.epipolar_choice_seconds`` of
    its own (:func:`_lowest_cost`): on a walker's circle the ground fit cannot tell a few
    frames late from a few degrees turned, and the paper's walker (bench_sync table 2b) had
    true candidates 2.6 and 3.2 frames off whose cost at that clock lost to a lap-off
    candidate's.

    Returns
    -------
    (k, ratio, shift) or None
        The best candidate's key in ``fits``, its cost over the runner-up's and the clock
        shift (frames) at which its cost is lowest; None unless two candidates could be
        compared.
    """
    costs = {}
    for k, fit in fits.items():
        found = _lowest_cost(i, j, fit, joints, cfg, int(rng.integers(2**62)))
        if found is not None:
            costs[k] = found
    if len(costs) < 2:
        return None
    best, second = sorted(costs, key=lambda m: costs[m][0])[:2]
    logger.info("pair %d-%d: epipolar costs of the candidates %s", i, j,
                ", ".join(f"{fits[k].offset:.1f}{c[1]:+.1f}: {c[0]:.3g}"
                          for k, c in costs.items()))
    return best, costs[best][0] / max(costs[second][0], 1e-300), costs[best][1]


def _lowest_cost(i: int, j: int, fit: SyncFit, joints: PairJoints, cfg: AlignConfig,
                 seed: int) -> tuple[float, float] | None:
    """The lowest epipolar cost of one candidate over clock shifts up to
    ``cfg.epipolar_choice_seconds`` (steps of two frames, then one beside the lowest, and the
    vertex of the parabola through those three), and the shift; every shift on the same random
    subset of joints."""
    n_i = joints.keypoints[i].shape[0]
    times = np.linspace(0.0, (n_i - 1) * joints.rho[i], cfg.epipolar_times)
    cam_i = joints.cameras[i].with_(time_offset=0.0, time_rate=joints.rho[i])
    placed = place_camera(joints.cameras[j], fit.transform).with_(
        time_rate=fit.rate * joints.rho[j])
    reach = cfg.epipolar_choice_seconds * joints.fps_ref

    def cost(shift: float) -> float:
        found = pair_cost([joints.keypoints[i], joints.keypoints[j]],
                          [joints.links[i], joints.links[j]],
                          [cam_i, placed.with_(time_offset=fit.offset + shift)], times,
                          height=joints.height, max_points=cfg.epipolar_points, rng=seed)
        return np.inf if found is None else found[0]

    tried = {float(d): cost(float(d)) for d in np.arange(-2 * (reach // 2), reach + 0.5, 2)}
    at = min(tried, key=tried.__getitem__)
    if not np.isfinite(tried[at]):
        return None
    if reach >= 1:
        tried.update({d: cost(d) for d in (at - 1.0, at + 1.0) if d not in tried})
        at = min(tried, key=tried.__getitem__)
    shifts = np.array(sorted(tried))
    costs = np.array([tried[d] for d in shifts])
    finite = np.isfinite(costs)
    # the vertex through the lowest and its neighbours a frame away (None: too few, or concave)
    vertex = quadratic_minimum(shifts[finite], costs[finite], at, 1.0)
    return tried[at], at if vertex is None else vertex[0]


def scan_candidates(i: int, j: int, curve: SyncCurve, results: list[IcpResult | None],
                    lanes: ByCamera[Lanes], fps_ref: float, cfg: AlignConfig, sr: float
                    ) -> tuple[SyncCurve, list[IcpResult | None]]:
    """More candidates for an ambiguous pair (one whose candidates include a plausible fit)
    from quick ICP at offsets ``cfg.scan_seconds`` apart (at most ``cfg.scan_max_offsets``
    of them) wherever both cameras overlap for at least half of the shorter one's recording.

    The vote scores chunks of a few seconds, each with its own rotation. A person walking a
    circle fits any offset that way (a time shift is a rotation about the centre), so the
    vote's peaks are the longest overlaps, not the truth: the paper's walker (bench_sync
    table 2b) at offset 200 had the truth among none of its candidates in 4 of 7 subjects.
    ICP fits one similarity to the whole overlap, where the lap-to-lap differences of the path
    show, and ranked the truth first in all 7. Short overlaps are left out: a few seconds of a
    circle fit to the noise at many offsets. The scan's best local maxima (``cfg.n_candidates``,
    ``cfg.nms_seconds`` apart) join the candidates; one near a vote candidate replaces it when
    its evidence is higher (the vote's peaks can sit a few frames off). Returns the curve and
    the quick ICP results, in the same order.
    """
    have = np.flatnonzero(curve.score > 0)
    if have.size < 2 or curve.angles is None:
        return curve, results
    lo, hi = curve.offsets[have[0]], curve.offsets[have[-1]]
    step = max(cfg.scan_seconds * fps_ref, (hi - lo) / cfg.scan_max_offsets)
    idx = np.unique(np.searchsorted(curve.offsets, np.arange(lo, hi + 0.5 * step, step)))
    idx = idx[idx < curve.offsets.size]
    idx = idx[curve.score[idx] > 0]
    seen = min(int(np.isfinite(la.pos[..., 0]).any(axis=1).sum()) for la in (lanes[i], lanes[j]))
    scan = [pair_icp(i, j, int(round(curve.offsets[k])), float(curve.angles[k]), lanes, cfg, sr,
                 quick=True) for k in idx]
    scan = [r if r is not None and r.n_overlap >= 0.5 * seen else None for r in scan]
    sig = evidence_sigma(results + scan, cfg)
    full = cfg.evidence_seconds * fps_ref
    score = evidence(scan, sig, lanes[i], lanes[j], full)
    cands, results = list(curve.candidates), list(results)
    held = evidence(results, sig, lanes[i], lanes[j], full)
    nms = cfg.nms_seconds * fps_ref
    maxima: list[int] = []
    for m in np.argsort(score)[::-1]:
        if score[m] <= 0 or len(maxima) >= cfg.n_candidates:
            break
        o = curve.offsets[idx[m]]
        if any(abs(o - curve.offsets[idx[q]]) < nms for q in maxima):
            continue
        maxima.append(int(m))
        near = [c for c, cand in enumerate(cands) if abs(cand.offset - o) < nms]
        found = SyncCandidate(float(o), float(curve.angles[idx[m]]), float(curve.score[idx[m]]))
        if not near:
            cands.append(found)
            results.append(scan[m])
            held.append(score[m])
        elif score[m] > max(held[c] for c in near):
            c = max(near, key=held.__getitem__)
            cands[c], results[c], held[c] = found, scan[m], score[m]
    logger.debug("pair %d-%d: ambiguous, %d offsets scanned, candidates now at %s", i, j,
                 idx.size, [round(c.offset, 1) for c in cands])
    return replace(curve, candidates=cands), results
