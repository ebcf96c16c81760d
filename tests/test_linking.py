"""Linking the track pieces of the 3D poses into persons."""

from __future__ import annotations

import numpy as np

from cascalib.linking import MIN_PERSON_S, link_persons
from cascalib.metrics import identity_switches

FPS = 25.0


def walkers(heights, starts, velocities, seconds=6.0, seed=0):
    """Persons of the given heights walking straight lines: joints (T, P, 26, 3), times."""
    rng = np.random.default_rng(seed)
    template = rng.normal(scale=0.15, size=(26, 3)) + [0.0, 0.0, 0.9]
    times = np.arange(int(seconds * FPS)) / FPS
    joints = np.empty((times.size, len(heights), 26, 3))
    for p, (h, s, v) in enumerate(zip(heights, starts, velocities, strict=True)):
        floor = np.asarray(s) + times[:, None] * np.asarray(v)
        joints[:, p] = template * h / 1.7 + np.c_[floor, np.zeros(times.size)][:, None]
    return joints + rng.normal(scale=0.005, size=joints.shape), times


def test_a_person_lost_for_a_second_is_one_person():
    joints, times = walkers([1.7, 1.7], [(0, 0), (0, 5)], [(1.2, 0), (1.0, 0.3)])
    ids = np.tile([0, 1], (len(times), 1))
    gap = (times >= 2.0) & (times < 3.0)
    joints[gap, 0] = np.nan
    ids[gap, 0] = -1
    ids[times >= 3.0, 0] = 7  # the reconstruction gave the rest a new track
    linked = link_persons(joints, ids, times)
    assert set(np.unique(linked[~gap, 0])) == {0}
    assert set(np.unique(linked[:, 1])) == {1}


def test_a_track_that_goes_on_in_a_new_one_a_few_frames_early_is_one_person():
    joints, times = walkers([1.7, 1.7], [(0, 0), (0, 5)], [(1.2, 0), (1.0, 0.3)])
    cut = int(3.0 * FPS)
    twice = joints[cut - 3:cut, :1] + 0.01  # samples where both tracks hold the person
    joints = np.concatenate([joints, np.full_like(joints[:, :1], np.nan)], axis=1)
    ids = np.tile([0, 1, -1], (len(times), 1))
    joints[cut - 3:cut, 2:], ids[cut - 3:cut, 2] = twice, 7
    joints[cut:, 2], ids[cut:, 2] = joints[cut:, 0], 7
    joints[cut:, 0], ids[cut:, 0] = np.nan, -1
    linked = link_persons(joints, ids, times)
    person = linked[0, 0]
    assert (linked[cut:, 2] == person).all() and (linked[:cut, 0] == person).all()
    assert ((linked == person).sum(axis=1) == 1).all()  # one slot per person and time


def test_crossing_persons_are_told_apart_by_size_and_heading():
    # two people meet at (3, 0) at t = 3 s: there, one track each ends and two new ones start
    joints, times = walkers([1.55, 1.90], [(0, -3), (6, -3)], [(1.0, 1.0), (-1.0, 1.0)])
    ids = np.tile([0, 1], (len(times), 1))
    meet = (times >= 2.8) & (times < 3.2)
    joints[meet] = np.nan
    ids[meet] = -1
    after = times >= 3.2
    ids[after] = [2, 3]
    joints[after] = joints[after][:, ::-1]  # after the crossing the slots are swapped
    ids[after] = ids[after][:, ::-1]
    linked = link_persons(joints, ids, times)
    tall_before, tall_after = linked[0, 1], linked[after][0, 0]
    assert tall_before == tall_after
    assert linked[0, 0] == linked[after][0, 1] != tall_before


def test_short_pieces_get_no_person():
    joints, times = walkers([1.7], [(0, 0)], [(1.0, 0)], seconds=MIN_PERSON_S * 0.8)
    ids = np.zeros((len(times), 1), dtype=int)
    assert (link_persons(joints, ids, times) == -1).all()


def test_identity_switches_count_a_swap_once_per_person():
    truth, times = walkers([1.7, 1.8], [(0, 0), (0, 4)], [(1.0, 0), (1.0, 0)])
    ids = np.tile([0, 1], (len(times), 1))
    assert identity_switches(ids, truth, truth) == 0
    ids[len(times) // 2:] = [1, 0]
    assert identity_switches(ids, truth, truth) == 2
