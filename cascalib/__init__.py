"""cascalib: calibrate and synchronise sparse, unsynchronised multi-camera rigs from people.

The cascade (tracks -> single-view -> sync -> ground alignment -> bundle adjustment -> result)
of the CasCalib paper, with a GTSAM factor graph as its final stage.
"""

from cascalib.calibration import Calibration
from cascalib.camera import Camera
from cascalib.errors import (
    CalibrationFileError,
    CascalibError,
    EstimationFailed,
    InputError,
    RefinementFailed,
)
from cascalib.skeletons import CANONICAL_JOINTS, SKELETONS, Skeleton, get_skeleton
from cascalib.tracks import Tracks

__version__ = "0.1.0"

__all__ = [
    "CANONICAL_JOINTS",
    "SKELETONS",
    "Calibration",
    "CalibrationFileError",
    "Camera",
    "CascalibError",
    "EstimationFailed",
    "InputError",
    "RefinementFailed",
    "Skeleton",
    "Tracks",
    "get_skeleton",
    "__version__",
]
