"""RQ job functions (thin): load inputs by key, call vpp_core, store the result, return a dict.

`plan_job(plan)` runs the whole pipeline for one plan. Its ray tracing is fanned out: the
candidates are cut into chunks, each enqueued as a `chunk_job` that any worker can take;
the plan job takes back (LREM, atomic against the workers' LMOVE) and traces itself every
chunk no other worker has started, so one worker alone finishes too, and it waits for the
rest. Finished chunks stay in the store, so a cancelled or crashed plan resumes where it
stopped; R is traced once per trace id.

Faults (see worker.faults): a job whose worker died is put back on the queue up to
`job_retries` times; a job that raises fails at once. A failed chunk fails the plan with its
reason; a chunk put back is traced again by any worker or taken back; a retried plan job
adopts the chunk jobs of its previous attempt.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass
from datetime import UTC, datetime
from functools import partial
from typing import Any

import numpy as np
from redis import Redis
from rq import Queue, Retry, get_current_job
from rq.job import Job, JobStatus

from vpp_core.camera.pose import Viewpoints
from vpp_core.camera.sensor import Sensor
from vpp_core.cell.geometry import Cell
from vpp_core.errors import VppError
from vpp_core.mesh.part import Part
from vpp_core.mesh.refine import Elements, elements
from vpp_core.plan.cellplan import scene_occluders, setup_backend
from vpp_core.plan.document import PlanRequest, Timings
from vpp_core.plan.pipeline import (
    candidates_for,
    check_limits,
    elements_of,
    finish,
    grow,
    spent_s,
    tracer_of,
)
from vpp_core.plan.warm import warm
from vpp_core.report.scene import plan_scene, unpack
from vpp_core.trace.rays import RayBackend
from vpp_core.trace.raytrace import Trace, join_traces, make_backend, trace_counts
from worker import artifacts as art
from worker.faults import delete_job, fail_fast, failure_reason
from worker.settings import Settings, get_settings
from worker.store import Store, open_store
from worker.tracelock import TraceLock

META_INTERVAL_S = 0.5
"""Least seconds between two progress writes of one job (Redis round trips)."""
POLL_S = 0.25
"""Seconds between two looks at the chunks other workers run."""
WATCH_S = 1.0
"""While the plan job traces a chunk itself: seconds between two looks at the others."""
STARTED_META = "started_at"
"""The job meta field holding when the job's body started (ISO 8601, UTC): RQ writes its own
`started_at` twice, when the work horse takes the job and again, a few ms later, when it
finishes, so a state read in between (the document already stored) gave another start."""
FAILED = {JobStatus.FAILED, JobStatus.STOPPED, JobStatus.CANCELED}
ADOPT = {JobStatus.QUEUED, JobStatus.STARTED, JobStatus.FINISHED}
"""Chunk job states a retried plan job adopts instead of enqueueing the chunk again."""


class _Meta:
    """The current job's progress in its meta, written at most every META_INTERVAL_S."""

    def __init__(self, job: Job) -> None:
        self.job = job
        self.last = 0.0

    def update(self, force: bool = False, **fields: Any) -> None:
        self.job.meta.update(fields)
        now = time.monotonic()
        if force or now - self.last >= META_INTERVAL_S:
            self.job.save_meta()  # type: ignore[no-untyped-call]
            self.last = now


@dataclass
class Context:
    """What a job works with: settings, store, its RQ job, queue and progress."""

    settings: Settings
    store: Store
    job: Job
    queue: Queue
    meta: _Meta

    @classmethod
    def current(cls) -> Context:
        job = get_current_job()
        if job is None:
            raise RuntimeError("not running inside an RQ job")
        settings = get_settings()
        queue = Queue(job.origin, connection=job.connection)
        store = open_store(settings.store_url, job.connection, settings.s3_endpoint_url)
        return cls(settings, store, job, queue, _Meta(job))


def plan_job(plan: str) -> dict[str, Any]:
    """Compute and store the plan `plan` (its request is in the store); returns a summary."""
    return run_job(_plan, plan)


def run_job(body: Callable[[Context, str], dict[str, Any]], job_id: str) -> dict[str, Any]:
    """Run a job body in the current RQ job's context; its error recorded for clients."""
    ctx = Context.current()
    ctx.meta.update(force=True, **{STARTED_META: datetime.now(UTC).isoformat()})
    try:
        return body(ctx, job_id)
    except BaseException as exc:
        fail_fast(ctx.job, exc)
        ctx.meta.update(force=True, error=error_record(exc))
        raise


def error_record(exc: BaseException) -> dict[str, str]:
    """{type, title, detail} of an exception, for clients."""
    if isinstance(exc, VppError):
        return {"type": type(exc).__name__, "title": exc.title, "detail": exc.detail}
    return {"type": "InternalError", "title": "Internal error", "detail": f"{exc!r}"}


def _plan(ctx: Context, plan: str) -> dict[str, Any]:
    if ctx.store.exists(art.plan_key(plan)):
        return {"plan": plan, "cached": True}
    mesh_id, request = art.get_request(ctx.store, plan)
    part = art.get_planned_part(ctx.store, mesh_id, request)
    cell = art.get_cell(ctx.store, request.setup)
    split = elements_of(part, request)
    trace_id = art.trace_id(mesh_id, request, split.max_area_mm2 if split else None)
    timings = Timings()
    progress = stage_progress(ctx.meta)
    # stage `compiling` while numba compiles (fresh install); not counted in the plan's budget
    timings.compiling = round(warm(request.backend, progress), 4)
    views, info, trace, reused = _trace(ctx, part, request, trace_id, timings, cell, split)
    progress("adaptive", 0, 1)
    start = time.perf_counter()
    views, info, trace, rounds = grow(
        part,
        request,
        views,
        info,
        trace,
        threads=ctx.settings.threads,
        cell=cell,
        spent_s=spent_s(timings),
    )
    timings.adaptive = round(time.perf_counter() - start, 4)
    doc = finish(
        part,
        request,
        views,
        info,
        trace,
        timings=timings,
        threads=ctx.settings.threads,
        progress=progress,
        reused=reused,
        rounds=rounds,
        cell=cell,
    )
    ctx.meta.update(force=True, stage="plots")
    scene = plan_scene(part, doc, trace.counts, cell)
    faces = unpack(scene)[1]  # the part in cameras.png wears the viewer's r* colours
    from vpp_core.report.plots import plan_plots  # matplotlib: preloaded by workers, not the API

    pngs = plan_plots(part, doc, faces=(faces["state"], faces["resolution_mm"]))
    for name, png in pngs.items():  # before the document: it means done
        ctx.store.put(art.plot_key(f"plans/{plan}", name), png)
    if doc.candidate_info.added:  # R of the grown pool, for the scene and re-plans
        pool = art.plan_trace_id(mesh_id, request, doc)
        ctx.store.put(art.counts_key(pool), art.trace_bytes(trace))
    art.put_scene(ctx.store, plan, scene)
    art.put_plan(ctx.store, plan, doc)
    ctx.meta.update(force=True, stage="done")
    return {"plan": plan, "viewpoints": len(doc.viewpoints), "trace": trace_id}


def _trace(
    ctx: Context,
    part: Part,
    request: PlanRequest,
    trace_id: str,
    timings: Timings,
    cell: Cell | None = None,
    split: Elements | None = None,
) -> tuple[Viewpoints, Any, Trace, bool]:
    """(views, candidate info, R, reused): from the store, or traced under the trace's lock,
    in the setup `cell`, on the part's elements `split` where given."""
    if not ctx.store.exists(art.counts_key(trace_id)):
        lock = TraceLock(ctx.job.connection, trace_id, ctx.job.id, ctx.settings.plan_timeout_s)
        with lock.hold(lambda: ctx.store.exists(art.counts_key(trace_id)), ctx.meta.update):
            if not ctx.store.exists(art.counts_key(trace_id)):
                backend = setup_backend(part, request, cell)  # candidates see the faces
                start = time.perf_counter()
                views, info = _candidates(ctx, part, request, trace_id, backend, cell)
                timings.candidates = round(time.perf_counter() - start, 4)
                tracer = tracer_of(split, request, cell, backend)
                trace = _fan_out(ctx, part, request.sensor, views, trace_id, tracer, split)
                timings.trace = round(trace.seconds, 4)
                ctx.store.put(art.counts_key(trace_id), art.trace_bytes(trace))
                return views, info, trace, False
    _, views, info = art.get_views(ctx.store, trace_id)
    trace = art.get_trace(ctx.store, trace_id)
    return views, info, trace, True


def _candidates(
    ctx: Context,
    part: Part,
    request: PlanRequest,
    trace_id: str,
    backend: RayBackend,
    cell: Cell | None = None,
) -> tuple[Viewpoints, Any]:
    """Generate (or read back) the candidates of `trace_id`, checked against the limits."""
    if ctx.store.exists(art.views_key(trace_id)):
        _, views, info = art.get_views(ctx.store, trace_id)
        return views, info
    ctx.meta.update(force=True, stage="candidates", done=0, total=1)
    views, info = candidates_for(part, request, backend, cell)
    check_limits(len(views), request.sensor.n_pixels, ctx.settings.limits())
    art.put_views(ctx.store, trace_id, request.sensor, views, info, request.setup)
    return views, info


def _fan_out(
    ctx: Context,
    part: Part,
    sensor: Sensor,
    views: Viewpoints,
    trace_id: str,
    backend: RayBackend,
    split: Elements | None = None,
) -> Trace:
    """R of all views: chunks enqueued for any worker, the ones still queued traced here (on
    the elements `split` where given, `backend` over them)."""
    start = time.perf_counter()
    size = ctx.settings.chunk_views
    element_mm2 = split.max_area_mm2 if split else None
    chunks = _Chunks(ctx, part.id, trace_id, len(views), size, backend.name, element_mm2)
    own: dict[int, Trace] = {}  # traced here: kept, not read back from the store
    while not chunks.all_done():
        index = chunks.take_back()
        if index is None:
            chunks.watch()
            time.sleep(POLL_S)
            continue
        lo, hi = chunk_range(index, size, len(views))
        own[index] = _trace_range(
            ctx, part, sensor, views, lo, hi, backend, chunks.own_progress, chunks.watch_due, split
        )
        ctx.store.put(art.chunk_key(trace_id, size, index), art.trace_bytes(own[index]))
        chunks.taken_done(index)
    parts = [
        own.get(i) or art.trace_from_bytes(ctx.store.get(art.chunk_key(trace_id, size, i)))
        for i in range(chunks.n)
    ]
    return join_traces(parts, time.perf_counter() - start)


def chunk_range(index: int, size: int, n_views: int) -> tuple[int, int]:
    """Views [lo, hi) of chunk `index` when `n_views` are cut into chunks of `size`."""
    return index * size, min((index + 1) * size, n_views)


def _trace_range(
    ctx: Context,
    part: Part,
    sensor: Sensor,
    views: Viewpoints,
    lo: int,
    hi: int,
    backend: RayBackend | None,
    progress: Callable[[int], None],
    tick: Callable[[], None] | None = None,
    split: Elements | None = None,
) -> Trace:
    """R of views [lo, hi), with trace_counts' `progress` and `tick` (of the elements `split`
    where given)."""
    subset = views.take(np.arange(lo, hi))
    threads = ctx.settings.threads
    return trace_counts(
        part,
        sensor,
        subset,
        backend=backend,
        threads=threads,
        progress=progress,
        tick=tick,
        elements=split,
    )


def chunk_job(
    mesh_id: str,
    trace_id: str,
    size: int,
    index: int,
    backend: str | None = None,
    element_mm2: float | None = None,
) -> dict[str, Any]:
    """Trace chunk `index` (views [index·size, (index+1)·size)) of `trace_id` into the store,
    with the ray backend the plan asked for, on the part's elements of at most `element_mm2`
    (mm²) where given (each is part of the trace id)."""
    body = partial(
        _chunk, mesh_id=mesh_id, size=size, index=index, backend=backend, element_mm2=element_mm2
    )
    return run_job(body, trace_id)


def _chunk(
    ctx: Context,
    trace_id: str,
    *,
    mesh_id: str,
    size: int,
    index: int,
    backend: str | None,
    element_mm2: float | None,
) -> dict[str, Any]:
    key = art.chunk_key(trace_id, size, index)
    if ctx.store.exists(key):
        return {"chunk": index, "cached": True}
    part = art.get_part(ctx.store, mesh_id)
    sensor, views, _ = art.get_views(ctx.store, trace_id)
    lo, hi = chunk_range(index, size, len(views))
    done = [0]

    def progress(n: int) -> None:
        done[0] += n
        ctx.meta.update(done=done[0])

    cell = art.get_cell(ctx.store, art.get_setup(ctx.store, trace_id))
    split = None if element_mm2 is None else elements(part, element_mm2)
    traced = split.part if split else part
    tracer = make_backend(traced, backend, scene_occluders(part, sensor, cell))
    trace = _trace_range(ctx, part, sensor, views, lo, hi, tracer, progress, None, split)
    ctx.store.put(key, art.trace_bytes(trace))
    ctx.meta.update(force=True, done=hi - lo)
    return {"chunk": index, "views": hi - lo, "rays_cast": trace.rays_cast}


def stage_progress(meta: _Meta) -> Any:
    """A vpp_core progress callback writing stage, done and total into the job's meta."""

    def progress(stage: str, done: int, total: int) -> None:
        meta.update(force=done == 0, stage=stage, done=done, total=total)

    return progress


class _Chunks:
    """The chunk jobs of one fan-out and what the plan job knows of them."""

    def __init__(
        self,
        ctx: Context,
        mesh_id: str,
        trace_id: str,
        n_views: int,
        size: int,
        backend: str,
        element_mm2: float | None = None,
    ) -> None:
        self.ctx, self.mesh_id, self.trace_id, self.backend = ctx, mesh_id, trace_id, backend
        self.element_mm2 = element_mm2
        self.n_views, self.size = n_views, size
        self.n = -(-n_views // size)
        self.worker = ctx.job.worker_name or "?"
        self.records: list[dict[str, Any]] = []
        for i in range(self.n):
            lo, hi = chunk_range(i, size, n_views)
            self.records.append({"index": i, "views": hi - lo, "status": "queued"})
        self.last_cleanup = self.last_watch = time.monotonic()
        self._enqueue()

    def _adoptable(self) -> dict[int, str]:
        """Chunk jobs of this plan job's previous attempt still queued, running or done."""
        old = self.ctx.job.meta.get("chunks", [])
        old = [r for r in old if r.get("job") and not r.get("taken_back") and r["index"] < self.n]
        jobs = Job.fetch_many([r["job"] for r in old], connection=self.ctx.job.connection)
        alive = {job.id for job in jobs if job is not None and job.get_status(False) in ADOPT}
        return {r["index"]: r["job"] for r in old if r["job"] in alive}

    def _enqueue(self) -> None:
        """Enqueue a job for every chunk not in the store yet (or adopt the previous attempt's),
        once the plan's records name them: a plan stopped between the two otherwise left
        queued chunks that no cancel's sweep (worker.queue.cancel) finds."""
        ctx, s = self.ctx, self.ctx.settings
        stored = [
            ctx.store.exists(art.chunk_key(self.trace_id, self.size, i)) for i in range(self.n)
        ]
        adopted = self._adoptable()
        token = f"{int(time.time() * 1000):x}"
        calls = []
        for i, rec in enumerate(self.records):
            if stored[i]:
                rec.update(status="succeeded", worker="store")
                continue
            if i in adopted:
                rec["job"] = adopted[i]
                continue
            rec["job"] = f"{ctx.job.id}-{token}-c{i:05d}"
            calls.append(
                Queue.prepare_data(
                    chunk_job,
                    (self.mesh_id, self.trace_id, self.size, i, self.backend, self.element_mm2),
                    job_id=rec["job"],
                    timeout=s.chunk_timeout_s,
                    result_ttl=s.result_ttl_s,
                    failure_ttl=s.failure_ttl_s,
                    description=f"trace chunk {i} of plan {ctx.job.id[:12]}",
                    retry=Retry(max=s.job_retries) if s.job_retries else None,
                )
            )
        self._publish(force=True)  # named first: a cancel's sweep finds every chunk queued
        if calls:
            ctx.queue.enqueue_many(calls)

    def take_back(self) -> int | None:
        """Index of a chunk taken back from the queue to trace here, or None if none is left."""
        for rec in self.records:
            if rec["status"] == "queued" and self.ctx.queue.remove(rec["job"]):
                rec.update(status="running", worker=self.worker, taken_back=True)
                self.taking = rec
                self._publish(force=True)
                return int(rec["index"])
        return None

    def own_progress(self, n: int) -> None:
        self.taking["done"] = self.taking.get("done", 0) + n
        self._publish()

    def taken_done(self, index: int) -> None:
        self.records[index].update(status="succeeded", done=self.records[index]["views"])
        delete_job(Job(self.records[index]["job"], connection=self.ctx.job.connection), False)
        self.watch()

    def watch_due(self) -> None:
        """`watch()` if WATCH_S have passed since the last look: a chunk that failed elsewhere
        stops the chunk traced here, not only the wait after it."""
        if time.monotonic() - self.last_watch >= WATCH_S:
            self.watch()

    def watch(self) -> None:
        """Refresh the chunks other workers run; raise VppError when one failed."""
        self.last_watch = time.monotonic()
        others = [r for r in self.records if r.get("job") and not r.get("taken_back")]
        others = [r for r in others if r["status"] not in ("succeeded",)]
        jobs = Job.fetch_many([r["job"] for r in others], connection=self.ctx.job.connection)
        for rec, job in zip(others, jobs, strict=True):
            self._update(rec, job)
        self._cleanup()
        self._publish()

    def _update(self, rec: dict[str, Any], job: Job | None) -> None:
        if job is None:
            raise VppError(f"ray-tracing chunk {rec['index']} vanished from the queue")
        status = job.get_status(refresh=False)
        if status in FAILED:
            rec["status"] = "failed"
            raise VppError(f"ray-tracing chunk {rec['index']} failed: {failure_reason(job)}")
        rec["worker"] = job.worker_name or rec.get("worker")
        rec["done"] = int(job.meta.get("done", 0))
        retries = self.ctx.settings.job_retries - (job.retries_left or 0)
        if job.retries_left is not None and retries:
            rec["retries"] = retries  # its worker died under it that many times
        if status == JobStatus.FINISHED:
            rec.update(status="succeeded", done=rec["views"])
        elif status == JobStatus.STARTED:
            rec["status"] = "running"
        elif status == JobStatus.QUEUED:  # put back after its worker died: may be taken back
            rec.update(status="queued", done=0)

    def _cleanup(self) -> None:
        """Retry or fail chunks of dead workers (their heartbeat expired) every `sweep_s`."""
        if time.monotonic() - self.last_cleanup > self.ctx.settings.sweep_s:
            self.ctx.queue.started_job_registry.cleanup()
            self.last_cleanup = time.monotonic()

    def all_done(self) -> bool:
        return all(r["status"] == "succeeded" for r in self.records)

    def _publish(self, force: bool = False) -> None:
        done = sum(int(r.get("done", 0)) for r in self.records)
        self.ctx.meta.update(
            force=force, stage="trace", done=done, total=self.n_views, chunks=self.records
        )


def connect(url: str) -> Redis:
    """A Redis client for `url` (redis://, rediss:// or unix://)."""
    return Redis.from_url(url)
