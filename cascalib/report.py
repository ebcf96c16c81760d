"""The self-contained ``report.html`` of a calibration run, with its PNG plots.

One page a lab member can read without the code: a verdict, one table row per camera
(intrinsics, position, time offset, uncertainties, verdict and reason), the plots of every stage
and a glossary of every number. Plots are embedded as base64 PNG (the HTML file alone is enough)
and also written next to it (``report_*.png``).
"""

from __future__ import annotations

import base64
import html
import importlib
import logging
from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np

from cascalib.plots import (
    plot_birdseye,
    plot_reprojection_histograms,
    plot_rig_3d,
    save_figure,
)
from cascalib.stages.align import AlignmentResult

if TYPE_CHECKING:
    from cascalib.pipeline import CalibrationResult

__all__ = ["write_report", "reprojection_errors"]

log = logging.getLogger(__name__)

GLOSSARY = (
    ("focal f", "Focal length in pixels (fx = fy). With the image width W, the horizontal field "
                "of view is 2 atan(W / 2f)."),
    ("principal point c", "Pixel where the optical axis meets the image; near the image centre."),
    ("distortion", "OpenCV radial (k1, k2, k3) and tangential (p1, p2) lens distortion."),
    ("position", "Camera centre in the world frame: x, y on the ground, z = height above the "
                 "ground (metres). The world's origin and heading are the reference camera's."),
    ("time offset / rate", "Frame k of the camera shows the scene at reference-camera frame "
                           "rate * k + offset (reference camera: 0 and 1). The offset's "
                           "± is its 1-s.d. uncertainty (frames) from how well the "
                           "people's motion over the recording agrees on it; for a camera "
                           "that starts long before or after the reference it includes the "
                           "rate's uncertainty carried to the camera's first frame."),
    ("reprojection median / p90", "Distance in pixels between each detected keypoint and the "
                                  "projection of its triangulated 3D joint: median and 90th "
                                  "percentile over the inliers."),
    ("inlier rate", "Share of the camera's associated keypoints within the inlier threshold."),
    ("sigma (1-s.d.)", "Uncertainty of focal, rotation and position from the bundle adjustment's "
                       "marginal covariances, scaled by the measured residual spread and a "
                       "factor calibrated on simulated rigs against true errors."),
    ("verdict", "accepted: all checks passed; suspicious: a check failed (the reason says "
                "which), use with care; failed: do not use this camera."),
)


#: Most person-frames whose keypoints the reprojection histograms show: evenly spread, they
#: draw the same distribution, and triangulating every one again took seconds.
HISTOGRAM_GROUPS = 2000


def reprojection_errors(result: CalibrationResult, max_groups: int | None = HISTOGRAM_GROUPS
                        ) -> dict[str, np.ndarray]:
    """Per camera, the reprojection errors (px) of its associated keypoints (of at most
    ``max_groups`` person-frames spread over the recording; None: all)."""
    from cascalib.stages.reconstruct import triangulate_groups

    assoc = result.refinement.association
    if max_groups is not None and assoc.n_groups > max_groups:
        assoc = assoc.subset(np.linspace(0, assoc.n_groups - 1, max_groups).astype(np.int64))
    joints = np.arange(assoc.obs.shape[2])
    _, err = triangulate_groups(assoc, list(result.calibration.cameras), joints)
    return {cam.name: err[:, c].ravel() for c, cam in enumerate(result.calibration)}


def _warnings(result: CalibrationResult) -> str:
    """The result's warnings (cameras left out, stage I replaced, no ground) as a list."""
    items = result.warnings()
    if not items:
        return ""
    return ("<h2>Warnings</h2><ul>"
            + "".join(f"<li class='suspicious'>{html.escape(w)}</li>" for w in items) + "</ul>")


def _camera_table(result: CalibrationResult) -> str:
    head = ("camera", "image", "f [px]", "&sigma;f", "c [px]", "k1, k2, p1, p2, k3",
            "position x, y, z [m]", "&sigma; rot [deg] / pos [cm]", "offset [frames]", "rate",
            "reproj. median / p90 [px]", "inliers", "verdict")
    rows = []
    for cam in result.calibration:
        q = result.refinement.quality.get(cam.name)
        c = cam.center
        cells = (
            cam.name, f"{cam.image_size[0]}x{cam.image_size[1]}", f"{cam.focal:.1f}",
            f"{q.sigma_focal_px:.1f}" if q else "", f"{cam.K[0, 2]:.1f}, {cam.K[1, 2]:.1f}",
            ", ".join(f"{v:.3g}" for v in cam.dist), f"{c[0]:.2f}, {c[1]:.2f}, {c[2]:.2f}",
            f"{q.sigma_rotation_deg:.2f} / {100 * q.sigma_position_m:.1f}" if q else "",
            f"{cam.time_offset:.2f}" + (f" &plusmn; {q.sigma_time_offset_frames:.2f}"
                                        if q and np.isfinite(q.sigma_time_offset_frames)
                                        else ""),
            f"{cam.time_rate:.5f}",
            f"{q.reprojection_median_px:.2f} / {q.reprojection_p90_px:.2f}" if q else "",
            f"{q.inlier_rate:.0%}" if q else "",
            f"<b class='{q.verdict}'>{q.verdict}</b><br><small>{html.escape(q.reason)}</small>"
            if q else "")
        rows.append("<tr>" + "".join(f"<td>{v}</td>" for v in cells) + "</tr>")
    return ("<table><tr>" + "".join(f"<th>{h}</th>" for h in head) + "</tr>" + "".join(rows)
            + "</table>")


def _figure_list(result: CalibrationResult) -> list[tuple[str, str, str, str]]:
    """(section, caption, kind, camera) of every plot, in reading order (see :func:`_draw`)."""
    figs: list[tuple[str, str, str, str]] = []
    if _optional("cascalib.stages.single_view_plot", "plot_single_view") is not None:
        figs += [("Stage I: single-view ground plane", f"{name}: 1 m ground grid and inlier "
                  "(green) / outlier (red) ankle-to-shoulder segments", "single_view", name)
                 for name in result.single_view]
    align = result.alignment
    staged = isinstance(align, AlignmentResult)  # else the multi-view start
    if staged and _optional("cascalib.stages.align_plot", "plot_sync_curves") is not None:
        figs.append(("Stages II-IV: synchronisation", "Sync cost per camera pair with the "
                     "chosen offset", "sync", ""))
        if align.epipolar is not None and align.epipolar.pairs:  # type: ignore[union-attr]
            figs.append(("Stages II-IV: synchronisation", "Sub-frame clocks: the epipolar "
                         "consistency of the people's joints per camera pair over the clock "
                         "shift (lower is better), with the shift chosen in each iteration",
                         "epipolar", ""))
    figs.append(("Cameras and trajectories", "Bird's-eye view of the final cameras and the "
                 "triangulated feet", "birdseye", ""))
    figs.append(("Cameras and trajectories", "3D view of the cameras and a few poses",
                 "rig_3d", ""))
    figs.append(("Reprojection errors", "Per camera, after the bundle adjustment",
                 "reprojection", ""))
    return figs


def _draw(result: CalibrationResult, kind: str, camera: str, path: str) -> str:
    """Draw one plot of :func:`_figure_list` and write it as PNG to ``path``."""
    if kind == "single_view":
        fig = _optional("cascalib.stages.single_view_plot", "plot_single_view")(
            result.single_view[camera])
    elif kind in ("sync", "epipolar"):
        fig = _optional("cascalib.stages.align_plot", "plot_sync_curves" if kind == "sync"
                        else "plot_epipolar_curves")(result.alignment)
    elif kind == "birdseye":
        fig = plot_birdseye(result.calibration, result.poses.joints)
    elif kind == "rig_3d":
        fig = plot_rig_3d(result.calibration, result.poses.joints)
    else:
        fig = plot_reprojection_histograms(reprojection_errors(result))
    save_figure(fig, path)
    return path


def _optional(module: str, name: str):  # noqa: ANN202 - returns a plot function or None
    try:
        return getattr(importlib.import_module(module), name)
    except (ImportError, AttributeError):
        return None


_CSS = """
body{font-family:sans-serif;margin:2em;max-width:1400px}table{border-collapse:collapse}
td,th{border:1px solid #ccc;padding:4px 6px;font-size:13px;vertical-align:top}
th{background:#f0f0f0}.accepted{color:#080}.suspicious{color:#b60}.failed{color:#c00}
img{max-width:100%;border:1px solid #ddd;margin:6px 0}figure{margin:0 0 1.5em 0}
"""


def write_report(result: CalibrationResult, outdir: str | Path) -> Path:
    """Write ``report.html`` and its ``report_*.png`` plots into ``outdir``; return its path.

    The plots are drawn one after the other in this process: drawn in two forked workers they
    took no less time on 2 cores shared with other jobs (docs/decisions/writing-speed.md).
    """
    outdir = Path(outdir)
    outdir.mkdir(parents=True, exist_ok=True)
    figures = _figure_list(result)
    pngs = [outdir / f"report_{i:02d}.png" for i in range(len(figures))]
    for (_, _, kind, camera), png in zip(figures, pngs, strict=True):
        _draw(result, kind, camera, str(png))
    verdicts = [q.verdict for q in result.refinement.quality.values()]
    overall = "failed" if "failed" in verdicts else (
        "suspicious" if "suspicious" in verdicts else "accepted")
    parts = [f"<html><head><meta charset='utf-8'><title>cascalib report</title>"
             f"<style>{_CSS}</style></head><body><h1>Calibration report</h1>",
             f"<p>Overall verdict: <b class='{overall}'>{overall}</b> &middot; "
             f"{len(result.calibration)} cameras &middot; reference camera "
             f"<b>{html.escape(str(result.calibration.reference_camera))}</b> &middot; "
             f"person height prior {result.config.height:.2f} m &middot; run time "
             f"{sum(result.timings.values()):.1f} s</p>",
             _warnings(result), "<h2>Cameras</h2>", _camera_table(result)]
    section = None
    for (sec, caption, _, _), png in zip(figures, pngs, strict=True):
        if sec != section:
            parts.append(f"<h2>{html.escape(sec)}</h2>")
            section = sec
        data = base64.b64encode(png.read_bytes()).decode("ascii")
        parts.append(f"<figure><img src='data:image/png;base64,{data}'>"
                     f"<figcaption>{html.escape(caption)}</figcaption></figure>")
    parts.append("<h2>What the numbers mean</h2><dl>")
    parts += [f"<dt><b>{k}</b></dt><dd>{html.escape(v)}</dd>" for k, v in GLOSSARY]
    parts.append("</dl></body></html>")
    path = outdir / "report.html"
    path.write_text("\n".join(parts), encoding="utf-8")  # as its meta tag says
    return path
