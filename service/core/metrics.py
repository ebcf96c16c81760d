"""Prometheus metrics of one app instance (its own registry: several apps can share a process)."""

from __future__ import annotations

import time
from collections.abc import Iterable

from prometheus_client import CollectorRegistry, Counter, Histogram
from prometheus_client.core import (
    CounterMetricFamily,
    GaugeMetricFamily,
    HistogramMetricFamily,
    Metric,
)
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
            events = st.read_events(session)
        for status in _STATUSES:
            g.add_metric([status], counts.get(status, 0))
        yield g
        yield from _job_events(events)


def _buckets(events: dict[tuple[str, str], float], name: str) -> list[tuple[str, float]]:
    return [(f"{b:g}", events.get((name, f"{b:g}"), 0.0)) for b in st.JOB_BUCKETS] + [
        ("+Inf", events.get((name, "+Inf"), 0.0))]


def _job_events(events: dict[tuple[str, str], float]) -> Iterable[Metric]:
    """Job histograms and counters from the store's running totals (all processes')."""
    wait = HistogramMetricFamily("cascalib_job_queue_wait_seconds",
                                 "Time from submission to a job's first start")
    wait.add_metric([], _buckets(events, "queue_wait"), events.get(("queue_wait", "sum"), 0.0))
    run = HistogramMetricFamily("cascalib_job_duration_seconds",
                                "Run time of a job's last attempt, by outcome",
                                labels=["status"])
    for status in ("succeeded", "failed"):
        name = f"duration:{status}"
        run.add_metric([status], _buckets(events, name), events.get((name, "sum"), 0.0))
    failed = CounterMetricFamily("cascalib_jobs_failed", "Jobs that ended failed")
    failed.add_metric([], events.get(("failed", ""), 0.0))
    retried = CounterMetricFamily("cascalib_job_retries",
                                  "Attempts re-queued after their worker died")
    retried.add_metric([], events.get(("retried", ""), 0.0))
    yield from (wait, run, failed, retried)


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
