"""New clocks for a new recording of an already calibrated rig.

Unsynchronised cameras start at different moments in every recording, so a calibration's time
offsets only hold for the session it was made from. With the geometry known, synchronising again
needs no single-view step: each calibrated camera already places the people on the common ground
plane, so stages II-III (:func:`cascalib.stages.align.align_cameras`) find every camera's offset and
frame-rate ratio from the ground trajectories, and Stage V's sub-frame search
(:func:`cascalib.stages.refine.refine_clocks`) polishes the offsets and rates. The cameras'
intrinsics and poses are kept exactly.
"""

from __future__ import annotations

import logging

import numpy as np

from cascalib.calibration import Calibration
from cascalib.skeletons import CANONICAL_INDEX
from cascalib.stages.align import AlignConfig, align_cameras
from cascalib.stages.reconstruct import match_calibration, prepare
from cascalib.stages.refine import refine_clocks
from cascalib.stages.refine_config import RefineConfig
from cascalib.tracks import Tracks

__all__ = ["resynchronize"]

log = logging.getLogger(__name__)


def resynchronize(tracks: list[Tracks], calibration: Calibration, *, height: float = 1.70,
                  align: AlignConfig | None = None, refine: RefineConfig | None = None,
                  rng: np.random.Generator | int | None = 0) -> Calibration:
    """Time offsets and rates of a new recording, the cameras' geometry kept.

    Parameters
    ----------
    tracks : list of Tracks
        The new recording, two or more cameras of ``calibration`` (matched by name; see
        :func:`cascalib.stages.reconstruct.match_calibration`).
    calibration : Calibration
        The rig (world z up, ground z = 0); its time offsets and rates are replaced.
    height : float
        Mean person height (m).
    align, refine : optional
        Settings of the coarse (stages II-III) and sub-frame (Stage V) searches.
    rng : Generator or int, optional

    Returns
    -------
    Calibration
        Same cameras with the new ``time_offset`` and ``time_rate`` (reference: 0 and 1).

    Raises
    ------
    InputError
        If a camera has no tracks.
    EstimationFailed
        If no camera's people can be matched with the reference camera's.
    """
    rng = np.random.default_rng(rng)
    rcfg = refine or RefineConfig()
    calibration = match_calibration(tracks, calibration)
    by_name = {t.camera: t for t in tracks}
    data = prepare(list(tracks), calibration)  # checks names and counts
    ordered = [by_name[n] for n in calibration.names]
    # a calibrated camera is its own "plane frame" with the common ground: stages II-III apply
    aligned = align_cameras(ordered, list(calibration.cameras), align,
                            reference=calibration.reference_camera, rng=rng, height=height)
    clocks = {c.name: (c.time_offset, c.time_rate) for c in aligned.calibration}
    cameras = [c.with_(time_offset=clocks[c.name][0], time_rate=clocks[c.name][1])
               for c in calibration.cameras]
    joints = np.array([CANONICAL_INDEX[n] for n in rcfg.joints])
    cameras = refine_clocks(data, cameras, rcfg, joints, height, rng)
    for c in cameras:
        log.info("camera %s: time offset %+.2f frames, rate %.5f", c.name, c.time_offset,
                 c.time_rate)
    return Calibration(cameras, reference_camera=calibration.reference_camera,
                       quality=calibration.quality, world=calibration.world)
