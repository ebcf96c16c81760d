"""Plots of a calibrated rig: a person checks a calibration by looking.

All functions return a :class:`matplotlib.figure.Figure` drawn with the non-interactive Agg
backend (no display needed); :func:`save_figure` writes it as PNG.
"""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from numpy.typing import NDArray  # noqa: E402

from cascalib.calibration import Calibration  # noqa: E402
from cascalib.camera import Camera  # noqa: E402
from cascalib.skeletons import CANONICAL_BONES, CANONICAL_INDEX  # noqa: E402

if TYPE_CHECKING:
    from mpl_toolkits.mplot3d import Axes3D

__all__ = ["fixed_layout", "plot_rig_3d", "plot_birdseye", "plot_reprojection_histograms",
           "save_figure"]

_BONES = np.array([(CANONICAL_INDEX[a], CANONICAL_INDEX[b]) for a, b in CANONICAL_BONES])


def save_figure(fig: Figure, path: str | Path, dpi: int = 100) -> Path:
    """Write ``fig`` as PNG and close it.

    The figure is drawn once, with the layout it was made with (``bbox_inches="tight"`` would
    draw it twice to crop it); zlib level 1 packs the plots' flat colours almost as small as
    the default level 6, in less time.
    """
    path = Path(path)
    fig.savefig(path, dpi=dpi, pil_kwargs={"compress_level": 1})
    plt.close(fig)
    return path


def fixed_layout(fig: Figure, *, left: float = 0.55, right: float = 0.15, bottom: float = 0.5,
                 top: float = 0.3, wspace: float = 0.55, hspace: float = 0.75) -> None:
    """Place the subplot grid of ``fig`` with margins and gaps given in inches.

    A fixed layout costs nothing to compute, where ``tight_layout`` measures every label; the
    defaults fit tick labels and axis labels of font size 7-10 and a one-line title per axes.
    """
    w, h = fig.get_size_inches()
    rows, cols = fig.axes[0].get_subplotspec().get_gridspec().get_geometry()  # type: ignore[union-attr]
    axes_w = (w - left - right - (cols - 1) * wspace) / cols
    axes_h = (h - bottom - top - (rows - 1) * hspace) / rows
    fig.subplots_adjust(left=left / w, right=1 - right / w, bottom=bottom / h, top=1 - top / h,
                        wspace=wspace / axes_w, hspace=hspace / axes_h)


def _frustum(cam: Camera, depth: float) -> NDArray[np.float64]:
    """Camera centre and the four image corners at ``depth`` metres, world coordinates (5, 3)."""
    w, h = cam.image_size
    corners = np.array([[0, 0], [w, 0], [w, h], [0, h]], dtype=np.float64)
    xy = cam.undistort(corners)
    pts_cam = np.c_[xy * depth, np.full(4, depth)]
    pts = (pts_cam - cam.t) @ cam.R  # R.T @ (x - t)
    return np.vstack([cam.center, pts])


def _scene_extent(calib: Calibration, joints: NDArray[np.float64] | None) -> float:
    pts = [c.center for c in calib]
    if joints is not None and np.isfinite(joints).any():
        pts.extend(joints[np.isfinite(joints).all(-1)].reshape(-1, 3)[::50])
    pts_a = np.asarray(pts)
    return float(max(np.ptp(pts_a[:, :2], axis=0).max(), 1.0))


def plot_rig_3d(calib: Calibration, joints: NDArray[np.float64] | None = None,
                n_poses: int = 4) -> Figure:
    """3D view of the cameras (frusta) and a few poses.

    Parameters
    ----------
    calib : Calibration
        Cameras in a z-up world.
    joints : ndarray, shape (T, P, 26, 3), optional
        3D poses; ``n_poses`` time samples spread over the sequence are drawn.
    """
    from mpl_toolkits.mplot3d.art3d import Line3DCollection

    fig = plt.figure(figsize=(7, 6))
    ax = fig.add_subplot(projection="3d")
    depth = 0.12 * _scene_extent(calib, joints)
    frusta = []
    for cam in calib:
        f = _frustum(cam, depth)
        frusta += [f[[0, i]] for i in range(1, 5)] + [f[[i, i % 4 + 1]] for i in range(1, 5)]
        ax.text(*f[0], f" {cam.name}", fontsize=8)
    bones = np.empty((0, 2, 3))
    if joints is not None and len(joints):
        valid_t = np.flatnonzero(np.isfinite(joints).any(axis=(1, 2, 3)))
        shown = valid_t[np.linspace(0, len(valid_t) - 1, min(n_poses, len(valid_t))).astype(int)]
        bones = joints[shown][:, :, _BONES].reshape(-1, 2, 3)  # (poses * persons * bones, 2, 3)
        bones = bones[np.isfinite(bones).all(axis=(1, 2))]
    # two collections instead of one line per segment: matplotlib draws each artist separately
    ax.add_collection3d(Line3DCollection(frusta, colors="tab:blue", linewidths=0.8))
    ax.add_collection3d(Line3DCollection(list(bones), colors="tab:red", linewidths=1))
    pts = np.concatenate([np.reshape(frusta, (-1, 3)), bones.reshape(-1, 3)])
    ax.auto_scale_xyz(pts[:, 0], pts[:, 1], pts[:, 2], had_data=False)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_zlabel("z [m]")
    ax.set_title("Cameras and 3D poses (ground z = 0)")
    fig.subplots_adjust(left=0.0, right=0.95, bottom=0.03, top=0.92)  # the 3D box has margins
    _equal_3d(ax)
    return fig


def _equal_3d(ax: Axes3D) -> None:
    lims = np.array([ax.get_xlim3d(), ax.get_ylim3d(), ax.get_zlim3d()])
    centre, radius = lims.mean(1), (lims[:, 1] - lims[:, 0]).max() / 2
    for setter, c in zip((ax.set_xlim3d, ax.set_ylim3d, ax.set_zlim3d), centre, strict=True):
        setter(c - radius, c + radius)


def plot_birdseye(calib: Calibration, joints: NDArray[np.float64] | None = None) -> Figure:
    """Bird's-eye view: camera positions and viewing directions, and the feet trajectories."""
    fig, ax = plt.subplots(figsize=(6.5, 6))
    if joints is not None and len(joints):
        feet = 0.5 * (joints[..., CANONICAL_INDEX["left_ankle"], :]
                      + joints[..., CANONICAL_INDEX["right_ankle"], :])
        for p in range(feet.shape[1]):
            ok = np.isfinite(feet[:, p, 0])
            ax.plot(feet[ok, p, 0], feet[ok, p, 1], ".", ms=1.5, alpha=0.6)
    scale = 0.08 * _scene_extent(calib, joints)
    for cam in calib:
        c = cam.center
        d = cam.R[2]  # optical axis in world coordinates
        ax.plot(c[0], c[1], "k^", ms=8)
        ax.arrow(c[0], c[1], scale * d[0], scale * d[1], head_width=0.3 * scale, color="k")
        ax.annotate(f"{cam.name}\n{c[2]:.2f} m", (c[0], c[1]), fontsize=8,
                    textcoords="offset points", xytext=(5, 5))
    ax.set_aspect("equal")
    ax.grid(True, alpha=0.3)
    ax.set_xlabel("x [m]")
    ax.set_ylabel("y [m]")
    ax.set_title("Bird's-eye view: cameras (height above ground) and feet trajectories")
    return fig


def plot_reprojection_histograms(errors: Mapping[str, NDArray[np.float64]]) -> Figure:
    """One histogram of reprojection errors (pixels) per camera, with median and 90th percentile."""
    n = max(len(errors), 1)
    cols = min(n, 4)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(3.2 * cols, 2.6 * rows), squeeze=False)
    for ax, (name, err) in zip(axes.ravel(), errors.items(), strict=False):
        e = np.asarray(err, dtype=np.float64)
        e = e[np.isfinite(e)]
        if e.size:
            hi = np.percentile(e, 99)
            ax.hist(e, bins=40, range=(0, max(hi, 1e-3)), color="tab:blue")
            for q, style in ((50, "-"), (90, "--")):
                v = np.percentile(e, q)
                ax.axvline(v, color="k", ls=style, lw=1, label=f"p{q} {v:.2f} px")
            ax.legend(fontsize=7)
        ax.set_title(name, fontsize=9)
        ax.set_xlabel("reprojection error [px]", fontsize=8)
    for ax in axes.ravel()[len(errors):]:
        ax.axis("off")
    fixed_layout(fig, left=0.5, wspace=0.5, hspace=0.8)
    return fig
