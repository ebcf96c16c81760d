"""``cascalib serve``: run the REST calibration service (needs the ``service`` extra).

Configured by CASCALIB_* environment variables (see ``service/core/config.py``):
CASCALIB_DATA_DIR, CASCALIB_DATABASE_URL, CASCALIB_API_TOKENS, CASCALIB_BROKER_URL, ...
"""

from __future__ import annotations

import argparse
import sys


def add_parser(sub: argparse._SubParsersAction) -> None:  # type: ignore[type-arg]
    p = sub.add_parser("serve", help="run the REST calibration service",
                       description="Run the REST calibration service (API + embedded worker "
                       "pool, or the API alone when CASCALIB_BROKER_URL selects Celery workers).")
    p.add_argument("--host", default="127.0.0.1",
                   help="interface to listen on (default: %(default)s)")
    p.add_argument("--port", type=int, default=8000, help="TCP port (default: %(default)s)")
    p.add_argument("--insecure-no-auth", action="store_true",
                   help="accept requests without a token (only for a trusted network)")
    p.set_defaults(run=run)


def run(args: argparse.Namespace) -> int:
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
