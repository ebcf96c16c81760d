"""The FastAPI application: ``create_app(settings)`` (nothing happens at import time).

Start-up (the lifespan) migrates the database, refuses to run without authentication unless
asked to, recovers jobs and starts the execution back-end (the embedded worker pool, or the
Celery dispatcher when CASCALIB_BROKER_URL is set), the upload validators and the retention
sweeper (which also removes half-stored submissions a crash may have left).
"""

from __future__ import annotations

import logging
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager
from typing import Any

from fastapi import FastAPI
from fastapi.middleware.cors import CORSMiddleware

from cascalib import __version__
from service import store as st
from service.api.deps import AppState, Dispatcher
from service.api.routes import health, jobs
from service.core.config import Settings
from service.core.limits import BodyLimitMiddleware
from service.core.metrics import Metrics, MetricsMiddleware
from service.core.problems import install_handlers, problem_openapi
from service.core.proc import start_forkserver
from service.store import Store
from service.sweeper import Sweeper
from service.validation import Validator

__all__ = ["create_app"]

log = logging.getLogger(__name__)

DESCRIPTION = """\
Calibrate and synchronise multi-camera rigs from the people in the scene.

Submit one keypoint file per camera (the file name is the camera name) and the options:

    curl -H "Authorization: Bearer $TOKEN" \\
         -F files=@cam0.json -F files=@cam1.json -F files=@cam2.zip \\
         -F 'options={"image_size": "1920x1080", "fps": {"cam2": 25, "cam0": 30}, "height": 1.7}' \\
         http://127.0.0.1:8000/v1/jobs

then poll `GET /v1/jobs/{id}` until `status` is `succeeded` and download
`GET /v1/jobs/{id}/result` (`?format=toml|opencv|colmap|easymocap`), `/report` and `/poses`.
Errors are `application/problem+json` bodies naming the camera, file and field.
"""


def _dispatcher(settings: Settings, store: Store) -> Dispatcher:
    if settings.broker_url:
        from service.worker.celery_app import CeleryDispatcher

        return CeleryDispatcher(settings, store)
    from service.worker.local_pool import LocalPool

    return LocalPool(settings, store)


def prepare_store(settings: Settings) -> Store:
    """Open the store, migrate it and check the service may start.

    Raises
    ------
    ConfigurationError
        No token configured outside development mode (see ``Settings.check_startable``).
    """
    store = Store.from_settings(settings)
    try:
        store.prepare()
        with store.session() as session:
            settings.check_startable(n_stored_tokens=st.count_api_tokens(session))
    except BaseException:
        store.dispose()
        raise
    return store


def _warm_up() -> None:
    """Import the keypoint readers and the config now, not during the first upload."""
    import importlib

    for name in ("cascalib.formats", "cascalib.config"):
        try:
            importlib.import_module(name)
        except ImportError:
            log.warning("%s not importable: uploads cannot be validated fully", name)


def _document_problems(app: FastAPI) -> None:
    """Have ``/openapi.json`` document errors as problem+json (built once, on first use)."""
    plain = app.openapi

    def openapi() -> dict[str, Any]:
        if app.openapi_schema is None:
            app.openapi_schema = problem_openapi(plain())
        return app.openapi_schema

    app.openapi = openapi  # type: ignore[method-assign]


def create_app(settings: Settings | None = None) -> FastAPI:
    """The service application for ``settings`` (read from the environment when None)."""
    settings = settings or Settings()

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        store = prepare_store(settings)
        _warm_up()
        if not settings.auth_enabled:
            log.warning("authentication is OFF: every client sees every job")
        dispatcher = _dispatcher(settings, store)
        metrics = Metrics(store)
        start_forkserver()
        validator = Validator(settings)
        validator.warm_up()
        app.state.cascalib = AppState(settings, store, dispatcher, metrics, validator)
        dispatcher.start()
        sweeper = Sweeper(settings, store)
        sweeper.start()
        try:
            yield
        finally:
            sweeper.stop()
            validator.stop()
            dispatcher.stop()
            store.dispose()

    app = FastAPI(title="cascalib calibration service", version=__version__,
                  description=DESCRIPTION, lifespan=lifespan)
    install_handlers(app)
    _document_problems(app)

    app.add_middleware(MetricsMiddleware)
    if settings.cors_origins:
        app.add_middleware(CORSMiddleware, allow_origins=settings.cors_origins,
                           allow_methods=["GET", "POST", "DELETE"],
                           allow_headers=["Authorization", "Content-Type", "Idempotency-Key"])
    app.add_middleware(BodyLimitMiddleware, max_bytes=settings.max_upload_bytes,
                       timeout=settings.body_timeout_seconds)
    app.include_router(jobs.router)
    app.include_router(health.router)
    return app
