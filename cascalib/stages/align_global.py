"""Stages II-IV, step 3: globally consistent clocks and ground alignments from all camera
pairs.

Each camera pair's alignment (:class:`PairAlignment`: its offset candidates, ICP evidence and
fitted offset, rate and 2D similarity) is one edge of the pair graph. :func:`global_clocks` solves
the clocks by robust L1 over that graph, so that one wrong pair is outvoted by the cycles through
the other cameras; :func:`global_ground` fits every camera's ground similarity to the matched
points of all accepted pairs (robust least squares from a spanning-tree start);
:func:`doubtful_cameras` names the cameras worth the camera vote. :mod:`cascalib.stages.align`
runs them.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace

import numpy as np
from numpy.typing import NDArray
from scipy.optimize import least_squares

from cascalib.stages.align_config import AlignConfig
from cascalib.stages.icp import Similarity2D, SyncFit
from cascalib.stages.sync import SyncCurve, solve_time

__all__ = ["PairAlignment", "doubtful_cameras", "global_alignment", "global_clocks",
           "global_ground"]


@dataclass(frozen=True)
class PairAlignment:
    """Everything known about one camera pair (A = ``cameras[i]``, B = ``cameras[j]``).

    Grid times are reference frames under the fps prior: ``u_a = rate * u_b + offset``.
    ``icp_scores`` holds the ICP evidence of each candidate of ``curve`` (same order);
    ``ambiguity`` = second-best over best evidence; ``accepted``: kept by the global solve;
    ``icp_angles``: each candidate's rotation after ICP (rad); ``evidence_sigma``: the residual
    scale (m) of its evidence. A pair refitted at the offset chosen by the camera vote
    (:mod:`~cascalib.stages.consensus`) has ``chosen = -1`` unless a candidate lies there,
    and the vote's ambiguity.
    """

    i: int
    j: int
    curve: SyncCurve
    icp_scores: list[float]
    chosen: int
    fit: SyncFit | None
    ambiguity: float
    accepted: bool = False
    icp_angles: list[float] = field(default_factory=list)
    evidence_sigma: float = 0.2


def global_clocks(n: int, ref: int, pairs: list[PairAlignment], cfg: AlignConfig
                  ) -> tuple[NDArray[np.float64], NDArray[np.float64], NDArray[np.bool_]]:
    """Every camera's clock ``ref = a_c * u_c + b_c`` (:func:`~cascalib.stages.sync.solve_time`)
    from the fitted pairs, and which pairs agree with it (``accepted``, one per pair of
    ``pairs``). A camera whose every pair disagrees keeps its most confident one."""
    usable = [p for p in pairs if p.fit is not None]
    edges = [(p.i, p.j, p.fit.offset, np.log(p.fit.rate),  # type: ignore[union-attr]
              max(0.05, 1.0 - p.ambiguity), p.fit.offset_sd,  # type: ignore[union-attr]
              p.fit.rate_sd / p.fit.rate) for p in usable]  # type: ignore[union-attr]
    a, b, ok = solve_time(n, edges, ref, tolerance=cfg.offset_tolerance)  # type: ignore[arg-type]
    # a camera whose every pair disagrees with the others keeps its most confident pair
    # (flagged ambiguous by its confidence) rather than dropping out of the rig
    for c in range(n):
        inc = [k for k, p in enumerate(usable) if c in (p.i, p.j)]
        if c != ref and inc and not ok[inc].any():
            ok[max(inc, key=lambda k: edges[k][4])] = True
            a, b, _ = solve_time(n, [e for e, keep in zip(edges, ok, strict=True) if keep],
                                 ref, tolerance=np.inf)
    accepted = np.zeros(len(pairs), bool)
    idx = [k for k, p in enumerate(pairs) if p.fit is not None]
    accepted[idx] = ok
    return a, b, accepted


def global_alignment(n: int, ref: int, pairs: list[PairAlignment], cfg: AlignConfig, sr: float
                     ) -> tuple[list[PairAlignment], NDArray[np.float64], NDArray[np.float64],
                                list[Similarity2D | None]]:
    """Global clocks, the pairs marked accepted or not, and the ground transforms."""
    a, b, accepted = global_clocks(n, ref, pairs, cfg)
    pairs = [replace(p, accepted=bool(acc)) for p, acc in zip(pairs, accepted, strict=True)]
    T = global_ground(n, ref, [p for p in pairs if p.accepted], sr)
    return pairs, a, b, T


def doubtful_cameras(n: int, ref: int, pairs: list[PairAlignment], placed: NDArray[np.bool_],
                     cfg: AlignConfig) -> NDArray[np.bool_]:
    """Cameras worth a vote: not placed, with a pair that disagrees with the global clocks,
    or whose every agreeing pair is ambiguous."""
    out = ~placed
    for c in range(n):
        inc = [p for p in pairs if c in (p.i, p.j) and p.fit is not None]
        acc = [p for p in inc if p.accepted]
        if len(acc) < len(inc) or min((p.ambiguity for p in acc), default=1.0) > \
                cfg.ambiguity_ratio:
            out[c] = True
    out[ref] = False
    return out


def _spanning_init(n: int, ref: int, pairs: list[PairAlignment]) -> list[Similarity2D | None]:
    """Chain pairwise similarities from the reference along the most confident pairs."""
    T: list[Similarity2D | None] = [None] * n
    T[ref] = Similarity2D(0.0, np.zeros(2))
    order = sorted(pairs, key=lambda p: p.ambiguity)
    changed = True
    while changed:
        changed = False
        for p in order:
            fit = p.fit
            assert fit is not None
            if T[p.i] is not None and T[p.j] is None:
                T[p.j] = T[p.i].compose(fit.transform)  # type: ignore[union-attr]
                changed = True
            elif T[p.j] is not None and T[p.i] is None:
                T[p.i] = T[p.j].compose(fit.transform.inverse())  # type: ignore[union-attr]
                changed = True
    return T


def global_ground(n: int, ref: int, pairs: list[PairAlignment], scale_range: float
                  ) -> list[Similarity2D | None]:
    """Robust joint fit of all ground similarities to every accepted pair's matched points."""
    T0 = _spanning_init(n, ref, pairs)
    free = [c for c in range(n) if c != ref and T0[c] is not None]
    pairs = [p for p in pairs if T0[p.i] is not None and T0[p.j] is not None]
    if not free or len(pairs) < 2:
        return T0
    pos = {c: k for k, c in enumerate(free)}

    def unpack(x: NDArray[np.float64], c: int) -> Similarity2D:
        if c == ref:
            return Similarity2D(0.0, np.zeros(2))
        v = x[4 * pos[c]: 4 * pos[c] + 4]
        return Similarity2D(float(v[0]), v[1:3], float(np.exp(v[3])))

    def resid(x: NDArray[np.float64]) -> NDArray[np.float64]:
        out = []
        for p in pairs:
            f = p.fit
            assert f is not None
            w = np.sqrt(max(0.05, 1.0 - p.ambiguity))
            out.append(w * (unpack(x, p.i).apply(f.pairs_a)
                            - unpack(x, p.j).apply(f.pairs_b)).ravel())
        return np.concatenate(out)

    x0 = np.concatenate([[T0[c].angle, *T0[c].t, np.log(T0[c].scale)]  # type: ignore[union-attr]
                         for c in free])
    ls = np.log(scale_range) + 1e-9
    lo = np.tile([-np.inf, -np.inf, -np.inf, -ls], len(free))
    hi = np.tile([np.inf, np.inf, np.inf, ls], len(free))
    sol = least_squares(resid, np.clip(x0, lo + 1e-12, hi - 1e-12), bounds=(lo, hi),
                        loss="soft_l1", f_scale=0.1)
    return [unpack(sol.x, c) if (c == ref or c in pos) else None for c in range(n)]
