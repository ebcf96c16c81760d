"""The greedy frame selection (re-scoring only the rows a pick changes) picks what re-scoring
every group at every step picks."""

from __future__ import annotations

import numpy as np

from cascalib.stages.frame_selection import _greedy_cover


def test_greedy_cover_equals_rescoring_every_row_at_every_step():
    rng = np.random.default_rng(11)
    for trial in range(20):
        n, k = int(rng.integers(5, 400)), int(rng.integers(1, 7))
        cells = rng.integers(-1, int(rng.integers(2, 40)), size=(n, k))
        # equal qualities on some trials: ties must go to the first row, as np.argmax does
        q = np.ones(n) if trial % 4 == 0 else rng.random(n)
        n_select = int(rng.integers(1, n + 1))
        counts = np.zeros(cells.max() + 2)
        valid = cells >= 0
        safe = np.where(valid, cells, counts.size - 1)
        chosen = np.zeros(n, dtype=bool)
        want = []
        for _ in range(n_select):
            score = np.where(chosen, -1.0, q * (0.25 + (valid * 0.5 ** counts[safe]).sum(1)))
            i = int(np.argmax(score))
            chosen[i] = True
            want.append(i)
            np.add.at(counts, safe[i][valid[i]], 1)
        assert _greedy_cover(cells, q, n_select) == want
