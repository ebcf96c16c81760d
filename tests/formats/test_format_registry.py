"""One registry of calibration formats: the library, the CLI, the REST schemas and the docs
read the same names and output paths."""

from __future__ import annotations

import re
from pathlib import Path

import pytest
from test_calibration_files import random_rig

from cascalib import calibration_formats as reg
from cascalib.formats import load_calibration
from cascalib.formats.calibration import FORMATS as MODULES

DOCS = Path(__file__).resolve().parents[2] / "docs" / "formats.md"


def test_every_format_has_its_reader_and_writer() -> None:
    assert list(MODULES) == list(reg.FORMATS)
    for name, fmt in reg.FORMATS.items():
        assert MODULES[name] is fmt.load() and callable(MODULES[name].read)
        assert callable(getattr(MODULES[name], "write", None)) == fmt.writable, name
    assert reg.WRITABLE == ("json", "toml", "caliscope", "opencv", "colmap", "easymocap")


def test_result_save_writes_each_format_where_the_registry_says(tmp_path: Path) -> None:
    from cascalib.formats import save_calibration
    from cascalib.pipeline import _calibration_path

    calib = random_rig()
    for name in reg.WRITABLE:
        fmt = reg.get_format(name)
        path = _calibration_path(tmp_path, name)
        assert path == tmp_path / fmt.output_name
        save_calibration(calib, path, name)
        assert path.is_dir() == fmt.is_folder
        assert load_calibration(path, format=name).names == calib.names


def test_cli_and_rest_take_the_registry_names() -> None:
    from api_schemas import RESULT_FORMATS
    from cascalib.cli.calibrate import FORMATS as CLI_FORMATS
    from cascalib.cli.convert import output_format

    assert CLI_FORMATS == RESULT_FORMATS == reg.WRITABLE
    assert "caliscope" in RESULT_FORMATS
    for name in reg.WRITABLE:
        fmt = reg.get_format(name)
        if not fmt.is_folder:
            assert output_format(Path("out") / fmt.output_name, None) == name


@pytest.mark.parametrize("name", reg.WRITABLE)
def test_docs_table_lists_each_written_format_with_its_output(name: str) -> None:
    fmt = reg.get_format(name)
    row = re.search(rf"^\| `{name}` \| `([^`]+)`", DOCS.read_text(), re.M)
    assert row is not None, f"docs/formats.md has no table row for {name}"
    assert row.group(1).split("/")[0] == fmt.output_name
    assert name in DOCS.read_text().splitlines()[2]  # the --formats example line
