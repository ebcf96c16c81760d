"""The multi-view start: cameras from the people's joints as point matches, no ground plane needed.

Stage I reads a camera's focal length and ground plane from people walking upright over a floor.
Real recordings often give it too little: one person in one spot, upper bodies at a desk, a camera
nearly horizontal. Once the clocks are known (hardware-synchronised cameras, timestamps on one
clock, or stage II-IV's offsets), the same joint of the same person at the same instant seen by
two cameras is a point match, and the cameras follow as in structure from motion:

1. persons matched across each camera pair with a robust fundamental matrix
   (:mod:`~cascalib.stages.multiview_pairs`), and across all cameras by joining the pairs' matches;
2. for each field-of-view hypothesis of a wide prior (every camera the same angle, stage I's focal
   length where it gave one), the best pair's essential matrix, the other cameras by PnP, and a
   bundle adjustment with the focal lengths held; the hypothesis whose bundle explains the joints
   best is kept and adjusted again with free focal lengths (a weak prior on each);
3. the world: up from the people (neck above mid-hip, head above shoulders), the ground through the
   stance ankles when feet are seen, the metric scale from the bone lengths and the height prior.

The result is a start for stage V, which adjusts everything again with its factor graph.

References
----------
Hartley, R. & Zisserman, A. *Multiple View Geometry*, 2nd ed.: sec. 9.6 (essential matrix),
sec. 18.1 (bundle adjustment). Schoenberger, J. & Frahm, J.-M. Structure-from-Motion Revisited,
CVPR 2016 (incremental registration).
"""

from __future__ import annotations

import itertools
import logging
from dataclasses import dataclass, field

import cv2
import gtsam
import numpy as np
from gtsam.symbol_shorthand import K, P, X
from numpy.typing import NDArray

from cascalib.camera import Camera
from cascalib.geometry import rodrigues_to_matrix
from cascalib.nanstats import nanmean
from cascalib.native_output import points_behind_reported
from cascalib.stages.multiview_pairs import MIN_CONFIDENCE, PairMatches, match_pair
from cascalib.stages.stature import joint_points, metric_scale, people_who_move
from cascalib.stages.triangulation import triangulate

__all__ = ["MultiviewStart", "PersonGroups", "WorldFrame", "join_matches", "multiview_start",
           "reprojection_fit", "to_world", "world_frame", "focal_range", "FOV_PRIOR_DEG"]

log = logging.getLogger(__name__)

#: Diagonal fields of view (deg) tried as starts: from a long lens (30) to an action camera (110).
FOV_PRIOR_DEG = (30.0, 45.0, 60.0, 75.0, 90.0, 110.0)
#: Prior on each focal length in the final bundle: sd of log f around the start (0.5: a factor
#: of 1.65 either way, so the people decide unless they say nothing).
FOCAL_PRIOR_SD = 0.5
#: Cauchy scale of the reprojection residuals as a fraction of the image diagonal.
LOSS_SCALE = 0.004
#: Prior sd of the radial term k1 when the lens is fitted (webcams reach k1 = -0.34); k2 is held
#: at 0: one person's joints cannot tell the two apart.
LENS_PRIOR_SD = 0.3
#: A fitted lens is kept when it lowers the bundle's cost by this share (a fraction).
LENS_GAIN = 0.05
#: A camera whose median reprojection error is this many times the others' is left out.
STRANGER_FACTOR = 3.0
#: Least median error (px) of the others that the comparison counts (noise-free data).
STRANGER_FLOOR_PX = 2.0
#: Starts adjusted again with free focal lengths (the best by their held-focal cost).
N_FINALISTS = 3
#: Most instants put into one bundle adjustment (evenly spread).
MAX_INSTANTS = 150


@dataclass(frozen=True)
class PersonGroups:
    """Persons matched across all cameras: one row per person instance at one instant.

    Attributes
    ----------
    times : ndarray of int, shape (G,)
        Instant index.
    slots : ndarray of int, shape (G, C)
        Person slot in each camera, -1 where the camera has no match.
    """

    times: NDArray[np.int64]
    slots: NDArray[np.int64]

    def observations(self, views: list[NDArray[np.float64]]) -> NDArray[np.float64]:
        """Detections (C, G, J, 3) of every group in every camera, NaN where unmatched."""
        out = []
        for c, v in enumerate(views):
            s = self.slots[:, c]
            o = v[self.times, np.maximum(s, 0)].copy()
            o[s < 0] = np.nan
            out.append(o)
        return np.stack(out)


def join_matches(pairs: list[PairMatches], n_cams: int) -> PersonGroups:
    """Join the pairwise person matches into multi-camera groups (union-find per instant); a
    group in which one camera would hold two persons is split back to its best-matched pair."""
    parent: dict[tuple[int, int, int], tuple[int, int, int]] = {}

    def find(x: tuple[int, int, int]) -> tuple[int, int, int]:
        while parent.setdefault(x, x) != x:
            parent[x] = parent[parent[x]]
            x = parent[x]
        return x

    for m in pairs:
        for t, (pa, pb) in zip(m.times, m.persons, strict=True):
            a, b = find((m.i, int(t), int(pa))), find((m.j, int(t), int(pb)))
            if a != b:
                parent[b] = a
    comps: dict[tuple[int, int, int], list[tuple[int, int, int]]] = {}
    for node in list(parent):
        comps.setdefault(find(node), []).append(node)
    times, slots = [], []
    for nodes in comps.values():
        cams = [c for c, _, _ in nodes]
        if len(set(cams)) != len(cams):
            continue  # a camera holds two persons: an association error, dropped
        row = np.full(n_cams, -1, dtype=np.int64)
        for c, _, p in nodes:
            row[c] = p
        times.append(nodes[0][1])
        slots.append(row)
    order = np.argsort(times, kind="stable")
    return PersonGroups(np.asarray(times, np.int64)[order],
                        np.asarray(slots, np.int64).reshape(-1, n_cams)[order])


@dataclass(frozen=True)
class MultiviewStart:
    """Outcome of :func:`multiview_start`.

    Attributes
    ----------
    cameras : list of Camera or None
        Per input camera, placed in the bundle's frame (arbitrary similarity), or None where it
        could not be registered.
    reasons : dict of str to str
        Why a camera was left out.
    points : ndarray, shape (G, J, 3)
        The joints of every group in the bundle's frame (NaN where not triangulated).
    groups : PersonGroups
    reprojection_px : dict of str to float
        Median reprojection error per registered camera.
    fov_start_deg : float
        The field-of-view hypothesis that explained the joints best.
    uv : ndarray, shape (C, N, 2)
        The bundle's observations: every joint of every group (N = G x J), NaN where unseen.
    """

    cameras: list[Camera | None]
    reasons: dict[str, str]
    points: NDArray[np.float64]
    groups: PersonGroups
    reprojection_px: dict[str, float]
    fov_start_deg: float
    pairs: list[PairMatches] = field(default_factory=list, repr=False)
    uv: NDArray[np.float64] = field(default_factory=lambda: np.zeros((0, 0, 2)), repr=False)


def _focal_for_fov(size: tuple[int, int], fov_deg: float) -> float:
    return float(np.hypot(*size) / (2.0 * np.tan(np.radians(fov_deg) / 2.0)))


def focal_range(size: tuple[int, int]) -> tuple[float, float]:
    """Least and largest focal length (px) of the field-of-view prior for an image ``size``."""
    return _focal_for_fov(size, max(FOV_PRIOR_DEG)), _focal_for_fov(size, min(FOV_PRIOR_DEG))


def _camera(base: Camera, f: float, R: NDArray[np.float64], t: NDArray[np.float64]) -> Camera:
    K = base.K.copy()
    K[0, 0] = K[1, 1] = f
    return base.with_(K=K, R=R, t=t)


def _relative_pose(m: PairMatches, ci: Camera, cj: Camera
                   ) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    """Camera j's pose in camera i's frame (unit baseline) from the essential matrix."""
    ni = cv2.undistortPoints(m.xi.reshape(-1, 1, 2), ci.K, ci.dist).reshape(-1, 2)
    nj = cv2.undistortPoints(m.xj.reshape(-1, 1, 2), cj.K, cj.dist).reshape(-1, 2)
    thr = LOSS_SCALE * 2.5 * np.hypot(*ci.image_size) / ci.focal
    E, mask = cv2.findEssentialMat(nj, ni, np.eye(3), cv2.USAC_MAGSAC, 0.9999, thr)
    if E is None or E.shape != (3, 3):
        return None
    _, R, t, _ = cv2.recoverPose(E, nj, ni, np.eye(3), mask=mask)
    # recoverPose gives x_i = R x_j + t (points from j's frame into i's): invert for j from i
    Rt: NDArray[np.float64] = np.asarray(R, dtype=np.float64).T
    return Rt, -Rt @ np.asarray(t, dtype=np.float64).ravel()


def _observations(groups: PersonGroups, views: list[NDArray[np.float64]],
                  joints: NDArray[np.int64]) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Pixels (C, N, 2) and confidences (C, N) of every (group, joint) point."""
    obs = groups.observations(views)[:, :, joints]  # (C, G, J, 3)
    conf = np.nan_to_num(obs[..., 2])
    uv = obs[..., :2].copy()
    uv[conf < MIN_CONFIDENCE] = np.nan
    n_c = len(views)
    return uv.reshape(n_c, -1, 2), np.where(conf >= MIN_CONFIDENCE, conf, 0).reshape(n_c, -1)


def _register(cam: Camera, X: NDArray[np.float64], uv: NDArray[np.float64]
              ) -> tuple[NDArray[np.float64], NDArray[np.float64]] | None:
    ok = np.isfinite(X).all(1) & np.isfinite(uv).all(1)
    if ok.sum() < 12:
        return None
    thr = LOSS_SCALE * 2.5 * np.hypot(*cam.image_size)
    found, rvec, tvec, inl = cv2.solvePnPRansac(X[ok], uv[ok], cam.K, cam.dist,
                                                reprojectionError=thr, iterationsCount=2000,
                                                flags=cv2.SOLVEPNP_SQPNP)
    if not found or inl is None or len(inl) < 12:
        return None
    return rodrigues_to_matrix(rvec.ravel()), np.asarray(tvec, dtype=np.float64).ravel()


def _best_pair(pairs: list[PairMatches]) -> PairMatches:
    """The pair with most matched persons whose joints fit their geometry tightly."""
    return max(pairs, key=lambda m: m.n_groups / (1.0 + float(np.median(m.distances))))


def _initial_rig(pairs: list[PairMatches], uv: NDArray[np.float64], conf: NDArray[np.float64],
                 bases: list[Camera]) -> list[Camera | None]:
    """Cameras from the best pair's essential matrix, then each other camera by PnP against the
    joints triangulated so far (most shared points first)."""
    n_c = len(bases)
    cams: list[Camera | None] = [None] * n_c
    m = _best_pair(pairs)
    rel = _relative_pose(m, bases[m.i], bases[m.j])
    if rel is None:
        return cams
    cams[m.i] = bases[m.i].with_(R=np.eye(3), t=np.zeros(3))
    cams[m.j] = bases[m.j].with_(R=rel[0], t=rel[1])
    while True:
        points = _triangulate_known(cams, uv, conf)
        seen = np.isfinite(points).all(1)
        todo = [c for c in range(n_c) if cams[c] is None]
        todo.sort(key=lambda c: -int((np.isfinite(uv[c]).all(1) & seen).sum()))
        placed = False
        for c in todo:
            pose = _register(bases[c], points, uv[c])
            if pose is not None:
                cams[c] = bases[c].with_(R=pose[0], t=pose[1])
                placed = True
                break
        if not placed:
            return cams


def _triangulate_known(cams: list[Camera | None], uv: NDArray[np.float64],
                       conf: NDArray[np.float64]) -> NDArray[np.float64]:
    idx = [c for c, cam in enumerate(cams) if cam is not None]
    points, _ = triangulate([cams[c] for c in idx], uv[idx], conf[idx])  # type: ignore[misc]
    return points


def _pose(cam: Camera) -> gtsam.Pose3:
    """gtsam's world_from_camera pose of ``cam``."""
    return gtsam.Pose3(gtsam.Rot3(cam.R.T), cam.center)


def _build_bundle(cams: list[Camera | None], idx: list[int], pts: NDArray[np.int64],
                  uv: NDArray[np.float64], free_focal: bool, log_f0: NDArray[np.float64],
                  lens: bool) -> tuple[gtsam.NonlinearFactorGraph, int]:
    """Reprojection factors (Cauchy), priors on focal and radial terms, and the gauge: the first
    camera's pose and its distance to the second held."""
    graph = gtsam.NonlinearFactorGraph()
    n_obs = 0
    for c in idx:
        cam = cams[c]
        assert cam is not None
        k = LOSS_SCALE * np.hypot(*cam.image_size)
        noise = gtsam.noiseModel.Robust.Create(gtsam.noiseModel.mEstimator.Cauchy.Create(k),
                                               gtsam.noiseModel.Isotropic.Sigma(2, 1.0))
        seen = pts[np.isfinite(uv[c, pts]).all(1)]
        for n in seen:
            graph.add(gtsam.GeneralSFMFactor2Cal3Bundler(uv[c, n], noise, X(c), P(int(n)), K(c)))
        n_obs += seen.size
        f0 = float(np.exp(log_f0[c]))
        sd = np.array([(FOCAL_PRIOR_SD if free_focal else 1e-6) * f0,
                       LENS_PRIOR_SD if lens else 1e-6, 1e-6])
        graph.add(gtsam.PriorFactorCal3Bundler(K(c), _bundler(cam, f0, lens),
                                               gtsam.noiseModel.Diagonal.Sigmas(sd)))
    first, second = cams[idx[0]], cams[idx[1]]
    assert first is not None and second is not None
    graph.add(gtsam.PriorFactorPose3(X(idx[0]), _pose(first),
                                     gtsam.noiseModel.Isotropic.Sigma(6, 1e-6)))
    graph.add(gtsam.RangeFactorPose3(X(idx[0]), X(idx[1]),
                                     float(np.linalg.norm(first.center - second.center)),
                                     gtsam.noiseModel.Isotropic.Sigma(1, 1e-6)))
    return graph, n_obs


def _bundler(cam: Camera, f: float, lens: bool) -> gtsam.Cal3Bundler:
    """gtsam's focal and radial terms of ``cam`` (k1 only where ``lens``, k2 = 0)."""
    k1 = cam.dist[0] if lens else 0.0
    return gtsam.Cal3Bundler(f, float(k1), 0.0, *cam.principal_point)


def _pinhole_observations(cams: list[Camera | None], uv: NDArray[np.float64], lens: bool
                          ) -> NDArray[np.float64]:
    """``uv`` with each held lens taken out (pixels of a pinhole with the same K); a lens being
    fitted keeps its observations as they are."""
    out = uv.copy()
    for c, cam in enumerate(cams):
        if cam is not None and cam.has_distortion and not lens:
            out[c] = cam.undistort_pixels(uv[c])
    return out


def _in_front(cams: list[Camera | None], X3: NDArray[np.float64], uv: NDArray[np.float64]
              ) -> NDArray[np.float64]:
    """``uv`` without the observations of points behind their camera (a wrong match)."""
    out = uv.copy()
    for c, cam in enumerate(cams):
        if cam is not None:
            least = MIN_DEPTH_FRACTION * np.linalg.norm(cam.t)
            with np.errstate(invalid="ignore"):
                out[c, ~((X3 @ cam.R[2] + cam.t[2]) > least)] = np.nan
    return out


def bundle_adjust(cams: list[Camera | None], X3: NDArray[np.float64], uv: NDArray[np.float64],
                  *, free_focal: bool, log_f0: NDArray[np.float64] | None = None,
                  lens: bool = False, max_iterations: int = 50
                  ) -> tuple[list[Camera | None], NDArray[np.float64], float]:
    """Bundle adjustment of the placed cameras and the points they see (gtsam, Cauchy loss).

    Parameters
    ----------
    cams : list of Camera or None
        None for cameras left out. Principal points and lenses are held.
    X3 : ndarray, shape (N, 3)
        Start points (NaN: not in the bundle).
    uv : ndarray, shape (C, N, 2)
        Observations, NaN where unseen.
    free_focal : bool
        Adjust each focal length too, with a log-normal prior (sd :data:`FOCAL_PRIOR_SD`)
        around ``log_f0``.
    log_f0 : ndarray, shape (C,), optional
        Prior centres of log f (default: the start's).
    lens : bool
        Fit a radial term per camera (OpenCV's k1; prior sd :data:`LENS_PRIOR_SD` around the
        start's), replacing any lens the cameras carry.
    max_iterations : int
        Levenberg-Marquardt iterations.

    Returns
    -------
    cameras, points, cost
        The adjusted cameras and points, and the robust cost per observation (px^2); infinite
        when the solver fails (a point behind a camera).
    """
    idx = [c for c, cam in enumerate(cams) if cam is not None]
    uv = _in_front(cams, X3, _pinhole_observations(cams, uv, lens))
    pts = np.flatnonzero(np.isfinite(X3).all(1) & (np.isfinite(uv[idx]).all(-1).sum(0) >= 2))
    start = np.log([c.focal if c is not None else 1.0 for c in cams])
    prior = start if log_f0 is None else np.asarray(log_f0)
    graph, n_obs = _build_bundle(cams, idx, pts, uv, free_focal, prior, lens)
    values = gtsam.Values()
    for c in idx:
        cam = cams[c]
        assert cam is not None
        values.insert(X(c), _pose(cam))
        values.insert(K(c), _bundler(cam, cam.focal, lens))
    for n in pts:
        values.insert(P(int(n)), X3[n])
    params = gtsam.LevenbergMarquardtParams()
    params.setMaxIterations(max_iterations)
    params.setRelativeErrorTol(1e-5)
    try:
        with points_behind_reported([f"camera {c}" for c in range(len(cams))], "multi-view bundle"):
            result = gtsam.LevenbergMarquardtOptimizer(graph, values, params).optimize()
            cost = 2.0 * graph.error(result) / max(1, n_obs)
    except RuntimeError as exc:  # cheirality or an indeterminate system
        log.debug("multi-view bundle failed: %s", exc)
        return cams, X3, float("inf")
    out: list[Camera | None] = list(cams)
    for c in idx:
        pose, cal = result.atPose3(X(c)), result.atCal3Bundler(K(c))
        R = pose.rotation().matrix().T
        cam = _camera(cams[c], float(cal.fx()), R, -R @ pose.translation())  # type: ignore[arg-type]
        out[c] = cam.with_(dist=np.r_[cal.k1(), cal.k2(), 0.0, 0.0, 0.0]) if lens else cam
    Xo = np.full_like(X3, np.nan)
    for n in pts:
        Xo[n] = result.atPoint3(P(int(n)))
    return out, Xo, cost


def _spread_instants(groups: PersonGroups, n: int) -> PersonGroups:
    """At most ``n`` instants, evenly spread, with all their groups."""
    ut = np.unique(groups.times)
    if ut.size <= n:
        return groups
    keep = np.isin(groups.times, ut[np.linspace(0, ut.size - 1, n).round().astype(int)])
    return PersonGroups(groups.times[keep], groups.slots[keep])


def _hypothesis(pairs: list[PairMatches], uv: NDArray[np.float64], conf: NDArray[np.float64],
                bases: list[Camera]) -> tuple[list[Camera | None], NDArray[np.float64], float]:
    """Rig, points and bundle cost with the focal lengths of ``bases`` held."""
    cams = _initial_rig(pairs, uv, conf, bases)
    if sum(c is not None for c in cams) < 2:
        return cams, np.full((uv.shape[1], 3), np.nan), np.inf
    points = _triangulate_known(cams, uv, conf)
    cams, points, cost = bundle_adjust(cams, points, uv, free_focal=False)
    return cams, points, cost


def multiview_start(views: list[NDArray[np.float64]], bases: list[Camera],
                    rng: np.random.Generator, *, joints: NDArray[np.int64],
                    focal_hints: list[float | None] | None = None) -> MultiviewStart:
    """Place the cameras from the people's joints seen at common instants.

    Parameters
    ----------
    views : list of ndarray, each (T, P_c, 26, 3)
        Each camera's canonical detections at the same T instants.
    bases : list of Camera
        Per camera: name, image size, principal point and lens (held); pose and focal ignored.
    rng : numpy.random.Generator
    joints : ndarray of int
        Canonical joints used as point matches.
    focal_hints : list of float or None, optional
        A focal length per camera (stage I's, or known) tried as one more start.

    Returns
    -------
    MultiviewStart
    """
    n_c = len(views)
    names = [b.name for b in bases]
    pairs = [m for i, j in itertools.combinations(range(n_c), 2)
             if (m := match_pair(i, j, views[i], views[j],
                                 max(np.hypot(*bases[i].image_size),
                                     np.hypot(*bases[j].image_size)), rng)) is not None]
    groups = join_matches(pairs, n_c)
    reasons = {}
    for c in range(n_c):
        if not any(c in (m.i, m.j) for m in pairs):
            reasons[names[c]] = "sees no person at the same instants as another camera"
    if not pairs:
        return MultiviewStart([None] * n_c, reasons, np.zeros((0, joints.size, 3)), groups,
                              {}, float("nan"), pairs)
    sub = _spread_instants(groups, MAX_INSTANTS)
    uv, conf = _observations(sub, views, joints)
    starts: list[tuple[float, list[float]]] = [
        (fov, [_focal_for_fov(b.image_size, fov) for b in bases]) for fov in FOV_PRIOR_DEG]
    if focal_hints is not None and any(h is not None for h in focal_hints):
        starts.append((float("nan"), [h if h is not None else _focal_for_fov(b.image_size, 60.0)
                                      for h, b in zip(focal_hints, bases, strict=True)]))
    tried = []
    for fov, focals in starts:
        trial = [_camera(b, f, np.eye(3), np.zeros(3)) for b, f in zip(bases, focals, strict=True)]
        cams, points, cost = _hypothesis(pairs, uv, conf, trial)
        n_placed = sum(c is not None for c in cams)
        log.info("multi-view start: fov %.0f deg -> cost %.3g, %d cameras", fov, cost, n_placed)
        tried.append((-n_placed, cost, fov, cams, points))
    tried.sort(key=lambda r: (r[0], r[1]))
    finals = []
    for n_neg, _, fov, cams, points in tried[:N_FINALISTS]:
        if n_neg != tried[0][0]:
            break
        cams, points, cost = bundle_adjust(cams, points, uv, free_focal=True)
        log.info("multi-view start: from fov %.0f deg, focal free -> cost %.3g", fov, cost)
        finals.append((cost, fov, cams, points))
    cost, fov, cams, points = min(finals, key=lambda r: r[0])
    cams, points, cost = _drop_strangers(cams, points, uv, reasons, cost)
    if not any(b.has_distortion for b in bases):
        with_lens = bundle_adjust(cams, points, uv, free_focal=True, lens=True)
        log.info("multi-view start: with a radial term -> cost %.3g", with_lens[2])
        if with_lens[2] < cost * (1.0 - LENS_GAIN):
            cams, points, _ = with_lens
    for c, cam in enumerate(cams):
        if cam is None and names[c] not in reasons:
            reasons[names[c]] = "its joints fit no pose against the other cameras' people"
    return MultiviewStart(cams, reasons, points.reshape(-1, joints.size, 3), sub,
                          _reprojection(cams, points, uv), fov, pairs, uv)


def reprojection_fit(cams: list[Camera], uv: NDArray[np.float64]) -> float:
    """How well a rig explains observations ``uv`` (C, N, 2) of the same points: the median
    over cameras of the median reprojection error (px) after a robust triangulation."""
    X, err = triangulate(cams, uv)
    per = [np.nanmedian(e) for e in err if np.isfinite(e).any()]
    return float(np.median(per)) if per else float("inf")


def _drop_strangers(cams: list[Camera | None], points: NDArray[np.float64],
                    uv: NDArray[np.float64], reasons: dict[str, str], cost: float
                    ) -> tuple[list[Camera | None], NDArray[np.float64], float]:
    """Leave out, one at a time, a camera whose joints reproject :data:`STRANGER_FACTOR` times
    worse than the others' (it saw other people or other instants: a person's shape fits some
    pose), and adjust the rest again; ``reasons`` gets why. Returns the bundle's cost."""
    while sum(c is not None for c in cams) > 2:
        errors = _reprojection(cams, points, uv)
        worst = max(errors, key=lambda n: errors[n])
        others = float(np.median([e for n, e in errors.items() if n != worst]))
        if errors[worst] <= STRANGER_FACTOR * max(others, STRANGER_FLOOR_PX):
            break
        reasons[worst] = (f"its joints reproject at {errors[worst]:.1f} px against "
                          f"{others:.1f} px for the other cameras: it does not see the same "
                          "people at the same instants")
        log.warning("multi-view start: %s left out (%s)", worst, reasons[worst])
        cams = [None if c is not None and c.name == worst else c for c in cams]
        cams, points, cost = bundle_adjust(cams, points, uv, free_focal=True)
    return cams, points, cost


def _reprojection(cams: list[Camera | None], points: NDArray[np.float64], uv: NDArray[np.float64]
                  ) -> dict[str, float]:
    """Median reprojection error (px) per placed camera; a point behind a camera counts as
    infinitely far off."""
    out = {}
    for c, cam in enumerate(cams):
        if cam is None:
            continue
        ok = np.isfinite(points).all(1) & np.isfinite(uv[c]).all(1)
        if ok.any():
            err = np.linalg.norm(cam.project(points[ok]) - uv[c, ok], axis=1)
            out[cam.name] = float(np.median(np.where(np.isfinite(err), err, np.inf)))
    return out


#: Pairs (lower, upper) whose direction, averaged over the people, is the world's up, in order
#: of preference: the trunk, else the head above the shoulders (upper bodies only).
UP_PAIRS = (("mid_hip", "neck"), ("neck", "nose"))
#: Joints whose mean stands for the body's centre of mass (the 17 COCO joints).
BODY_CENTRE_JOINTS = np.arange(17)
#: People lean when their trunks' up and their balance's up differ by more than this (deg); the
#: trunks are the better up of people walking upright (0.2 deg on the simulator, against 1.4).
LEAN_DEG = 10.0
#: Passes of the stance-foot / body-centre estimate (the stance foot depends on the up).
BALANCE_ITERATIONS = 3
#: Standing: the hips rise above the stance foot by more than this share of the leg's length.
STANDING_LEG_FRACTION = 0.7
#: Least depth of a bundle point in front of a camera, as a fraction of the camera's distance
#: from the first camera (points nearer or behind are dropped from that camera's observations).
MIN_DEPTH_FRACTION = 0.05
#: Least groups that must show a pair for it to set the up direction.
MIN_UP_GROUPS = 10


@dataclass(frozen=True)
class WorldFrame:
    """How the bundle's frame becomes the world: ``X_w = scale * R @ X_b + t``.

    Attributes
    ----------
    up_from : str
        Which joints set the up direction (``"mid_hip-neck"`` or ``"neck-nose"``).
    ground : bool
        Whether the ground (z = 0) comes from stance ankles; else z = 0 is the lowest joint seen.
    """

    scale: float
    R: NDArray[np.float64]
    t: NDArray[np.float64]
    up_from: str
    ground: bool


def _up(points: NDArray[np.float64], joints: NDArray[np.int64]) -> tuple[NDArray[np.float64], str]:
    """The world's up from the people: their trunks; or, where they stand on their legs and lean
    (the trunks more than :data:`LEAN_DEG` off), the line from the foot they stand on to their
    body's centre: a body in balance holds its centre of mass over its support."""
    trunk, source = _trunk_up(points, joints)
    if source != "mid_hip-neck":
        return trunk, source
    balance = _balance_up(points, joints, trunk)
    if (balance is not None and np.degrees(np.arccos(np.clip(balance @ trunk, -1, 1))) > LEAN_DEG
            and _standing(points, joints, balance)):
        return balance, "stance foot-body centre"
    return trunk, source


def _trunk_up(points: NDArray[np.float64], joints: NDArray[np.int64]
              ) -> tuple[NDArray[np.float64], str]:
    for lo, hi in UP_PAIRS:
        d = joint_points(points, joints, hi) - joint_points(points, joints, lo)
        d = d[np.isfinite(d).all(1)]
        if len(d) >= MIN_UP_GROUPS:
            u = np.median(d / np.linalg.norm(d, axis=1, keepdims=True), axis=0)
            return u / np.linalg.norm(u), f"{lo}-{hi}"
    raise ValueError("no trunk or head seen by two cameras: the up direction is unknown")


def _finite_median(x: NDArray[np.float64]) -> float:
    """Median of the finite values of ``x`` (NaN when there are none)."""
    x = x[np.isfinite(x)]
    return float(np.median(x)) if x.size else float("nan")


def _stance(points: NDArray[np.float64], joints: NDArray[np.int64], up: NDArray[np.float64]
            ) -> NDArray[np.float64]:
    """Per group, the foot it stands on along ``up``: the lower ankle, or both ankles' middle
    when they are at one height (within a tenth of the leg)."""
    la, ra = joint_points(points, joints, "left_ankle"), joint_points(points, joints, "right_ankle")
    zl, zr = la @ up, ra @ up
    leg = _finite_median(np.linalg.norm(joint_points(points, joints, "left_hip") - la, axis=1))
    lower = np.where((zl <= zr) | ~np.isfinite(zr), 0, 1)[:, None]
    one = np.where(lower == 0, la, ra)
    both = np.isfinite(zl) & np.isfinite(zr) & (np.abs(zl - zr) < 0.1 * leg)
    return np.where(both[:, None], (la + ra) / 2, one)


def _balance_up(points: NDArray[np.float64], joints: NDArray[np.int64],
                start: NDArray[np.float64]) -> NDArray[np.float64] | None:
    """The median direction from the stance foot to the mean of the body's joints."""
    body = np.isin(joints, BODY_CENTRE_JOINTS)
    u = start
    for _ in range(BALANCE_ITERATIONS):
        centre = nanmean(points[:, body], axis=1)
        d = centre - _stance(points, joints, u)
        d = d[np.isfinite(d).all(1)]
        if len(d) < MIN_UP_GROUPS:
            return None
        u = np.median(d / np.linalg.norm(d, axis=1, keepdims=True), axis=0)
        u /= np.linalg.norm(u)
    return u


def _standing(points: NDArray[np.float64], joints: NDArray[np.int64], up: NDArray[np.float64]
              ) -> bool:
    """Whether the people stand on their legs along ``up``: the hips above the stance foot by
    most of the leg's length (seated, the legs lie nearly level)."""
    hip = joint_points(points, joints, "mid_hip")
    leg = _finite_median(np.linalg.norm(joint_points(points, joints, "left_hip")
                                        - joint_points(points, joints, "left_knee"), axis=1)
                         + np.linalg.norm(joint_points(points, joints, "left_knee")
                                          - joint_points(points, joints, "left_ankle"), axis=1))
    rise = (hip - _stance(points, joints, up)) @ up
    rise = rise[np.isfinite(rise)]
    return bool(rise.size >= MIN_UP_GROUPS and np.median(rise) > STANDING_LEG_FRACTION * leg)


def world_frame(points: NDArray[np.float64], joints: NDArray[np.int64], cameras: list[Camera],
                *, height: float, ankle_height: float) -> WorldFrame:
    """The world of a multi-view start: z up from the people, the ground
    through the stance ankles (at ``ankle_height``), x along the first camera's view, metres
    from ``height``.

    Raises
    ------
    ValueError
        When neither trunk nor head, or no limb, is seen by two cameras.
    """
    points = people_who_move(points)
    up, up_from = _up(points, joints)
    reference = cameras[0]
    fwd = reference.R[2] - up * (reference.R[2] @ up)
    if np.linalg.norm(fwd) < 1e-3:  # looking straight down: the camera's x instead
        fwd = reference.R[0] - up * (reference.R[0] @ up)
    x = fwd / np.linalg.norm(fwd)
    R = np.stack([x, np.cross(up, x), up])
    s = metric_scale(points, joints, height)
    P = points.reshape(-1, 3) @ R.T * s
    stance = _stance(points, joints, up)
    az = (stance[np.isfinite(stance).all(1)] @ R.T * s)[:, 2]
    ground = az.size >= MIN_UP_GROUPS
    z0 = (np.median(az) - ankle_height) if ground else float(np.nanmin(P[:, 2]))
    hips = joint_points(points, joints, "mid_hip") @ R.T * s
    hips = hips[np.isfinite(hips).all(1)]
    centre = np.median(hips if len(hips) else P[np.isfinite(P).all(1)], axis=0)
    return WorldFrame(s, R, np.array([-centre[0], -centre[1], -z0]), up_from, ground)


def to_world(cam: Camera, frame: WorldFrame) -> Camera:
    """``cam`` (placed in the bundle's frame) in the world of ``frame``."""
    R = cam.R @ frame.R.T
    return cam.with_(R=R, t=frame.scale * cam.t - R @ frame.t)
