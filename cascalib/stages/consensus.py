"""Stages II-IV, global check: each camera's clock and heading chosen by the evidence of all of
its pairs at once.

Pairwise sync picks one candidate offset per pair and the global L1 solve (:func:`cascalib.
stages.sync.solve_time`) then keeps the pairs that agree. Periodic motion defeats that vote: the
ambiguity of people walking in circles is a property of the scene, so every pair with one
camera shows the same wrong peak, and two wrong pairs that agree outvote the right one. A pair's
second-ranked candidate, though, is often the right one, and what one pair cannot tell apart the
sum over pairs can. So, per camera and with the other cameras held where they are, every
hypothesis ``(clock offset, heading)`` implied by any candidate of any of its pairs is scored by
the ICP evidence it gives on **every** pair of that camera, and the camera moves to the best.

The scoring (ICP on the ground tracks) is passed in, so this module stays free of track data.
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Iterable, Sequence
from dataclasses import dataclass
from functools import partial
from typing import Any

import numpy as np
from numpy.typing import NDArray

__all__ = ["CandidateEdge", "CameraVote", "vote_cameras"]

logger = logging.getLogger(__name__)


@dataclass(frozen=True)
class CandidateEdge:
    """The candidates of one camera pair: ``u_i = u_j + offsets[k]`` (grid frames) and B -> A
    ground rotation ``angles[k]`` (rad), with their pairwise evidence."""

    i: int
    j: int
    offsets: Sequence[float]
    angles: Sequence[float]
    scores: Sequence[float]


@dataclass(frozen=True)
class CameraVote:
    """Outcome for one camera: the chosen clock offset ``b`` (reference frames) and heading
    ``yaw`` (rad), their summed evidence, and the best score of a hypothesis whose clock
    differs by more than the tolerance (``ambiguity = runner_up / score``)."""

    camera: int
    b: float
    yaw: float
    score: float
    runner_up: float
    moved: bool

    @property
    def ambiguity(self) -> float:
        return float(self.runner_up / self.score) if self.score > 0 else 1.0


def _hypotheses(c: int, edges: list[CandidateEdge], b: NDArray[np.float64],
                yaw: NDArray[np.float64], placed: NDArray[np.bool_], keep: float,
                settle: Callable[[int, int, float, float], tuple[float, float] | None],
                mapper: Callable[..., Iterable[Any]]) -> list[tuple[float, float]]:
    """Clock offset and heading of camera ``c`` implied by the stronger candidates of its pairs
    (``b_j - b_i = offset``, ``yaw_j - yaw_i = angle``), each settled on its own pair first
    (a coarse peak a few frames off scores far below the truth), the current state first."""
    out = [(float(b[c]), float(yaw[c]))] if placed[c] else []
    tries = []
    for e, other in _pairs_of(c, edges, placed):
        if not e.scores:
            continue
        top = max(e.scores)
        tries += [(e, other, off, ang) for off, ang, s in
                  zip(e.offsets, e.angles, e.scores, strict=True) if s >= keep * top]
    fits = mapper(lambda t: settle(t[0].i, t[0].j, t[2], t[3]), tries)
    for (e, other, _, _), fit in zip(tries, fits, strict=True):
        if fit is None:
            continue
        sign = 1.0 if c == e.j else -1.0
        out.append((float(b[other] + sign * fit[0]), float(yaw[other] + sign * fit[1])))
    return out


def vote_cameras(n: int, ref: int, edges: list[CandidateEdge], b: NDArray[np.float64],
                 yaw: NDArray[np.float64], placed: NDArray[np.bool_],
                 score: Callable[[int, int, float, float, bool], float],
                 settle: Callable[[int, int, float, float], tuple[float, float] | None], *,
                 movable: NDArray[np.bool_] | None = None, tolerance: float = 2.0,
                 keep: float = 0.5, n_full: int = 3, n_sweeps: int = 2,
                 mapper: Callable[..., Iterable[Any]] = map) -> list[CameraVote]:
    """Coordinate ascent over cameras on the summed pair evidence.

    Parameters
    ----------
    n, ref : int
        Number of cameras and the reference (never moved).
    edges : list of CandidateEdge
    b, yaw : ndarray, shape (n,)
        Current clock offsets (``u_ref = u_c + b_c``, grid frames) and headings (rad).
    placed : ndarray of bool, shape (n,)
        Cameras with a current state (the others can be placed by the vote).
    score : callable
        ``score(i, j, offset, angle, full)``: evidence of pair ``(i, j)`` at that offset and
        rotation, from a quick check or (``full``) a thorough one.
    settle : callable
        ``settle(i, j, offset, angle)``: the pair's candidate refined to ``(offset, angle)``
        on its own pair, or None when it does not fit.
    movable : ndarray of bool, shape (n,), optional
        Cameras the vote may move (default all but the reference): the doubtful ones.
    tolerance : float
        Hypotheses closer than this (frames) are one.
    keep : float
        Candidates below ``keep`` times their pair's best are not tried, and hypotheses below
        ``keep`` times the best quick score are not scored in full.
    n_full : int
        At most this many hypotheses per camera are scored in full.
    n_sweeps : int
        Passes over the cameras; the vote stops early when no camera moves.
    mapper : callable
        ``map``-like; e.g. a thread pool's ``map`` to score hypotheses in parallel (the scores
        must then be thread-safe).

    Returns
    -------
    list of CameraVote
        One per movable camera that has a hypothesis, from the last sweep.
    """
    b, yaw, placed = b.astype(np.float64).copy(), yaw.astype(np.float64).copy(), placed.copy()
    votes: dict[int, CameraVote] = {}
    moved_ever: set[int] = set()
    for _ in range(n_sweeps):
        moved_any = False
        for c in range(n):
            if c == ref or (movable is not None and not movable[c]):
                continue
            hyps = _hypotheses(c, edges, b, yaw, placed, keep, settle, mapper)
            if not hyps:
                continue
            quick = partial(_scored, c, edges, b, yaw, placed, score, False)
            thorough = partial(_scored, c, edges, b, yaw, placed, score, True)
            scored = list(mapper(quick, _distinct(hyps, tolerance)))
            # the quick scores screen; the strongest few (at least two, so that the runner-up
            # is measured alike) are scored in full and only those compete
            scored.sort(key=lambda t: -t[0])
            top = scored[0][0]
            scored = list(mapper(thorough,
                                 [(bc, yc) for k, (s, bc, yc) in enumerate(scored)
                                  if k < 2 or (s >= keep * top and k < n_full)]))
            logger.debug("camera %d: hypotheses %s", c,
                         ", ".join(f"{bc:.1f}/{np.degrees(yc):.0f}deg:{s:.2f}"
                                   for s, bc, yc in scored))
            best = max(scored, key=lambda t: t[0])
            rivals = [s for s, bc, _ in scored if abs(bc - best[1]) > tolerance]
            moved = not placed[c] or abs(best[1] - b[c]) > tolerance
            if moved:
                moved_any = True
                moved_ever.add(c)
                b[c], yaw[c], placed[c] = best[1], best[2], True
            votes[c] = CameraVote(c, float(b[c]), float(yaw[c]), best[0],
                                  max(rivals, default=0.0), c in moved_ever)
        if not moved_any:
            break
    return [votes[c] for c in sorted(votes)]


def _pairs_of(c: int, edges: list[CandidateEdge], placed: NDArray[np.bool_]
              ) -> list[tuple[CandidateEdge, int]]:
    """The pairs of camera ``c`` whose other camera is placed, with that camera."""
    out = []
    for e in edges:
        other = e.j if e.i == c else e.i
        if c in (e.i, e.j) and placed[other]:
            out.append((e, other))
    return out


def _scored(c: int, edges: list[CandidateEdge], b: NDArray[np.float64], yaw: NDArray[np.float64],
            placed: NDArray[np.bool_], score: Callable[[int, int, float, float, bool], float],
            full: bool, h: tuple[float, float]) -> tuple[float, float, float]:
    """``(evidence summed over its pairs, clock, heading)`` of hypothesis ``h`` of camera
    ``c``."""
    bc, yc = h
    total = 0.0
    for e, _ in _pairs_of(c, edges, placed):
        bi, bj = (bc, b[e.j]) if e.i == c else (b[e.i], bc)
        yi, yj = (yc, yaw[e.j]) if e.i == c else (yaw[e.i], yc)
        total += score(e.i, e.j, float(bj - bi), float(yj - yi), full)
    return total, bc, yc


def _distinct(hyps: list[tuple[float, float]], tolerance: float) -> list[tuple[float, float]]:
    """The hypotheses with clocks more than ``tolerance`` apart (the first of each kept)."""
    out: list[tuple[float, float]] = []
    for h in hyps:
        if all(abs(h[0] - o[0]) > tolerance for o in out):
            out.append(h)
    return out
