"""``cascalib evaluate RESULT --truth GT``: errors of a calibration against a reference one."""

from __future__ import annotations

import argparse
import json
from pathlib import Path

from cascalib.errors import InputError


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser(
        "evaluate", help="compare a calibration with a reference calibration",
        description="Print focal, principal-point, relative-rotation, camera-centre (after a "
                    "similarity and a ground-plane alignment), scale and time errors of RESULT "
                    "against GT. Cameras are matched by name unless --map is given.")
    p.add_argument("result", type=Path, metavar="RESULT", help="calibration to evaluate")
    p.add_argument("--truth", type=Path, required=True, metavar="GT",
                   help="reference calibration (any supported format)")
    p.add_argument("--map", action="append", default=[], metavar="EST=GT",
                   help="match camera EST of RESULT with camera GT of the reference "
                        "(repeat for each camera; default: same names)")
    p.add_argument("--reference", metavar="NAME",
                   help="camera of RESULT that rotations and time offsets refer to")
    p.add_argument("--from", dest="from_format", metavar="FMT", help="format of RESULT")
    p.add_argument("--truth-format", metavar="FMT", help="format of GT")
    p.add_argument("--ground", action=argparse.BooleanOptionalAction, default=None,
                   help="compute the ground-plane alignment (default: when both calibrations "
                        "have the ground at z=0)")
    p.add_argument("--json", action="store_true", help="print machine-readable JSON")
    p.set_defaults(run=run)


def parse_mapping(items: list[str]) -> dict[str, str] | None:
    """``["a=cam_1", ...]`` -> ``{"a": "cam_1"}`` (None when empty)."""
    mapping = {}
    for item in items:
        est, sep, truth = item.partition("=")
        if not sep or not est or not truth:
            raise InputError(f"expected EST=GT, got {item!r}", field="--map")
        mapping[est] = truth
    return mapping or None


def run(args: argparse.Namespace) -> int:
    from cascalib.formats.calibration import load_calibration
    from cascalib.metrics import compare_calibrations

    result = load_calibration(args.result, format=args.from_format)
    truth = load_calibration(args.truth, format=args.truth_format)
    errors = compare_calibrations(result, truth, mapping=parse_mapping(args.map),
                                  reference=args.reference, ground=args.ground)
    if args.json:
        print(json.dumps({"ok": True, "result": str(args.result), "truth": str(args.truth),
                          **errors.to_dict()}, indent=2))
    else:
        print(f"{args.result} against {args.truth}:\n")
        print(errors.table())
    return 0
