"""The progress display: a bar on a terminal, plain lines elsewhere."""

from __future__ import annotations

import io

from cascalib.cli.progress import StageProgress


class _Terminal(io.StringIO):
    def isatty(self) -> bool:
        return True


def _drive(progress: StageProgress) -> None:
    with progress:
        for f in (0.0, 0.25, 0.5, 1.0):
            progress("refine", f)
        progress("triangulate", 1.0)


def test_plain_lines_when_not_a_terminal():
    out = io.StringIO()
    _drive(StageProgress(stream=out))
    assert out.getvalue().splitlines() == [
        "[cascalib] refine: started", "[cascalib] refine: done",
        "[cascalib] triangulate: started", "[cascalib] triangulate: done"]


def test_a_bar_per_stage_on_a_terminal(monkeypatch):
    term = _Terminal()
    monkeypatch.setattr("sys.stderr", term)  # the default stream is the stderr of the moment
    _drive(StageProgress())
    text = term.getvalue()
    assert "[cascalib]" not in text
    assert "refine" in text and "100%" in text and "triangulate" in text


def test_quiet_prints_nothing():
    out = _Terminal()
    _drive(StageProgress(quiet=True, stream=out))
    assert out.getvalue() == ""
