"""MediaPipe landmarks in caliscope's long CSV layout (several cameras in one file)::

    sync_index,port,frame_index,frame_time,point_id,img_loc_x,img_loc_y,obj_loc_x,obj_loc_y
    0,0,0,47389.90246235,0,520,193,,
    ...

One row per landmark. ``port`` is the camera: every port becomes one :class:`Tracks`, named
``port_N`` unless the caller names it (a file with a single port is named after the file, like
the single-camera formats). ``frame_index`` is the row of that camera,
``frame_time`` its capture time in seconds (kept as ``timestamps``, on the clock shared by all
ports; ``nan`` or empty when unknown). ``point_id`` 0-32 are the BlazePose-33 body landmarks;
other ids (hands 100+, 200+, face 500+) are not body joints and are not read. The file stores
no confidence (every landmark read gets 1.0), no image size, no frame rate and one person per
camera. ``sync_index`` is caliscope's own frame grouping and is not read;
:func:`write_mediapipe_csv` writes ``frame_index`` there.
"""

from __future__ import annotations

import csv
import re
import warnings
from collections.abc import Callable, Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np
from numpy.typing import NDArray

from cascalib.errors import InputError
from cascalib.formats.keypoints import _common as c
from cascalib.skeletons import SKELETONS
from cascalib.tracks import Tracks

__all__ = ["read_mediapipe_csv", "write_mediapipe_csv", "looks_like", "COLUMNS"]

#: Columns caliscope writes, in order.
COLUMNS = ("sync_index", "port", "frame_index", "frame_time", "point_id", "img_loc_x",
           "img_loc_y", "obj_loc_x", "obj_loc_y")
_NEEDED = ("port", "frame_index", "frame_time", "point_id", "img_loc_x", "img_loc_y")
_N_BODY = 33

#: Camera names as a caller may give them: one name (single-port files), a template with
#: ``{port}``, a mapping port -> name, or names in port order.
CameraArg = str | Mapping[Any, str] | Sequence[str] | None


def looks_like(header: str) -> bool:
    """True when a CSV header line has caliscope's landmark columns (the reader then checks
    that all the columns it needs are there)."""
    cols = {h.strip() for h in header.split(",")}
    return {"point_id", "img_loc_x"} <= cols


def _header(path: Path) -> list[str]:
    try:
        with open(path, encoding="utf-8", newline="") as fh:
            return [h.strip() for h in fh.readline().split(",")]
    except (OSError, UnicodeDecodeError) as exc:
        raise InputError(f"cannot read: {exc}", file=str(path)) from None


def _load(path: Path) -> dict[str, NDArray[np.float64]]:
    """The needed columns as float arrays, shape (n_rows,) each."""
    header = _header(path)
    missing = [n for n in _NEEDED if n not in header]
    if missing:
        raise InputError(f"missing CSV column(s) {', '.join(missing)}", file=str(path),
                         field=missing[0])
    cols = [header.index(n) for n in _NEEDED]
    data = None
    # Plain C parsing first; per-cell converters (for empty cells) only when that fails.
    for converters in (None, _empty_as_nan(cols)):
        try:
            with warnings.catch_warnings():
                # A header without rows is reported as "no detections" by the caller.
                warnings.filterwarnings("ignore", "loadtxt: input contained no data")
                data = np.loadtxt(path, delimiter=",", skiprows=1, usecols=cols, ndmin=2,
                                  dtype=np.float64, converters=converters, encoding="utf-8")
            break
        except ValueError:
            continue
    if data is None:
        _raise_first_bad_row(path, cols)
        raise InputError("cannot parse the CSV", file=str(path))  # pragma: no cover
    return {n: data[:, k] for k, n in enumerate(_NEEDED)}


def _empty_as_nan(cols: list[int]) -> dict[int | str, Callable[[str], float]]:
    # Only frame_time may be empty (unknown); any other empty cell is caught as NaN later.
    return {i: (lambda s: float(s) if s.strip() else np.nan) for i in cols}


def _raise_first_bad_row(path: Path, cols: list[int]) -> None:
    with open(path, encoding="utf-8", newline="") as fh:
        reader = csv.reader(fh)
        next(reader)
        for line, row in enumerate(reader, start=2):
            cells = dict(zip(_NEEDED, (row[i] if i < len(row) else None for i in cols),
                             strict=True))
            for name, cell in cells.items():
                if cell is not None and (not cell.strip() or _is_number(cell)):
                    continue
                what = "missing value" if cell is None else repr(cell)
                port, frame = cells["port"], cells["frame_index"]
                raise InputError(
                    f"line {line}: {what} is not a number", file=str(path),
                    camera=f"port_{port}" if port and port.isdigit() else None,
                    frame=int(frame) if frame and frame.isdigit() else None, field=name)


def _is_number(cell: str) -> bool:
    try:
        float(cell)
    except ValueError:
        return False
    return True


def _integers(a: NDArray[np.float64], name: str, path: Path, cams: NDArray[np.float64] | None
              ) -> NDArray[np.int64]:
    bad = ~np.isfinite(a) | (a < 0) | (a != np.round(a))
    if bad.any():
        i = int(np.argmax(bad))
        cam = None if cams is None or not np.isfinite(cams[i]) else f"port_{int(cams[i])}"
        raise InputError(f"line {i + 2}: {name} must be an integer >= 0, got {a[i]:g}",
                         file=str(path), camera=cam, field=name)
    return a.astype(np.int64)


def _names(ports: list[int], camera: CameraArg, path: Path) -> list[str]:
    if camera is None:
        # One camera per file (as the simulator writes them): named like any other file.
        return [c.default_camera(path)] if len(ports) == 1 else [f"port_{p}" for p in ports]
    if isinstance(camera, str):
        if "{port}" in camera:
            return [camera.format(port=p) for p in ports]
        if len(ports) == 1:
            return [camera]
        raise InputError(f"the file holds {len(ports)} cameras (ports {ports}): give a name "
                         "template with {port}, a mapping port -> name or one name per port",
                         file=str(path), field="camera")
    if isinstance(camera, Mapping):
        named = {int(k): v for k, v in camera.items()}
        missing = [p for p in ports if p not in named]
        if missing:
            raise InputError(f"no camera name given for port(s) {missing}", file=str(path),
                             field="port")
        return [named[p] for p in ports]
    names = list(camera)
    if len(names) != len(ports):
        raise InputError(f"{len(names)} camera names for {len(ports)} ports {ports}",
                         file=str(path), field="camera")
    return names


def read_mediapipe_csv(path: str | Path, *, camera: CameraArg = None,
                       skeleton: Any = None, image_size: c.SizeArg = None,
                       fps: c.FpsArg = None) -> list[Tracks]:
    """Read a caliscope landmark CSV into one Tracks per port, in port order.

    Parameters
    ----------
    camera : optional
        Camera names: see :data:`CameraArg`; default ``port_N`` (the file stem when the file
        holds one port).
    skeleton : optional
        Must be BlazePose-33 if given (the CSV's point ids are BlazePose's).
    image_size, fps : optional
        Not stored by the CSV: one value, or a mapping camera name -> value.

    Returns
    -------
    list of Tracks
        keypoints of shape (last frame_index + 1, 1, 33, 3); timestamps from ``frame_time``.

    Raises
    ------
    InputError
        Missing columns, non-numeric cells, NaN/inf landmark coordinates, duplicate landmarks,
        contradicting frame times, no body landmark for a port; naming file, camera (port),
        frame and field.
    """
    path = Path(path)
    if skeleton is not None and c.named_skeleton(skeleton, file=path,
                                                 camera=None).name != "blazepose33":
        raise InputError("caliscope CSV point ids are BlazePose-33", file=str(path),
                         field="skeleton")
    d = _load(path)
    ports_all = _integers(d["port"], "port", path, None)
    ports = sorted(set(ports_all.tolist()))
    if not ports:
        raise InputError("no detections: the file has no rows", file=str(path),
                         field="point_id")
    names = _names(ports, camera, path)
    frames_all = _integers(d["frame_index"], "frame_index", path, d["port"])
    point = _integers(d["point_id"], "point_id", path, d["port"])
    out = []
    for port, name in zip(ports, names, strict=True):
        rows = np.flatnonzero(ports_all == port)
        out.append(_port_tracks(d, rows, frames_all[rows], point[rows], path=path,
                                camera=name, image_size=image_size, fps=fps))
    return out


def _frame_times(times: NDArray[np.float64], frames: NDArray[np.int64], n_frames: int, *,
                 path: Path, camera: str) -> NDArray[np.float64] | None:
    """One time per frame (NaN where unknown); every row of a frame must agree on it."""
    ts = np.full(n_frames, np.nan)
    ts[frames] = times
    same = (ts[frames] == times) | (np.isnan(ts[frames]) & np.isnan(times))
    if not same.all():
        f = int(frames[np.argmin(same)])
        raise InputError("rows of one frame disagree on frame_time", file=str(path),
                         camera=camera, frame=f, field="frame_time")
    bad = np.isinf(ts)
    if bad.any():
        raise InputError("infinite frame_time", file=str(path), camera=camera,
                         frame=int(np.argmax(bad)), field="frame_time")
    return ts if np.isfinite(ts).any() else None


def _port_tracks(d: dict[str, NDArray[np.float64]], rows: NDArray[np.int64],
                 frames: NDArray[np.int64], point: NDArray[np.int64], *, path: Path,
                 camera: str, image_size: c.SizeArg, fps: c.FpsArg) -> Tracks:
    n_frames = int(frames.max()) + 1
    c.check_dense(n_frames, 1, _N_BODY, n_detections=len(np.unique(frames)), file=path,
                  camera=camera)
    ts = _frame_times(d["frame_time"][rows], frames, n_frames, path=path, camera=camera)
    body = point < _N_BODY
    c.require_records(int(body.sum()), file=path, camera=camera, field="point_id")
    f, pt = frames[body], point[body]
    xy = np.stack([d["img_loc_x"][rows][body], d["img_loc_y"][rows][body]], -1)
    bad = ~np.isfinite(xy)
    if bad.any():
        i, k = (int(v) for v in np.argwhere(bad)[0])
        raise InputError(f"landmark {pt[i]} has no finite coordinate ({xy[i, k]})",
                         file=str(path), camera=camera, frame=int(f[i]),
                         field=("img_loc_x", "img_loc_y")[k])
    key = f * _N_BODY + pt
    uniq, first, counts = np.unique(key, return_index=True, return_counts=True)
    if (counts > 1).any():
        i = int(first[np.argmax(counts > 1)])
        raise InputError(f"landmark {pt[i]} appears twice", file=str(path), camera=camera,
                         frame=int(f[i]), field="point_id")
    kp = np.full((n_frames, 1, _N_BODY, 3), np.nan)
    kp[f, 0, pt, :2] = xy
    kp[f, 0, pt, 2] = 1.0
    return Tracks(camera=camera, keypoints=kp, skeleton=SKELETONS["blazepose33"],
                  image_size=c.resolve_image_size(None, image_size, camera=camera, file=path),
                  fps=c.resolve_fps(None, fps, camera=camera, file=path), timestamps=ts,
                  source=str(path))


def _port(name: str, index: int) -> int:
    m = re.fullmatch(r"(?:port|cam)_?(\d+)", name)
    return int(m.group(1)) if m else index


def write_mediapipe_csv(tracks: Tracks | Sequence[Tracks], path: str | Path) -> Path:
    """Write one or several cameras into one caliscope CSV.

    The port of a camera named ``port_N`` (or ``cam_N``) is N, else its position in the list.
    Skeletons other than BlazePose-33 are converted through the canonical joints. ``frame_time``
    is the timestamp, else ``frame_index / fps``, else ``nan``. Confidences are not stored.

    Raises
    ------
    InputError
        If a camera has more than one person in a frame (the layout has no person column), or
        two cameras map to the same port.
    """
    path = Path(path)
    cams = [tracks] if isinstance(tracks, Tracks) else list(tracks)
    ports = [_port(t.camera, i) for i, t in enumerate(cams)]
    if len(set(ports)) != len(ports):
        raise InputError(f"cameras {[t.camera for t in cams]} map to ports {ports}: name them "
                         "port_0, port_1, ... or give distinct positions", file=str(path),
                         field="port")
    blocks = [_rows(c.convert_skeleton(t, "blazepose33", "mediapipe-csv"), port, path)
              for t, port in zip(cams, ports, strict=True)]
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "w", encoding="utf-8", newline="") as fh:
        fh.write(",".join(COLUMNS) + "\n")
        for block in blocks:
            fh.writelines(block)
    return path


def _rows(tracks: Tracks, port: int, path: Path) -> list[str]:
    """CSV lines of one camera (floats via repr, so they read back exactly)."""
    present = np.isfinite(tracks.keypoints[..., 0])
    n_persons = present.any(-1).sum(-1)
    if (n_persons > 1).any():
        first = int(np.argmax(n_persons > 1))
        raise InputError(f"{n_persons[first]} persons in one frame: the caliscope CSV holds "
                         "one person per camera", file=str(path), camera=tracks.camera,
                         frame=first, field="keypoints")
    if tracks.timestamps is not None:
        times = tracks.timestamps
    elif tracks.fps is not None:
        times = np.arange(tracks.n_frames) / tracks.fps
    else:
        times = np.full(tracks.n_frames, np.nan)
    f, p, j = np.nonzero(present)
    xy = tracks.keypoints[f, p, j, :2].tolist()
    t = times[f].tolist()
    return [f"{fi},{port},{fi},{ti!r},{ji},{x!r},{y!r},,\n"
            for fi, ti, ji, (x, y) in zip(f.tolist(), t, j.tolist(), xy, strict=True)]
