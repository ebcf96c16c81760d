"""Job execution: the embedded pool and the Celery workers (``celery -A service.worker worker``).

``app`` (alias ``celery``) is the Celery application, built from the ``CASCALIB_*``
environment on first access, so importing this package has no side effect.
"""

from __future__ import annotations

from typing import Any

__all__ = ["app", "celery"]


def __getattr__(name: str) -> Any:
    if name in ("app", "celery"):
        from service.worker import celery_app

        return celery_app.app
    raise AttributeError(name)
