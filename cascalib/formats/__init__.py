"""File formats: keypoint tracks and calibrations."""

from cascalib.formats.calibration import load_calibration, save_calibration
from cascalib.formats.keypoints import read_session, read_tracks, read_tracks_many, write_tracks

__all__ = ["load_calibration", "save_calibration", "read_session", "read_tracks",
           "read_tracks_many", "write_tracks"]
