"""Capture of what compiled code writes to file descriptor 1."""

from __future__ import annotations

import os

import pytest

from cascalib.native_output import captured_stdout_fd


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
