"""Local worker processes: `python -m worker` subprocesses, started and stopped together."""

from __future__ import annotations

import ctypes
import itertools
import os
import signal
import subprocess
import sys
from collections.abc import Mapping
from typing import IO

_serial = itertools.count()
PR_SET_PDEATHSIG = 1
"""prctl option: the signal a child gets when its parent dies."""
STOP_WAIT_S = 10.0
"""Seconds a worker gets to finish its warm shutdown before it is killed."""


def worker_env(workers: int, threads: int | None, extra: Mapping[str, str] = {}) -> dict[str, str]:
    """Environment of a worker: one BLAS thread, and the cores shared among the workers."""
    env = {**os.environ, **extra}
    for var in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS", "MKL_NUM_THREADS"):
        env[var] = "1"
    cores = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    env["VPP_THREADS"] = str(threads or max(1, (cores or 1) // workers))
    return env


def start_workers(
    url: str,
    count: int,
    threads: int | None = None,
    burst: bool = False,
    prefix: str = "vpp",
    log: IO[bytes] | None = None,
) -> list[subprocess.Popen[bytes]]:
    """Start `count` worker processes on the queue at `url`; their output to `log` if given."""
    env = worker_env(count, threads)
    procs = []
    for i in range(count):
        cmd = [
            sys.executable,
            "-m",
            "worker",
            "--url",
            url,
            "--name",
            f"{prefix}-{os.getpid()}-{i}",
        ]
        args = cmd + (["--burst"] if burst else [])
        procs.append(
            subprocess.Popen(
                args,
                env=env,
                stdout=log,
                stderr=log and subprocess.STDOUT,
                preexec_fn=die_with_parent,
            )
        )
    return procs


def die_with_parent() -> None:
    """Linux: SIGTERM this child when its parent dies (a killed `vpp serve` leaves no workers)."""
    if sys.platform.startswith("linux"):
        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(PR_SET_PDEATHSIG, signal.SIGTERM)


def stop_workers(procs: list[subprocess.Popen[bytes]], wait_s: float = STOP_WAIT_S) -> None:
    """SIGTERM (RQ's warm shutdown: the job in hand finishes); after `wait_s` a second SIGTERM
    (cold shutdown: the work horse is killed, the job fails), then SIGKILL."""
    for sig_wait in ((signal.SIGTERM, wait_s), (signal.SIGTERM, wait_s / 2), (signal.SIGKILL, 5)):
        alive = [p for p in procs if p.poll() is None]
        for p in alive:
            p.send_signal(sig_wait[0])
        for p in alive:
            try:
                p.wait(sig_wait[1])
            except subprocess.TimeoutExpired:
                pass
