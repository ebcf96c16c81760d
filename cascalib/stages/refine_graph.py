"""The stage V factor graph: build, initial values, optimise, unpack.

Key table (``gtsam.symbol_shorthand``):

======  =====================================================  =================================
Key     Variable                                               Type
======  =====================================================  =================================
X(c)    pose of camera c, *world_from_camera* (gtsam's Pose3)    ``gtsam.Pose3``
K(c)    intrinsics of camera c: one focal with the principal     ``gtsam.Cal3f`` or ``Cal3DS2``
        point fixed, or fx, fy, s, principal point, k1, k2,
        p1, p2 in the final distortion pass; a camera whose
        intrinsics are known is held at an ideal pinhole by a
        tight prior, its keypoints undistorted with its lens
P(k)    3D joint k = s * J + j: joint j of selected group s      ``gtsam.Point3`` (world, metres)
======  =====================================================  =================================

Factors, all built into gtsam (Python ``CustomFactor`` callbacks copy the whole ``Values`` on each
call inside gtsam's optimisers, which grows with the square of the problem):

* ``GeneralSFMFactor2Cal3f`` / ``...Cal3DS2``: reprojection of every keypoint, sigma
  ``sigma_px / sqrt(confidence)`` (px), in a Huber or Cauchy kernel;
* ``PriorFactorPoint3`` on a stance ankle, precision on z only: the feet stand on the ground
  plane (z = ankle height) -- fixes the world's z, roll and pitch;
* ``PriorFactorPoint3`` on the head top of upright persons, precision on z only: the height prior
  -- fixes the metric scale (the average over persons, sd ``height_sd / sqrt(n_persons)``);
* ``RangeFactor3`` on bones: constant bone length over a track and left/right symmetry, both to the
  per-track median triangulated with the previous round's cameras;
* ``BetweenFactorPoint3`` from the mid-hip to the neck of upright persons, precision on x, y only:
  upright torsos, the neck ahead by the walking lean (:mod:`cascalib.stages.torso_lean`), in the
  intrinsics passes;
* ``PriorFactorPose3`` on the reference camera with a full covariance that is tight on its yaw and
  x, y in the *world* frame and loose on tilt and height: fixes the world's yaw and origin.
"""

from __future__ import annotations

import logging
import time
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Literal

import gtsam
import numpy as np
from gtsam.symbol_shorthand import K, P, X
from numpy.typing import NDArray

from cascalib.camera import Camera
from cascalib.errors import RefinementFailed
from cascalib.native_output import points_behind_reported
from cascalib.stages.refine_config import RefineConfig
from cascalib.stages.torso_lean import TORSO

__all__ = ["GraphProblem", "build_graph", "initial_values", "optimize", "unpack"]

log = logging.getLogger(__name__)

_LOOSE = 1e3  # sd (m) of the unconstrained axes of the z-only priors: precision 1e-6


@dataclass
class GraphProblem:
    """Everything the graph is built from.

    Attributes
    ----------
    cameras : list of Camera
        Initial cameras (C).
    obs : ndarray, shape (S, C, J, 3)
        Keypoints (x, y, confidence) of the selected groups, for the joints ``joint_names``.
    joint_names : tuple of str, length J
    points0 : ndarray, shape (S, J, 3)
        Initial 3D joints; NaN joints are not variables.
    stance : ndarray of bool, shape (S, J)
        Joints (ankles) that stand on the ground.
    head : ndarray of bool, shape (S, J)
        Joints (head tops of upright persons) that carry the height prior.
    bones : ndarray of int, shape (B, 2)
        Joint index pairs (into J) of the bone-length terms.
    bone_lengths : ndarray, shape (S, B)
        Target length of each bone of each group (m), NaN for none.
    reference : int
        Index of the reference camera (gauge).
    model : {"f", "s2", "ds2"}
        Calibration model: ``Cal3f`` (one focal, principal point fixed), ``Cal3_S2`` (focal and
        principal point, fx = fy by a tight prior) or ``Cal3DS2`` (also k1, k2, p1, p2).
    height : float
        Height prior (m).
    n_persons : int
        Number of distinct persons (the height prior's weight is shared between their groups).
    sigma_px : float
        Keypoint noise (px) at confidence 1 for this solve: from a poor start it is raised to the
        spread of the initial residuals so they stay in the kernel's quadratic zone (graduated
        robustness; a Huber kernel far beyond its knee has no curvature to pull cameras back).
    noise_scale : ndarray, shape (S, C), optional
        Relative keypoint noise of each view (the person's size in the image,
        :mod:`cascalib.stages.keypoint_noise`); None: 1 for every view.
    torso : ndarray, shape (S, 2), optional
        Expected horizontal offset (m) of the neck from the mid-hip of each group that carries
        the upright-torso term, NaN for the others; None: no such term.
    fixed : dict of int to Camera
        Cameras whose intrinsics are known, as given (only their K and distortion are used).
        Their ``obs`` are already undistorted to the ideal square-pixel pinhole that ``cameras``
        carries for them, which every pass's calibration model expresses exactly; a tight prior
        holds it, and :func:`unpack` returns the given K and distortion exactly.
    lens : dict of int to ndarray, shape (5,)
        Cameras whose lens distortion (OpenCV's k1, k2, p1, p2, k3) a lens pass estimated and
        this solve holds: their ``obs`` are undistorted to the square-pixel pinhole of their
        start ``cameras`` (its focal and principal point still free in the graph), and
        :func:`unpack` gives them this distortion back around their solved K.
    """

    cameras: list[Camera]
    obs: NDArray[np.float64]
    joint_names: tuple[str, ...]
    points0: NDArray[np.float64]
    stance: NDArray[np.bool_]
    head: NDArray[np.bool_]
    bones: NDArray[np.int64]
    bone_lengths: NDArray[np.float64]
    reference: int
    model: Literal["f", "s2", "ds2"]
    height: float
    n_persons: int
    sigma_px: float
    fixed: dict[int, Camera] = field(default_factory=dict)
    noise_scale: NDArray[np.float64] | None = None
    torso: NDArray[np.float64] | None = None
    lens: dict[int, NDArray[np.float64]] = field(default_factory=dict)

    @property
    def n_joints(self) -> int:
        return len(self.joint_names)

    def point_keys(self) -> NDArray[np.int64]:
        """(S, J) index k of P(k), -1 where the joint is not a variable."""
        s, j = self.points0.shape[:2]
        idx = np.arange(s * j, dtype=np.int64).reshape(s, j)
        return np.where(np.isfinite(self.points0).all(-1), idx, -1)

    def projected(self, min_confidence: float) -> NDArray[np.bool_]:
        """(S, C, J) whether an observation gets a reprojection factor: seen with at least
        ``min_confidence``, of a joint that is a variable."""
        conf = self.obs[..., 2]
        return ((self.point_keys()[:, None, :] >= 0) & np.isfinite(self.obs[..., 0])
                & (conf >= min_confidence))


def _robust(kernel: str, k: float, base: gtsam.noiseModel.Base) -> gtsam.noiseModel.Base:
    est = (gtsam.noiseModel.mEstimator.Huber.Create(k) if kernel == "huber"
           else gtsam.noiseModel.mEstimator.Cauchy.Create(k))
    return gtsam.noiseModel.Robust.Create(est, base)


def _add_reprojection(graph: gtsam.NonlinearFactorGraph, prob: GraphProblem,
                      cfg: RefineConfig) -> int:
    """Reprojection factors; the noise models are shared per confidence level (1/20 steps) and
    per relative view noise (steps of 5 %)."""
    factor = {"f": gtsam.GeneralSFMFactor2Cal3f, "s2": gtsam.GeneralSFMFactor2Cal3_S2,
              "ds2": gtsam.GeneralSFMFactor2Cal3DS2}[prob.model]
    keys = prob.point_keys()
    conf = prob.obs[..., 2]
    ok = prob.projected(cfg.min_confidence)
    level = np.clip(np.round(np.nan_to_num(conf) * 20), 1, 20).astype(int)
    s_i, c_i, j_i = np.nonzero(ok)
    step = np.log(1.05)
    size = np.zeros(len(s_i), dtype=int)
    if prob.noise_scale is not None:
        size = np.round(np.log(prob.noise_scale[s_i, c_i]) / step).astype(int)
    levels = list(zip(level[s_i, c_i, j_i].tolist(), size.tolist(), strict=True))
    models = {(lv, k): _robust(cfg.robust, cfg.robust_k, gtsam.noiseModel.Isotropic.Sigma(
        2, prob.sigma_px * np.exp(k * step) / np.sqrt(lv / 20.0))) for lv, k in set(levels)}
    # everything per factor precomputed as Python objects: the loop only builds factors
    uv = list(prob.obs[s_i, c_i, j_i, :2])
    noise = [models[key] for key in levels]
    points = (keys[s_i, j_i].astype(np.uint64) + np.uint64(P(0))).tolist()  # P(k) = P(0) + k
    poses = [X(c) for c in range(len(prob.cameras))]
    cals = [K(c) for c in range(len(prob.cameras))]
    for z, nm, c, p in zip(uv, noise, c_i.tolist(), points, strict=True):
        graph.add(factor(z, nm, poses[c], p, cals[c]))
    return len(s_i)


def _add_body_priors(graph: gtsam.NonlinearFactorGraph, prob: GraphProblem,
                     cfg: RefineConfig) -> tuple[int, int, int]:
    """Ground (stance ankles), height (head tops) and bone-length factors."""
    keys = prob.point_keys()
    huber = gtsam.noiseModel.mEstimator.Huber.Create(cfg.robust_k)
    feet = np.nonzero(prob.stance & (keys >= 0))
    sigma_g = cfg.ground_sigma_m * np.sqrt(max(len(feet[0]) / cfg.ground_effective_n, 1.0))
    ground = gtsam.noiseModel.Robust.Create(
        huber, gtsam.noiseModel.Diagonal.Sigmas(np.array([_LOOSE, _LOOSE, sigma_g])))
    n_ground = 0
    for s, j in zip(*feet, strict=True):
        graph.add(gtsam.PriorFactorPoint3(P(int(keys[s, j])),
                                          np.array([0.0, 0.0, cfg.ankle_height]), ground))
        n_ground += 1
    heads = np.nonzero(prob.head & (keys >= 0))
    n_head = len(heads[0])
    if n_head:
        # n_head factors of sd sigma_h average to the sd of the mean height of n_persons people
        sigma_h = cfg.height_sd * np.sqrt(n_head / max(prob.n_persons, 1))
        head = gtsam.noiseModel.Robust.Create(huber, gtsam.noiseModel.Diagonal.Sigmas(
            np.array([_LOOSE, _LOOSE, sigma_h])))
        for s, j in zip(*heads, strict=True):
            target = np.array([0.0, 0.0, cfg.head_height(prob.joint_names[j], prob.height)])
            graph.add(gtsam.PriorFactorPoint3(P(int(keys[s, j])), target, head))
    bone = gtsam.noiseModel.Robust.Create(huber, gtsam.noiseModel.Isotropic.Sigma(
        1, cfg.bone_sigma_m))
    n_bone = 0
    for s, b in zip(*np.nonzero(np.isfinite(prob.bone_lengths)), strict=True):
        ka, kb = keys[s, prob.bones[b, 0]], keys[s, prob.bones[b, 1]]
        if ka >= 0 and kb >= 0:
            graph.add(gtsam.RangeFactor3(P(int(ka)), P(int(kb)),
                                         float(prob.bone_lengths[s, b]), bone))
            n_bone += 1
    return n_ground, n_head, n_bone


def _add_torso_priors(graph: gtsam.NonlinearFactorGraph, prob: GraphProblem,
                      cfg: RefineConfig) -> int:
    """Upright torsos: the neck at ``prob.torso`` (horizontally) from the mid-hip, sd
    ``cfg.upright_sigma_m`` in a Huber kernel, the height difference free."""
    if prob.torso is None or not all(n in prob.joint_names for n in TORSO):
        return 0
    keys = prob.point_keys()
    lo, hi = (prob.joint_names.index(n) for n in TORSO)
    noise = gtsam.noiseModel.Robust.Create(
        gtsam.noiseModel.mEstimator.Huber.Create(cfg.robust_k),
        gtsam.noiseModel.Diagonal.Sigmas(np.array([cfg.upright_sigma_m, cfg.upright_sigma_m,
                                                   _LOOSE])))
    rows = np.nonzero(np.isfinite(prob.torso).all(1) & (keys[:, lo] >= 0) & (keys[:, hi] >= 0))[0]
    for s in rows:
        offset = np.array([prob.torso[s, 0], prob.torso[s, 1], 0.0])
        graph.add(gtsam.BetweenFactorPoint3(P(int(keys[s, lo])), P(int(keys[s, hi])), offset,
                                            noise))
    return int(rows.size)


def _gauge_noise(cam: Camera, cfg: RefineConfig) -> gtsam.noiseModel.Base:
    """Pose prior noise: tight on world yaw and x, y, loose on tilt and z.

    gtsam perturbs a Pose3 in its body frame: a body rotation delta is the world rotation
    ``R_wc @ delta`` and a body translation delta moves the centre by ``R_wc @ delta``, so a
    world-frame information matrix ``L`` becomes ``R_wc.T @ L @ R_wc`` in the body frame.
    """
    R_wc = cam.R.T
    tilt = np.radians(cfg.gauge_tilt_sigma_deg)
    cov_rot_w = np.diag([tilt**2, tilt**2, np.radians(cfg.gauge_yaw_sigma_deg) ** 2])
    cov_pos_w = np.diag([cfg.gauge_xy_sigma_m**2, cfg.gauge_xy_sigma_m**2,
                         cfg.gauge_z_sigma_m**2])
    cov = np.zeros((6, 6))
    cov[:3, :3] = R_wc.T @ cov_rot_w @ R_wc
    cov[3:, 3:] = R_wc.T @ cov_pos_w @ R_wc
    return gtsam.noiseModel.Gaussian.Covariance(cov)


def _calibration(cam: Camera, model: str) -> gtsam.Cal3f | gtsam.Cal3_S2 | gtsam.Cal3DS2:
    if model == "f":
        return gtsam.Cal3f(cam.focal, cam.K[0, 2], cam.K[1, 2])
    if model == "s2":
        return gtsam.Cal3_S2(cam.fx, cam.fy, cam.K[0, 1], cam.K[0, 2], cam.K[1, 2])
    k1, k2, p1, p2, _ = cam.dist
    return gtsam.Cal3DS2(cam.fx, cam.fy, cam.K[0, 1], cam.K[0, 2], cam.K[1, 2], k1, k2, p1, p2)


def _add_intrinsic_priors(graph: gtsam.NonlinearFactorGraph, prob: GraphProblem,
                          cfg: RefineConfig) -> None:
    """Loose focal prior (30 %); in the distortion pass, priors on principal point and lens;
    known intrinsics held by a tight prior (1e-4 of the focal, 0.01 px)."""
    for c, cam in enumerate(prob.cameras):
        if c in prob.fixed:
            _hold_intrinsics(graph, c, cam, prob.model)
            continue
        if prob.model == "f":
            graph.addPriorCal3f(K(c), _calibration(cam, "f"),  # type: ignore[arg-type]
                                gtsam.noiseModel.Isotropic.Sigma(1, 0.3 * cam.focal))
            continue
        w, h = cam.image_size
        centred = cam.with_(K=np.array([[cam.focal, 0, (w - 1) / 2], [0, cam.focal, (h - 1) / 2],
                                        [0, 0, 1]]), dist=np.zeros(5))
        pp_sigma = cfg.principal_point_sigma * w
        mean = centred
        if prob.model == "ds2":
            # the lens pass holds the principal point where the previous pass put it: free, it
            # trades against rotation and the lens terms (phones: focal and centres worse)
            mean = cam.with_(K=np.array([[cam.focal, 0, cam.K[0, 2]],
                                         [0, cam.focal, cam.K[1, 2]], [0, 0, 1]]), dist=np.zeros(5))
            pp_sigma = cfg.distortion_pp_sigma_px
        # fx = fy up to 0.01 % (square pixels), their mean loose (30 %): a Gaussian with
        # correlated fx, fy; no skew; the principal point around its prior centre
        loose, tight = (0.3 * cam.focal) ** 2, (1e-4 * cam.focal) ** 2
        var = [0.0, 0.0, 1e-6, pp_sigma**2, pp_sigma**2]
        if prob.model == "ds2":
            var += [cfg.distortion_sigma**2] * 2 + [cfg.tangential_sigma**2] * 2
        cov = np.diag(var)
        cov[:2, :2] = 0.5 * (loose + tight) * np.eye(2) + 0.5 * (loose - tight) * (
            np.ones((2, 2)) - np.eye(2))
        prior = gtsam.PriorFactorCal3_S2 if prob.model == "s2" else gtsam.PriorFactorCal3DS2
        graph.add(prior(K(c), _calibration(mean, prob.model),  # type: ignore[arg-type]
                        gtsam.noiseModel.Gaussian.Covariance(cov)))


def _hold_intrinsics(graph: gtsam.NonlinearFactorGraph, c: int, cam: Camera, model: str
                     ) -> None:
    """A prior that holds camera ``c`` at its (square-pixel, distortion-free) ``cam.K``."""
    f = cam.focal
    if model == "f":
        graph.addPriorCal3f(K(c), _calibration(cam, "f"),  # type: ignore[arg-type]
                            gtsam.noiseModel.Isotropic.Sigma(1, 1e-4 * f))
        return
    sig = [1e-4 * f, 1e-4 * f, 1e-4, 1e-2, 1e-2]
    if model == "s2":
        graph.add(gtsam.PriorFactorCal3_S2(K(c), _calibration(cam, "s2"),  # type: ignore[arg-type]
                                           gtsam.noiseModel.Diagonal.Sigmas(np.array(sig))))
        return
    lens = gtsam.noiseModel.Diagonal.Sigmas(np.array(sig + [1e-6] * 4))
    graph.add(gtsam.PriorFactorCal3DS2(K(c), _calibration(cam, "ds2"), lens))  # type: ignore[arg-type]


def build_graph(prob: GraphProblem, cfg: RefineConfig) -> gtsam.NonlinearFactorGraph:
    """The factor graph of one solve (see the module docstring for the terms)."""
    graph = gtsam.NonlinearFactorGraph()
    n_rep = _add_reprojection(graph, prob, cfg)
    n_ground, n_head, n_bone = _add_body_priors(graph, prob, cfg)
    n_torso = _add_torso_priors(graph, prob, cfg)
    ref = prob.cameras[prob.reference]
    graph.add(gtsam.PriorFactorPose3(X(prob.reference), _pose(ref), _gauge_noise(ref, cfg)))
    _add_intrinsic_priors(graph, prob, cfg)
    log.debug("graph: %d reprojection, %d ground, %d height, %d bone, %d torso factors",
              n_rep, n_ground, n_head, n_bone, n_torso)
    if n_ground == 0 or n_head == 0:
        raise RefinementFailed("no stance feet or no upright person among the selected frames: "
                               "the ground plane and the scale are not observable")
    return graph


def _pose(cam: Camera) -> gtsam.Pose3:
    return gtsam.Pose3(gtsam.Rot3(cam.R.T), cam.center)


def initial_values(prob: GraphProblem) -> gtsam.Values:
    """Cameras and 3D joints of ``prob`` as gtsam Values."""
    values = gtsam.Values()
    for c, cam in enumerate(prob.cameras):
        values.insert(X(c), _pose(cam))
        values.insert(K(c), _calibration(cam, prob.model))
    keys = prob.point_keys()
    for s, j in zip(*np.nonzero(keys >= 0), strict=True):
        values.insert(P(int(keys[s, j])), prob.points0[s, j])
    return values


@dataclass(frozen=True)
class SolveInfo:
    """Outcome of one solve."""

    error_before: float
    error_after: float
    iterations: int
    n_factors: int
    seconds: float


#: Nonlinear solvers of :func:`optimize`.
Solver = Literal["levenberg-marquardt", "gauss-newton"]


def _points_first(values: gtsam.Values) -> gtsam.Ordering:
    """Elimination ordering: every 3D point, then the cameras (the Schur complement)."""
    keys = np.array(values.keys(), dtype=np.uint64)
    point = (keys >> np.uint64(56)) == gtsam.Symbol(P(0)).chr()
    return gtsam.Ordering(np.concatenate([keys[point], keys[~point]]).tolist())


def _optimizer(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, cfg: RefineConfig,
               schur: bool, method: Solver = "levenberg-marquardt") -> gtsam.NonlinearOptimizer:
    """LM or Gauss-Newton (``method`` "gauss-newton"); with ``schur``, eliminating the points
    first, else in gtsam's COLAMD ordering.

    Measured on the principal-point pass (4 x 3000 x 5, 1200 person-frames, 117k factors, three
    iterations): points first 0.03 s to set up and 1.1 s to solve, gtsam's
    SfmLevenbergMarquardtOptimizer (Schur mode) 0.24 + 1.8 s, COLAMD 2.5 s for the ordering
    alone; the same solution (errors equal to 1e-12).
    """
    if method == "gauss-newton":
        params, optimizer = gtsam.GaussNewtonParams(), gtsam.GaussNewtonOptimizer
    else:
        params, optimizer = gtsam.LevenbergMarquardtParams(), gtsam.LevenbergMarquardtOptimizer  # type: ignore[assignment]
        params.setlambdaLowerBound(cfg.lambda_lower_bound)  # type: ignore[attr-defined]
    params.setMaxIterations(cfg.max_iterations)
    params.setRelativeErrorTol(cfg.relative_tolerance)
    if schur:
        params.setOrdering(_points_first(values))
    return optimizer(graph, values, params)


def _levenberg_marquardt(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values,
                         cfg: RefineConfig) -> tuple[gtsam.Values, int, float, float]:
    """LM; a points-first run that raises is repeated in COLAMD ordering. Returns the result,
    the iterations and the graph's error before and after."""
    try:
        opt = _optimizer(graph, values, cfg, cfg.schur)
        before = opt.error()
        result = opt.optimize()
    except (RuntimeError, ValueError) as exc:
        if not cfg.schur:
            raise
        log.warning("points-first solve failed (%s), solving in COLAMD ordering", exc or
                    "no message")
        opt = _optimizer(graph, values, cfg, False)
        before = opt.error()
        result = opt.optimize()
    return result, opt.iterations(), before, opt.error()


def optimize(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, cfg: RefineConfig, *,
             method: Solver = "levenberg-marquardt", names: Sequence[str] = ()
             ) -> tuple[gtsam.Values, SolveInfo]:
    """Levenberg-Marquardt, or Gauss-Newton (eliminating the points first when ``cfg.schur``).

    Should the points-first solve raise a ``RuntimeError`` (gtsam's Schur-mode optimiser once
    stopped with an empty one on a simulated phone rig with known intrinsics, where COLAMD
    went on) or a ``ValueError`` (gtsam's, for a variable in no factor), it is repeated in
    COLAMD ordering.

    Gauss-Newton ("gauss-newton", for starts already near the solution) takes every step
    undamped: one linear solve per iteration, where LM also builds a damped copy of the linear
    system and may try several dampings. If it fails or its steps do not lower the error,
    Levenberg-Marquardt solves from ``values`` instead.

    The errors before and after come from the optimiser's own state: evaluating the graph
    again costs 0.07 s each on the 235k factors of the principal-point pass of 4 cameras x
    3000 frames x 5 persons.

    gtsam's messages about points behind a camera, one line per factor evaluation, are
    summed up in one log line per solve (naming the cameras by ``names``, in the order of the
    keys X(c); without them, by key).

    Raises
    ------
    RefinementFailed
        If gtsam fails (indeterminate system, a variable in no factor, NaN) or the error does
        not decrease.
    """
    with points_behind_reported(names, "bundle adjustment"):
        return _optimize(graph, values, cfg, method)


def _optimize(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, cfg: RefineConfig,
              method: Solver) -> tuple[gtsam.Values, SolveInfo]:
    """:func:`optimize` without its output capture."""
    t0 = time.perf_counter()
    result, after = None, np.inf
    if method == "gauss-newton":
        try:
            opt = _optimizer(graph, values, cfg, cfg.schur, method)
            before = opt.error()
            result, iterations = opt.optimize(), opt.iterations()
            after = opt.error()
        except (RuntimeError, ValueError) as exc:
            log.info("Gauss-Newton failed (%s): Levenberg-Marquardt instead",
                     str(exc).strip().split("\n")[0] or "no message")
            result = None
        else:
            if not after < before:
                log.info("Gauss-Newton did not lower the error: Levenberg-Marquardt instead")
                result = None
    if result is None:
        try:
            result, iterations, before, after = _levenberg_marquardt(graph, values, cfg)
        # gtsam's IndeterminantLinearSystemException and friends; a ValueError when a variable
        # is in no factor (the ordering names it; solve() checks for a camera that sees nobody)
        except (RuntimeError, ValueError) as exc:
            raise RefinementFailed(f"bundle adjustment failed: {exc}") from exc
    if not np.isfinite(after) or after > before * (1 + 1e-9):
        raise RefinementFailed(f"bundle adjustment diverged (error {before:.4g} -> {after:.4g})")
    log.info("bundle adjustment: error %.4g -> %.4g in %d iterations (%d factors)", before,
             after, iterations, graph.size())
    return result, SolveInfo(before, after, iterations, graph.size(), time.perf_counter() - t0)


def unpack(values: gtsam.Values, prob: GraphProblem) -> tuple[list[Camera], NDArray[np.float64]]:
    """Cameras and 3D joints from optimised values.

    Returns
    -------
    cameras : list of Camera
        With the refined pose and intrinsics (distortion from the ``ds2`` model, or the lens
        ``prob.lens`` held); cameras in ``prob.fixed`` keep their given K and distortion
        exactly.
    points : ndarray, shape (S, J, 3)
        NaN where the joint was not a variable.
    """
    cams = []
    for c, cam in enumerate(prob.cameras):
        pose = values.atPose3(X(c))
        R = pose.rotation().matrix().T
        t = -R @ pose.translation()
        if c in prob.fixed:  # exactly as given, not the prior-held values
            known = prob.fixed[c]
            cams.append(cam.with_(R=R, t=t, K=np.array(known.K), dist=np.array(known.dist)))
            continue
        if prob.model == "f":
            cal = values.atCal3f(K(c))
            Kmat = np.array([[cal.fx(), 0, cal.px()], [0, cal.fx(), cal.py()], [0, 0, 1.0]])
            dist = np.zeros(5)
        elif prob.model == "s2":
            Kmat = values.atCal3_S2(K(c)).K()
            dist = np.zeros(5)
        else:
            cal = values.atCal3DS2(K(c))  # type: ignore[assignment]
            Kmat = cal.K()
            k1, k2, p1, p2 = cal.k()  # type: ignore[attr-defined]
            dist = np.array([k1, k2, p1, p2, 0.0])
        # skew is held at 0 by a tight prior: drop its numerical residue, so that writers of
        # skew-free formats (COLMAP) accept the camera
        Kmat = np.array(Kmat, dtype=np.float64)
        Kmat[0, 1] = 0.0
        if c in prob.lens:
            dist = prob.lens[c]
        cams.append(cam.with_(R=R, t=t, K=Kmat, dist=dist))
    keys = prob.point_keys()
    points = np.full(prob.points0.shape, np.nan)
    for s, j in zip(*np.nonzero(keys >= 0), strict=True):
        points[s, j] = values.atPoint3(P(int(keys[s, j])))
    return cams, points


def _shape_graph(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, prob: GraphProblem
                 ) -> gtsam.NonlinearFactorGraph:
    """``graph`` plus tight priors that fix the reference pose and the rig's scale.

    The marginals of the result describe the rig's *shape* (what a similarity alignment to a
    reference measures), without the shared uncertainty of the world's plane, yaw and scale.
    """
    shape = gtsam.NonlinearFactorGraph()
    shape.push_back(graph)
    ref = prob.reference
    pose_ref = values.atPose3(X(ref))
    shape.add(gtsam.PriorFactorPose3(X(ref), pose_ref, gtsam.noiseModel.Isotropic.Sigma(6, 1e-5)))
    others = [c for c in range(len(prob.cameras)) if c != ref]
    far = max(others, key=lambda c: np.linalg.norm(values.atPose3(X(c)).translation()
                                                   - pose_ref.translation()))
    dist = float(np.linalg.norm(values.atPose3(X(far)).translation() - pose_ref.translation()))
    shape.add(gtsam.RangeFactorPose3(X(ref), X(far), dist, gtsam.noiseModel.Isotropic.Sigma(
        1, 1e-5)))
    return shape


def marginal_sigmas(graph: gtsam.NonlinearFactorGraph, values: gtsam.Values, prob: GraphProblem
                    ) -> list[dict[str, float]]:
    """1-sigma focal (px), rotation (deg) and position (m) per camera from gtsam.Marginals.

    Rotation and position are relative to the reference camera with the scale fixed (the rig's
    shape, see :func:`_shape_graph`), as the largest axis of the world-frame covariance; the
    reference camera gets the smallest value of the others. NaN if gtsam cannot invert.
    """
    nan = dict(focal=np.nan, rotation=np.nan, position=np.nan)
    try:
        with points_behind_reported([c.name for c in prob.cameras], "marginals"):
            marg = gtsam.Marginals(_shape_graph(graph, values, prob), values)
    except RuntimeError as exc:
        log.warning("marginal covariances unavailable: %s", exc)
        return [dict(nan) for _ in prob.cameras]
    out = []
    for c in range(len(prob.cameras)):
        try:
            cov = marg.marginalCovariance(X(c))
            kc = marg.marginalCovariance(K(c))
        except RuntimeError as exc:  # nearly indeterminate: report as unknown, not a crash
            log.warning("marginal covariance of camera %d unavailable: %s", c, exc)
            out.append(dict(nan))
            continue
        R_wc = values.atPose3(X(c)).rotation().matrix()
        rot = R_wc @ cov[:3, :3] @ R_wc.T
        pos = R_wc @ cov[3:, 3:] @ R_wc.T
        f_var = kc[0, 0] if prob.model == "f" else 0.5 * (kc[0, 0] + kc[1, 1])
        out.append(dict(focal=float(np.sqrt(f_var)),
                        rotation=float(np.degrees(np.sqrt(max(np.linalg.eigvalsh(rot)[-1], 0)))),
                        position=float(np.sqrt(max(np.linalg.eigvalsh(pos)[-1], 0)))))
    ref = prob.reference
    for key in ("rotation", "position"):
        vals = [o[key] for c, o in enumerate(out) if c != ref and np.isfinite(o[key])]
        out[ref][key] = float(np.min(vals)) if vals else np.nan
    return out
