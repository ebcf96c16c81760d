"""OpenSim TRC marker files, written as OpenSim 4.6's ``TRCFileAdapter`` reads them.

Its reading rules: line 1 starts with ``PathFileType``; line 2 holds exactly the eight keys
``DataRate CameraRate NumFrames NumMarkers Units OrigDataRate OrigDataStartFrame
OrigNumFrames`` and line 3 their eight values; line 4 ``Frame#``, ``Time`` and the marker names
(empty fields ignored), line 5 ``X1 Y1 Z1 X2 ...`` (empty fields ignored); data follow a blank
line, tab-separated, each row with exactly ``2 + 3 * NumMarkers`` fields, a missing marker as
three empty fields. A row's fields are split at every tab but an empty last field is dropped, so
every field here is followed by a tab (as OpenSim writes them): a row then keeps its count
whatever is missing. An empty line ends the data.

Axes: OpenSim is y-up, cascalib z-up; a marker's (X, Y, Z) in the file is cascalib's
(x, z, -y), a rotation of -90 deg about x that keeps x and puts the ground in the X-Z plane.
(Pose2Sim's own conversion writes (y, z, x) instead: a further turn about the vertical, so a
Pose2Sim TRC and ours of the same recording differ by a 90 deg heading.) Units are metres.
"""

from __future__ import annotations

from collections.abc import Sequence
from pathlib import Path

import numpy as np
from numpy.typing import NDArray

__all__ = ["OPENSIM_FROM_WORLD", "write_trc"]

#: OpenSim (y-up) from cascalib's world (z-up): (x, y, z)_opensim = (x, z, -y)_cascalib.
OPENSIM_FROM_WORLD = np.array([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]])

_KEYS = ("DataRate", "CameraRate", "NumFrames", "NumMarkers", "Units", "OrigDataRate",
         "OrigDataStartFrame", "OrigNumFrames")


def write_trc(path: str | Path, joints: NDArray[np.float64], frames: NDArray[np.int64],
              times: NDArray[np.float64], names: Sequence[str], fps: float) -> Path:
    """Write one person's markers as an OpenSim TRC file.

    Parameters
    ----------
    path : str or Path
        Output file.
    joints : ndarray, shape (N, M, 3)
        World coordinates (cascalib's, z up, metres) of the M markers at N rows; NaN where
        missing (a marker is missing as a whole).
    frames : ndarray of int, shape (N,)
        Frame number of each row (written in ``Frame#``; OpenSim ignores it).
    times : ndarray, shape (N,)
        Seconds of each row, increasing.
    names : sequence of str
        The M marker names (no tabs).
    fps : float
        Frame rate of the recording (``DataRate``).

    Returns
    -------
    Path
        ``path``.
    """
    path = Path(path)
    n, m = joints.shape[:2]
    xyz = (joints @ OPENSIM_FROM_WORLD.T).reshape(n, 3 * m)
    first = int(frames[0]) if n else 1
    header = [
        f"PathFileType\t4\t(X/Y/Z)\t{path.name}",
        "\t".join(_KEYS),
        f"{fps:g}\t{fps:g}\t{n}\t{m}\tm\t{fps:g}\t{first}\t{n}",
        "Frame#\tTime\t" + "".join(f"{name}\t\t\t" for name in names),
        "\t\t" + "".join(f"X{i}\tY{i}\tZ{i}\t" for i in range(1, m + 1)),
        "",
    ]
    # one %-format for all rows: every field ends in a tab; NaN prints as "nan", made empty
    row = "%d\t%.6f\t" + "%.6f\t" * (3 * m) + "\n"
    values = np.column_stack([frames, times, xyz]).ravel().tolist()
    body = ((row * n) % tuple(values)).replace("nan", "")
    path.write_text("\n".join(header) + "\n" + body)
    return path
