"""Pictures of a simulated scene: a bird's-eye view of paths and cameras, and one camera's view."""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import matplotlib

matplotlib.use("Agg")  # files only; never open a window
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.axes import Axes  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402
from matplotlib.patches import Polygon  # noqa: E402

from cascalib.camera import Camera  # noqa: E402
from cascalib.skeletons import CANONICAL_BONES, CANONICAL_INDEX  # noqa: E402

if TYPE_CHECKING:
    from cascalib.simulate.scene import Scene

__all__ = ["plot_scene", "plot_birds_eye", "plot_camera_view"]


def _colors(n: int) -> list[tuple[float, ...]]:
    cmap = plt.get_cmap("tab20" if n > 10 else "tab10")
    return [cmap(i % cmap.N) for i in range(n)]


def _wedge(cam: Camera, length: float) -> np.ndarray:
    """Ground-plane triangle (3, 2) of the camera's horizontal field of view."""
    w, h = cam.image_size
    edges = np.array([[0.0, (h - 1) / 2], [w - 1.0, (h - 1) / 2]])
    d = cam.rays(edges)[:, :2]
    d /= np.linalg.norm(d, axis=1, keepdims=True)
    c = cam.center[:2]
    return np.vstack([c, c + length * d[0], c + length * d[1]])


def plot_birds_eye(scene: Scene, ax: Axes) -> None:
    """Paths of the persons (start dots), camera positions and field-of-view wedges."""
    t = np.arange(0.0, scene.config.duration_s, 0.1)
    hip = scene.joints_at(t)[:, :, CANONICAL_INDEX["mid_hip"], :2]  # (T, P, 2)
    for p, color in enumerate(_colors(hip.shape[1])):
        ax.plot(hip[:, p, 0], hip[:, p, 1], "-", color=color, lw=1)
        ax.plot(*hip[0, p], "o", color=color, ms=4)
    span = float(np.max(np.abs([c.center[:2] for c in scene.truth])))
    for cam in scene.truth:
        length = 0.6 * span + float(np.linalg.norm(cam.center[:2]))
        ax.add_patch(Polygon(_wedge(cam, length), closed=True, alpha=0.12, color="k", lw=0))
        c = cam.center
        ax.plot(c[0], c[1], "k^", ms=7)
        ax.annotate(f"{cam.name}\n{c[2]:.1f} m, {cam.fps:g} fps", (c[0], c[1]), fontsize=7,
                    xytext=(4, 4), textcoords="offset points")
    w, d = scene.config.people.area
    ax.add_patch(Polygon([[-w / 2, -d / 2], [w / 2, -d / 2], [w / 2, d / 2], [-w / 2, d / 2]],
                         closed=True, fill=False, ls="--", color="gray"))
    ax.set_aspect("equal")
    lim = 1.15 * max(span, w / 2, d / 2)
    ax.set_xlim(-lim, lim)
    ax.set_ylim(-lim, lim)
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title("bird's-eye view: paths, cameras, fields of view")


def _busiest_frame(scene: Scene, camera: str) -> int:
    tr = scene.tracks[scene.camera_names.index(camera)]
    n = np.isfinite(tr.keypoints[..., 0]).sum(axis=(1, 2))
    return int(np.argmax(n))


def plot_camera_view(scene: Scene, camera: str, ax: Axes, frame: int | None = None) -> None:
    """One camera's image: detected skeletons (coloured per true person) and true joints (x)."""
    idx = scene.camera_names.index(camera)
    tr = scene.tracks[idx]
    cam = scene.truth[camera]
    frame = _busiest_frame(scene, camera) if frame is None else frame
    kp = tr.canonical()[frame]  # (S, 26, 3)
    s2p = scene.slot_to_person(camera)[frame]
    truth = cam.project(scene.joints3d(camera)[frame])  # (P, 26, 2)
    colors = _colors(len(scene.heights))
    w, h = cam.image_size
    ax.add_patch(Polygon([[0, 0], [w, 0], [w, h], [0, h]], closed=True, color="0.93"))
    ax.plot(truth[..., 0].ravel(), truth[..., 1].ravel(), "x", color="0.5", ms=3)
    for slot, person in enumerate(s2p):
        if person == -2:
            continue
        color = "k" if person == -1 else colors[person]
        for a, b in CANONICAL_BONES:
            pa, pb = kp[slot, CANONICAL_INDEX[a]], kp[slot, CANONICAL_INDEX[b]]
            if np.isfinite(pa[0]) and np.isfinite(pb[0]):
                ax.plot([pa[0], pb[0]], [pa[1], pb[1]], "-", color=color, lw=1.2)
        ax.plot(kp[slot, :, 0], kp[slot, :, 1], ".", color=color, ms=3)
    ax.set_xlim(-0.05 * w, 1.05 * w)
    ax.set_ylim(1.05 * h, -0.05 * h)
    ax.set_aspect("equal")
    ax.set_title(f"{camera} frame {frame} ({w}x{h}, f={cam.focal:.0f} px): detections, "
                 "true joints (x), false positives black", fontsize=8)


def plot_scene(scene: Scene, path: str | Path | None = None, camera: str | None = None,
               frame: int | None = None) -> Figure:
    """Bird's-eye view and one camera's view side by side; saved to ``path`` when given."""
    camera = camera or scene.camera_names[0]
    fig, (a, b) = plt.subplots(1, 2, figsize=(14, 6.5))
    plot_birds_eye(scene, a)
    plot_camera_view(scene, camera, b, frame)
    fig.suptitle(scene.config.description or "simulated scene", fontsize=9)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=110)
        plt.close(fig)
    return fig
