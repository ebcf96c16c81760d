"""Picture of a Stage I result: the 1 m ground grid and the ankle-to-upper segments on the image.

As the paper's Figure "Single view calibration results": the predicted ground plane as a blue
grid of 1 m squares, inlier detections in green and outliers in red (ankle centre to shoulder
centre), drawn over the video frame or a blank canvas of the image size.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")  # no display needed; the caller saves the figure
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.collections import LineCollection  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from cascalib.stages.single_view_result import SingleViewResult  # noqa: E402

__all__ = ["plot_single_view"]


def _grid_segments(result: SingleViewResult, extent: float, samples: int = 60
                   ) -> list[NDArray[np.float64]]:
    """Image polylines of the ground lines x = k and y = k (1 m apart) of the plane frame."""
    cam = result.to_camera()
    inl = result.inliers if result.inliers.any() else np.ones(len(result.ankle), bool)
    feet = cam.backproject_to_plane(result.ankle[inl])
    feet = feet[np.isfinite(feet).all(1)]
    lo = np.floor(np.percentile(feet[:, :2], 2, axis=0) - 1.0) if len(feet) else np.array([1, -5])
    hi = np.ceil(np.percentile(feet[:, :2], 98, axis=0) + 1.0) if len(feet) else np.array([11, 5])
    lo, hi = np.maximum(lo, -extent), np.minimum(hi, extent)
    lines = []
    for axis in (0, 1):
        for k in np.arange(lo[axis], hi[axis] + 1):
            s = np.linspace(lo[1 - axis], hi[1 - axis], samples)
            pts = np.zeros((samples, 3))
            pts[:, axis], pts[:, 1 - axis] = k, s
            uv = cam.project(pts)
            lines.append(uv)
    return lines


def plot_single_view(result: SingleViewResult, frame: NDArray[np.uint8] | None = None,
                     path: str | Path | None = None, *, max_segments: int = 600,
                     grid_extent: float = 60.0, rng: np.random.Generator | int | None = 0
                     ) -> Figure:
    """Draw the ground grid and the ankle-to-shoulder segments of a Stage I result.

    Parameters
    ----------
    result : SingleViewResult
    frame : ndarray, shape (H, W[, 3]), optional
        A video frame of that camera; a blank canvas of the image size when None.
    path : str or Path, optional
        Where to save the PNG.
    max_segments : int
        At most this many segments (a random subset, in the inlier/outlier proportions).
    grid_extent : float
        The grid covers at most this many metres from the camera's foot point.

    Returns
    -------
    matplotlib.figure.Figure
    """
    rng = np.random.default_rng(rng)
    w, h = result.image_size
    fig, ax = plt.subplots(figsize=(8, 8 * h / w), dpi=100)
    if frame is not None:
        ax.imshow(frame, extent=(-0.5, w - 0.5, h - 0.5, -0.5))
    else:
        ax.add_patch(plt.Rectangle((-0.5, -0.5), w, h, color="0.92"))
    ax.add_collection(LineCollection(_grid_segments(result, grid_extent), colors="tab:blue",
                                     linewidths=0.8, alpha=0.8))
    shoulder = result.upper[:, 0]
    shown = np.flatnonzero(np.isfinite(shoulder[:, 0]))
    if len(shown) > max_segments:  # one random subset keeps the inlier/outlier proportions
        shown = rng.choice(shown, max_segments, replace=False)
    for mask, color, label in ((result.inliers, "tab:green", "inlier"),
                               (~result.inliers, "tab:red", "outlier")):
        idx = shown[mask[shown]]
        seg = np.stack([result.ankle[idx], shoulder[idx]], axis=1)
        ax.add_collection(LineCollection(seg, colors=color, linewidths=1.0,  # type: ignore[arg-type]
                                         label=f"{label} ({int(mask.sum())})"))
    lo, hi = result.focal_interval
    ax.set_title(f"{result.camera}: f = {result.focal:.0f} px [{lo:.0f}, {hi:.0f}], "
                 f"camera {result.camera_height:.2f} m above ground, "
                 f"pitch {result.pitch_deg:.1f} deg", fontsize=9)
    ax.set_xlim(-0.5, w - 0.5)
    ax.set_ylim(h - 0.5, -0.5)
    ax.set_aspect("equal")
    ax.legend(loc="lower right", fontsize=8)
    ax.set_xticks([])
    ax.set_yticks([])
    # fixed margins (no ticks; a one-line title), cheaper than measuring with tight_layout
    fig.subplots_adjust(left=0.01, right=0.99, bottom=0.01, top=1 - 0.35 / (8 * h / w))
    if path is not None:
        fig.savefig(path)
    return fig
