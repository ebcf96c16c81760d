"""Prometheus metrics of one app instance (its own registry: several apps can share a process)."""

from __future__ import annotations

import time
from collections.abc import Awaitable, Callable, Iterable

from prometheus_client import CollectorRegistry, Counter, Histogram
from prometheus_client.core import GaugeMetricFamily, Metric
from prometheus_client.registry import Collector
from starlette.requests import Request
from starlette.responses import Response

from service import store as st
from service.store import Store

__all__ = ["Metrics"]

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

    async def middleware(self, request: Request,
                         call_next: Callable[[Request], Awaitable[Response]]) -> Response:
        """Time every request; label by route template (bounded cardinality)."""
        start = time.perf_counter()
        response = await call_next(request)
        route = request.scope.get("route")
        name = getattr(route, "path", "unmatched")
        self.latency.labels(request.method, name).observe(time.perf_counter() - start)
        self.requests.labels(request.method, name, str(response.status_code)).inc()
        return response
