"""The people's joints check the clocks stages II-III could not decide.

Stage III times the cameras by their ground trajectories. One person walking back and forth
along a line makes that ambiguous in a way no candidate search resolves: on a straight leg a
time shift looks like a shift along the line, which the ground alignment absorbs, so only the
turns time the cameras and the ICP's best offset can sit many frames off the truth with the
runner-up nearly as good (the camera is flagged ``ambiguous``). Stage V's clock search moves an
offset by at most half a frame per update and cannot walk that far.

The joints do not have that freedom: at a wrong offset the two cameras see the person at
different instants, and no two-view geometry explains the joints. For each doubtful camera,
:func:`joint_clock` descends the epipolar cost of its joints against the reference camera
(persons matched and a fundamental matrix fitted afresh at every offset,
:func:`~cascalib.stages.multiview_pairs.match_pair`; the mean Cauchy loss of the Sampson
distances) from stage IV's clock, or, for a camera stage III flags, takes the lowest on grids
around stage IV's clock and each of its pair's candidates. :func:`checked_clocks` returns the
cameras whose clock that moves by more than :data:`CLOCK_TOLERANCE` frames; the pipeline then
places the cameras from the joints (the multi-view start) on the corrected clocks, as stage
IV's ground alignment was made at the wrong ones.
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from dataclasses import dataclass, replace

import numpy as np

from cascalib.stages.align_global import PairAlignment
from cascalib.stages.epipolar_sync import cauchy_cost, quadratic_minimum
from cascalib.stages.multiview_pairs import match_pair
from cascalib.stages.track_interpolation import frame_links, interpolate_views
from cascalib.tracks import Tracks

__all__ = ["JointClock", "checked_clocks", "joint_clock", "pair_starts", "DOUBTFUL_FLAGS"]

log = logging.getLogger(__name__)

#: Reference instants (evenly spread) whose joints the cost compares.
INSTANTS = 240
#: Scale (px) of the Cauchy loss of the Sampson distances (the epipolar clock search's).
CAUCHY_PX = 2.0
#: Coarse step (frames) of the descent; single frames beside its lowest point follow.
DESCENT_STEP = 2.0
#: Farthest (s) a descent walks from stage IV's clock (a camera stage III did not flag).
DESCENT_REACH_S = 1.0
#: Half-width (s) of the grid around stage IV's clock of a camera stage III flags: on one
#: walker's line its offsets were up to half a second off.
WINDOW_S = 1.5
#: Half-width (s) of the grid around each of that camera's pair candidates (a lap off).
START_WINDOW_S = 0.5
#: A camera's clock is replaced when the joints put it more than this many frames from stage
#: IV's (stage V's clock search repairs less, half a frame per update) ...
CLOCK_TOLERANCE = 1.5
#: ... and only when the joints' cost there is at most this fraction of the cost at stage IV's
#: clock: in a crowd the cost varies from offset to offset as the persons matched change.
DECISIVE = 0.7
#: Fewest person pairs the two cameras must share at an offset for its cost to count.
MIN_GROUPS = 20
#: Stage III's flags that make a camera's clock doubtful.
DOUBTFUL_FLAGS = ("ambiguous", "inconsistent")
#: ... as does a stage III confidence below this (1 - ambiguity of its best pair, times the
#: share of its pairs that agree).
DOUBTFUL_CONFIDENCE = 0.5
#: Most pair candidates of a flagged camera searched around.
MAX_STARTS = 3


@dataclass(frozen=True)
class JointClock:
    """A camera's offset (reference frames) where its joints fit one two-view geometry with
    the reference camera's best, that cost (px^2, mean Cauchy loss), and the cost at the clock
    it was searched from."""

    offset: float
    cost: float
    cost_at_clock: float


class _Costs:
    """The epipolar cost of one camera's joints against the reference's at given offsets
    (cached by offset)."""

    def __init__(self, reference: Tracks, ref_clock: tuple[float, float], other: Tracks,
                 rate: float, rng: np.random.Generator) -> None:
        kr, self._ko = reference.canonical(), other.canonical()
        self._lo = frame_links(self._ko, other.track_ids)
        self._times = np.linspace(0.0, kr.shape[0] - 1, INSTANTS)
        self._va = interpolate_views(kr, frame_links(kr, reference.track_ids),
                                     (self._times - ref_clock[0]) / ref_clock[1])
        self._diagonal = float(max(np.hypot(*reference.require_image_size()),
                                   np.hypot(*other.require_image_size())))
        self._rate = rate
        self._rng = rng
        self._seen: dict[float, float] = {}

    def __call__(self, offset: float) -> float:
        if offset not in self._seen:
            vb = interpolate_views(self._ko, self._lo, (self._times - offset) / self._rate)
            m = match_pair(0, 1, self._va, vb, self._diagonal, self._rng, min_groups=MIN_GROUPS)
            self._seen[offset] = np.inf if m is None else cauchy_cost(m.distances, CAUCHY_PX)
        return self._seen[offset]

    def descend(self, start: float, step: float, reach: float) -> float:
        """The lowest cost reached from ``start`` by steps of ``step`` frames, within
        ``reach`` frames of it."""
        at = float(round(start))
        while abs(at - start) <= reach:
            lower = min((at - step, at + step), key=self)
            if not self(lower) < self(at):
                break
            at = lower
        return at

    def lowest(self, centre: float, reach: float) -> float:
        """The lowest cost on a grid of :data:`DESCENT_STEP` frames within ``reach`` of
        ``centre``: a walker's stride repeats, and so do the joints' poses, which leaves lesser
        minima a stride apart that a descent from far off can end in."""
        grid = float(round(centre)) + np.arange(-reach, reach + 0.5, DESCENT_STEP)
        return float(min(grid, key=self))

    def settle(self, at: float) -> JointClock | None:
        """The single-frame descent from ``at`` and the vertex of the parabola through the
        lowest and its neighbours; None where the cost is nowhere finite."""
        at = self.descend(at, 1.0, DESCENT_STEP)
        if not np.isfinite(self(at)):
            return None
        x = np.array([at - 1.0, at, at + 1.0])
        y = np.array([self(v) for v in x])
        vertex = quadratic_minimum(x, y, at, 1.0) if np.isfinite(y).all() else None
        return JointClock(at if vertex is None else float(np.clip(vertex[0], at - 1, at + 1)),
                          self(at), np.inf)


def joint_clock(reference: Tracks, ref_clock: tuple[float, float], other: Tracks,
                clock: tuple[float, float], starts: Sequence[float] | None,
                rng: np.random.Generator) -> JointClock | None:
    """The offset of ``other`` (on the clock ``reference`` is read on, at ``clock``'s rate)
    whose joints fit one two-view geometry with ``reference``'s best. With ``starts`` None, a
    descent from ``clock``'s offset (:data:`DESCENT_STEP`, at most :data:`DESCENT_REACH_S`);
    else the lowest on grids within :data:`WINDOW_S` of ``clock``'s offset and within
    :data:`START_WINDOW_S` of each of ``starts``. None where the two cameras never share
    :data:`MIN_GROUPS` person pairs."""
    fps = reference.frame_rate() or 1.0
    costs = _Costs(reference, ref_clock, other, clock[1], rng)
    if starts is None:
        at = [costs.descend(clock[0], DESCENT_STEP, DESCENT_REACH_S * fps)]
    else:
        at = [costs.lowest(clock[0], WINDOW_S * fps),
              *(costs.lowest(s, START_WINDOW_S * fps) for s in starts)]
    found = [f for f in (costs.settle(a) for a in at) if f is not None]
    if not found:
        return None
    return replace(min(found, key=lambda f: f.cost), cost_at_clock=costs(clock[0]))


def checked_clocks(tracks: Sequence[Tracks], clocks: Sequence[tuple[float, float]],
                   flags: dict[str, list[str]], confidence: dict[str, float],
                   starts: dict[str, list[float]], rng: np.random.Generator) -> dict[str, float]:
    """The offsets (on the first camera's clock) of the cameras stage III doubts that the
    joints put more than :data:`CLOCK_TOLERANCE` frames from stage IV's clock, where they
    explain the joints clearly better (:data:`DECISIVE`). ``clocks`` are stage IV's (offset,
    rate) per camera, ``flags`` and ``confidence`` stage III's, ``starts`` more offsets per
    camera (its pair's candidates with the first camera, best first).

    A camera flagged :data:`DOUBTFUL_FLAGS` is searched on grids around its clock and its
    first :data:`MAX_STARTS` starts; one not flagged but below :data:`DOUBTFUL_CONFIDENCE` by a
    descent from its clock (one walker's line can leave it frames off without a flag, but not
    a stride or a lap off); the others are not checked: in a crowd the cost varies too much
    from offset to offset to overrule a confident stage III."""
    out: dict[str, float] = {}
    for t, clock in zip(tracks[1:], clocks[1:], strict=True):
        flagged = bool(set(flags.get(t.camera, ())) & set(DOUBTFUL_FLAGS))
        if not flagged and confidence.get(t.camera, 1.0) >= DOUBTFUL_CONFIDENCE:
            continue
        found = joint_clock(tracks[0], clocks[0], t, clock,
                            starts.get(t.camera, [])[:MAX_STARTS] if flagged else None, rng)
        if found is None:
            continue
        log.info("camera %s: stage IV's clock %.2f frames (joint cost %.3g), the joints' %.2f "
                 "(%.3g)", t.camera, clock[0], found.cost_at_clock, found.offset, found.cost)
        if (abs(found.offset - clock[0]) > CLOCK_TOLERANCE
                and found.cost <= DECISIVE * found.cost_at_clock):
            out[t.camera] = found.offset
    return out


def pair_starts(pairs: Sequence[PairAlignment], names: Sequence[str], reference: int = 0
                ) -> dict[str, list[float]]:
    """Per camera, the offsets of its pair's candidates with the reference camera
    (``u_ref = rate * u_c + offset``: the candidate offset is the camera's clock offset)."""
    out: dict[str, list[float]] = {}
    for p in pairs:
        if reference not in (p.i, p.j):
            continue
        sign, c = (1.0, p.j) if p.i == reference else (-1.0, p.i)
        out.setdefault(names[c], []).extend(sign * float(k.offset) for k in p.curve.candidates)
    return out
