"""ICP evidence of a camera pair's clock candidates, and a camera placed by a ground alignment.

Shared by the pairwise alignment and the camera vote (:mod:`~cascalib.stages.align`) and by the
scan and epipolar check of ambiguous pairs (:mod:`~cascalib.stages.ambiguous_pairs`).
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import TypeAlias, TypeVar

import numpy as np

from cascalib.camera import Camera
from cascalib.geometry import rot_z
from cascalib.stages.align_config import AlignConfig
from cascalib.stages.icp import IcpResult, Lanes, Similarity2D, icp_pair

T = TypeVar("T")
# per-camera inputs of a pair's steps: every camera's, or only the pair's two by index
ByCamera: TypeAlias = Sequence[T] | Mapping[int, T]

__all__ = ["ByCamera", "ambiguity_of", "candidate_score", "evidence", "evidence_sigma", "pair_icp",
           "place_camera", "plausible"]


def pair_icp(i: int, j: int, offset: int, angle: float, lanes: ByCamera[Lanes], cfg: AlignConfig,
             sr: float, quick: bool = False) -> IcpResult | None:
    """Trimmed ICP of cameras ``i`` and ``j`` at an integer offset with ``cfg``'s settings;
    ``quick`` compares a quarter of the frames in 8 iterations (a first look at a candidate)."""
    frames = cfg.icp_max_frames // 4 if quick else cfg.icp_max_frames
    return icp_pair(lanes[i], lanes[j], offset, angle, sigma=cfg.sigma, gate=cfg.icp_gate,
                    min_gate=cfg.icp_min_gate, scale_range=sr, trim=cfg.icp_trim,
                    max_frames=frames, n_iter=8 if quick else 15)


def evidence(results: list[IcpResult | None], sig: float, la: Lanes, lb: Lanes, full: float
             ) -> list[float]:
    """ICP evidence (:func:`candidate_score`) of each candidate at residual scale ``sig``."""
    return [candidate_score(r, sig, la, lb, full) for r in results]


def evidence_sigma(results: list[IcpResult | None], cfg: AlignConfig) -> float:
    """Residual scale of a pair's evidence: the best candidate's RMS (one lap of a loop off
    fits to a few decimetres, the true offset to the detection noise)."""
    rms = [r.rms for r in results if plausible(r, cfg)]  # type: ignore[union-attr]
    return max(0.5 * cfg.refine_sigma, min(rms, default=cfg.sigma))


def candidate_score(r: IcpResult | None, sig: float, la: Lanes, lb: Lanes, full: float) -> float:
    """Evidence per frame compared (so quick, subsampled and full runs are comparable) times
    sqrt(overlap / full), capped at 1: quality first, and a short overlap counts less (a brief
    coincidence is likely). Past ``full`` frames length stops counting: a periodic scene's
    coincidence one lap off lasts as long as the overlap, like the truth, so only the quality
    of the fit tells them apart. Identities are kept along tracklets
    (:meth:`IcpResult.evidence`)."""
    if r is None:
        return 0.0
    return (r.evidence(sig, la, lb) / max(1, r.n_frames)
            * np.sqrt(min(1.0, r.n_overlap / max(full, 1.0))))


def plausible(res: IcpResult | None, cfg: AlignConfig) -> bool:
    """A tight fit (RMS under twice the vote's residual scale) of at least 30 matches."""
    return res is not None and res.rms < 2 * cfg.sigma and res.n_matches >= 30


def ambiguity_of(scores: list[float]) -> float:
    """Second-best evidence over the best (0 with fewer than two candidates or no evidence)."""
    rest = sorted(scores, reverse=True)
    return rest[1] / rest[0] if len(rest) > 1 and rest[0] > 0 else 0.0


def place_camera(cam: Camera, T: Similarity2D) -> Camera:
    """Move a camera from its own plane frame by ``X' = s Rz X + (t, 0)``."""
    Rz = rot_z(T.angle)
    center = T.scale * Rz @ cam.center + np.r_[T.t, 0.0]
    R = cam.R @ Rz.T
    return cam.with_(R=R, t=-R @ center)
