"""3D poses of every frame from calibrated, synchronised cameras.

The last step of the cascade (after Stage V) and the whole of ``cascalib triangulate`` (new
recordings of an already calibrated rig): resample each camera's detections at the reference
camera's frame times (its clock: offset and rate), associate the persons across cameras by their
ground position and a triangulation check, triangulate every joint robustly (confidence weighted,
Huber), link the persons over time (and across gaps), and scatter the result into a
``(T, P, 26, 3)`` array.
"""

from __future__ import annotations

import logging
import weakref
from dataclasses import dataclass, replace

import numpy as np
from numpy.typing import NDArray

from cascalib.blas import one_blas_thread
from cascalib.calibration import Calibration
from cascalib.camera import Camera
from cascalib.errors import InputError
from cascalib.poses import Poses3D
from cascalib.skeletons import CANONICAL_JOINTS
from cascalib.stages.association import Association, associate, stitch_tracks
from cascalib.stages.person_size import bone_pairs, split_by_size
from cascalib.stages.refine_config import RefineConfig
from cascalib.stages.track_interpolation import frame_links, interpolate_views
from cascalib.stages.triangulation import triangulate
from cascalib.tracks import Tracks

log = logging.getLogger(__name__)

__all__ = ["SessionData", "clock_check_times", "match_calibration", "prepare", "views_at",
           "triangulate_groups", "persons_per_time", "poses_by_slot", "reconstruct",
           "triangulate_poses"]


@dataclass
class SessionData:
    """Per-camera inputs in calibration order (canonical joints), on the reference clock."""

    keypoints: list[NDArray[np.float64]]  # (F_c, P_c, 26, 3) canonical
    links: list[NDArray[np.int64]]  # (F_c, P_c) frame-to-frame person links
    sizes: list[tuple[int, int]]
    times: NDArray[np.float64]  # reference frames
    reference: int
    fps: float  # of the reference camera (frames per second; 1.0 when unknown)


def prepare(tracks: list[Tracks], calibration: Calibration) -> SessionData:
    """Order ``tracks`` like ``calibration``'s cameras and map them to the canonical joints.

    Raises
    ------
    InputError
        If a camera of ``calibration`` has no tracks, or there are fewer than two cameras.
    """
    by_name = {t.camera: t for t in tracks}
    missing = [n for n in calibration.names if n not in by_name]
    if missing:
        raise InputError(f"no tracks for camera(s) {missing} of the calibration (tracks are for "
                         f"{sorted(by_name)}); camera names must match", camera=missing[0],
                         field="tracks")
    if len(calibration) < 2:
        raise InputError("3D reconstruction needs at least two cameras", field="cameras")
    ordered = [by_name[n] for n in calibration.names]
    kps = [t.canonical() for t in ordered]
    links = [_frame_links(t) for t in ordered]
    sizes = [t.image_size or cam.image_size
             for t, cam in zip(ordered, calibration.cameras, strict=True)]
    ref = calibration.names.index(calibration.reference_camera)  # type: ignore[arg-type]
    times = np.arange(kps[ref].shape[0], dtype=np.float64)
    return SessionData(kps, links, sizes, times, ref, ordered[ref].frame_rate() or 1.0)


#: Frame links of each Tracks met (weakly held): stage IV's epipolar clock step and stage V
#: prepare the same session (0.27 s for 4 cameras x 3000 frames of 5 persons).
_LINKS: weakref.WeakKeyDictionary[Tracks, NDArray[np.int64]] = weakref.WeakKeyDictionary()


def _frame_links(tracks: Tracks) -> NDArray[np.int64]:
    """:func:`~cascalib.stages.track_interpolation.frame_links` of ``tracks``, made once."""
    links = _LINKS.get(tracks)
    if links is None:
        links = frame_links(tracks.canonical(), tracks.track_ids)
        links.flags.writeable = False
        _LINKS[tracks] = links
    return links


def clock_check_times(data: SessionData, n: int) -> SessionData:
    """``data`` at about ``n`` reference times spread over the recording, each moved by a
    fraction of a frame in [-0.5, 0.5), for searches that shift a camera's clock.

    Why the fractions: a detection interpolated between two frames averages their noise, so it
    lies closer to the truth than a detection at a frame. At whole reference frames every group
    sits at the same fraction of a camera's frame, and that fraction moves with the offset being
    searched: the search then prefers offsets that put the camera half-way between its frames
    (with the true geometry, stage V's clock search moved clocks 0.3 frame off the truth).
    Spread fractions make the noise averaging the same for every candidate offset. They are a
    low-discrepancy sequence (golden-ratio steps): evenly spread even for a few dozen times,
    where random ones would leave a cost at the mercy of the draw.
    """
    times = data.times[:: max(1, len(data.times) // n)]
    frac = np.mod(np.arange(times.size) * 0.6180339887498949, 1.0) - 0.5
    return replace(data, times=np.clip(times + frac, data.times[0], data.times[-1]))


def views_at(data: SessionData, cameras: list[Camera]) -> list[NDArray[np.float64]]:
    """Each camera's detections resampled at the reference frames through its clock."""
    return [interpolate_views(k, lk, (data.times - cam.time_offset) / cam.time_rate)
            for k, lk, cam in zip(data.keypoints, data.links, cameras, strict=True)]


def triangulate_groups(assoc: Association, cameras: list[Camera], joints: NDArray[np.int64],
                       *, huber_px: float = 4.0) -> tuple[NDArray[np.float64], NDArray[np.float64]]:
    """Robust triangulation of the joints ``joints`` of every group.

    Returns
    -------
    points : ndarray, shape (G, J, 3)
    errors : ndarray, shape (G, C, J)
        Reprojection errors (px), NaN where unobserved.
    """
    obs = assoc.obs[:, :, joints]
    n_g, n_c, n_j = obs.shape[:3]
    uv = obs[..., :2].transpose(1, 0, 2, 3).reshape(n_c, -1, 2)
    conf = obs[..., 2].transpose(1, 0, 2).reshape(n_c, -1)
    X, err = triangulate(cameras, uv, conf, huber_px=huber_px)
    return X.reshape(n_g, n_j, 3), err.reshape(n_c, n_g, n_j).transpose(1, 0, 2)


def persons_per_time(assoc: Association) -> int:
    """Most persons associated at one reference frame."""
    if assoc.n_groups == 0:
        return 0
    _, counts = np.unique(assoc.times, return_counts=True)
    return int(counts.max())


def poses_by_slot(assoc: Association, points: NDArray[np.float64], times: NDArray[np.float64],
                  errors: NDArray[np.float64] | None = None
                  ) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.float64]]:
    """Scatter group joints (G, 26, 3) into (T, P, 26, 3) slots ordered by track.

    Returns the poses, the track of each slot (T, P) (-1 where empty) and, from ``errors``
    (G, C, 26), the mean reprojection error (px) of each joint over its cameras (T, P, 26).
    """
    n_p = max(persons_per_time(assoc), 1)
    poses = np.full((len(times), n_p, 26, 3), np.nan)
    ids = np.full((len(times), n_p), -1, dtype=np.int64)
    resid = np.full((len(times), n_p, 26), np.nan)
    row = np.searchsorted(times, assoc.times)
    order = np.lexsort((assoc.tracks, row))
    slot = np.zeros(assoc.n_groups, dtype=np.int64)
    r_sorted = row[order]
    first = np.searchsorted(r_sorted, r_sorted, side="left")
    slot[order] = np.arange(len(order)) - first
    poses[row, slot] = points
    ids[row, slot] = assoc.tracks
    if errors is not None and assoc.n_groups:
        seen = np.isfinite(errors)
        total = np.where(seen, errors, 0.0).sum(axis=1)
        with np.errstate(invalid="ignore", divide="ignore"):
            resid[row, slot] = total / seen.sum(axis=1)
    return poses, ids, resid


def reconstruct(data: SessionData, cameras: list[Camera], cfg: RefineConfig, height: float
                ) -> tuple[Association, NDArray[np.float64], NDArray[np.float64]]:
    """Associate and triangulate all 26 canonical joints of every frame with fixed cameras.

    Returns
    -------
    association : Association
    points : ndarray, shape (G, 26, 3)
    errors : ndarray, shape (G, C, 26)
        Reprojection errors (px), NaN where unobserved.
    """
    assoc = associate(views_at(data, cameras), cameras, data.times, height=height,
                      **cfg.association_gates(refined=True))  # type: ignore[arg-type]
    assoc = stitch_tracks(assoc, fps=data.fps)
    points, err = triangulate_groups(assoc, cameras, np.arange(26))
    # stitching and linking can swap two people who pass close: cut where the size jumps
    bones, classes = bone_pairs(CANONICAL_JOINTS)
    tracks = split_by_size(points, assoc.tracks, assoc.times, bones, classes, join=False)
    return replace(assoc, tracks=tracks), points, err


def match_calibration(tracks: list[Tracks], calibration: Calibration) -> Calibration:
    """The cameras of ``calibration`` that ``tracks`` have, when two or more of them do.

    Cameras without tracks are left out (with a warning; the clocks are re-based if the
    reference camera is among them, see :meth:`Calibration.subset`).

    Raises
    ------
    InputError
        If a track's camera is not in the calibration.
    """
    have = {t.camera for t in tracks}
    unknown = sorted(have - set(calibration.names))
    if unknown:
        raise InputError(f"tracks for camera(s) {unknown} that the calibration does not have "
                         f"(its cameras: {calibration.names}); camera names must match",
                         camera=unknown[0], field="tracks")
    present = [n for n in calibration.names if n in have]
    if 2 <= len(present) < len(calibration):
        log.warning("no tracks for camera(s) %s: using %s",
                    [n for n in calibration.names if n not in have], present)
        return calibration.subset(present)
    return calibration


@one_blas_thread
def triangulate_poses(tracks: list[Tracks], calibration: Calibration, *, height: float = 1.70,
                      config: RefineConfig | None = None) -> Poses3D:
    """3D poses of every reference frame from a calibration (a new recording of the same rig).

    Parameters
    ----------
    tracks : list of Tracks
        2D detections of two or more cameras of ``calibration`` (matched by name); cameras of
        the calibration without tracks are left out (with a warning), tracks of unknown
        cameras are an error. Times are the frames of the calibration's reference camera, or
        of the first camera with tracks if the reference has none.
    calibration : Calibration
        Cameras with their time offsets and rates (the reference camera's frames are the times).
    height : float
        Mean person height (m), used to place persons on the ground for the association.
    config : RefineConfig, optional
        Association gates and consistency tolerance (Stage V's refined settings).

    Returns
    -------
    Poses3D
        Canonical joints (T, P, 26, 3) in metres at the reference camera's frames.

    Raises
    ------
    InputError
        If a camera has no tracks, or no person is seen by two cameras at once.
    """
    cfg = config or RefineConfig()
    calibration = match_calibration(tracks, calibration)
    data = prepare(list(tracks), calibration)
    assoc, points, err = reconstruct(data, list(calibration.cameras), cfg, height)
    if assoc.n_groups == 0:
        raise InputError("no person is seen by two cameras at the same time: check that the "
                         "tracks belong to this rig and that its time offsets fit this recording",
                         field="tracks")
    poses, ids, resid = poses_by_slot(assoc, points, data.times, err)
    return Poses3D(poses, data.times, data.fps, ids, resid)
