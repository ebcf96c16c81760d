"""Plots of stages II-IV: sync cost curves per camera pair (ground trajectories, then the
epipolar sub-frame search) and the aligned bird's-eye view.

matplotlib with the Agg backend (no display needed); each function writes one PNG and returns
the figure so callers (CLI, notebooks) can also show or embed it.
"""

from __future__ import annotations

from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
from matplotlib.figure import Figure  # noqa: E402

from cascalib.plots import fixed_layout  # noqa: E402
from cascalib.stages.align import AlignmentResult  # noqa: E402

__all__ = ["plot_epipolar_curves", "plot_sync_curves", "plot_ground_alignment"]


def plot_sync_curves(result: AlignmentResult, path: str | Path | None = None) -> Figure:
    """Sync cost (``1 - score / max score``) over the offset for every camera pair, with the
    verified candidates and the chosen sub-frame offset marked.

    Parameters
    ----------
    result : AlignmentResult
    path : str or Path, optional
        PNG to write.
    """
    names = result.calibration.names
    n = len(result.pairs)
    cols = min(3, n)
    rows = int(np.ceil(n / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(5 * cols, 3.2 * rows), squeeze=False)
    for ax, pair in zip(axes.ravel(), result.pairs, strict=False):
        curve = pair.curve
        top = curve.score.max() if curve.score.size and curve.score.max() > 0 else 1.0
        ax.plot(curve.offsets, 1.0 - curve.score / top, lw=0.8, color="0.3")
        for k, cand in enumerate(curve.candidates):
            ax.plot(cand.offset, 1.0 - cand.score / top, "o", ms=4, mfc="none",
                    color="tab:orange" if k != pair.chosen else "tab:green")
        title = f"{names[pair.i]} - {names[pair.j]}"
        if pair.fit is not None:
            ax.axvline(pair.fit.offset, color="tab:green" if pair.accepted else "tab:red",
                       lw=1, ls="--")
            title += (f": offset {pair.fit.offset:.2f}, rate {pair.fit.rate:.5f}, "
                      f"ambiguity {pair.ambiguity:.2f}")
            if not pair.accepted:
                title += " (rejected)"
        ax.set_title(title, fontsize=8)
        ax.set_xlabel("offset (reference frames): u_a = rate u_b + offset", fontsize=7)
        ax.set_ylabel("cost", fontsize=7)
        ax.tick_params(labelsize=7)
    for ax in axes.ravel()[n:]:
        ax.axis("off")
    fixed_layout(fig)
    if path is not None:
        fig.savefig(path, dpi=120)
    return fig


def plot_epipolar_curves(result: AlignmentResult, path: str | Path | None = None
                         ) -> Figure | None:
    """The epipolar clock search per camera pair: the robust Sampson cost over the change of
    the second camera's offset since stage III (each iteration's curve, relative to its
    lowest sample), with the shift each iteration chose.

    Parameters
    ----------
    result : AlignmentResult
        With ``epipolar`` (None without it: nothing to plot).
    path : str or Path, optional
        PNG to write.
    """
    if result.epipolar is None or not result.epipolar.pairs:
        return None
    names = result.calibration.names
    keys = sorted({(p.i, p.j) for p in result.epipolar.pairs})
    cols = min(3, len(keys))
    rows = int(np.ceil(len(keys) / cols))
    fig, axes = plt.subplots(rows, cols, figsize=(5 * cols, 3.2 * rows), squeeze=False)
    colors = ["tab:blue", "tab:orange", "tab:green", "tab:purple"]
    for ax, (i, j) in zip(axes.ravel(), keys, strict=False):
        done = 0.0
        for p in (q for q in result.epipolar.pairs if (q.i, q.j) == (i, j)):
            color = colors[p.iteration % len(colors)]
            ax.plot(p.base + p.shifts, p.costs / p.costs.min(), ".-", lw=0.8, ms=3,
                    color=color, label=f"iteration {p.iteration + 1}")
            ax.axvline(p.base + p.shift, color=color, lw=1, ls="--")
            done = p.base + p.shift
        ax.set_title(f"{names[i]} - {names[j]}: {names[j]} {done:+.2f} frame against "
                     f"{names[i]}", fontsize=8)
        ax.set_xlabel(f"change of {names[j]}'s offset relative to {names[i]}'s "
                      "(reference frames)", fontsize=7)
        ax.set_ylabel("Sampson cost / lowest", fontsize=7)
        ax.tick_params(labelsize=7)
        ax.legend(fontsize=6)
    for ax in axes.ravel()[len(keys):]:
        ax.axis("off")
    fixed_layout(fig)
    if path is not None:
        fig.savefig(path, dpi=120)
    return fig


def plot_ground_alignment(result: AlignmentResult, path: str | Path | None = None) -> Figure:
    """Bird's-eye view: every camera's ground trajectories mapped into the reference plane frame,
    one colour per camera, with the camera positions and viewing directions.

    Parameters
    ----------
    result : AlignmentResult
    path : str or Path, optional
        PNG to write.
    """
    fig, ax = plt.subplots(figsize=(7, 7))
    colors = plt.get_cmap("tab10")
    for c, (g, T, cam) in enumerate(zip(result.ground, result.transforms,
                                        result.calibration.cameras, strict=True)):
        col = colors(c % 10)
        for k, tl in enumerate(g.tracklets):
            xy = T.apply(tl.xy)
            ax.plot(xy[:, 0], xy[:, 1], "-", lw=0.5, alpha=0.6, color=col,
                    label=cam.name if k == 0 else None)
        center = cam.center
        axis = cam.R[2]  # optical axis in world coordinates
        d = axis[:2] / max(np.linalg.norm(axis[:2]), 1e-9)
        ax.plot(*center[:2], "^", ms=9, color=col, mec="k")
        ax.annotate("", xy=center[:2] + 1.5 * d, xytext=center[:2],  # type: ignore[arg-type]
                    arrowprops={"arrowstyle": "->", "color": col, "lw": 1.5})
        flag = "" if not result.flags.get(cam.name) else " !"
        ax.text(center[0], center[1], f" {cam.name} ({result.confidence[cam.name]:.2f}){flag}",
                fontsize=8)
    ax.set_aspect("equal")
    ax.set_xlabel("x (m)")
    ax.set_ylabel("y (m)")
    ax.set_title(f"Ground trajectories in {result.calibration.reference_camera}'s plane frame")
    ax.legend(fontsize=7, loc="upper right")
    ax.grid(alpha=0.3)
    fig.tight_layout()
    if path is not None:
        fig.savefig(path, dpi=120)
    return fig
