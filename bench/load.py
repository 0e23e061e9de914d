"""A bounded mixed load on loopback: uploads, plan submissions and job polls from many clients.

    python bench/load.py [--clients 50] [--duration 20] [--workers 2] [--distinct 10]
                         [--max-requests 2000] [--seed 0] [--redis-url redis://127.0.0.1:6379/8]

The API runs in a uvicorn subprocess on 127.0.0.1 (`create_app()`, one process, no access log)
with a fresh store (temporary directory), its own queue name and `--workers` real forking RQ
workers (`python -m worker`); nothing else is contacted (the Redis URL must be loopback too).
The sample part is uploaded once, then `--clients` concurrent clients (one keep-alive HTTP/1.1
connection each, bench/latency.py's RawClient) send, back to back, requests drawn at random
(seeded per client):

    10%  POST /v1/meshes               the sample part again (same bytes: same id, stored once)
    20%  POST /v1/plans same           one small plan, identical for everybody (computed once)
    10%  POST /v1/plans distinct       one of `--distinct` small plans (another candidate seed)
    10%  POST /v1/plans keyed          the same plan with an Idempotency-Key shared by three
                                       successive submissions of a client (one processed, two
                                       replayed)
    50%  GET  /v1/jobs/{id}            a job this client submitted (a submission when none)

for `--duration` s, each client for at most `--max-requests` requests. Every loop is bounded in
time and count (duration ≤ 600 s, clients ≤ 200, distinct ≤ 100). Afterwards the jobs are
waited for (at most 300 s) and the worker log is read: how many times a worker ran and
computed each plan.

Prints one JSON line per endpoint (requests, status codes, errors, p50/p95/p99/max ms,
requests/s), then a summary line (distinct plans submitted; plan job runs, computations and
no-op reruns, from the RQ log's run times: a rerun that finds its plan stored returns in about
a millisecond; jobs succeeded or failed; 5xx), and a table on stderr. Exit status 1 on any 5xx
or transport error, or a plan computed more than once; 0 otherwise.

Redis: db 8 of the machine's Redis by default, flushed before and after (only db 8 is ever
flushed); --redis-url for another loopback Redis (then nothing is flushed).
"""

from __future__ import annotations

import argparse
import asyncio
import importlib.util
import json
import os
import random
import re
import shutil
import sys
import tempfile
import time
from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

_spec = importlib.util.spec_from_file_location(
    "vpp_bench_latency", Path(__file__).resolve().with_name("latency.py")
)
assert _spec is not None and _spec.loader is not None
latency = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(latency)  # RawClient; it loads bench/service.py and fixes sys.path
svc = latency.svc

import numpy as np  # noqa: E402
from redis import Redis  # noqa: E402,TID251

from vpp_core.samples import sample_stl  # noqa: E402
from worker.pool import start_workers, stop_workers  # noqa: E402

DEFAULT_REDIS = "redis://127.0.0.1:6379/8"
FLUSH_DB = 8
"""The only database this benchmark flushes."""
LOOPBACK = {"127.0.0.1", "localhost", "::1"}
MAX_DURATION_S = 600.0
MAX_CLIENTS = 200
MAX_DISTINCT = 100
NOOP_S = 0.05
"""A job run shorter than this found its result stored and returned without computing."""
WAIT_JOBS_S = 300.0
"""Longest wait for the submitted jobs after the load."""
SMALL_PLAN = {
    "sensor": {"width_px": 320, "height_px": 200},
    "profile": "paper",
    "candidates": {"count": 20},
}
"""The plans of the load: 20 candidates of 64,000 px, about a second of work each."""
BOUNDARY = "vpp-load-boundary"
MIX = (
    (0.10, "POST /v1/meshes"),
    (0.20, "POST /v1/plans same"),
    (0.10, "POST /v1/plans distinct"),
    (0.10, "POST /v1/plans keyed"),
    (0.50, "GET /v1/jobs/{id}"),
)
"""(share, endpoint) of the requests."""


def multipart(data: bytes, name: str) -> tuple[bytes, str]:
    """A multipart/form-data body with one `file` part, and its Content-Type."""
    head = (
        f'--{BOUNDARY}\r\nContent-Disposition: form-data; name="file"; filename="{name}"\r\n'
        "Content-Type: application/octet-stream\r\n\r\n"
    ).encode()
    return (
        head + data + f"\r\n--{BOUNDARY}--\r\n".encode(),
        f"multipart/form-data; boundary={BOUNDARY}",
    )


@dataclass
class Tally:
    """What the clients saw, per endpoint."""

    lat: dict[str, list[float]] = field(default_factory=dict)
    codes: dict[str, Counter[str]] = field(default_factory=dict)
    jobs: set[str] = field(default_factory=set)
    plans: set[str] = field(default_factory=set)
    elapsed: float = 0.0

    def add(self, endpoint: str, code: str, seconds: float | None) -> None:
        self.codes.setdefault(endpoint, Counter())[code] += 1
        if seconds is not None:
            self.lat.setdefault(endpoint, []).append(seconds)

    def lines(self) -> list[dict[str, Any]]:
        """One line per endpoint: counts, codes, errors, percentiles."""
        out = []
        for endpoint in sorted(self.codes):
            codes = self.codes[endpoint]
            lat = np.array(self.lat.get(endpoint, [0.0])) * 1000
            n = sum(codes.values())
            ok = sum(v for k, v in codes.items() if k.isdigit() and int(k) < 400)
            pct = {f"p{p}_ms": round(float(np.percentile(lat, p)), 1) for p in (50, 95, 99)}
            out.append(
                {
                    "bench": "load",
                    "endpoint": endpoint,
                    "requests": n,
                    "errors": n - ok,
                    "status_codes": dict(codes),
                    **pct,
                    "max_ms": round(float(lat.max()), 1),
                    "req_per_s": round(n / max(self.elapsed, 1e-9), 1),
                }  # fmt: skip
            )
        return out

    def server_errors(self) -> int:
        """5xx answers and transport errors (no answer at all)."""
        return sum(
            v for c in self.codes.values() for k, v in c.items() if not k.isdigit() or k >= "500"
        )


async def drive(
    base: str,
    mesh_id: str,
    clients: int = 50,
    duration: float = 20.0,
    max_requests: int = 2000,
    distinct: int = 10,
    seed: int = 0,
) -> Tally:
    """`clients` clients sending the mix back to back for `duration` s (bounded); the tally."""
    if urlparse(base).hostname not in LOOPBACK:
        raise ValueError(f"bench/load.py only loads a server on loopback, not {base}")
    clients = max(1, min(clients, MAX_CLIENTS))
    duration = min(duration, MAX_DURATION_S)
    distinct = max(1, min(distinct, MAX_DISTINCT))
    upload, ctype = multipart(sample_stl(), "bushing.stl")
    same = {"mesh_id": mesh_id, **SMALL_PLAN}
    tally, client = Tally(), latency.RawClient(base, clients)
    stop = time.perf_counter() + duration

    def request(k: int, i: int, endpoint: str) -> tuple[str, str, dict[str, Any]]:
        if endpoint == "POST /v1/meshes":
            return "POST", "/v1/meshes", {"content": upload, "headers": {"Content-Type": ctype}}
        if endpoint == "POST /v1/plans distinct":
            cands = {**SMALL_PLAN["candidates"], "seed": 1 + (k * 7919 + i) % distinct}
            return "POST", "/v1/plans", {"json": {**same, "candidates": cands}}
        if endpoint == "POST /v1/plans keyed":
            return (
                "POST",
                "/v1/plans",
                {"json": same, "headers": {"Idempotency-Key": f"c{k}-{i // 30}"}},
            )
        return "POST", "/v1/plans", {"json": same}

    async def one(k: int) -> None:
        rng, mine = random.Random(seed * 1000 + k), list[str]()
        for i in range(max_requests):
            if time.perf_counter() >= stop:
                return
            endpoint = rng.choices([e for _, e in MIX], weights=[w for w, _ in MIX])[0]
            kw: dict[str, Any] = {}
            if endpoint.startswith("GET") and mine:
                method, path = "GET", f"/v1/jobs/{rng.choice(mine)}"
            else:
                endpoint = endpoint if endpoint.startswith("POST") else "POST /v1/plans same"
                method, path, kw = request(k, i, endpoint)
            t = time.perf_counter()
            try:
                code, _, body = await client.request(k, method, path, **kw)
            except (OSError, asyncio.IncompleteReadError, ValueError) as exc:
                tally.add(endpoint, type(exc).__name__, None)
                if client.conns[k] is not None:
                    client.conns[k][1].close()
                    client.conns[k] = None
                continue
            tally.add(endpoint, str(code), time.perf_counter() - t)
            if method == "POST" and path == "/v1/plans" and code == 202:
                job = json.loads(body)["id"]
                tally.plans.add(job)
                if job not in mine:
                    mine.append(job)

    start = time.perf_counter()
    try:
        await asyncio.gather(*(one(k) for k in range(clients)))
    finally:
        tally.elapsed = time.perf_counter() - start
        await client.aclose()
    return tally


def wait_jobs(base: str, jobs: set[str], timeout: float = WAIT_JOBS_S) -> Counter[str]:
    """Poll each job until it is done or `timeout` s have passed; the final statuses."""
    import httpx

    deadline, final = time.monotonic() + timeout, Counter[str]()
    with httpx.Client(base_url=base, timeout=30) as http:
        for job in sorted(jobs):
            while True:
                status = http.get(f"/v1/jobs/{job}").json()["status"]
                if status in ("succeeded", "failed", "canceled") or time.monotonic() > deadline:
                    final[status] += 1
                    break
                time.sleep(0.2)
    return final


def job_runs(log: Path, kind: str, jobs: set[str], wait_s: float = 10.0) -> dict[str, list[float]]:
    """The run times (s) of each job of `kind` (plan, study, cloud), from RQ's log lines
    `Successfully completed <kind> <id[:12]> job in H:MM:SS.ffffff`, read once every job has
    one or `wait_s` s have passed: RQ writes that line after it has marked the job finished,
    so a job can read as succeeded before its line is in the log."""
    pattern = rf"Successfully completed {kind} ([0-9a-f]{{12}}) job in (\d+):(\d+):([\d.]+)s"
    by_prefix = {job[:12]: job for job in jobs}
    deadline = time.monotonic() + wait_s
    while True:
        text = log.read_text(errors="replace") if log.exists() else ""
        runs: dict[str, list[float]] = {job: [] for job in jobs}
        for prefix, h, m, sec in re.findall(pattern, text):
            if prefix in by_prefix:
                runs[by_prefix[prefix]].append(int(h) * 3600 + int(m) * 60 + float(sec))
        if all(runs.values()) or time.monotonic() >= deadline:
            return runs
        time.sleep(0.1)


def computed(runs: list[float]) -> int:
    """How many of a job's runs computed it: the others found the result stored and returned
    at once (about a millisecond; computing takes seconds)."""
    return sum(1 for t in runs if t >= NOOP_S)


def check_loopback_redis(url: str) -> None:
    u = urlparse(url)
    if u.scheme != "unix" and u.hostname not in LOOPBACK:
        raise SystemExit(f"bench/load.py: only a loopback Redis, not {u.hostname}")


def table(lines: list[dict[str, Any]]) -> str:
    rows = [f"{'endpoint':26} {'requests':>8} {'errors':>6} {'p50':>7} {'p95':>7} {'p99':>7} "
            f"{'max':>7} {'req/s':>6}  codes"]  # fmt: skip
    for x in lines:
        rows.append(
            f"{x['endpoint']:26} {x['requests']:8d} {x['errors']:6d} {x['p50_ms']:7.1f} "
            f"{x['p95_ms']:7.1f} {x['p99_ms']:7.1f} {x['max_ms']:7.1f} {x['req_per_s']:6.1f}  "
            f"{x['status_codes']}"
        )
    return "\n".join(rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--clients", type=int, default=50, help=f"concurrent clients (≤ {MAX_CLIENTS})")
    ap.add_argument("--duration", type=float, default=20.0, help="seconds of load (≤ 600)")
    ap.add_argument("--max-requests", type=int, default=2000, help="requests per client, at most")
    ap.add_argument("--workers", type=int, default=2, help="RQ worker processes")
    ap.add_argument("--distinct", type=int, default=10, help="distinct plans in the mix (≤ 100)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--redis-url", default=DEFAULT_REDIS, help=f"default {DEFAULT_REDIS}")
    ap.add_argument("--keep", action="store_true", help="keep the logs and store (path on stderr)")
    args = ap.parse_args(argv)
    check_loopback_redis(args.redis_url)
    conn = Redis.from_url(args.redis_url, socket_connect_timeout=2)
    conn.ping()
    may_flush = svc.redis_db_of(args.redis_url) == FLUSH_DB
    tmp = Path(tempfile.mkdtemp(prefix="vpp-bench-load-"))
    env = {
        "VPP_REDIS_URL": args.redis_url,
        "VPP_STORE_URL": str(tmp / "store"),
        "VPP_QUEUE": f"vpp-bench-load-{os.getpid()}",
    }
    os.environ.update(env)  # for the workers
    if may_flush:
        conn.flushdb()
    procs = []
    try:
        with (
            svc.api_server(env, tmp / "api.log") as (base, pid),
            (tmp / "workers.log").open("ab") as log,
        ):
            procs = start_workers(args.redis_url, args.workers, prefix="load", log=log)
            svc.wait_workers(conn, env["VPP_QUEUE"], args.workers)
            import httpx

            r = httpx.post(
                base + "/v1/meshes", files={"file": ("bushing.stl", sample_stl())}, timeout=60
            )
            r.raise_for_status()
            print(
                f"bench/load.py: API pid {pid} at {base}, {args.workers} workers", file=sys.stderr
            )
            tally = asyncio.run(
                drive(
                    base,
                    r.json()["id"],
                    args.clients,
                    args.duration,
                    args.max_requests,
                    args.distinct,
                    args.seed,
                )  # fmt: skip
            )
            statuses = wait_jobs(base, tally.plans)
            runs = job_runs(tmp / "workers.log", "plan", tally.plans)
    finally:
        stop_workers(procs, wait_s=5)
        if may_flush:
            conn.flushdb()
        conn.close()
        if args.keep:
            print(f"bench/load.py: logs and store kept in {tmp}", file=sys.stderr)
        else:
            shutil.rmtree(tmp, ignore_errors=True)
    lines = tally.lines()
    for line in lines:
        print(json.dumps(line), flush=True)
    total = sum(x["requests"] for x in lines)
    summary = {
        "bench": "load",
        "summary": True,
        "clients": args.clients,
        "workers": args.workers,
        "duration_s": round(tally.elapsed, 2),
        "requests": total,
        "req_per_s": round(total / max(tally.elapsed, 1e-9), 1),
        "server_errors": tally.server_errors(),
        "distinct_plans": len(tally.plans),
        "plan_job_runs": sum(len(r) for r in runs.values()),
        "plan_computations": sum(computed(r) for r in runs.values()),
        "noop_reruns_s": sorted(t for r in runs.values() for t in r if t < NOOP_S),
        "plans_computed_more_than_once": sorted(j for j, r in runs.items() if computed(r) > 1),
        "job_status": dict(statuses),
    }
    print(json.dumps(summary), flush=True)
    print(table(lines), file=sys.stderr)
    bad = summary["server_errors"] or summary["plans_computed_more_than_once"]
    return 1 if bad else 0


if __name__ == "__main__":
    raise SystemExit(main())
