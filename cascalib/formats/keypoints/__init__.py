"""Readers and writers of 2D keypoint files, one module per format.

``read_tracks`` detects the format from the content; see :mod:`.dispatch` for the list. Each
format module also has its own pure ``read_<format>`` / ``write_<format>`` functions.
"""

from cascalib.formats.keypoints.dispatch import (
    FORMATS,
    detect_format,
    read_session,
    read_tracks,
    read_tracks_many,
    write_tracks,
)

__all__ = ["FORMATS", "detect_format", "read_session", "read_tracks", "read_tracks_many",
           "write_tracks"]
