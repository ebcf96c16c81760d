"""Prometheus metrics of one app instance (its own registry: several apps can share a process)."""

from __future__ import annotations

import time
from collections.abc import Iterable

from prometheus_client import CollectorRegistry, Counter, Histogram
from prometheus_client.core import GaugeMetricFamily, Metric
from prometheus_client.registry import Collector
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service import store as st
from service.store import Store

__all__ = ["Metrics", "MetricsMiddleware"]

_STATUSES = ("queued", "running", "succeeded", "failed", "cancelled")


class _JobsCollector(Collector):
    """Jobs by state, read from the store at scrape time (workers live in other processes)."""

    def __init__(self, store: Store) -> None:
        self.store = store

    def collect(self) -> Iterable[Metric]:
        g = GaugeMetricFamily("cascalib_jobs", "Jobs in the store by state", labels=["status"])
        with self.store.session() as session:
            counts = st.count_by_status(session)
        for status in _STATUSES:
            g.add_metric([status], counts.get(status, 0))
        yield g


class Metrics:
    """Request counts and latencies, job submissions, and job states."""

    def __init__(self, store: Store) -> None:
        self.registry = CollectorRegistry()
        self.requests = Counter("cascalib_http_requests", "HTTP requests answered",
                                ["method", "route", "status"], registry=self.registry)
        self.latency = Histogram("cascalib_http_request_duration_seconds",
                                 "Time to answer an HTTP request", ["method", "route"],
                                 registry=self.registry,
                                 buckets=(.005, .01, .025, .05, .1, .25, .5, 1, 2.5, 5, 10, 30))
        self.submitted = Counter("cascalib_jobs_submitted", "Jobs accepted",
                                 registry=self.registry)
        self.rejected = Counter("cascalib_jobs_rejected", "Submissions refused (4xx)",
                                registry=self.registry)
        self.registry.register(_JobsCollector(store))

    def observe(self, method: str, route: str, status: int, seconds: float) -> None:
        """Record one answered request."""
        self.latency.labels(method, route).observe(seconds)
        self.requests.labels(method, route, str(status)).inc()


class MetricsMiddleware:
    """Pure ASGI middleware timing every request, labelled by route template (bounded
    cardinality). Pure ASGI, not ``BaseHTTPMiddleware``, so exceptions raised while the body
    streams in reach the exception handlers unwrapped."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        metrics: Metrics | None = None
        if scope["type"] == "http":
            state = getattr(scope["app"].state, "cascalib", None) if "app" in scope else None
            metrics = getattr(state, "metrics", None)
        if metrics is None:
            await self.app(scope, receive, send)
            return
        start = time.perf_counter()
        status = 500

        async def send_status(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = int(message["status"])
            await send(message)

        try:
            await self.app(scope, receive, send_status)
        finally:
            route = getattr(scope.get("route"), "path", "unmatched")
            metrics.observe(scope["method"], route, status, time.perf_counter() - start)
