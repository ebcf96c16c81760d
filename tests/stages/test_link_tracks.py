"""Linking cross-view groups into person tracks over time (link_tracks)."""

from __future__ import annotations

import numpy as np

from cascalib.stages.association import Association, link_tracks

FPS = 25.0


def make(times: np.ndarray, ground: np.ndarray, person: np.ndarray
         ) -> tuple[Association, np.ndarray]:
    """Groups (one per row) with their true person, shuffled within each time like the
    association's clusters."""
    rng = np.random.default_rng(0)
    order = np.lexsort((rng.random(len(times)), times))
    obs = np.zeros((len(times), 2, 26, 3))
    assoc = Association(times[order].astype(float), obs, np.full(len(times), -1, np.int64),
                        ground[order])
    return assoc, person[order]


def walkers(paths: list[np.ndarray], noise_m: float, seed: int = 1
            ) -> tuple[Association, np.ndarray]:
    """Groups of walkers given as (T, 2) ground paths at frames 0..T-1, with ground noise."""
    rng = np.random.default_rng(seed)
    t = np.concatenate([np.arange(len(p)) for p in paths])
    g = np.concatenate(paths) + rng.normal(0, noise_m, (len(t), 2))
    who = np.concatenate([np.full(len(p), k) for k, p in enumerate(paths)])
    return make(t, g, who)


def line(start: tuple[float, float], vel_m_s: tuple[float, float], n: int) -> np.ndarray:
    return np.array(start) + np.outer(np.arange(n) / FPS, vel_m_s)


def test_walkers_crossing_are_followed_by_their_headings():
    """Pairs of walkers cross at right angles, passing 0.05-0.25 m apart, with 5 cm ground
    noise: each track keeps its own walker (matching the last positions alone swapped 2 of 5)."""
    mixed = 0
    for k, miss in enumerate((0.05, 0.1, 0.15, 0.2, 0.25)):
        a = line((-3.0, 0.0), (1.3, 0.0), 120)
        b = line((0.0, -3.0 + miss), (0.0, 1.3), 120)  # passes (0, miss) when a is at (0, 0)
        assoc, who = walkers([a, b], noise_m=0.05, seed=k)
        out = link_tracks(assoc)
        for tr in np.unique(out.tracks):
            mixed += len(np.unique(who[out.tracks == tr])) > 1
        for p in (0, 1):
            assert len(np.unique(out.tracks[who == p])) == 1
    assert mixed == 0


def test_side_by_side_and_turning_walkers_stay_one_track_each():
    """Two people walking together 0.6 m apart, and one walking a 2 m circle, with 5 cm ground
    noise and a two-frame gap: each is one track from start to end."""
    n = 250
    a = line((0.0, 0.0), (1.3, 0.2), n)
    b = a + np.array([-0.1, 0.6]) / np.hypot(0.1, 0.6) * 0.6
    ang = np.arange(n) * 1.3 / FPS / 2.0
    c = np.c_[10 + 2 * np.cos(ang), 2 * np.sin(ang)]
    assoc, who = walkers([a, b, c], noise_m=0.05)
    keep = ~((who == 2) & np.isin(assoc.times, (100, 101)))
    assoc = Association(assoc.times[keep], assoc.obs[keep], assoc.tracks[keep],
                        assoc.ground[keep])
    who = who[keep]
    out = link_tracks(assoc)
    for p in range(3):
        assert len(np.unique(out.tracks[who == p])) == 1, p
    assert len(np.unique(out.tracks)) == 3
