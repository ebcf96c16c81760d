"""What compiled code prints to the process's standard output, captured.

gtsam's C++ factors report some conditions by printing them straight to file descriptor 1,
past Python's ``sys.stdout``: a ``GeneralSFMFactor2`` whose 3D point is behind its camera prints
``CheiralityException: Landmark p1004 behind Camera x2`` every time it is evaluated. A solve that
meets one evaluates it at every iteration and every damping trial: 199 such lines in one Stage V
run of a simulated phone rig (60 s, a camera whose clock stage III had put 1418 frames off),
burying the command line's progress bar and a worker's log. Python cannot catch them (they are
not exceptions by then), so the file descriptor itself is pointed at a temporary file while the
library runs, and the caller decides what the lines mean.
"""

from __future__ import annotations

import logging
import os
import re
import sys
import tempfile
from collections import Counter
from collections.abc import Iterator, Sequence
from contextlib import contextmanager

__all__ = ["captured_stdout_fd", "points_behind_reported"]

log = logging.getLogger(__name__)


@contextmanager
def captured_stdout_fd() -> Iterator[list[str]]:
    """Capture everything written to file descriptor 1 while the block runs.

    Yields a list that holds the captured lines once the block has ended (also when it raised).
    Python's own ``sys.stdout`` is flushed on entry and exit, so that text it buffered keeps
    its place (where it writes to file descriptor 1, text printed inside the block is captured
    too). Where file descriptor 1 is not open, nothing is captured and the list stays empty.

    File descriptors belong to the process: a thread that writes to standard output while the
    block runs is captured too. cascalib's stage V runs its solves on one thread, and the
    service runs each job in its own process.
    """
    lines: list[str] = []
    _flush_stdout()
    try:
        saved = os.dup(1)
    except OSError:  # no standard output to capture
        yield lines
        return
    try:
        with tempfile.TemporaryFile() as tmp:
            os.dup2(tmp.fileno(), 1)
            try:
                yield lines
            finally:
                _flush_stdout()
                os.dup2(saved, 1)
                tmp.seek(0)
                lines.extend(tmp.read().decode(errors="replace").splitlines())
    finally:
        os.close(saved)


def _flush_stdout() -> None:
    """Flush Python's standard output, where there is one (None under some launchers)."""
    if sys.stdout is not None:
        sys.stdout.flush()


#: gtsam's message for a reprojection factor whose point is behind its camera, printed by the C++
#: factor to standard output at every evaluation (the factor counts as zero error meanwhile);
#: cameras are the keys X(c), which gtsam prints as "x<c>"
_BEHIND = re.compile(r"CheiralityException: Landmark \S+ behind Camera (x(\d+)|\S+)")


@contextmanager
def points_behind_reported(names: Sequence[str], what: str) -> Iterator[None]:
    """Run gtsam with its standard output captured, and sum its CheiralityException lines up
    in one INFO line of this module's log, prefixed by ``what``: how often a 3D point was
    behind each camera (``names`` in the order of the camera keys X(c); without a name, the
    key). Anything else gtsam printed is passed on to standard output unchanged."""
    lines: list[str] = []
    try:
        with captured_stdout_fd() as lines:
            yield
    finally:
        behind: Counter[str] = Counter()
        other = []
        for line in lines:
            m = _BEHIND.search(line)
            if m is None:
                other.append(line)
            elif m.group(2) is not None and int(m.group(2)) < len(names):
                behind[names[int(m.group(2))]] += 1
            else:
                behind[m.group(1)] += 1
        if other and sys.stdout is not None:
            sys.stdout.write("\n".join(other) + "\n")
            _flush_stdout()
        if behind:
            log.info("%s: a 3D joint was behind its camera in %d evaluations of reprojection "
                     "terms (%s); gtsam counts such a term as zero error while it is", what,
                     sum(behind.values()), ", ".join(f"{n}: {k}" for n, k in behind.most_common()))
