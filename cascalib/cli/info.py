"""``cascalib info``: what a keypoint file or folder holds (format, skeleton, frames, persons)."""

from __future__ import annotations

import argparse


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("info", help="list the supported skeletons and formats")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
    from cascalib.calibration_formats import FORMATS
    from cascalib.skeletons import SKELETONS

    print("skeletons:")
    for s in SKELETONS.values():
        print(f"  {s.name:12s} {s.n_joints:3d} joints  aliases: {', '.join(s.aliases)}")
    print("calibration formats (--formats, convert):")
    for f in FORMATS.values():
        print(f"  {f.name:12s} {f.output or '(read only)':24s} {f.description}")
    return 0
