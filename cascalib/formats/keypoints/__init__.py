"""Readers and writers of 2D keypoint files, one module per format.

``read_tracks`` detects the format from the content; see :mod:`.dispatch` for the list. Each
format module also has its own pure ``read_<format>`` / ``write_<format>`` functions, re-exported
here.
"""

from cascalib.formats.keypoints._common import LimitExceeded, ReadLimits, read_limits
from cascalib.formats.keypoints.cascalib_ref import read_cascalib_ref, write_cascalib_ref
from cascalib.formats.keypoints.coco import read_coco, write_coco
from cascalib.formats.keypoints.dispatch import (
    FORMATS,
    detect_format,
    read_session,
    read_tracks,
    read_tracks_many,
    write_tracks,
)
from cascalib.formats.keypoints.mediapipe_csv import read_mediapipe_csv, write_mediapipe_csv
from cascalib.formats.keypoints.mmpose import read_mmpose, write_mmpose
from cascalib.formats.keypoints.native import (
    read_native_json,
    read_native_npz,
    write_native_json,
    write_native_npz,
)
from cascalib.formats.keypoints.openpose import read_openpose, write_openpose

__all__ = [
    "FORMATS", "detect_format", "read_session", "read_tracks", "read_tracks_many",
    "write_tracks", "LimitExceeded", "ReadLimits", "read_limits",
    "read_cascalib_ref", "write_cascalib_ref", "read_coco", "write_coco",
    "read_mediapipe_csv", "write_mediapipe_csv", "read_mmpose", "write_mmpose",
    "read_native_json", "read_native_npz", "write_native_json", "write_native_npz",
    "read_openpose", "write_openpose",
]  # fmt: skip
