"""Where a long step's time goes: wall seconds per kind of work, summed over the functions,
however deep, that do it.

Stage V spends its time in a few kinds of work spread over many calls (the factor-graph solves
of every round and pass, the clock updates, the final triangulation); a profile names them, a
user's run should too. :func:`account` opens the tally for the calls below it, :func:`timed`
adds a block's seconds to one kind. Outside an open tally :func:`timed` costs one lookup and
records nothing. The tally is a :class:`contextvars.ContextVar`: each thread (each job of the
service's worker pool) has its own.
"""

from __future__ import annotations

import time
from collections.abc import Iterator
from contextlib import contextmanager
from contextvars import ContextVar

__all__ = ["account", "timed"]

_TALLY: ContextVar[dict[str, float] | None] = ContextVar("step_seconds", default=None)
# inside a timed block: a block within it is its kind's work already (a solve inside a clock
# update would else count twice), so that the kinds never sum to more than the time spent
_TIMING: ContextVar[bool] = ContextVar("step_seconds_timing", default=False)


@contextmanager
def account() -> Iterator[dict[str, float] | None]:
    """Open a tally of seconds per kind for the block.

    Yields the tally, filled by :func:`timed` inside the block; or None inside a tally already
    open (Stage V refining a rig again without a camera), whose owner then gets the block's
    seconds with the rest.
    """
    if _TALLY.get() is not None:
        yield None
        return
    tally: dict[str, float] = {}
    token = _TALLY.set(tally)
    try:
        yield tally
    finally:
        _TALLY.reset(token)


@contextmanager
def timed(kind: str) -> Iterator[None]:
    """Add the block's wall seconds to ``kind`` of the open tally (if any; an exception in the
    block still counts its time). A block inside another timed block counts as the outer
    one's kind: the kinds never overlap."""
    tally = _TALLY.get()
    if tally is None or _TIMING.get():
        yield
        return
    token = _TIMING.set(True)
    t0 = time.perf_counter()
    try:
        yield
    finally:
        tally[kind] = tally.get(kind, 0.0) + time.perf_counter() - t0
        _TIMING.reset(token)
