"""The camera vote of stages II-IV: every camera's clock chosen by the evidence of all its
pairs (periodic motion makes all pairs of a camera show the same wrong peak)."""

from __future__ import annotations

import numpy as np
import pytest

from cascalib.stages.consensus import CandidateEdge, vote_cameras

TRUE_B = np.array([0.0, 10.0, 20.0, 30.0])
LAP = 100.0  # a lap of the loop: every pair of camera 3 also fits, less well, 100 frames off


def _score(i: int, j: int, offset: float, angle: float, full: bool) -> float:
    """Evidence of a pair: 1 at the true offset, 0.7 one lap off, 0 elsewhere; the quick
    check is noisier but ranks alike."""
    err = offset - (TRUE_B[j] - TRUE_B[i])
    scale = 0.9 if not full else 1.0
    if abs(err) < 1.5 and abs(angle) < 0.05:
        return scale * 1.0
    if abs(abs(err) - LAP) < 1.5:
        return scale * 0.7
    return 0.0


def _settle(i: int, j: int, offset: float, angle: float) -> tuple[float, float]:
    return offset, angle  # the candidates are exact already


def _edges() -> list[CandidateEdge]:
    e = []
    for i, j in [(0, 1), (0, 2), (1, 2)]:
        d = TRUE_B[j] - TRUE_B[i]
        e.append(CandidateEdge(i, j, [d, d + 250.0], [0.0, 0.3], [1.0, 0.4]))
    # camera 3: one pair right, two pairs ranking the lap-off peak first
    e.append(CandidateEdge(0, 3, [30.0, 30.0 + LAP], [0.0, 0.0], [1.0, 0.95]))
    e.append(CandidateEdge(1, 3, [20.0 + LAP, 20.0], [0.0, 0.0], [1.0, 0.9]))
    e.append(CandidateEdge(2, 3, [10.0 + LAP, 10.0], [0.0, 0.0], [1.0, 0.8]))
    return e


def test_vote_moves_the_camera_that_two_agreeing_wrong_pairs_misplaced() -> None:
    b = TRUE_B.copy()
    b[3] += LAP  # where the pairwise L1 consensus puts it: 2 pairs against 1
    votes = vote_cameras(4, 0, _edges(), b, np.zeros(4), np.ones(4, bool), _score, _settle)
    by_cam = {v.camera: v for v in votes}
    assert by_cam[3].moved and by_cam[3].b == pytest.approx(30.0)
    # all three pairs at 1.0 against all three one lap off at 0.7
    assert by_cam[3].score == pytest.approx(3.0)
    assert by_cam[3].ambiguity == pytest.approx(0.7)
    for c in (1, 2):
        assert not by_cam[c].moved and by_cam[c].b == pytest.approx(TRUE_B[c])


def test_vote_leaves_fixed_cameras_and_places_unplaced_ones() -> None:
    b = TRUE_B.copy()
    b[3] += LAP
    movable = np.array([False, False, False, False])
    assert vote_cameras(4, 0, _edges(), b, np.zeros(4), np.ones(4, bool), _score, _settle,
                        movable=movable) == []
    placed = np.array([True, True, True, False])
    votes = vote_cameras(4, 0, _edges(), np.where(placed, TRUE_B, 0.0), np.zeros(4), placed,
                         _score, _settle)
    v3 = next(v for v in votes if v.camera == 3)
    assert v3.moved and v3.b == pytest.approx(30.0)
