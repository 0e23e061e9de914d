"""Local worker processes: `python -m worker` subprocesses, started and stopped together, and
kept running (`WorkerPool`): one killed (SIGKILL, the OOM killer) is started again."""

from __future__ import annotations

import ctypes
import itertools
import os
import signal
import subprocess
import sys
import threading
from collections.abc import Mapping
from typing import IO

_serial = itertools.count()
PR_SET_PDEATHSIG = 1
"""prctl option: the signal a child gets when its parent dies."""
STOP_WAIT_S = 10.0
"""Seconds a worker gets to finish its warm shutdown before it is killed."""
PARENT_ENV = "VPP_PARENT_PID"
"""Environment variable through which `start_worker` tells a worker whose end to follow."""
CHECK_S = 1.0
"""Seconds between two looks of a WorkerPool at its processes (a dead one is replaced then)."""


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
    return [start_worker(url, f"{prefix}-{os.getpid()}-{i}", env, burst, log) for i in range(count)]


def start_worker(
    url: str, name: str, env: Mapping[str, str], burst: bool = False, log: IO[bytes] | None = None
) -> subprocess.Popen[bytes]:
    """One `python -m worker` process called `name`; it ends when this process does
    (`follow_parent`, set up by the worker itself: no `preexec_fn`, so the spawn is a vfork)."""
    cmd = [sys.executable, "-m", "worker", "--url", url, "--name", name]
    return subprocess.Popen(
        cmd + (["--burst"] if burst else []),
        env={**env, PARENT_ENV: str(os.getpid())},
        stdout=log,
        stderr=log and subprocess.STDOUT,
    )


WARM_NICE = 10
"""Niceness of the warming process: plans and requests first."""


def start_warming() -> subprocess.Popen[bytes]:
    """`warm_main` in a process of its own: numba's cache is filled while the service starts
    (not delaying readiness), so the first plan on a fresh install finds its kernels compiled or
    compiles them (stage `compiling`) alongside. It ends with this process, like a worker."""
    return subprocess.Popen(
        [sys.executable, "-c", "from worker.pool import warm_main; warm_main()"],
        env={**worker_env(1, 1), PARENT_ENV: str(os.getpid())},
        stdout=subprocess.DEVNULL,
        stderr=subprocess.DEVNULL,
    )


def warm_main() -> None:
    """The warming process: `python -m vpp_core.plan.warm`, niced, following its parent."""
    follow_parent()
    os.nice(WARM_NICE)
    from vpp_core.plan.warm import main

    raise SystemExit(main([]))


def stop_warming(proc: subprocess.Popen[bytes]) -> None:
    """End a warming process that is still running (its kernels are cached as each is done)."""
    if proc.poll() is None:
        proc.kill()
        proc.wait()


class WorkerPool:
    """`count` worker processes kept running: one that ends before `stop` is started again
    (under a new name) at the next `check`, unless it exits 0 in burst mode (its queue done).
    `watch()` checks every CHECK_S in a thread; `stop()` stops them all."""

    def __init__(
        self,
        url: str,
        count: int,
        threads: int | None = None,
        burst: bool = False,
        prefix: str = "vpp",
        log: IO[bytes] | None = None,
    ) -> None:
        self.url, self.burst, self.log = url, burst, log
        self.env = worker_env(count, threads)
        self.prefix = f"{prefix}-{os.getpid()}"
        self.lock = threading.Lock()
        self.stopping = threading.Event()
        self.procs = [self._start() for _ in range(count)]
        self.restarts = 0

    def _start(self) -> subprocess.Popen[bytes]:
        return start_worker(
            self.url, f"{self.prefix}-{next(_serial)}", self.env, self.burst, self.log
        )

    def check(self) -> bool:
        """Replace the workers that died; whether any worker runs."""
        with self.lock:
            for i, proc in enumerate(self.procs):
                code = proc.poll()  # 0 also when another waiter reaped it first (ECHILD)
                if (
                    code is not None
                    and (code != 0 or not self.burst)
                    and not self.stopping.is_set()
                ):
                    print(
                        f"vpp: worker {proc.pid} died ({code}); starting another",
                        file=sys.stderr,
                    )
                    self.procs[i] = self._start()
                    self.restarts += 1
            return any(p.poll() is None for p in self.procs)

    def wait(self) -> None:
        """Keep the workers running until all have exited 0 (or `stop`)."""
        while self.check() and not self.stopping.wait(CHECK_S):
            pass

    def watch(self) -> threading.Thread:
        """`wait` in a daemon thread (beside a server). The workers it starts again get SIGTERM
        when this thread ends (PR_SET_PDEATHSIG follows the thread): after `stop`, as meant."""
        thread = threading.Thread(target=self.wait, name="vpp-worker-pool", daemon=True)
        thread.start()
        return thread

    def stop(self, wait_s: float = STOP_WAIT_S) -> None:
        """Stop every worker (see `stop_workers`); none is started again."""
        self.stopping.set()
        with self.lock:
            stop_workers(self.procs, wait_s)


_PRCTL = ctypes.CDLL(None, use_errno=True).prctl if sys.platform.startswith("linux") else None
"""libc's prctl, looked up here: a dlopen between fork and exec can deadlock on the loader lock
that another thread of the parent held when it forked."""


def die_with_parent() -> None:
    """Linux: SIGTERM this process when its parent dies (a killed `vpp serve` leaves no
    workers). Safe as a `preexec_fn` (between fork and exec): it only calls the prctl found at
    import; workers call it after exec instead (`follow_parent`)."""
    if _PRCTL is not None:
        _PRCTL(PR_SET_PDEATHSIG, signal.SIGTERM)


def follow_parent() -> None:
    """In a worker that `start_worker` started: `die_with_parent`, and exit at once when that
    parent (PARENT_ENV) has already gone. Called first thing after exec."""
    parent = os.environ.get(PARENT_ENV)
    if parent is None:
        return
    die_with_parent()
    if os.getppid() != int(parent):
        raise SystemExit(f"vpp: the process that started this worker ({parent}) has gone")


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
