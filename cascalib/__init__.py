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

# The heavier parts (the cascade pulls in gtsam, scipy, matplotlib) load on first use, so that
# ``import cascalib`` and the light commands stay fast.
_LAZY = {
    "calibrate": "cascalib.pipeline", "CalibrationResult": "cascalib.pipeline",
    "CalibrationConfig": "cascalib.config", "simulate": "cascalib.simulate",
    "read_tracks": "cascalib.formats", "write_tracks": "cascalib.formats",
    "load_calibration": "cascalib.formats", "save_calibration": "cascalib.formats",
    "load_session": "cascalib.session", "compare_calibrations": "cascalib.metrics",
    "Poses3D": "cascalib.poses", "triangulate_poses": "cascalib.stages.reconstruct",
    "resynchronize": "cascalib.stages.resync",
}


def __getattr__(name: str) -> object:
    if name in _LAZY:
        import importlib

        return getattr(importlib.import_module(_LAZY[name]), name)
    raise AttributeError(f"module 'cascalib' has no attribute {name!r}")

__all__ = [
    *_LAZY,
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
