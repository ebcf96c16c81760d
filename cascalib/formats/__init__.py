"""File formats: keypoint tracks and calibrations."""

from cascalib.formats.calibration import load_calibration, save_calibration

__all__ = ["load_calibration", "save_calibration"]
