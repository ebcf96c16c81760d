"""``python -m service.tokens add NAME``: create a bearer token kept (hashed) in the store.

Prints the token once; the store keeps only its SHA-256. Uses the same CASCALIB_* environment
as the service (CASCALIB_DATABASE_URL / CASCALIB_DATA_DIR).
"""

from __future__ import annotations

import argparse
import secrets
import sys

from sqlalchemy.exc import IntegrityError

from service import store as st
from service.core.config import Settings
from service.store import Store


def main(argv: list[str] | None = None) -> int:
    """Entry point; returns the exit code."""
    parser = argparse.ArgumentParser(prog="python -m service.tokens",
                                     description="Manage API tokens kept in the job store.")
    sub = parser.add_subparsers(dest="command", required=True)
    add = sub.add_parser("add", help="create a token and print it")
    add.add_argument("name", help="who the token is for (unique)")
    args = parser.parse_args(argv)
    settings = Settings()
    store = Store.from_settings(settings)
    try:
        store.prepare()
        token = secrets.token_urlsafe(32)
        with store.session() as session:
            st.add_api_token(session, name=args.name, token=token)
    except IntegrityError:
        print(f"a token named {args.name!r} exists already", file=sys.stderr)  # noqa: T201
        return 2
    finally:
        store.dispose()
    print(token)  # noqa: T201
    return 0


if __name__ == "__main__":
    sys.exit(main())
