"""Capture of what compiled code writes to file descriptor 1."""

from __future__ import annotations

import os

import pytest

from cascalib.native_output import captured_stdout_fd, points_behind_reported


def test_writes_to_the_descriptor_are_captured_and_it_is_restored(capfd):
    print("before", flush=True)
    with captured_stdout_fd() as lines:
        os.write(1, b"from C: one\nfrom C: two\n")  # what a C++ library does
    print("after", flush=True)
    assert lines == ["from C: one", "from C: two"]
    assert capfd.readouterr().out == "before\nafter\n"


def test_the_descriptor_is_restored_when_the_block_raises(capfd):
    with pytest.raises(ValueError), captured_stdout_fd() as lines:
        os.write(1, b"partial\n")
        raise ValueError("boom")
    os.write(1, b"visible\n")
    assert lines == ["partial"]
    assert capfd.readouterr().out == "visible\n"


def test_points_behind_become_one_log_line_and_other_output_passes(capfd, caplog):
    with caplog.at_level("INFO", logger="cascalib.native_output"), \
            points_behind_reported(["left", "right"], "solve"):
        os.write(1, b"CheiralityException: Landmark p3 behind Camera x1\n"
                    b"a message of the library's own\n"
                    b"CheiralityException: Landmark p7 behind Camera x1\n"
                    b"CheiralityException: Landmark p7 behind Camera l4\n")
    assert capfd.readouterr().out == "a message of the library's own\n"
    (record,) = [r for r in caplog.records if "behind its camera" in r.getMessage()]
    assert record.getMessage().startswith("solve: a 3D joint was behind its camera in 3 ")
    assert "(right: 2, l4: 1)" in record.getMessage()
