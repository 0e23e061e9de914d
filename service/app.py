"""The FastAPI application: routers, problem+json errors, body caps, Redis and store."""

from __future__ import annotations

import gc
from collections.abc import AsyncIterator
from contextlib import asynccontextmanager

from fastapi import FastAPI
from fastapi.routing import APIRoute
from fastapi.staticfiles import StaticFiles
from redis import Redis
from starlette.middleware.gzip import DEFAULT_EXCLUDED_CONTENT_TYPES, GZipMiddleware

from service import auth, fairuse, idempotency, problems
from service.limits import BodyLimits, JsonChecks
from service.requestid import RequestIds
from service.routers import health, jobs, meshes, metrics, plans, studies, viewer
from worker.queue import make_queue
from worker.settings import Settings, get_settings
from worker.store import open_store

API_VERSION = "1.0.0"
REDIS_TIMEOUT_S = 10
"""Socket timeouts of the API's Redis connection: a stuck Redis gives 503, not a hung request."""
GZIP_MIN_BYTES = 4096
"""Answers at least this long go gzipped (a job's JSON, ~1 KB, does not: polls stay cheap)."""
GZIP_LEVEL = 6
"""zlib level of those answers: most of level 9's gain at a fraction of its time."""


def _operation_id(route: APIRoute) -> str:
    """Clean operation ids for generated clients: the handler's name (upload_mesh, get_job...)."""
    return route.name


def _freeze_heap() -> None:
    """Take what is alive at startup (about 200 000 objects: numba, scipy, trimesh, the app)
    out of the cyclic collector's scans: each full collection walked them all in the event
    loop's thread, holding every request, `/livez` included, for about 0.1 s here."""
    gc.collect()
    gc.freeze()


def create_app(settings: Settings | None = None) -> FastAPI:
    """The API wired to the settings' Redis and store (settings read from VPP_* by default)."""
    settings = settings or get_settings()
    if not settings.redis_url:
        raise ValueError("the API needs VPP_REDIS_URL (`vpp serve` starts an embedded Redis)")

    @asynccontextmanager
    async def lifespan(app: FastAPI) -> AsyncIterator[None]:
        _freeze_heap()
        try:
            yield
        finally:
            gc.unfreeze()
            app.state.redis.close()

    app = FastAPI(
        title="vpp — inspection viewpoint planning",
        version=API_VERSION,
        description="Upload a part's mesh, ask for a plan, poll the job, fetch the plan (SPEC §6).",
        generate_unique_id_function=_operation_id,
        lifespan=lifespan,
        dependencies=[auth.BEARER],  # OpenAPI only; ApiKeys enforces it
    )
    conn = Redis.from_url(
        settings.redis_url,
        socket_connect_timeout=REDIS_TIMEOUT_S,
        socket_timeout=REDIS_TIMEOUT_S,
    )
    app.add_middleware(JsonChecks, settings=settings)  # innermost: JSON validated off the loop
    app.add_middleware(  # only requests the keys and the body cap let through
        idempotency.Idempotency,
        conn=conn,
        ttl_s=settings.idempotency_ttl_s,
        lock_s=settings.idempotency_lock_s,
    )
    app.add_middleware(BodyLimits, settings=settings)  # caps per route, 415, upload slots
    app.add_middleware(fairuse.FairUse, conn=conn, settings=settings)  # POST rate, bodies unread
    app.add_middleware(auth.ApiKeys, keys=settings.api_key_list())  # before bodies
    app.add_middleware(  # JSON and text gzipped for clients that take it (not SSE, PNG, PLY)
        GZipMiddleware,
        minimum_size=GZIP_MIN_BYTES,
        compresslevel=GZIP_LEVEL,
        exclude_content_types=(*DEFAULT_EXCLUDED_CONTENT_TYPES, "application/octet-stream"),
    )
    app.add_middleware(RequestIds)  # outermost: every answer has its X-Request-ID
    app.state.settings = settings
    app.state.redis = conn
    app.state.queue = make_queue(conn, settings)
    app.state.store = open_store(settings.store_url, conn, settings.s3_endpoint_url)
    problems.install(app)
    problems.extend_openapi(app, idempotency.document)
    for router in (meshes.router, plans.router, studies.router, jobs.router, health.router):
        app.include_router(router)
    app.include_router(metrics.router)
    app.include_router(viewer.router)
    app.mount("/static/viewer", StaticFiles(directory=viewer.STATIC_DIR), name="viewer-static")
    return app
