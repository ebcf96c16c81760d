"""The ``cascalib`` command line.

Each sub-command lives in its own module of this package with two functions,
``add_parser(subparsers)`` and ``run(args) -> int``; :func:`main` only parses arguments and maps
:class:`~cascalib.errors.CascalibError` to a clear message and a non-zero exit code.
"""

from __future__ import annotations

import argparse
import importlib
import json
import logging
import sys
from collections.abc import Sequence

from cascalib import __version__
from cascalib.errors import CascalibError

#: Sub-command modules, in the order ``cascalib --help`` lists them.
COMMANDS: tuple[str, ...] = (
    "calibrate", "triangulate", "simulate", "evaluate", "convert", "tracks_info", "info", "serve",
)

#: Exit codes: 0 success, 1 calibration failed or rejected, 2 bad input or usage.
EXIT_FAILED = 1
EXIT_USAGE = 2


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="cascalib",
        description="Calibrate and synchronise multi-camera rigs from the people in the scene.",
    )
    parser.add_argument("--version", action="version", version=f"cascalib {__version__}")
    parser.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", required=True)
    for name in COMMANDS:
        module = importlib.import_module(f"cascalib.cli.{name}")
        module.add_parser(sub)
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``cascalib`` command; returns the exit code."""
    parser = build_parser()
    args = parser.parse_args(argv)
    logging.basicConfig(
        level=logging.WARNING - 10 * min(args.verbose, 2),
        format="%(levelname)s %(name)s: %(message)s",
    )
    try:
        return int(args.run(args))
    except CascalibError as exc:
        if getattr(args, "json", False):
            print(json.dumps({"ok": False, "error": exc.to_dict()}))
        print(f"cascalib {args.command}: error: {exc}", file=sys.stderr)
        from cascalib.errors import EstimationFailed, RefinementFailed

        return EXIT_FAILED if isinstance(exc, (EstimationFailed, RefinementFailed)) else EXIT_USAGE


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
