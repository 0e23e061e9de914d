"""HiGHS on a covering MIP, in a child process that is killed when it outlives its deadline.

HiGHS 1.16 does not always keep its time limit. At the root its MIP solver computes an
analytic centre with the interior point method, capped at 200 iterations but not in time, and
waits for it (HighsMipSolverData::startAnalyticCenterComputation); on dense or tall covers
that wait runs past the limit with no callback to interrupt it (scpclr13: 19 s of a 3.2 s
limit; window_cover(40000, 800): 3.8 s of 2 s). A process can be stopped where a thread
cannot: each calling thread keeps one child (started on first use, in about 0.4 s), sends it
the model and the deadline, and kills it when no answer has come GRACE_S + GRACE_SHARE of
the limit after the deadline. The caller then keeps what it had; the next call starts a new
child.
"""

from __future__ import annotations

import atexit
import logging
import math
import os
import resource
import signal
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Callable
from dataclasses import dataclass
from multiprocessing.connection import Connection
from pathlib import Path

import highspy
import numpy as np

from vpp_core.cover.lpbound import HighsOption, run_highs, silent_highs

log = logging.getLogger(__name__)

GRACE_S = 0.3
GRACE_SHARE = 0.05
"""A child still running GRACE_S + GRACE_SHARE · time_limit after its deadline is killed."""
MIP_FEAS_TOL = 1e-9
"""HiGHS's primal and MIP feasibility tolerances for the covering MIPs."""
_HIGHS_FEASIBLE = 2  # HiGHS kSolutionStatusFeasible
_OBJ_TOL = 1e-6
"""Relative slack between HiGHS's reported objective and its solution's cost."""


@dataclass(frozen=True)
class MipAnswer:
    """What HiGHS returned: its best solution, model status and dual bound."""

    x: np.ndarray | None  # (N,) column values, None without a feasible solution
    status: highspy.HighsModelStatus
    dual_bound: float  # -inf when HiGHS gave none


NO_ANSWER = MipAnswer(None, highspy.HighsModelStatus.kNotset, -math.inf)
"""No solution, no status, no bound: HiGHS gave nothing, or was stopped unheard."""
TIMED_OUT = MipAnswer(None, highspy.HighsModelStatus.kTimeLimit, -math.inf)
"""No solution, no bound, out of time: HiGHS was stopped at its wall, or never started."""


def solve_mip(
    build: Callable[[], highspy.HighsLp],
    start: np.ndarray | None,
    time_limit: float,
    mip_rel_gap: float,
    threads: int | None,
) -> MipAnswer:
    """HiGHS on the MIP `build()` (a picklable callable, run in the child), warm-started at
    column values `start` (N,) when given, within `time_limit` s (a hard wall, see above)."""
    with submit(build, start, time_limit, mip_rel_gap, threads) as run:
        return run.answer()


@dataclass
class Pending:
    """A HiGHS run under way in this thread's child; `answer()` waits for it, up to its wall.

    Used as a context manager: leaving it without the answer (an exception, or no call)
    stops the child, so that its answer cannot reach the next call.
    """

    child: _Child | None  # None: the run could not be sent
    wall: float  # time.monotonic() after which the child is killed
    time_limit: float

    def ready(self) -> bool:
        """Whether the answer is in (or none can come)."""
        try:
            return self.child is None or self.child.conn.poll(0)
        except (EOFError, OSError):
            return True

    def answer(self) -> MipAnswer:
        """HiGHS's answer, or none (status kTimeLimit when it outlived its wall)."""
        child, self.child = self.child, None
        if child is None:
            return NO_ANSWER
        try:
            came = child.conn.poll(max(self.wall - time.monotonic(), 0.0))
            if came:
                reply: MipAnswer | Exception
                reply, rss_kib = child.conn.recv()
        except (EOFError, OSError) as exc:  # the child died: killed for memory, or crashed
            log.warning("the HiGHS process ended without an answer (%s)", exc)
            _retire(child)
            return NO_ANSWER
        except BaseException:  # interrupted here: its answer must not reach the next call
            _retire(child)
            raise
        if not came:
            log.warning("HiGHS ran past its %.1f s time limit and was stopped", self.time_limit)
            _retire(child)
            return TIMED_OUT
        _peak_kib[0] = max(_peak_kib[0], rss_kib)
        if isinstance(reply, Exception):  # raised in the child, which stays usable
            raise reply
        return reply

    def __enter__(self) -> Pending:
        return self

    def __exit__(self, *exc: object) -> None:
        if self.child is not None:
            _retire(self.child)
            self.child = None


def submit(
    build: Callable[[], highspy.HighsLp],
    start: np.ndarray | None,
    time_limit: float,
    mip_rel_gap: float,
    threads: int | None,
) -> Pending:
    """Start HiGHS on the MIP `build()` in this thread's child (see `solve_mip`); the caller
    may work meanwhile, on another core."""
    deadline = time.monotonic() + time_limit
    wall = deadline + max(time_limit, 0.0) * GRACE_SHARE + GRACE_S
    child = _child()
    try:
        child.conn.send((build, start, deadline, mip_rel_gap, threads))
    except (EOFError, OSError) as exc:  # the child died: killed for memory, or crashed
        log.warning("the HiGHS process ended without an answer (%s)", exc)
        _retire(child)
        return Pending(None, wall, time_limit)
    except BaseException:
        _retire(child)
        raise
    return Pending(child, wall, time_limit)


def solve_here(
    model: highspy.HighsLp,
    start: np.ndarray | None,
    time_limit: float,
    mip_rel_gap: float,
    threads: int | None,
) -> MipAnswer:
    """HiGHS on the MIP `model` in this process, warm-started at `start` (N,) when given.

    HiGHS 1.16 can answer a warm-started run with "optimal" at an objective that the solution
    it hands back does not have (it returns the start instead). Such an answer is dropped and
    HiGHS runs again, cold, in the time that is left; a second one gives no answer.
    """
    deadline = time.perf_counter() + time_limit
    h = _mip_highs(model, time_limit, mip_rel_gap, threads)
    if start is not None:
        warm = highspy.HighsSolution()
        warm.col_value = np.asarray(start, dtype=np.float64).tolist()
        warm.value_valid = True
        run_highs(h, threads, lambda: h.setSolution(warm))
        answer = _answer(h)
        if not _contradicts(answer, h, model):
            return answer
        h = _mip_highs(model, deadline - time.perf_counter(), mip_rel_gap, threads)
    run_highs(h, threads)
    answer = _answer(h)
    return NO_ANSWER if _contradicts(answer, h, model) else answer


def _answer(h: highspy.Highs) -> MipAnswer:
    """The solution, status and dual bound of a HiGHS instance that has run."""
    x = None
    if h.getInfo().primal_solution_status == _HIGHS_FEASIBLE:
        x = np.asarray(h.getSolution().col_value, dtype=np.float64)
    bound = float(h.getInfo().mip_dual_bound)
    return MipAnswer(x, h.getModelStatus(), bound if math.isfinite(bound) else -math.inf)


def _mip_highs(
    model: highspy.HighsLp, time_limit: float, mip_rel_gap: float, threads: int | None
) -> highspy.Highs:
    """A silent HiGHS instance holding `model`, with the MIP options set."""
    options: dict[str, HighsOption] = {
        "time_limit": max(float(time_limit), 0.01),
        "mip_rel_gap": float(mip_rel_gap),
        "primal_feasibility_tolerance": MIP_FEAS_TOL,
        "mip_feasibility_tolerance": MIP_FEAS_TOL,
    }
    h = silent_highs(options, threads)
    h.passModel(model)
    return h


def _contradicts(answer: MipAnswer, h: highspy.Highs, model: highspy.HighsLp) -> bool:
    """HiGHS says "optimal", but the solution it returns costs more than its objective."""
    if answer.status != highspy.HighsModelStatus.kOptimal or answer.x is None:
        return False
    cost = float(np.dot(np.asarray(model.col_cost_), answer.x))
    claimed = float(h.getInfo().objective_function_value)
    return cost > claimed + _OBJ_TOL * max(1.0, abs(claimed))


# ---------------------------------------------------------------------------- the child


@dataclass
class _Child:
    """A child process serving solve_here over `conn`."""

    proc: subprocess.Popen[bytes]
    conn: Connection


_children: dict[int, _Child] = {}  # by the ident of the thread that uses it
_lock = threading.Lock()
_peak_kib = [0]  # the largest peak resident set size a child has reported


def child_peak_rss_mib() -> float:
    """The largest peak resident memory (MiB) any HiGHS child of this process reported."""
    return _peak_kib[0] / 1024.0


def warm() -> None:
    """Start this thread's child now, so that its imports overlap the caller's own work."""
    _child()


def _child() -> _Child:
    """This thread's child, started if it has none (children of ended threads are stopped)."""
    with _lock:
        alive = {t.ident for t in threading.enumerate()}
        for ident in [i for i in _children if i not in alive]:
            _stop(_children.pop(ident))
        me = threading.get_ident()
        if me not in _children or _children[me].proc.poll() is not None:
            _children[me] = _start()
        return _children[me]


def _start() -> _Child:
    """A new child: `python -c` serving on one end of a socket pair."""
    ours, theirs = socket.socketpair()
    env = dict(os.environ)
    root = str(Path(__file__).resolve().parents[1])  # vpp_core importable without an install
    env["PYTHONPATH"] = os.pathsep.join(p for p in (root, env.get("PYTHONPATH")) if p)
    code = f"from vpp_core.cover.mip import _serve; _serve({theirs.fileno()})"
    proc = subprocess.Popen(
        [sys.executable, "-c", code], pass_fds=[theirs.fileno()], stdin=subprocess.DEVNULL, env=env
    )
    theirs.close()
    return _Child(proc, Connection(ours.detach()))


def _retire(child: _Child) -> None:
    """Kill `child` and forget it (its thread gets a new one on its next call)."""
    with _lock:
        for ident in [i for i, c in _children.items() if c is child]:
            del _children[ident]
    _stop(child)


def _stop(child: _Child) -> None:
    """Kill and reap a child, and close its connection."""
    child.conn.close()
    child.proc.kill()
    child.proc.wait()


def _forget_after_fork() -> None:
    """In a forked process the parent's children are not ours: close our ends, kill nothing."""
    global _lock
    for child in _children.values():
        child.conn.close()
    _children.clear()
    _lock = threading.Lock()


def _stop_all() -> None:
    """At exit: stop every child (they would end on their own, a little later)."""
    with _lock:
        for child in _children.values():
            _stop(child)
        _children.clear()


os.register_at_fork(after_in_child=_forget_after_fork)
atexit.register(_stop_all)


def _serve(fd: int) -> None:
    """The child's loop: (build, start, deadline, gap, threads) in; (MipAnswer or error, peak
    RSS in KiB) out."""
    # C-level prints go nowhere: stdout is the caller's. HiGHS's banner, which it prints on a
    # process's first Highs(), is the caller's to show, once (lpbound.silent_highs), not again
    # from each child: that first Highs() is made here
    null = os.open(os.devnull, os.O_WRONLY)
    os.dup2(null, 1)
    os.close(null)
    highspy.Highs()  # type: ignore[no-untyped-call]
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    parent = os.getppid()
    threading.Thread(target=_exit_with, args=(parent,), daemon=True).start()
    conn = Connection(fd)
    while True:
        try:
            build, start, deadline, gap, threads = conn.recv()
        except EOFError:
            return
        try:
            reply: MipAnswer | Exception = solve_here(
                build(), start, deadline - time.monotonic(), gap, threads
            )
        except Exception as exc:  # noqa: BLE001 - handed to the caller, who raises it
            reply = exc
        conn.send((reply, resource.getrusage(resource.RUSAGE_SELF).ru_maxrss))


def _exit_with(parent: int) -> None:
    """End this process once `parent` has (HiGHS releases the GIL while it runs)."""
    while os.getppid() == parent:
        time.sleep(0.5)
    os._exit(0)
