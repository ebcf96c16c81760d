"""The service's command line: ``cascalib-serve``, ``python -m service`` and ``cascalib serve``.

``[-v] [--host H] [--port P] [--insecure-no-auth]``, configured further by CASCALIB_*
environment variables (see ``service/core/config.py``): CASCALIB_DATA_DIR,
CASCALIB_DATABASE_URL, CASCALIB_API_TOKENS, CASCALIB_BROKER_URL, ... ``cascalib serve`` finds
:func:`main` through the ``cascalib.commands`` entry point, so the library never imports this
package.
"""

from __future__ import annotations

import argparse
import logging
import sys
from collections.abc import Sequence


def build_parser(prog: str = "cascalib-serve") -> argparse.ArgumentParser:
    """The flags of the service."""
    p = argparse.ArgumentParser(
        prog=prog, description="Run the REST calibration service (API + embedded worker "
        "pool, or the API alone when CASCALIB_BROKER_URL selects Celery workers).")
    p.add_argument("-v", "--verbose", action="count", default=0, help="more log output")
    p.add_argument("--host", default="127.0.0.1",
                   help="interface to listen on (default: %(default)s)")
    p.add_argument("--port", type=int, default=8000, help="TCP port (default: %(default)s)")
    p.add_argument("--insecure-no-auth", action="store_true",
                   help="accept requests without a token (only for a trusted network)")
    return p


def run(args: argparse.Namespace) -> int:
    """Check the settings and the store, then serve until stopped; returns the exit code."""
    try:
        import uvicorn

        from service.core.config import ConfigurationError, Settings
        from service.main import create_app, prepare_store
    except ImportError as exc:
        print(f"cascalib serve: the service extra is not installed ({exc}); "
              "pip install 'cascalib[service]'", file=sys.stderr)
        return 2
    from pydantic import ValidationError

    try:
        settings = Settings(insecure_no_auth=True) if args.insecure_no_auth else Settings()
        prepare_store(settings).dispose()  # migrate and check before binding the port
    except (ConfigurationError, ValidationError) as exc:
        print(f"cascalib serve: error: {exc}", file=sys.stderr)
        return 2
    level = "info" if args.verbose else "warning"
    uvicorn.run(create_app(settings), host=args.host, port=args.port, log_level=level,
                timeout_graceful_shutdown=10)
    return 0


def main(argv: Sequence[str] | None = None, *, prog: str = "cascalib-serve",
         verbose: int = 0) -> int:
    """Parse the flags and run the service; returns the exit code.

    ``verbose`` adds to the ``-v`` count (``cascalib -v serve`` passes the outer one).
    """
    args = build_parser(prog).parse_args(sys.argv[1:] if argv is None else list(argv))
    args.verbose += verbose
    logging.basicConfig(level=logging.WARNING - 10 * min(args.verbose, 2),
                        format="%(levelname)s %(name)s: %(message)s")
    return run(args)
