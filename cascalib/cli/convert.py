"""``cascalib convert IN OUT``: rewrite a calibration in another file format."""

from __future__ import annotations

import argparse
from pathlib import Path

from cascalib.calibration_formats import FORMATS, WRITABLE
from cascalib.errors import CalibrationFileError

_BY_SUFFIX = {".json": "json", ".toml": "toml", ".yml": "opencv", ".yaml": "opencv",
              ".xml": "opencv"}

#: Output names that say their format (``camera_array.toml``, ``calibration_opencv.yml``, ...).
_BY_NAME = {f.output_name: f.name for f in FORMATS.values() if f.writable and not f.is_folder}


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    names = ", ".join(FORMATS)
    p = sub.add_parser(
        "convert", help="convert a calibration between file formats",
        description="Read a calibration (format detected unless --from) and write it in another "
                    "format (from OUT's extension unless --to; COLMAP and EasyMocap write a "
                    f"folder). Formats: {names}.")
    p.add_argument("input", type=Path, metavar="IN", help="calibration file or folder")
    p.add_argument("output", type=Path, metavar="OUT", help="file or folder to write")
    p.add_argument("--from", dest="from_format", metavar="FMT", help="input format")
    p.add_argument("--to", dest="to_format", metavar="FMT",
                   help="output format (default: from OUT's extension)")
    p.set_defaults(run=run)


def output_format(path: Path, given: str | None) -> str:
    """The format to write: ``--to`` or the output's extension."""
    if given:
        return given
    if path.name in ("intri.yml", "extri.yml"):
        return "easymocap"
    fmt = _BY_NAME.get(path.name) or _BY_SUFFIX.get(path.suffix.lower())
    if fmt is None:
        raise CalibrationFileError("cannot tell the output format from the name; pass --to "
                                   f"({', '.join(WRITABLE)})", file=str(path), field="--to")
    return fmt


def run(args: argparse.Namespace) -> int:
    from cascalib.formats.calibration import TIME_SIDECAR, load_calibration, save_calibration

    calib = load_calibration(args.input, format=args.from_format)
    fmt = output_format(args.output, args.to_format)
    written = save_calibration(calib, args.output, format=fmt)
    print(f"{len(calib)} cameras ({', '.join(calib.names)}) -> {fmt}:")
    for path in written:
        print(f"  {path}")
    sidecars = [p for p in written if p.name == TIME_SIDECAR]
    if sidecars:
        print(f"warning: {fmt} has no place for frame rates, time offsets and the reference "
              f"camera: they are in {sidecars[0]}, which cascalib reads back (other tools do not)")
    return 0
