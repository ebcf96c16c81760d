"""``cascalib serve``: run the REST calibration service (needs the ``service`` extra).

The service is a layer above the library, so this command imports nothing of it: it hands its
arguments to the ``serve`` entry point of the ``cascalib.commands`` group (``service.cli:main``,
also installed as ``cascalib-serve``), which owns the flags (``cascalib serve --help``).
"""

from __future__ import annotations

import argparse
import importlib
import sys
from collections.abc import Callable
from importlib.metadata import entry_points
from typing import Any

#: Where the command lives when the installed metadata predates the entry point (an old
#: editable install): the module the entry point names.
_FALLBACK = "service.cli"


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    # Every argument goes to the service's own parser; "+" as the only option prefix keeps
    # argparse from reading "--port" here, and "--help" reaches the service's help.
    p = sub.add_parser("serve", help="run the REST calibration service", add_help=False,
                       prefix_chars="+")
    p.add_argument("service_args", nargs=argparse.REMAINDER)
    p.set_defaults(run=run)


def _service_main() -> Callable[..., Any] | None:
    found = entry_points(group="cascalib.commands", name="serve")
    if found:
        return next(iter(found)).load()  # type: ignore[no-any-return]
    try:
        return importlib.import_module(_FALLBACK).main  # type: ignore[no-any-return]
    except ImportError:
        return None


def run(args: argparse.Namespace) -> int:
    main = _service_main()
    if main is None:
        print("cascalib serve: the service is not installed; pip install 'cascalib[service]'",
              file=sys.stderr)
        return 2
    return int(main(args.service_args, prog="cascalib serve", verbose=args.verbose))
