"""Joining person-track fragments across gaps (stitch_tracks)."""

from __future__ import annotations

import numpy as np

from cascalib.stages.association import Association, stitch_tracks

FPS = 25.0


def make(paths: list[tuple[np.ndarray, np.ndarray, int]]) -> Association:
    """Groups from (times, ground positions, fragment id) triples."""
    times = np.concatenate([t for t, _, _ in paths])
    ground = np.concatenate([g for _, g, _ in paths])
    tracks = np.concatenate([np.full(len(t), k) for t, _, k in paths])
    obs = np.zeros((len(times), 2, 26, 3))
    return Association(times.astype(float), obs, tracks.astype(np.int64), ground)


def walk(t: np.ndarray, start: tuple[float, float], vel: tuple[float, float]) -> np.ndarray:
    """Ground positions at reference frames ``t`` walking at ``vel`` m/s."""
    return np.array(start) + np.outer(t / FPS, vel)


def test_fragments_of_one_walker_are_joined_across_a_gap():
    t1, t2, t3 = np.arange(0, 100), np.arange(130, 200), np.arange(230, 300)  # 1.2 s gaps
    v = (1.3, 0.2)
    assoc = make([(t1, walk(t1, (0, 0), v), 7), (t2, walk(t2, (0, 0), v), 3),
                  (t3, walk(t3, (0, 0), v), 11)])
    out = stitch_tracks(assoc, fps=FPS)
    assert len(np.unique(out.tracks)) == 1


def test_people_seen_together_are_never_joined_and_far_gaps_are_not_bridged():
    ta, tb = np.arange(0, 200), np.arange(50, 150)
    assoc = make([(ta, walk(ta, (0, 0), (1.0, 0)), 0), (tb, walk(tb, (0, 0.3), (1.0, 0)), 1),
                  # starts 3 s after track 0 ends, where track 0 would be: too long a gap
                  (np.arange(275, 300), walk(np.arange(275, 300), (0, 0), (1.0, 0)), 2)])
    out = stitch_tracks(assoc, fps=FPS)
    assert len(np.unique(out.tracks)) == 3


def test_ambiguous_continuations_are_left_apart():
    """Two walkers side by side (0.4 m apart) both vanish for a second and reappear close to
    each other, between their lanes: which fragment continues which is unclear, so neither is
    joined; a lone walker elsewhere still is."""
    t1, t2 = np.arange(0, 100), np.arange(125, 200)
    v = (1.2, 0.0)
    assoc = make([(t1, walk(t1, (0, 0), v), 0), (t1, walk(t1, (0, 0.4), v), 1),
                  (t2, walk(t2, (0, 0.17), v), 2), (t2, walk(t2, (0, 0.23), v), 3),
                  (t1, walk(t1, (0, 8), v), 4), (t2, walk(t2, (0, 8), v), 5)])
    out = stitch_tracks(assoc, fps=FPS)
    ids = {k: out.tracks[assoc.tracks == k][0] for k in range(6)}
    assert len({ids[0], ids[1], ids[2], ids[3]}) == 4
    assert ids[4] == ids[5]
