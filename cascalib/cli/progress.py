"""Progress display for long commands: a bar per stage on a terminal, log lines otherwise."""

from __future__ import annotations

import sys
from types import TracebackType

from tqdm import tqdm


class StageProgress:
    """A ``progress(stage, fraction)`` callback.

    On a terminal it shows one tqdm bar per stage; otherwise (pipes, CI, log files) it prints a
    plain line when a stage starts and when it ends. ``quiet`` shows nothing.
    """

    def __init__(self, *, quiet: bool = False, stream=None) -> None:  # noqa: ANN001
        self.quiet = quiet
        # resolved at call time: sys.stderr may have been replaced since import (tests, pipes)
        self.stream = sys.stderr if stream is None else stream
        self.tty = bool(getattr(self.stream, "isatty", lambda: False)())
        self._stage: str | None = None
        self._bar: tqdm | None = None
        self._done = False

    def __call__(self, stage: str, fraction: float) -> None:
        if self.quiet:
            return
        if stage != self._stage:
            self._close()
            self._stage, self._done = stage, False
            if self.tty:
                self._bar = tqdm(total=100, desc=f"{stage:12s}", file=self.stream,
                                 bar_format="{desc} {bar} {percentage:3.0f}% {elapsed}")
            else:
                print(f"[cascalib] {stage}: started", file=self.stream, flush=True)
        if self._bar is not None:
            self._bar.update(int(round(100 * fraction)) - self._bar.n)
        elif fraction >= 1.0 and not self._done:
            self._done = True
            print(f"[cascalib] {stage}: done", file=self.stream, flush=True)

    def _close(self) -> None:
        if self._bar is not None:
            self._bar.close()
            self._bar = None

    def __enter__(self) -> StageProgress:
        return self

    def __exit__(self, exc_type: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self._close()
