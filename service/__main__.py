"""``python -m service [-v] [--host H] [--port P] [--insecure-no-auth]``: the same as
``cascalib serve`` (same flags, same environment), without the rest of the command line."""

from __future__ import annotations

import argparse
import logging
import sys

from cascalib.cli import serve


def main(argv: list[str] | None = None) -> int:
    """Parse the ``serve`` flags and run the service; returns the exit code."""
    argv = list(sys.argv[1:] if argv is None else argv)
    verbose = sum(a == "-v" for a in argv)
    parser = argparse.ArgumentParser(prog="python -m service")
    sub = parser.add_subparsers(dest="command", required=True)
    serve.add_parser(sub)
    args = parser.parse_args(["serve", *(a for a in argv if a != "-v")])
    args.verbose = verbose
    logging.basicConfig(level=logging.WARNING - 10 * min(verbose, 2),
                        format="%(levelname)s %(name)s: %(message)s")
    return int(serve.run(args))


if __name__ == "__main__":
    sys.exit(main())
