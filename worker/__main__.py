"""`python -m worker --url REDIS_URL [--burst]`: one RQ worker, numerical stack preloaded."""

from __future__ import annotations

import argparse
import logging
import os

# Before numpy loads: one BLAS thread per process (a spinning helper thread slows forked horses).
for _var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
    os.environ.setdefault(_var, "1")

import embreex.rtcore_scene  # noqa: E402,F401  (preloaded: each forked horse reuses them)
import highspy  # noqa: E402,F401
import numpy  # noqa: E402,F401
import scipy.sparse  # noqa: E402,F401
import trimesh  # noqa: E402,F401
from rq import Queue, Worker  # noqa: E402

import worker.jobs  # noqa: E402,F401
from worker.jobs import connect  # noqa: E402
from worker.settings import get_settings  # noqa: E402

MAINTENANCE_S = 60
"""How often a worker sweeps for jobs of dead workers (RQ's default is 10 min)."""


def main(argv: list[str] | None = None) -> None:
    """Run one worker on the plan queue until stopped (or until empty with --burst)."""
    parser = argparse.ArgumentParser(prog="python -m worker")
    parser.add_argument("--url", help="Redis URL (default: VPP_REDIS_URL)")
    parser.add_argument("--name", help="worker name (default: RQ's)")
    parser.add_argument("--burst", action="store_true", help="exit when the queue is empty")
    args = parser.parse_args(argv)
    settings = get_settings()
    url = args.url or settings.redis_url
    if not url:
        parser.error("no Redis: pass --url or set VPP_REDIS_URL")
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(name)s %(message)s")
    conn = connect(url)
    queue = Queue(settings.queue, connection=conn)
    Worker([queue], connection=conn, name=args.name, maintenance_interval=MAINTENANCE_S).work(
        burst=args.burst, with_scheduler=False
    )


if __name__ == "__main__":
    main()
