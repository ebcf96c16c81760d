"""JSON keypoint files are parsed once, by orjson where installed, with the json module's
results and error messages; the calibrate command does not import the simulator."""

from __future__ import annotations

import gc
import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import cascalib
from cascalib import InputError
from cascalib.formats.keypoints import _common as c
from cascalib.session import is_manifest


@pytest.mark.parametrize("fast", [True, False])
def test_load_json_same_values_and_messages_with_or_without_orjson(tmp_path, monkeypatch,
                                                                   fast):
    if not fast:
        monkeypatch.setattr(c, "_fast_loads", None)
    ok = tmp_path / "ok.json"
    ok.write_text('{"a": [0.1, 1e-320, -0.0, 12345678901234567890123, NaN], "b": {"c": "\\u00e9"}}')
    data = c.load_json(ok)
    assert data["a"][:4] == [0.1, 1e-320, -0.0, 12345678901234567890123]
    assert np.isnan(data["a"][4]) and data["b"] == {"c": "\u00e9"}
    bad = tmp_path / "bad.json"
    bad.write_text('{"a": [1, 2,\n  3 4]}')
    with pytest.raises(InputError, match="not valid JSON: Expecting ',' delimiter at line 2, "
                                         "column 5"):
        c.load_json(bad, camera="cam0")


def test_gc_paused_restores_the_collector():
    assert gc.isenabled()
    with c.gc_paused():
        assert not gc.isenabled()
        with c.gc_paused():
            assert not gc.isenabled()
        assert not gc.isenabled()
    assert gc.isenabled()


def test_manifest_found_without_parsing_keypoint_files(tmp_path, monkeypatch):
    manifest = tmp_path / "session.json"
    manifest.write_text('{"c\\u0061meras": {"A": {"file": "a.json"}}}')  # escaped key name
    assert is_manifest(manifest)
    keypoints = tmp_path / "cam0.json"
    keypoints.write_text(json.dumps({"meta_info": {}, "instance_info": [{"frame_id": 0}]}))
    monkeypatch.setattr(json, "loads", lambda *a, **k: pytest.fail("parsed"))
    assert not is_manifest(keypoints)


def test_calibrate_command_does_not_import_the_simulator():
    script = ("import sys; from cascalib.cli import build_parser; build_parser(); "
              "print(sorted(m for m in ('cascalib.simulate', 'scipy.signal') if m in sys.modules))")
    r = subprocess.run([sys.executable, "-c", script], capture_output=True, text=True,
                       timeout=120, cwd=Path(cascalib.__file__).parents[1])
    assert r.returncode == 0, r.stderr
    assert r.stdout.strip() == "[]"


def test_simulate_command_offers_every_keypoint_format():
    from cascalib.formats.keypoints import FORMATS
    from cascalib.simulate.output import TRACK_SUFFIX

    assert sorted(TRACK_SUFFIX) == sorted(FORMATS)
