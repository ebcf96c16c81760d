"""``python -m service [-v] [--host H] [--port P] [--insecure-no-auth]``: the same as
``cascalib-serve`` and ``cascalib serve`` (same flags, same environment)."""

from __future__ import annotations

import sys

from service.cli import main

if __name__ == "__main__":
    sys.exit(main(prog="python -m service"))
