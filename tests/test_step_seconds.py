"""Stage V's time by kind of work: the tally of :mod:`cascalib.step_seconds`."""

from __future__ import annotations

import threading
import time

import pytest

from cascalib.step_seconds import account, timed


def test_blocks_add_up_per_kind_and_only_inside_an_open_tally() -> None:
    with timed("solves"):  # no tally open: nothing to record, nothing fails
        pass
    with account() as tally:
        for _ in range(2):
            with timed("solves"):
                time.sleep(0.02)
        with timed("clocks"):
            time.sleep(0.01)
    assert set(tally) == {"solves", "clocks"}
    assert 0.04 <= tally["solves"] < 0.5 and 0.01 <= tally["clocks"] < 0.5
    with account() as again:  # the closed tally is not reopened
        pass
    assert again == {} and again is not tally


def test_a_nested_tally_adds_to_its_owners_and_a_failed_block_still_counts() -> None:
    with account() as outer:
        with account() as inner:
            assert inner is None
            with timed("solves"):
                time.sleep(0.01)
        with pytest.raises(RuntimeError), timed("solves"):
            time.sleep(0.01)
            raise RuntimeError("solve failed")
    assert outer is not None and outer["solves"] >= 0.02


def test_a_block_inside_another_counts_as_the_outer_ones_kind() -> None:
    t0 = time.perf_counter()
    with account() as tally:
        with timed("clocks"):
            time.sleep(0.01)
            with timed("solves"):
                time.sleep(0.05)
        with timed("solves"):
            time.sleep(0.01)
    wall = time.perf_counter() - t0
    assert tally is not None and set(tally) == {"clocks", "solves"}
    # counted twice, the inner block would put solves at 0.06 s or more
    assert tally["clocks"] >= 0.06 and 0.01 <= tally["solves"] < 0.05
    assert sum(tally.values()) <= wall  # the kinds partition the time, never overlap


def test_each_thread_keeps_its_own_tally() -> None:
    seen: dict[str, dict[str, float] | None] = {}

    def job(name: str, seconds: float) -> None:
        with account() as tally:
            with timed(name):
                time.sleep(seconds)
        seen[name] = tally

    with account() as main:
        threads = [threading.Thread(target=job, args=(n, 0.01)) for n in ("a", "b")]
        for t in threads:
            t.start()
        for t in threads:
            t.join()
    assert main == {}  # the threads' work is theirs
    assert set(seen["a"] or {}) == {"a"} and set(seen["b"] or {}) == {"b"}
