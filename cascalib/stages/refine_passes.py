"""Stage V's intrinsics passes: solves with more intrinsics free than the rounds', and the
checks that decide on them.

:func:`intrinsics_pass` solves a pass (principal point, ``s2``; lens distortion, ``ds2``) from
refined cameras and keeps it if held-out person-frames agree (:func:`heldout_gain`);
:func:`settle_principal_points` solves the principal-point pass again with bone targets from its
own cameras; :func:`principal_point_spread` is the split-half standard error the quality report
gives the principal point; :func:`rounds_size_graph` is the graph the marginals come from.
:mod:`cascalib.stages.refine` decides when each runs.
"""

from __future__ import annotations

import logging
from dataclasses import replace

import gtsam
import numpy as np
from numpy.typing import NDArray

from cascalib.camera import Camera
from cascalib.errors import RefinementFailed
from cascalib.skeletons import CANONICAL_INDEX
from cascalib.stages.association import Association, ground_velocity
from cascalib.stages.frame_selection import usable_groups
from cascalib.stages.reconstruct import triangulate_groups
from cascalib.stages.refine_config import RefineConfig
from cascalib.stages.refine_graph import GraphProblem, build_graph, initial_values
from cascalib.stages.refine_problem import (
    pass_config,
    refined_problem,
    solve,
    track_targets,
    with_iterations,
)

__all__ = ["heldout_gain", "intrinsics_pass", "principal_point_spread", "rounds_size_graph",
           "settle_principal_points", "split_halves"]

log = logging.getLogger(__name__)


def _heldout_error(assoc: Association, idx: NDArray[np.int64], cameras: list[Camera],
                   joints: NDArray[np.int64]) -> float:
    _, err = triangulate_groups(assoc.subset(idx), cameras, joints)
    e = err[np.isfinite(err)]
    return float(np.median(e)) if e.size else float("inf")


def rounds_size_graph(assoc: Association, sel: NDArray[np.int64], cameras: list[Camera],
                      cfg: RefineConfig, kw: dict, model: str
                      ) -> tuple[gtsam.NonlinearFactorGraph, gtsam.Values, GraphProblem]:
    """The graph of the rounds' person-frames ``sel`` at the final ``cameras``, for marginals.

    ``uncertainty_inflation`` is calibrated on graphs of that size. A larger pass shrinks the
    marginals by the square root of its size, while the principal point's error (its trade-off
    with the rotation, settled by the priors more than by the images) falls far less.
    """
    prob = refined_problem(assoc, sel, cameras, cfg, kw, model)
    return build_graph(prob, cfg), initial_values(prob), prob


def heldout_gain(assoc: Association, exclude: NDArray[np.int64], before: list[Camera],
                 after: list[Camera], cfg: RefineConfig, rng: np.random.Generator, label: str
                 ) -> float | None:
    """Relative drop of the median reprojection error of held-out person-frames from cameras
    ``before`` to ``after`` (negative: it rose); None if nothing can be held out.

    Held out are person-frames of ``assoc`` that no solve behind either rig saw (``exclude``),
    or the rigs would be judged on their own data; and only those the selection could have
    chosen: a large pass leaves mostly the least consistent groups, on which a lens model's
    gain drowned (phones seed 0: 1.7 % there, 6.1 % on usable groups).
    """
    joints = np.array([CANONICAL_INDEX[n] for n in cfg.joints])
    rest = np.setdiff1d(usable_groups(assoc, joints), exclude)
    if rest.size == 0:
        return None
    held = np.sort(rng.choice(rest, min(rest.size, 1500), replace=False))
    e1 = _heldout_error(assoc, held, before, joints)
    e2 = _heldout_error(assoc, held, after, joints)
    gain = 1 - e2 / e1 if e1 > 0 else 0.0
    log.info("%s: held-out median reprojection %.3f -> %.3f px (gain %.1f %%)", label, e1, e2,
             100 * gain)
    return gain


def intrinsics_pass(assoc: Association, sel: NDArray[np.int64], cameras: list[Camera],
                    cfg: RefineConfig, kw: dict, rng: np.random.Generator, *, model: str,
                    mode: str, min_gain: float = 0.0,
                    fitted: NDArray[np.int64] | None = None):  # noqa: ANN202
    """A pass with more intrinsics free (with priors); kept if held-out frames agree.

    ``mode`` "always" keeps it; "auto" keeps it when the median reprojection error of held-out
    person-frames (neither in the graph nor in ``fitted``, the person-frames earlier solves
    saw) drops by at least ``min_gain`` (relative; may be negative).
    """
    prob = refined_problem(assoc, sel, cameras, cfg, kw, model)
    try:
        res = solve(prob, pass_config(cfg, model),
                    method=cfg.pass_solver if model == "s2" else "levenberg-marquardt")
    except RefinementFailed as exc:
        log.warning("%s pass failed, keeping the previous cameras: %s", model, exc)
        return None
    if mode == "always":
        return res + (prob,)
    seen = sel if fitted is None else np.union1d(sel, fitted)
    gain = heldout_gain(assoc, seen, cameras, res[0], cfg, rng, f"{model} pass")
    return res + (prob,) if gain is not None and gain >= min_gain else None


def settle_principal_points(assoc: Association, sel: NDArray[np.int64], res: tuple,
                            cfg: RefineConfig, kw: dict, joints: NDArray[np.int64],
                            height: float) -> tuple[Association, dict, tuple]:
    """The principal-point pass solved again ``cfg.principal_point_updates`` times, each with
    the bone targets (and the track cuts) triangulated anew with the previous solve's cameras.

    The targets come from the rounds' cameras, whose principal points sit at the image centre,
    and they hold the pass near that start; re-triangulated, they follow the pass. Returns the
    association, the passes' keywords (targets) and the solve's outcome (``res`` unchanged if
    an update fails).
    """
    solve_cfg = with_iterations(cfg, cfg.principal_point_update_iterations)
    for _ in range(cfg.principal_point_updates if cfg.use_bones else 0):
        cut, targets = track_targets(assoc, res[0], cfg, joints, height)
        cut = replace(cut, velocity=ground_velocity(cut))
        prob = refined_problem(cut, sel, res[0], cfg, kw | {"targets": targets}, "s2")
        try:
            res = solve(prob, solve_cfg, method=cfg.pass_solver) + (prob,)
        except RefinementFailed as exc:
            log.warning("principal-point update failed, keeping the previous solve: %s", exc)
            break
        assoc, kw = cut, kw | {"targets": targets}
    return assoc, kw, res


def split_halves(assoc: Association, order: NDArray[np.int64], *, min_groups: int = 10,
                 n_blocks: int = 8) -> tuple[NDArray[np.int64], NDArray[np.int64]]:
    """The person-frames ``order`` (sorted by time) in two halves for a split-half check:
    before and after the median time, or, where that leaves a camera that sees any of them
    with fewer than ``min_groups`` in a half (a camera that started recording late or stopped
    early), alternate blocks of ``n_blocks`` equal parts of ``order``: a solve on a half
    without a camera has nothing to constrain that camera."""
    t = assoc.times[order]
    first = t <= np.median(t)
    seen = np.isfinite(assoc.obs[order][..., 0]).any(-1)  # (G, C)
    counts = np.stack([seen[first].sum(0), seen[~first].sum(0)])  # type: ignore[index]
    present = seen.any(0)
    if (counts[:, present] < min_groups).any():
        first = (np.arange(order.size) * n_blocks // max(order.size, 1)) % 2 == 0
        log.info("split-half check in %d alternating time blocks: a camera sees too few "
                 "person-frames on one side of the median time", n_blocks)
    return order[first], order[~first]


def principal_point_spread(assoc: Association, sel: NDArray[np.int64], cameras: list[Camera],
                           cfg: RefineConfig, kw: dict, *, max_groups: int | None = None
                           ) -> NDArray[np.float64] | None:
    """Split-half standard error (px) of each camera's principal point, shape (C,).

    The principal-point pass is solved again on the selected person-frames of each half of the
    recording (split at the median time, so slowly varying detector errors do not repeat in
    both; in alternating blocks of time where a camera would miss a half, see
    :func:`split_halves`); half the distance between the two estimates is the standard error
    of one estimate from all of them. With ``max_groups``, each half keeps at most that many
    person-frames (evenly spread in time), so the check costs what two default passes cost
    whatever the pass's budget. The distance is then *not* scaled down to the pass's size: the
    principal point's error is mostly not noise (on noise-free, synchronised simulated data
    the free principal point moved 11 px at an unchanged reprojection error of 0.003 px rms:
    the people's priors, not the images, settle it), so a noise-like 1/sqrt(n) shrinkage would
    overstate what more person-frames buy. Cameras of known intrinsics get 0; None if a half
    cannot be solved.
    """
    order = sel[np.argsort(assoc.times[sel], kind="stable")]
    if max_groups is not None and order.size > 2 * max_groups:
        order = order[np.linspace(0, order.size - 1, 2 * max_groups).round().astype(int)]
    pps = []
    for part in split_halves(assoc, order):
        prob = refined_problem(assoc, np.sort(part), cameras, cfg, kw, "s2")
        try:
            cams = solve(prob, with_iterations(cfg, cfg.spread_iterations),
                         method=cfg.pass_solver)[0]
        except RefinementFailed as exc:
            log.info("split-half principal point unavailable: %s", exc)
            return None
        pps.append(np.array([c.K[:2, 2] for c in cams]))
    return np.linalg.norm(pps[0] - pps[1], axis=1) / 2
