"""`vpp serve` and `vpp worker`: the service's processes."""

from __future__ import annotations

import argparse
import signal
import sys
from contextlib import ExitStack
from types import FrameType

import uvicorn

from service.app import create_app
from vpp_core.errors import VppError
from worker import logs
from worker.embedded import EmbeddedRedis
from worker.pool import WorkerPool, start_warming, stop_warming
from worker.settings import get_settings


def run_serve(args: argparse.Namespace) -> int:
    """The API; without VPP_REDIS_URL also an embedded Redis and local workers."""
    settings = get_settings()
    with ExitStack() as stack:
        url, note = settings.redis_url, "API only: workers run with `vpp worker`"
        if not url:
            redis = stack.enter_context(EmbeddedRedis())
            redis.watch()  # a killed embedded Redis is started again (empty)
            count = args.workers or settings.workers
            pool = WorkerPool(redis.url, count, settings.threads)
            pool.watch()  # a worker killed (OOM) is started again
            stack.callback(pool.stop)
            stack.callback(stop_warming, start_warming())
            url, note = redis.url, f"embedded Redis, {count} local workers"
        app = create_app(settings.model_copy(update={"redis_url": url}))
        print(
            f"vpp serve: http://{args.host}:{args.port}  ({note}; store {app.state.store.url})",
            file=sys.stderr,
        )
        # uvicorn re-raises SIGTERM after its graceful shutdown: make that an exit that
        # unwinds the stack (workers stopped, embedded Redis shut down), not a sudden death
        signal.signal(signal.SIGTERM, _exit)
        logs.configure(settings.log_format)  # uvicorn's lines too: it configures none
        uvicorn.run(app, host=args.host, port=args.port, log_config=None, access_log=False)
    return 0


def _exit(signum: int, frame: FrameType | None) -> None:
    sys.exit(0)


def run_workers(args: argparse.Namespace) -> int:
    """Worker processes on a shared Redis, kept running, until SIGTERM/SIGINT (or until idle
    with --burst)."""
    settings = get_settings()
    url = args.url or settings.redis_url
    if not url:
        raise VppError("no Redis to work for: set VPP_REDIS_URL or pass --url")
    pool = WorkerPool(url, args.workers or settings.workers, settings.threads, args.burst)
    warming = start_warming()

    def stop(signum: int, frame: FrameType | None) -> None:
        stop_warming(warming)
        pool.stop()
        sys.exit(0)

    signal.signal(signal.SIGTERM, stop)
    try:
        pool.wait()  # a worker killed (OOM) or failing is started again; --burst: until done
    except KeyboardInterrupt:
        pool.stop()
        return 130
    finally:
        stop_warming(warming)
    return 0
