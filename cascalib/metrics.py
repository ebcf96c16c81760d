"""Accuracy of a calibration against a reference (ground truth or an independent calibration).

What is measured, per camera matched by name (or an explicit mapping):

* **focal error** (%), signed: ``100 (f_est / f_true - 1)`` with ``f`` the mean of fx and fy;
* **principal-point error** (px): distance between the principal points;
* **relative-rotation error** (deg): the geodesic angle of
  ``(R_i R_ref^T) (R_i,true R_ref,true^T)^T``: the error of camera i's orientation *relative to the
  reference camera*, free of the world frame (never a difference of angle magnitudes); the same for
  every pair of cameras (median and max in the summary);
* **centre error after a similarity alignment** (truth units, m): the estimated camera centres are
  mapped onto the true ones by the least-squares similarity (Umeyama); with fewer than 3 cameras
  the similarity is instead the one that puts the reference camera exactly on its true pose
  (rotation and position), with the scale of the baseline for 2 cameras (1 for a single camera),
  because 1-2 points do not fix a rotation;
* **metric-scale error** (%): ``100 (1 / s - 1)`` with ``s`` the similarity's scale from estimate
  to truth: +10 % means the estimated rig is 10 % too large;
* **centre error after a ground-plane alignment** (m): only a yaw about z and an xy translation
  (2D Procrustes of the centres' xy; the reference camera's heading for a single camera), z and
  scale kept, so camera heights and metric scale count. Computed when both calibrations have the
  ground at z = 0 (their ``world`` says ``"ground z=0"``), else NaN;
* **time-offset error** (reference frames) and **rate error** (%): both calibrations' time
  mappings are first re-expressed relative to the same reference camera.

:func:`reprojection_stats` summarises pixel errors between observed and projected points.
"""

from __future__ import annotations

import itertools
import logging
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np
from numpy.typing import ArrayLike, NDArray

from cascalib.calibration import Calibration
from cascalib.errors import CalibrationFileError
from cascalib.geometry import rot_z, rotation_angle_deg, umeyama
from cascalib.nanstats import nanmedian_last

__all__ = [
    "CalibrationErrors",
    "CameraErrors",
    "ErrorSummary",
    "compare_calibrations",
    "identity_switches",
    "match_persons",
    "reprojection_stats",
    "rotation_error_in_sigmas",
]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class CameraErrors:
    """Errors of one camera (see the module docstring for definitions and units)."""

    camera: str
    truth_camera: str
    focal_error_pct: float
    principal_point_error_px: float
    rotation_error_deg: float
    center_error_similarity: float
    center_error_ground: float
    time_offset_error_frames: float
    time_rate_error_pct: float


@dataclass(frozen=True)
class ErrorSummary:
    """Rig-level summary. Medians/maxima are over the matched cameras (rotation: over the
    non-reference cameras; pairwise: over all pairs); focal, time and rate use absolute values."""

    n_cameras: int
    reference_camera: str
    alignment: str
    scale_error_pct: float
    focal_error_pct_median: float
    focal_error_pct_max: float
    principal_point_error_px_max: float
    rotation_error_deg_median: float
    rotation_error_deg_max: float
    pairwise_rotation_error_deg_median: float
    pairwise_rotation_error_deg_max: float
    center_error_similarity_median: float
    center_error_similarity_max: float
    center_error_ground_median: float
    center_error_ground_max: float
    time_offset_error_frames_max: float
    time_rate_error_pct_max: float
    unmatched_truth: tuple[str, ...] = ()


@dataclass(frozen=True)
class CalibrationErrors:
    """Result of :func:`compare_calibrations`: one row per matched camera and a summary."""

    cameras: tuple[CameraErrors, ...]
    summary: ErrorSummary

    def __getitem__(self, name: str) -> CameraErrors:
        for row in self.cameras:
            if row.camera == name:
                return row
        raise KeyError(name)

    def to_dict(self) -> dict[str, Any]:
        """JSON-ready form (NaN becomes None)."""
        out: dict[str, Any] = _json_safe({"cameras": [asdict(r) for r in self.cameras],
                                          "summary": asdict(self.summary)})
        return out

    def table(self) -> str:
        """A printable text table: one line per camera, then the summary."""
        return _format_table(self)


# -- alignment ------------------------------------------------------------------------------------

def _similarity(est: Calibration, truth: Calibration, pairs: list[tuple[str, str]],
                ref: tuple[str, str]) -> tuple[float, NDArray[np.float64], NDArray[np.float64],
                                               str]:
    """Similarity ``x_true = s R x_est + t`` and the method used (see module docstring)."""
    c_est = np.array([est[a].center for a, _ in pairs])
    c_true = np.array([truth[b].center for _, b in pairs])
    if len(pairs) >= 3:
        s, R, t = umeyama(c_est, c_true, with_scale=True)
        return s, R, t, "umeyama"
    # x_cam = R_e x_est + t_e = R_t x_true + t_t for the reference camera -> R = R_t^T R_e
    cam_e, cam_t = est[ref[0]], truth[ref[1]]
    R = cam_t.R.T @ cam_e.R
    s = 1.0
    if len(pairs) == 2:
        base_est = np.linalg.norm(c_est[1] - c_est[0])
        s = float(np.linalg.norm(c_true[1] - c_true[0]) / base_est) if base_est > 0 else np.nan
    t = cam_t.center - s * R @ cam_e.center
    return s, R, t, "reference-pose"


def _ground_alignment(c_est: NDArray[np.float64], c_true: NDArray[np.float64],
                      heading: tuple[float, float]) -> NDArray[np.float64]:
    """Estimated centres (N, 3) moved by the yaw + xy translation that best fits the true ones."""
    if len(c_est) >= 2:
        _, R2, t2 = umeyama(c_est[:, :2], c_true[:, :2], with_scale=False)
        yaw = np.arctan2(R2[1, 0], R2[0, 0])
    else:  # one camera: match its heading and position
        yaw = heading[1] - heading[0]
        t2 = c_true[0, :2] - (rot_z(yaw) @ c_est[0])[:2]
    moved = c_est @ rot_z(yaw).T
    moved[:, :2] += t2
    return moved


def _heading(R: NDArray[np.float64]) -> float:
    """Azimuth of a camera's optical axis in the world xy plane."""
    axis = R[2]  # third row of cam_from_world = optical axis in world coordinates
    return float(np.arctan2(axis[1], axis[0]))


# -- the comparison -------------------------------------------------------------------------------

def _match(est: Calibration, truth: Calibration,
           mapping: dict[str, str] | None) -> list[tuple[str, str]]:
    if mapping is None:
        pairs = [(n, n) for n in est.names if n in truth]
    else:
        for a, b in mapping.items():
            if a not in est:
                raise CalibrationFileError(f"mapping {a!r} -> {b!r}: the estimate has no camera "
                                           f"{a!r} ({est.names})", camera=a, field="mapping")
            if b not in truth:
                raise CalibrationFileError(f"mapping {a!r} -> {b!r}: the reference has no "
                                           f"camera {b!r} ({truth.names})", camera=a,
                                           field="mapping")
        pairs = list(mapping.items())
    if not pairs:
        raise CalibrationFileError(
            f"no camera names in common: estimate {est.names}, reference {truth.names}; "
            "pass a mapping", field="cameras")
    return pairs


def _time_mapping(calib: Calibration, name: str, ref: str) -> tuple[float, float]:
    """(offset, rate) of camera ``name`` relative to camera ``ref`` of the same calibration."""
    cam, r = calib[name], calib[ref]
    return (cam.time_offset - r.time_offset) / r.time_rate, cam.time_rate / r.time_rate


def rotation_error_in_sigmas(errors: CalibrationErrors, sigma_deg: dict[str, float]
                             ) -> list[float]:
    """Each non-reference camera's rotation error in units of its reported 1-sigma.

    Parameters
    ----------
    errors : CalibrationErrors
        From :func:`compare_calibrations`; the rotation errors are relative to the reference
        camera.
    sigma_deg : dict of str to float
        Reported 1-sigma rotation uncertainty (deg) of every estimated camera (a quality
        report's ``sigma_rotation_deg``).

    Returns
    -------
    list of float
        ``rotation_error_deg / hypot(sigma of the camera, sigma of the reference)``, in the
        order of ``errors.cameras``, NaN where a sigma is missing: about 68 % of them are <= 1
        and 95 % <= 2 when the uncertainty is calibrated.
    """
    ref = errors.summary.reference_camera
    return [float(row.rotation_error_deg / np.hypot(sigma_deg[row.camera], sigma_deg[ref]))
            for row in errors.cameras if row.camera != ref]


def compare_calibrations(estimated: Calibration, truth: Calibration, *,
                         mapping: dict[str, str] | None = None, reference: str | None = None,
                         ground: bool | None = None) -> CalibrationErrors:
    """Errors of ``estimated`` against ``truth``.

    Parameters
    ----------
    estimated, truth : Calibration
        The calibration to evaluate and the reference one.
    mapping : dict, optional
        ``{estimated name: truth name}``; default: cameras with the same name.
    reference : str, optional
        Estimated camera that relative rotations and time offsets refer to; default: the
        estimate's reference camera if it is matched, else the first matched camera.
    ground : bool, optional
        Compute the ground-plane alignment; default: when both worlds have the ground at z = 0.

    Returns
    -------
    CalibrationErrors

    Raises
    ------
    CalibrationFileError
        When no camera can be matched or the mapping names unknown cameras.
    """
    pairs = _match(estimated, truth, mapping)
    est_to_true = dict(pairs)
    if reference is None:
        reference = (estimated.reference_camera if estimated.reference_camera in est_to_true
                     else pairs[0][0])
    if reference not in est_to_true:
        raise CalibrationFileError(f"reference camera {reference!r} is not matched",
                                   camera=reference, field="reference")
    ref = (reference, est_to_true[reference])
    if ground is None:
        ground = "ground z=0" in estimated.world and "ground z=0" in truth.world
    s, R_align, t_align, method = _similarity(estimated, truth, pairs, ref)
    c_est = np.array([estimated[a].center for a, _ in pairs])
    c_true = np.array([truth[b].center for _, b in pairs])
    sim_err = np.linalg.norm(s * c_est @ R_align.T + t_align - c_true, axis=1)
    if ground:
        moved = _ground_alignment(c_est, c_true, (_heading(estimated[reference].R),
                                                  _heading(truth[ref[1]].R)))
        ground_err = np.linalg.norm(moved - c_true, axis=1)
    else:
        ground_err = np.full(len(pairs), np.nan)
    rows = tuple(_camera_row(estimated, truth, a, b, ref, sim_err[i], ground_err[i])
                 for i, (a, b) in enumerate(pairs))
    unmatched = tuple(n for n in truth.names if n not in est_to_true.values())
    if unmatched:
        logger.info("reference cameras without an estimate: %s", ", ".join(unmatched))
    return CalibrationErrors(rows, _summary(estimated, truth, pairs, ref, rows, s, method,
                                            unmatched))


def _camera_row(est: Calibration, truth: Calibration, a: str, b: str, ref: tuple[str, str],
                sim_err: float, ground_err: float) -> CameraErrors:
    ce, ct = est[a], truth[b]
    rel_e = ce.R @ est[ref[0]].R.T
    rel_t = ct.R @ truth[ref[1]].R.T
    off_e, rate_e = _time_mapping(est, a, ref[0])
    off_t, rate_t = _time_mapping(truth, b, ref[1])
    return CameraErrors(
        camera=a, truth_camera=b,
        focal_error_pct=100.0 * (ce.focal / ct.focal - 1.0),
        principal_point_error_px=float(np.linalg.norm(ce.principal_point - ct.principal_point)),
        rotation_error_deg=rotation_angle_deg(rel_e @ rel_t.T),
        center_error_similarity=float(sim_err), center_error_ground=float(ground_err),
        time_offset_error_frames=off_e - off_t,
        time_rate_error_pct=100.0 * (rate_e / rate_t - 1.0))


def _pairwise_rotation_errors(est: Calibration, truth: Calibration,
                              pairs: list[tuple[str, str]]) -> NDArray[np.float64]:
    errs = []
    for (a1, b1), (a2, b2) in itertools.combinations(pairs, 2):
        rel_e = est[a2].R @ est[a1].R.T
        rel_t = truth[b2].R @ truth[b1].R.T
        errs.append(rotation_angle_deg(rel_e @ rel_t.T))
    return np.asarray(errs, dtype=np.float64)


def _stat(values: ArrayLike, fn: Any) -> float:
    v = np.asarray(values, dtype=np.float64)
    v = v[np.isfinite(v)]
    return float(fn(v)) if v.size else float("nan")


def _summary(est: Calibration, truth: Calibration, pairs: list[tuple[str, str]],
             ref: tuple[str, str], rows: tuple[CameraErrors, ...], s: float, method: str,
             unmatched: tuple[str, ...]) -> ErrorSummary:
    col = {f: np.array([getattr(r, f) for r in rows]) for f in CameraErrors.__dataclass_fields__
           if f not in ("camera", "truth_camera")}
    rot = [r.rotation_error_deg for r in rows if r.camera != ref[0]]
    pairwise = _pairwise_rotation_errors(est, truth, pairs)
    return ErrorSummary(
        n_cameras=len(rows), reference_camera=ref[0], alignment=method,
        scale_error_pct=100.0 * (1.0 / s - 1.0) if len(pairs) >= 2 and s > 0 else float("nan"),
        focal_error_pct_median=_stat(np.abs(col["focal_error_pct"]), np.median),
        focal_error_pct_max=_stat(np.abs(col["focal_error_pct"]), np.max),
        principal_point_error_px_max=_stat(col["principal_point_error_px"], np.max),
        rotation_error_deg_median=_stat(rot, np.median),
        rotation_error_deg_max=_stat(rot, np.max),
        pairwise_rotation_error_deg_median=_stat(pairwise, np.median),
        pairwise_rotation_error_deg_max=_stat(pairwise, np.max),
        center_error_similarity_median=_stat(col["center_error_similarity"], np.median),
        center_error_similarity_max=_stat(col["center_error_similarity"], np.max),
        center_error_ground_median=_stat(col["center_error_ground"], np.median),
        center_error_ground_max=_stat(col["center_error_ground"], np.max),
        time_offset_error_frames_max=_stat(np.abs(col["time_offset_error_frames"]), np.max),
        time_rate_error_pct_max=_stat(np.abs(col["time_rate_error_pct"]), np.max),
        unmatched_truth=unmatched)


# -- reprojection ---------------------------------------------------------------------------------

def reprojection_stats(observed: ArrayLike, projected: ArrayLike) -> dict[str, float]:
    """Pixel distance statistics between observed and projected points.

    Parameters
    ----------
    observed, projected : array_like, shape (..., 2)
        Pixels; a point where either has a NaN coordinate is left out.

    Returns
    -------
    dict
        ``n`` (points used), ``median``, ``p90``, ``mean`` (px); NaN statistics when n = 0.

    Examples
    --------
    >>> reprojection_stats([[0, 0], [3, 4], [np.nan, 0]], [[0, 0], [0, 0], [1, 1]])["mean"]
    2.5
    """
    obs = np.asarray(observed, dtype=np.float64)
    proj = np.asarray(projected, dtype=np.float64)
    if obs.shape != proj.shape or obs.shape[-1] != 2:
        raise ValueError(f"observed {obs.shape} and projected {proj.shape} must both be (..., 2)")
    d = np.linalg.norm(obs - proj, axis=-1).ravel()
    d = d[np.isfinite(d)]
    if d.size == 0:
        return {"n": 0, "median": float("nan"), "p90": float("nan"), "mean": float("nan")}
    return {"n": int(d.size), "median": float(np.median(d)),
            "p90": float(np.percentile(d, 90)), "mean": float(d.mean())}


# -- output ---------------------------------------------------------------------------------------

def _json_safe(value: Any) -> Any:
    if isinstance(value, dict):
        return {k: _json_safe(v) for k, v in value.items()}
    if isinstance(value, (list, tuple)):
        return [_json_safe(v) for v in value]
    if isinstance(value, float) and not np.isfinite(value):
        return None
    return value


def _fmt(x: float, spec: str) -> str:
    return "-" if not np.isfinite(x) else format(x, spec)


_COLUMNS = [("camera", "camera", "s"), ("focal %", "focal_error_pct", "+.2f"),
            ("pp px", "principal_point_error_px", ".1f"), ("rot deg", "rotation_error_deg", ".2f"),
            ("centre sim m", "center_error_similarity", ".3f"),
            ("centre ground m", "center_error_ground", ".3f"),
            ("offset fr", "time_offset_error_frames", "+.2f"),
            ("rate %", "time_rate_error_pct", "+.3f")]


def _format_table(result: CalibrationErrors) -> str:
    cells = [[h for h, _, _ in _COLUMNS]]
    for row in result.cameras:
        name = row.camera if row.camera == row.truth_camera else f"{row.camera}={row.truth_camera}"
        cells.append([name] + [_fmt(getattr(row, f), spec) for _, f, spec in _COLUMNS[1:]])
    widths = [max(len(c[i]) for c in cells) for i in range(len(_COLUMNS))]
    lines = ["  ".join(c.ljust(w) if i == 0 else c.rjust(w) for i, (c, w)
                       in enumerate(zip(line, widths, strict=True))) for line in cells]
    lines.insert(1, "  ".join("-" * w for w in widths))
    s = result.summary
    lines += [
        "",
        f"reference camera: {s.reference_camera}   alignment: {s.alignment}   "
        f"metric scale error: {_fmt(s.scale_error_pct, '+.2f')} %",
        f"focal error |%|: median {_fmt(s.focal_error_pct_median, '.2f')}, "
        f"max {_fmt(s.focal_error_pct_max, '.2f')}",
        f"rotation vs reference (deg): median {_fmt(s.rotation_error_deg_median, '.2f')}, "
        f"max {_fmt(s.rotation_error_deg_max, '.2f')};  all pairs: median "
        f"{_fmt(s.pairwise_rotation_error_deg_median, '.2f')}, "
        f"max {_fmt(s.pairwise_rotation_error_deg_max, '.2f')}",
        f"centre error (m): similarity median {_fmt(s.center_error_similarity_median, '.3f')}, "
        f"max {_fmt(s.center_error_similarity_max, '.3f')};  ground median "
        f"{_fmt(s.center_error_ground_median, '.3f')}, "
        f"max {_fmt(s.center_error_ground_max, '.3f')}",
        f"time offset |error| max {_fmt(s.time_offset_error_frames_max, '.2f')} frames, "
        f"rate |error| max {_fmt(s.time_rate_error_pct_max, '.3f')} %",
    ]
    if s.unmatched_truth:
        lines.append(f"reference cameras without an estimate: {', '.join(s.unmatched_truth)}")
    return "\n".join(lines)


def match_persons(estimated: NDArray[np.float64], truth: NDArray[np.float64],
                  joints: ArrayLike | None = None
                  ) -> tuple[NDArray[np.float64], NDArray[np.int64], NDArray[np.bool_]]:
    """Match each reconstructed person to the nearest true person, frame by frame.

    Parameters
    ----------
    estimated : ndarray, shape (T, P, J, 3)
        Reconstructed joints (NaN where missing), e.g. :attr:`cascalib.poses.Poses3D.joints`.
    truth : ndarray, shape (T, Pt, J, 3)
        True joints at the same times.
    joints : array_like of int, optional
        Joints compared (default all).

    Returns
    -------
    errors : ndarray, shape (T, P, len(joints))
        Distance of each joint to the same joint of the matched true person (the one with the
        smallest median joint distance); NaN where missing.
    person : ndarray of int, shape (T, P)
        Index of the matched true person.
    present : ndarray of bool, shape (T, P)
        Slots holding a reconstructed person.
    """
    idx = np.arange(estimated.shape[2]) if joints is None else np.asarray(joints)
    est, true = estimated[:, :, idx], truth[:, :, idx]
    d = np.linalg.norm(est[:, :, None] - true[:, None], axis=-1)  # (T, P, Pt, J)
    per_person = np.nan_to_num(nanmedian_last(d), nan=np.inf)  # (T, P, Pt); empty slots: inf
    person = np.argmin(per_person, axis=-1)
    errors = np.take_along_axis(d, person[..., None, None], axis=2)[:, :, 0]
    present = np.asarray(np.isfinite(est[..., 0]).any(-1))
    return errors, person, present




def identity_switches(ids: NDArray[np.int64], estimated: NDArray[np.float64],
                      truth: NDArray[np.float64], joints: ArrayLike | None = None,
                      max_error_m: float = 0.5) -> int:
    """Identity switches of reconstructed persons against the true ones (CLEAR-MOT's IDSW).

    At each time the reconstructed slots with an identity are matched one-to-one to the true
    persons (Hungarian, on the median joint distance, below ``max_error_m``); a switch is a
    change of the identity matched to a true person between two consecutive times it is matched.

    Parameters
    ----------
    ids : ndarray of int, shape (T, P)
        Identity of each reconstructed slot, -1 for none (such slots are not matched).
    estimated : ndarray, shape (T, P, J, 3)
        Reconstructed joints, NaN where missing.
    truth : ndarray, shape (T, Pt, J, 3)
        True joints at the same times.
    joints : array_like of int, optional
        Joints compared (default all).
    max_error_m : float
        Largest median joint distance (m) of a match.

    Returns
    -------
    int
        Switches summed over the true persons.
    """
    from scipy.optimize import linear_sum_assignment

    idx = np.arange(estimated.shape[2]) if joints is None else np.asarray(joints)
    d = np.linalg.norm(estimated[:, :, None, idx] - truth[:, None, :, idx], axis=-1)
    cost = np.nan_to_num(nanmedian_last(d), nan=np.inf)  # (T, P, Pt)
    cost[ids < 0] = np.inf
    last = np.full(truth.shape[1], -1)
    switches = 0
    for t in np.flatnonzero(np.isfinite(cost).any(axis=(1, 2))):
        c = cost[t]
        r, q = linear_sum_assignment(np.where(c < max_error_m, c, 1e9))
        for a, b in zip(r, q, strict=True):
            if c[a, b] < max_error_m:
                switches += int(last[b] >= 0 and last[b] != ids[t, a])
                last[b] = ids[t, a]
    return switches
