"""Prometheus metrics counted in Redis, so every process counts: the API, each worker and each
forked work horse, on any machine (prometheus-client's multiprocess mode sums the processes of
one host only). `inc` and `observe` add to Redis hashes; `render` turns them, with the queue
depths read at scrape time, into the Prometheus text format with prometheus-client.

Metrics (all `vpp_`): jobs_submitted_total{kind}, jobs_finished_total{kind,status},
job_duration_seconds{kind,status} (histogram), stage_duration_seconds{stage} (histogram, per
finished plan), rays_traced_total, solver_runs_total{status}, solver_gap (histogram),
queue_depth{queue}, jobs_running, store_errors_total{operation} (put, get, exists, ping: every
operation shown, at 0 until one fails; counted by worker.store.CountedStore).
"""

from __future__ import annotations

import json
import math
from collections.abc import Iterable, Mapping
from typing import Any

from prometheus_client import CollectorRegistry, generate_latest
from prometheus_client.core import CounterMetricFamily, GaugeMetricFamily, HistogramMetricFamily
from redis import Redis
from rq import Queue
from rq.registry import StartedJobRegistry

COUNTERS = "vpp:metrics:counters"
"""Hash: JSON [name, labels] -> count."""
HISTOGRAMS = "vpp:metrics:histograms"
"""Hash: JSON [name, labels, le] -> count ("sum" and "count" as le for those)."""
SECONDS = (0.1, 0.5, 1, 2.5, 5, 10, 30, 60, 120, 300, 600, 1800, 3600, 7200, 21600)
"""Bucket bounds of the duration histograms (s)."""
GAPS = (0.0, 1e-4, 1e-3, 0.01, 0.05, 0.1, 0.5, 1.0)
"""Bucket bounds of the solver's relative MIP gap."""
BUCKETS = {"solver_gap": GAPS}
HELP = {
    "jobs_submitted_total": "Job submissions (plans, studies, point clouds) accepted by the API",
    "jobs_finished_total": "Job ends by kind and status (a retried failure counts each time)",
    "job_duration_seconds": "Seconds from a job's start to its end",
    "stage_duration_seconds": "Seconds each stage of a finished plan took",
    "rays_traced_total": "Rays cast by finished plans (reused traces not counted again)",
    "solver_runs_total": "Set-cover solves of finished plans by solver status",
    "solver_gap": "Relative MIP gap of finished plans' solves",
    "store_errors_total": "Artifact store operations that failed (disk full, object store down)",
}
STORE_OPERATIONS = ("put", "get", "exists", "ping")
"""The store's operations: each has its `store_errors_total` series from the start."""


def _labels_key(name: str, labels: Mapping[str, str], *extra: str) -> str:
    return json.dumps([name, dict(sorted(labels.items())), *extra])


def inc(conn: Redis, name: str, labels: Mapping[str, str] | None = None, by: float = 1) -> None:
    """Add `by` to the counter `vpp_<name>{labels}`."""
    conn.hincrbyfloat(COUNTERS, _labels_key(name, labels or {}), by)


def observe(conn: Redis, name: str, value: float, labels: Mapping[str, str] | None = None) -> None:
    """Record `value` in the histogram `vpp_<name>{labels}`."""
    labels = labels or {}
    pipe = conn.pipeline()
    for bound in (*BUCKETS.get(name, SECONDS), math.inf):
        if value <= bound:
            pipe.hincrbyfloat(HISTOGRAMS, _labels_key(name, labels, str(bound)), 1)
    pipe.hincrbyfloat(HISTOGRAMS, _labels_key(name, labels, "sum"), value)
    pipe.hincrbyfloat(HISTOGRAMS, _labels_key(name, labels, "count"), 1)
    pipe.execute()


def plan_finished(conn: Redis, doc: Any) -> None:
    """The metrics of a finished plan document: stage times, rays, solver status and gap."""
    for stage, seconds in doc.timings_s.model_dump().items():
        observe(conn, "stage_duration_seconds", float(seconds), {"stage": stage})
    if not doc.rays.reused:
        inc(conn, "rays_traced_total", by=doc.rays.cast)
    inc(conn, "solver_runs_total", {"status": doc.solver.status})
    if doc.solver.gap is not None:
        observe(conn, "solver_gap", float(doc.solver.gap))


def _read(conn: Redis, key: str) -> dict[tuple[Any, ...], float]:
    raw: dict[bytes, bytes] = conn.hgetall(key)  # type: ignore[assignment]
    out = {}
    for field, value in raw.items():
        name, labels, *extra = json.loads(field)
        out[(name, tuple(sorted(labels.items())), *extra)] = float(value)
    return out


class RedisCollector:
    """prometheus-client collector of the Redis-held metrics and the live queue state."""

    def __init__(self, conn: Redis, queues: Iterable[str]) -> None:
        self.conn, self.queues = conn, list(queues)

    def collect(self) -> Iterable[Any]:
        yield from self._counters()
        yield from self._histograms()
        depth = GaugeMetricFamily("vpp_queue_depth", "Jobs waiting in a queue", labels=["queue"])
        running = GaugeMetricFamily("vpp_jobs_running", "Jobs being run by a worker (chunks too)")
        busy = 0
        for name in self.queues:
            queue = Queue(name, connection=self.conn)
            depth.add_metric([name], queue.count)
            busy += StartedJobRegistry(name, connection=self.conn).count
        running.add_metric([], busy)
        yield depth
        yield running

    def _counters(self) -> Iterable[Any]:
        families: dict[str, CounterMetricFamily] = {}
        counts = _read(self.conn, COUNTERS)
        for op in STORE_OPERATIONS:  # a failure rate needs its zero before the first failure
            counts.setdefault(("store_errors_total", (("operation", op),)), 0.0)
        for (name, labels), value in sorted(counts.items()):
            keys = [k for k, _ in labels]
            family = families.setdefault(
                name, CounterMetricFamily(f"vpp_{name}", HELP.get(name, name), labels=keys)
            )
            family.add_metric([v for _, v in labels], value)
        return families.values()

    def _histograms(self) -> Iterable[Any]:
        series: dict[tuple[str, tuple[Any, ...]], dict[str, float]] = {}
        for (name, labels, le), value in _read(self.conn, HISTOGRAMS).items():
            series.setdefault((name, labels), {})[le] = value
        families: dict[str, HistogramMetricFamily] = {}
        for (name, labels), values in sorted(series.items()):
            keys = [k for k, _ in labels]
            family = families.setdefault(
                name, HistogramMetricFamily(f"vpp_{name}", HELP.get(name, name), labels=keys)
            )
            bounds = (*BUCKETS.get(name, SECONDS), math.inf)
            buckets = [(_le(b), values.get(str(b), 0.0)) for b in bounds]
            family.add_metric([v for _, v in labels], buckets, values.get("sum", 0.0))
        return families.values()


def _le(bound: float) -> str:
    return "+Inf" if math.isinf(bound) else repr(float(bound))


def render(conn: Redis, queues: Iterable[str]) -> bytes:
    """The metrics in the Prometheus text format."""
    registry = CollectorRegistry(auto_describe=False)
    registry.register(RedisCollector(conn, queues))
    return generate_latest(registry)
