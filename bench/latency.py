"""Latency of the API's light endpoints under concurrent clients on loopback; one JSON line each.

    python bench/latency.py [--clients 50] [--duration 10 | --requests N] [--warmup 1]
                            [--candidates 30] [--redis-url URL | --embedded]

The API runs in a uvicorn subprocess (`create_app()` from VPP_* in its environment, one
process, log level warning: no access log), with a fresh store (temporary directory) and its
own queue name; the clients are one `httpx.AsyncClient` (HTTP/1.1 keep-alive, one connection per
client) in this process with `--clients` concurrent tasks, each sending requests back to back
for `--duration` s (or `--requests` each), after `--warmup` s of the same load not counted.

Before the load, the sample part (vpp_core.samples) is uploaded and one plan of it
(`--candidates` candidates) is computed by one burst worker, which exits when it is done: during
the measurements NO worker runs, so every new plan stays queued. The cases, in this order:

    GET  /livez                     the HTTP stack alone (no Redis, no store): a floor
    POST /v1/plans  stored          the computed plan's request again: answered from the store
                                    (202, status succeeded; nothing enqueued)
    POST /v1/plans  new             a new request each time (another candidate seed): stored
                                    and enqueued (202, status queued)
    GET  /v1/jobs/{id} queued       the jobs just enqueued, in turn (status queued)
    GET  /v1/jobs/{id} succeeded    the computed plan's job (status succeeded)
    GET  /v1/plans/{id}             the computed plan's document

Each line: requests, errors (transport errors and non-2xx), status codes, the job statuses the
bodies gave, latency p50/p90/p99/max/mean in ms (send to body read, as the client sees it:
on a 2-core machine this includes the client's own event-loop delays), requests/s, and the CPU
seconds the client, the API process and Redis used during the case. With every client sending
back to back the server is saturated, so p50 ≈ clients / (requests/s) (Little's law); run with
--clients 1 for the unloaded service time.

Redis: redis://127.0.0.1:6379/12 by default (db 12 flushed before and after), --redis-url
(flushed only when its db is 12), or --embedded.
"""

from __future__ import annotations

import argparse
import asyncio
import importlib.util
import json
import os
import resource
import shutil
import sys
import tempfile
import time
from collections import Counter
from collections.abc import Callable
from pathlib import Path
from typing import Any

_spec = importlib.util.spec_from_file_location(
    "vpp_bench_service", Path(__file__).resolve().with_name("service.py")
)
assert _spec is not None and _spec.loader is not None
svc = importlib.util.module_from_spec(_spec)
_spec.loader.exec_module(svc)  # helpers shared with bench/service.py (it also fixes sys.path)

import httpx  # noqa: E402
import numpy as np  # noqa: E402
from redis import Redis  # noqa: E402,TID251

from vpp_core.samples import sample_stl  # noqa: E402
from worker.pool import start_workers  # noqa: E402

Make = Callable[[int, int], tuple[str, str, dict[str, Any]]]
"""make(client index, request index) -> (method, path, httpx keyword arguments)."""


def cpu_self() -> float:
    ru = resource.getrusage(resource.RUSAGE_SELF)
    return ru.ru_utime + ru.ru_stime


def redis_cpu(conn: Redis) -> float:
    info = conn.info("cpu")
    return float(info["used_cpu_user"]) + float(info["used_cpu_sys"])


class RawClient:
    """A minimal HTTP/1.1 keep-alive client on asyncio streams: one connection per client task.

    httpx.AsyncClient with 50 connections spends a whole core of its own per ~100-200
    requests/s here (2 cores), so its latencies measure mostly the client; this one costs
    little and leaves the CPU to the server.
    """

    def __init__(self, base: str, clients: int) -> None:
        host, port = base.removeprefix("http://").split(":")
        self.host, self.port = host, int(port)
        self.conns: list[tuple[asyncio.StreamReader, asyncio.StreamWriter] | None] = [
            None
        ] * clients

    async def request(self, k: int, method: str, path: str, **kw: Any) -> tuple[int, str, bytes]:
        """(status, content type, body) of one request on connection k; `json=` or `content=`
        bytes (with their Content-Type in `headers=`) as the body."""
        if self.conns[k] is None:
            self.conns[k] = await asyncio.open_connection(self.host, self.port)
        reader, writer = self.conns[k]  # type: ignore[misc]
        body = json.dumps(kw["json"]).encode() if "json" in kw else kw.get("content", b"")
        head = f"{method} {path} HTTP/1.1\r\nHost: {self.host}:{self.port}\r\n"
        if "json" in kw:
            head += "Content-Type: application/json\r\n"
        if body or method in ("POST", "PUT", "PATCH"):
            head += f"Content-Length: {len(body)}\r\n"
        head += "".join(f"{name}: {value}\r\n" for name, value in kw.get("headers", {}).items())
        writer.write(head.encode() + b"\r\n" + body)
        status = int((await reader.readline()).split()[1])
        headers = {}
        while (line := await reader.readline()) not in (b"\r\n", b""):
            name, _, value = line.decode("latin-1").partition(":")
            headers[name.strip().lower()] = value.strip()
        if headers.get("transfer-encoding", "").lower() == "chunked":
            parts = []
            while size := int((await reader.readline()).strip().split(b";")[0], 16):
                parts.append(await reader.readexactly(size))
                await reader.readline()
            await reader.readline()
            data = b"".join(parts)
        else:
            data = await reader.readexactly(int(headers.get("content-length", 0)))
        if headers.get("connection", "").lower() == "close":
            writer.close()
            self.conns[k] = None
        return status, headers.get("content-type", ""), data

    async def aclose(self) -> None:
        for conn in self.conns:
            if conn is not None:
                conn[1].close()


class HttpxClient:
    """httpx.AsyncClient behind RawClient's interface."""

    def __init__(self, base: str, clients: int) -> None:
        limits = httpx.Limits(max_connections=clients, max_keepalive_connections=clients)
        self.client = httpx.AsyncClient(base_url=base, limits=limits, timeout=60)

    async def request(self, k: int, method: str, path: str, **kw: Any) -> tuple[int, str, bytes]:
        r = await self.client.request(method, path, **kw)
        return r.status_code, r.headers.get("content-type", ""), r.content

    async def aclose(self) -> None:
        await self.client.aclose()


async def load(
    client: RawClient | HttpxClient,
    make: Make,
    clients: int,
    duration: float | None,
    each: int | None,
) -> dict[str, Any]:
    """`clients` tasks sending make(k, i) back to back; latencies, codes and job statuses."""
    lat: list[float] = []
    codes: Counter[str] = Counter()
    statuses: Counter[str] = Counter()
    ids: list[str] = []
    size = [0]
    stop = time.perf_counter() + (duration or 0)

    async def one(k: int) -> None:
        i = 0
        while (i < each) if each else (time.perf_counter() < stop):
            method, path, kw = make(k, i)
            t = time.perf_counter()
            try:
                code, ctype, body = await client.request(k, method, path, **kw)
                lat.append(time.perf_counter() - t)
                codes[str(code)] += 1
                size[0] += len(body)
                if ctype.startswith("application/json"):
                    data = json.loads(body)
                    if isinstance(data, dict) and "status" in data and "id" in data:
                        statuses[str(data["status"])] += 1
                        ids.append(data["id"])
            except (httpx.HTTPError, OSError, asyncio.IncompleteReadError, ValueError) as exc:
                codes[type(exc).__name__] += 1
                if isinstance(client, RawClient) and client.conns[k] is not None:
                    client.conns[k][1].close()  # type: ignore[index]
                    client.conns[k] = None
            i += 1

    start = time.perf_counter()
    await asyncio.gather(*(one(k) for k in range(clients)))
    return {"elapsed": time.perf_counter() - start, "lat": lat, "codes": codes,
            "statuses": statuses, "ids": ids, "bytes": size[0]}  # fmt: skip


def figures(res: dict[str, Any]) -> dict[str, Any]:
    lat = np.array(res["lat"]) * 1000
    ok = sum(v for k, v in res["codes"].items() if k.isdigit() and 200 <= int(k) < 400)
    n = sum(res["codes"].values())
    q = (lambda p: round(float(np.percentile(lat, p)), 2)) if len(lat) else (lambda p: None)
    return {
        "requests": n,
        "errors": n - ok,
        "status_codes": dict(res["codes"]),
        "job_status": dict(res["statuses"]),
        "p50_ms": q(50),
        "p90_ms": q(90),
        "p99_ms": q(99),
        "max_ms": round(float(lat.max()), 2) if len(lat) else None,
        "mean_ms": round(float(lat.mean()), 2) if len(lat) else None,
        "req_per_s": round(n / res["elapsed"], 1),
        "duration_s": round(res["elapsed"], 3),
        "response_bytes_mean": round(res["bytes"] / max(1, len(lat))),
    }


async def run_cases(
    base: str, server_pid: int, conn: Redis, plan_body: dict[str, Any], plan_id: str, args: Any
) -> list[dict[str, Any]]:
    seed = [10_000]
    queued: list[str] = []

    def new_body(k: int, i: int) -> tuple[str, str, dict[str, Any]]:
        seed[0] += 1
        body = {**plan_body, "candidates": {**plan_body["candidates"], "seed": seed[0]}}
        return "POST", "/v1/plans", {"json": body}

    cases: list[tuple[str, str, Make]] = [
        ("GET /livez", "baseline: HTTP stack only", lambda k, i: ("GET", "/livez", {})),
        (
            "POST /v1/plans",
            "stored: identical to a computed plan, answered from the store",
            lambda k, i: ("POST", "/v1/plans", {"json": plan_body}),
        ),
        ("POST /v1/plans", "new: a new request each time, enqueued", new_body),
        (
            "GET /v1/jobs/{id}",
            "queued jobs (no worker running), cycled",
            lambda k, i: ("GET", f"/v1/jobs/{queued[(k * 7919 + i) % len(queued)]}", {}),
        ),
        (
            "GET /v1/jobs/{id}",
            "succeeded job",
            lambda k, i: ("GET", f"/v1/jobs/{plan_id}", {}),
        ),
        (
            "GET /v1/plans/{id}",
            "the computed plan's document",
            lambda k, i: ("GET", f"/v1/plans/{plan_id}", {}),
        ),
    ]
    out = []
    client = (RawClient if args.client == "raw" else HttpxClient)(base, args.clients)
    try:
        for endpoint, case, make in cases:
            if args.warmup > 0:
                warm = await load(client, make, args.clients, args.warmup, None)
                if case.startswith("new"):
                    queued.extend(warm["ids"])
            c0, s0, r0 = cpu_self(), svc.proc_cpu_s(server_pid), redis_cpu(conn)
            res = await load(client, make, args.clients, args.duration, args.requests)
            c1, s1, r1 = cpu_self(), svc.proc_cpu_s(server_pid), redis_cpu(conn)
            if case.startswith("new"):
                queued.extend(res["ids"])
            line: dict[str, Any] = {"bench": "latency", "endpoint": endpoint, "case": case}
            line |= {"clients": args.clients, "client": args.client, "workers": 0}
            line |= figures(res)
            line |= {
                "client_cpu_s": round(c1 - c0, 2),
                "server_cpu_s": round(s1 - s0, 2),
                "redis_cpu_s": round(r1 - r0, 2),
            }
            if endpoint.startswith("GET /v1/jobs") and case.startswith("queued"):
                line["distinct_jobs"] = len(set(queued))
            print(json.dumps(line), flush=True)
            out.append(line)
    finally:
        await client.aclose()
    return out


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--clients", type=int, default=50, help="concurrent clients")
    ap.add_argument("--duration", type=float, default=10.0, help="seconds per case")
    ap.add_argument("--requests", type=int, help="requests per client per case (not --duration)")
    ap.add_argument("--warmup", type=float, default=1.0, help="seconds of load before each case")
    ap.add_argument(
        "--client", choices=["raw", "httpx"], default="raw", help="raw asyncio HTTP/1.1 or httpx"
    )
    ap.add_argument("--candidates", type=int, default=30, help="candidates of the computed plan")
    ap.add_argument("--redis-url", help=f"default {svc.DEFAULT_REDIS}")
    ap.add_argument("--embedded", action="store_true", help="a private embedded Redis")
    args = ap.parse_args(argv)

    tmp = Path(tempfile.mkdtemp(prefix="vpp-bench-latency-"))
    with svc.redis_server(args.redis_url, args.embedded) as (url, may_flush):
        conn = Redis.from_url(url)
        if may_flush:
            conn.flushdb()
        env = {
            "VPP_REDIS_URL": url,
            "VPP_STORE_URL": str(tmp / "store"),
            "VPP_QUEUE": f"vpp-bench-latency-{os.getpid()}",
        }
        os.environ.update(env)  # for the burst worker
        try:
            with svc.api_server(env, tmp / "api.log") as (base, pid):
                r = httpx.post(
                    base + "/v1/meshes", files={"file": ("bushing.stl", sample_stl())}, timeout=60
                )
                r.raise_for_status()
                body = {"mesh_id": r.json()["id"], "candidates": {"count": args.candidates}}
                r = httpx.post(base + "/v1/plans", json=body, timeout=60)
                r.raise_for_status()
                plan_id = r.json()["id"]
                with (tmp / "worker.log").open("ab") as log:
                    (proc,) = start_workers(url, 1, burst=True, prefix="latency", log=log)
                    proc.wait(600)
                job = httpx.get(f"{base}/v1/jobs/{plan_id}", timeout=60).json()
                if job["status"] != "succeeded":
                    raise SystemExit(f"bench/latency.py: the plan to answer from failed: {job}")
                print(
                    f"bench/latency.py: API pid {pid} at {base}; plan {plan_id[:12]} computed, "
                    "no workers from here on",
                    file=sys.stderr,
                )
                asyncio.run(run_cases(base, pid, conn, body, plan_id, args))
        finally:
            if may_flush:
                conn.flushdb()
            conn.close()
            shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
