"""Stage V's outcome (:class:`RefineResult`), and the outcome of a rig one of whose cameras
Stage V had to leave out (:func:`with_failed_camera`)."""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray

from cascalib.calibration import Calibration
from cascalib.stages.association import Association
from cascalib.stages.quality import CameraQuality
from cascalib.stages.refine_graph import SolveInfo

__all__ = ["RefineResult", "with_failed_camera"]


@dataclass(frozen=True)
class RefineResult:
    """Outcome of stage V.

    Attributes
    ----------
    calibration : Calibration
        Refined cameras (same order as the input), ``quality`` filled per camera.
    poses3d : ndarray, shape (T, P, 26, 3)
        Triangulated canonical joints at reference frames ``times`` (NaN where unknown); slots are
        ordered by person track.
    times : ndarray, shape (T,)
        Reference frames of ``poses3d``.
    track_ids : ndarray of int, shape (T, P)
        Person track of each slot of ``poses3d`` (-1 for empty slots).
    quality : dict of str to CameraQuality
        Per-camera report.
    association : Association
        The final cross-view association.
    solves : list of SolveInfo
        One per step, in order: each round, the lens-distortion pass after the rounds, the
        principal-point pass (as its update left it) and the lens pass at the end, when they
        are kept. Each is the last Levenberg-Marquardt run
        of that step's graduated solve (error before / after, iterations, seconds of that run
        alone); earlier graduated stages, a pass its update replaced and the split-half check
        of the principal point are not listed, so their seconds sum to less than the time
        spent in gtsam.
    distortion : bool
        Whether the final cameras carry a lens distortion: found by a lens pass, or carried
        by the start cameras and held (not those of known intrinsics).
    n_selected : int
        Person-frames in the last graph.
    residuals : ndarray, shape (T, P, 26), optional
        Mean reprojection error (px) of each joint of ``poses3d`` over its cameras.
    step_seconds : dict of str to float
        Where the stage's wall time went: "solves" (every factor-graph solve, graph building
        and the marginals included, the split-half check and replaced passes too),
        "clock_updates", "reconstruction" (every frame triangulated with the final cameras,
        and the quality report), "other" (association, frame selection, bone targets, the
        held-out checks) and their sum "total". A camera left out and refined without counts
        both attempts.
    """

    calibration: Calibration
    poses3d: NDArray[np.float64]
    times: NDArray[np.float64]
    track_ids: NDArray[np.int64]
    quality: dict[str, CameraQuality]
    association: Association
    solves: list[SolveInfo] = field(default_factory=list)
    distortion: bool = False
    n_selected: int = 0
    residuals: NDArray[np.float64] | None = None
    step_seconds: dict[str, float] = field(default_factory=dict)


def with_failed_camera(result: RefineResult, initial: Calibration, name: str, reason: str
                       ) -> RefineResult:
    """``result`` of a rig without camera ``name``, with that camera put back where it was in
    ``initial``: as stages I-IV left it, verdict "failed" for ``reason``, no observation in the
    association (its column NaN) and no uncertainty."""
    index = initial.names.index(name)
    cam = initial[name]
    cameras = list(result.calibration.cameras)
    cameras.insert(index, cam)
    failed = CameraQuality(name, 0, np.nan, np.nan, 0.0, np.nan, np.nan, np.nan, np.nan,
                           cam.time_offset, "failed", reason)
    quality = {c.name: result.quality[c.name] if c.name != name else failed for c in cameras}
    assoc = result.association
    obs = np.insert(assoc.obs, index, np.nan, axis=1)  # (G, C, 26, 3)
    calib = Calibration(cameras, reference_camera=result.calibration.reference_camera,
                        quality={n: q.to_dict() for n, q in quality.items()},
                        world=result.calibration.world)
    return replace(result, calibration=calib, quality=quality, association=replace(assoc, obs=obs))
