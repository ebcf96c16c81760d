"""One solve of stage V: the factor graph's problem from an association and cameras, and the
graduated solve of it.

:func:`make_problem` triangulates the person-frames, picks the stance feet and head points that
carry the ground and height priors, the bone-length targets of the tracks
(:func:`track_targets`) and the upright torsos, and fits the keypoint noise model;
:func:`solve` builds the graph (:mod:`cascalib.stages.refine_graph`) and solves it, lowering the
noise level from the spread of the residuals. :mod:`cascalib.stages.refine` runs these in rounds
and passes.
"""

from __future__ import annotations

from dataclasses import replace

import numpy as np
from numpy.typing import NDArray

from cascalib.camera import Camera
from cascalib.errors import RefinementFailed
from cascalib.geometry import norm_xy
from cascalib.skeletons import CANONICAL_INDEX
from cascalib.stages.association import Association
from cascalib.stages.keypoint_noise import size_noise_scale, triangulation_weights
from cascalib.stages.person_size import bone_pairs, split_by_size
from cascalib.stages.reconstruct import triangulate_groups
from cascalib.stages.refine_config import HEAD_HEIGHT_FRACTIONS, RefineConfig
from cascalib.stages.refine_graph import (
    GraphProblem,
    Solver,
    build_graph,
    initial_values,
    optimize,
    unpack,
)
from cascalib.stages.torso_lean import expected_torso_offsets, torso_offsets
from cascalib.step_seconds import timed

__all__ = ["bone_targets", "head_joint", "ideal_pinhole", "make_problem", "pass_config",
           "refined_problem", "solve", "track_targets", "with_iterations"]


def bone_targets(points: NDArray[np.float64], tracks: NDArray[np.int64], bones: NDArray[np.int64],
                 classes: NDArray[np.int64], *, min_samples: int = 3) -> dict[int, NDArray]:
    """Per-track median length of each bone class (left and right pooled).

    Parameters
    ----------
    points : ndarray, shape (G, J, 3)
    tracks : ndarray of int, shape (G,)
    bones, classes : ndarray, shape (B, 2) and (B,)

    Returns
    -------
    dict of int to ndarray, shape (n_classes,)
        Median per class (NaN with fewer than ``min_samples`` lengths) for each track.
    """
    lengths = np.linalg.norm(points[:, bones[:, 0]] - points[:, bones[:, 1]], axis=-1)  # (G, B)
    n_cls = int(classes.max()) + 1 if classes.size else 0
    out: dict[int, NDArray] = {}
    for tr in np.unique(tracks[tracks >= 0]):
        rows = lengths[tracks == tr]
        med = np.full(n_cls, np.nan)
        for k in range(n_cls):
            v = rows[:, classes == k].ravel()
            v = v[np.isfinite(v)]
            if v.size >= min_samples:
                med[k] = np.median(v)
        out[int(tr)] = med
    return out


def head_joint(points: NDArray[np.float64], names: tuple[str, ...]) -> str | None:
    """The head keypoint that carries the height prior: the first of
    :data:`HEAD_HEIGHT_FRACTIONS` (head top first) that is in ``names`` and reconstructed in at
    least a tenth of the person-frames; None when there is none."""
    n = max(points.shape[0], 1)
    for joint in HEAD_HEIGHT_FRACTIONS:
        if joint in names and np.isfinite(points[:, names.index(joint), 2]).sum() >= 0.1 * n:
            return joint
    return None


def track_targets(assoc: Association, cameras: list[Camera], cfg: RefineConfig,
                  joints: NDArray[np.int64], height: float
                  ) -> tuple[Association, dict[int, NDArray]]:
    """``assoc`` with its tracks cut where the person's size jumps (:func:`split_by_size`), and
    the bone-length targets of those tracks (:func:`bone_targets`), triangulated with
    ``cameras`` (solved, so that the height prior has set their scale) and rescaled to the
    height prior, so that the bone terms never pin a scale it disagrees with."""
    pts, _ = triangulate_groups(assoc, cameras, joints)
    bones, classes = bone_pairs(tuple(cfg.joints))
    person = split_by_size(pts, assoc.tracks, assoc.times, bones, classes)
    targets = bone_targets(pts, person, bones, classes)
    k = _height_scale(pts, tuple(cfg.joints), cfg, height)
    return replace(assoc, tracks=person), {tr: v * k for tr, v in targets.items()}


def _foot_and_head(points: NDArray[np.float64], names: tuple[str, ...], cfg: RefineConfig
                   ) -> tuple[NDArray[np.bool_], NDArray[np.bool_]]:
    """Stance ankles and head points (see :func:`head_joint`) of upright persons, (S, J) masks."""
    s, j = points.shape[:2]
    stance = np.zeros((s, j), dtype=bool)
    head = np.zeros((s, j), dtype=bool)
    if "left_ankle" not in names or "right_ankle" not in names:
        return stance, head
    ia, ib = names.index("left_ankle"), names.index("right_ankle")
    z = points[:, [ia, ib], 2]
    with np.errstate(invalid="ignore"):
        low = np.nanmin(np.where(np.isfinite(z), z, np.inf), axis=1)
        both = np.isfinite(z).all(1)
        stance[:, [ia, ib]] = both[:, None] & (z - low[:, None] < cfg.stance_tolerance_m)  # type: ignore[index]
    joint = head_joint(points, names)
    if joint is not None:
        ih = names.index(joint)
        rise = points[:, ih, 2] - low
        ok = np.isfinite(rise) & both
        if ok.any():
            head[:, ih] = ok & (rise > 0.85 * np.median(rise[ok]))
    return stance, head


def _height_scale(points: NDArray[np.float64], names: tuple[str, ...], cfg: RefineConfig,
                  height: float) -> float:
    """Factor that brings the median head height of upright persons to the prior."""
    stance, head = _foot_and_head(points, names, cfg)
    if not head.any() or not stance.any():
        return 1.0
    feet_z = np.nanmedian(points[stance][:, 2])
    head_z = np.nanmedian(points[head][:, 2])
    joint = names[int(np.nonzero(head.any(0))[0][0])]
    target = cfg.head_height(joint, height) - cfg.ankle_height
    rise = head_z - feet_z
    return float(target / rise) if rise > 0.5 else 1.0


def make_problem(assoc: Association, cameras: list[Camera], cfg: RefineConfig, *,
                 height: float, n_persons: int, reference: int, model: str = "f",
                 targets: dict[int, NDArray] | None = None,
                 fixed: frozenset[int] = frozenset(), solved: bool = True) -> GraphProblem:
    """The graph's problem for the groups of ``assoc`` from ``cameras``.

    ``solved`` says that ``cameras`` come out of a solve, so that their residuals are detector
    noise and the size noise model (``cfg.size_noise``) can be fitted to them. From the first
    start they are mostly the start's geometry errors, which grow with the person's size as well
    (a position error is seen larger from nearby): fitted there, the model took them for noise
    and weighed the near persons down (phones preset from 3 deg / 0.3 m / 5 % focal: sigma^2 =
    (0.115 h)^2 instead of about 4 + (0.008 h)^2 px^2 after a solve; relative rotations 0.59 ->
    1.06 deg).
    """
    names = tuple(cfg.joints)
    joints = np.array([CANONICAL_INDEX[n] for n in names])
    obs = assoc.obs.copy()
    # a joint is a variable only with two usable observations: drop weak ones before triangulating
    obs[np.nan_to_num(obs[..., 2]) < cfg.min_confidence] = np.nan
    assoc = Association(assoc.times, obs, assoc.tracks, assoc.ground, assoc.residual,
                        assoc.velocity)
    huber_px = 4.0
    points, err = triangulate_groups(assoc, cameras, joints, huber_px=huber_px)
    scale = None
    if cfg.size_noise and solved:
        w = triangulation_weights(err, obs[:, :, joints, 2], huber_px)
        scale = size_noise_scale(err, points, cameras, w, height)
        err = err / scale[..., None]
    e = err[np.isfinite(err)]
    # median of a 2D error norm is 1.18 sigma (chi, 2 dof); relative to each view's noise
    sigma = max(cfg.sigma_px, float(np.median(e)) / 1.18 if e.size else 0.0)
    stance, head = _foot_and_head(points, names, cfg)
    bones, classes = bone_pairs(names)
    lengths = np.full((assoc.n_groups, len(bones)), np.nan)
    if targets and cfg.use_bones:
        for s, tr in enumerate(assoc.tracks):
            if int(tr) in targets:
                lengths[s] = targets[int(tr)][classes]
    obs = assoc.obs[:, :, joints].copy()
    graph_cams = list(cameras)
    # a lens the camera carries (a lens pass found it, or the start gave it) is held by
    # every solve but the lens pass itself
    lens = {c: cam.dist.copy() for c, cam in enumerate(cameras)
            if c not in fixed and model != "ds2" and cam.has_distortion}
    for c in [*fixed, *lens]:
        graph_cams[c], obs[:, c, :, :2] = ideal_pinhole(cameras[c], obs[:, c, :, :2])
    torso = None
    if model != "f" and cfg.upright_sigma_m > 0:
        upright = head.any(1)
        lean = expected_torso_offsets(torso_offsets(points, names), assoc.velocity, upright)  # type: ignore[arg-type]
        torso = np.where(upright[:, None], lean, np.nan)  # type: ignore[index]
    return GraphProblem(graph_cams, obs, names, points, stance, head, bones, lengths, reference,
                        model, height, n_persons, sigma,  # type: ignore[arg-type]
                        {c: cameras[c] for c in fixed}, scale, torso, lens)


def ideal_pinhole(cam: Camera, uv: NDArray[np.float64]) -> tuple[Camera, NDArray[np.float64]]:
    """A camera of known intrinsics as the distortion-free, square-pixel pinhole that the graph's
    calibration models (``Cal3f`` has one focal) express exactly, with its keypoints ``uv``
    (..., 2) mapped to that pinhole's pixels (any lens model, k3 included, which gtsam's
    ``Cal3DS2`` lacks). Pixels of the two differ by ``fx / fy`` at most."""
    f = float(np.sqrt(cam.fx * cam.fy))
    K = np.array([[f, 0.0, cam.K[0, 2]], [0.0, f, cam.K[1, 2]], [0.0, 0.0, 1.0]])
    xy = cam.undistort(uv)
    return cam.with_(K=K, dist=np.zeros(5)), xy * f + cam.K[:2, 2]


def solve(prob: GraphProblem, cfg: RefineConfig, *, max_stages: int = 4,  # noqa: ANN201
          method: Solver = "levenberg-marquardt"):
    """Graduated solve: from a poor start the noise level is the spread of the residuals.

    Each stage solves with ``prob.sigma_px``, then lowers it to the spread of the new residuals
    (never below ``cfg.sigma_px``) and solves again from the result, by ``method`` (see
    :func:`~cascalib.stages.refine_graph.optimize`).

    Returns
    -------
    cameras, points, info, graph, values
        Refined cameras and joints (S, J, 3), the last SolveInfo, graph and gtsam Values.

    Raises
    ------
    RefinementFailed
        If a camera sees none of the person-frames (nothing would constrain it), or the solve
        fails (:func:`~cascalib.stages.refine_graph.optimize`).

    Notes
    -----
    Its wall time (graph building included) counts as "solves" in an open
    :func:`cascalib.step_seconds.account`.
    """
    with timed("solves"):
        return _solve(prob, cfg, max_stages, method)


def _solve(prob: GraphProblem, cfg: RefineConfig, max_stages: int, method: Solver):  # noqa: ANN202
    """:func:`solve`, untimed."""
    seen = prob.projected(cfg.min_confidence).any(-1).sum(0)  # (C,) person-frames
    blind = [prob.cameras[c].name for c in np.flatnonzero(seen == 0)]
    if blind:
        raise RefinementFailed(f"sees none of the {prob.obs.shape[0]} person-frames of this "
                               f"solve (nothing constrains it)" + (
                                   f"; nor do {', '.join(blind[1:])}" if blind[1:] else ""),
                               camera=blind[0])
    values = initial_values(prob)
    for _ in range(max_stages):
        graph = build_graph(prob, cfg)
        values, info = optimize(graph, values, cfg, method=method,
                                names=[c.name for c in prob.cameras])
        cameras, points = unpack(values, prob)
        if prob.sigma_px <= cfg.sigma_px:
            break
        # in the graph's pixels: cameras of known intrinsics, or of a held lens, observe their
        # ideal pinhole's
        proj = np.stack([_graph_camera(prob, c, cam).project(points)
                         for c, cam in enumerate(cameras)], axis=1)  # (S, C, J, 2)
        err = norm_xy(proj - prob.obs[..., :2])
        if prob.noise_scale is not None:
            err = err / prob.noise_scale[..., None]
        e = err[np.isfinite(err)]
        prob.sigma_px = max(cfg.sigma_px, min(prob.sigma_px / 3, float(np.median(e)) / 1.18))
    return cameras, points, info, graph, values


def _graph_camera(prob: GraphProblem, c: int, cam: Camera) -> Camera:
    """Solved camera ``c`` as the graph sees it: the pinhole its ``prob.obs`` are in."""
    if c in prob.fixed:
        return prob.cameras[c].with_(R=cam.R, t=cam.t)
    return cam.with_(dist=np.zeros(5)) if c in prob.lens else cam


def with_iterations(cfg: RefineConfig, n: int) -> RefineConfig:
    """``cfg`` with Levenberg-Marquardt stopping after ``n`` iterations (``max_iterations`` at
    most): the intrinsics passes start from refined cameras, and their later iterations, mostly
    rejected LM trials, only reweight outliers."""
    return cfg.model_copy(update={"max_iterations": min(cfg.max_iterations, n)})


def pass_config(cfg: RefineConfig, model: str) -> RefineConfig:
    """The settings of an intrinsics pass: the principal-point pass stops after
    ``cfg.principal_point_iterations``."""
    return with_iterations(cfg, cfg.principal_point_iterations) if model == "s2" else cfg


def refined_problem(assoc: Association, sel: NDArray[np.int64], cameras: list[Camera],
                    cfg: RefineConfig, kw: dict, model: str) -> GraphProblem:
    """The problem of the person-frames ``sel`` from already refined ``cameras``: its noise
    level starts at ``cfg.sigma_px`` (no graduation)."""
    prob = make_problem(assoc.subset(sel), cameras, cfg, model=model, **kw)
    prob.sigma_px = cfg.sigma_px
    return prob
