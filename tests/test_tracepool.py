"""The tracing thread pool outlives a trace: reused, safe after a fork, usable after an error."""

from __future__ import annotations

import os
import pickle
import select
import signal

import numpy as np
import pytest

from tests.conftest import plate_part
from vpp_core.pose import make_viewpoints
from vpp_core.raytrace import trace_counts
from vpp_core.sensor import Sensor

PAPER = Sensor()


def _views(n: int):
    """n cameras above the plate at slightly different heights, looking down."""
    pos = np.array([[0.0, 0.0, 450.0 + 10 * k] for k in range(n)])
    return make_viewpoints(pos, np.tile([0.0, 0.0, -1.0], (n, 1)))


def _in_child(fn, timeout_s: float = 60.0):
    """fn() run in a forked child, its pickled result back; fails (not hangs) on a timeout."""
    read, write = os.pipe()
    pid = os.fork()
    if pid == 0:  # pragma: no cover - the child
        os.close(read)
        try:
            os.write(write, pickle.dumps(fn()))
        finally:
            os._exit(0)
    os.close(write)
    try:
        ready, _, _ = select.select([read], [], [], timeout_s)
        if not ready:
            os.kill(pid, signal.SIGKILL)
            pytest.fail(f"the forked child did not finish its trace in {timeout_s:g} s")
        data = b"".join(iter(lambda: os.read(read, 1 << 16), b""))
    finally:
        os.close(read)
        os.waitpid(pid, 0)
    return pickle.loads(data)


def test_a_forked_child_traces_after_its_parent_did():
    part, views = plate_part(side=20.0, n=8), _views(3)
    parent = trace_counts(part, PAPER, views, threads=2).counts
    child = _in_child(lambda: trace_counts(part, PAPER, views, threads=2).counts.toarray())
    assert parent.sum() > 0 and (child == parent.toarray()).all()


def test_an_error_in_the_caller_leaves_the_pool_usable():
    part, views = plate_part(side=20.0, n=8), _views(12)

    def stop(done: int) -> None:
        raise KeyboardInterrupt("cancelled")

    with pytest.raises(KeyboardInterrupt):
        trace_counts(part, PAPER, views, threads=2, progress=stop)
    again = trace_counts(part, PAPER, views, threads=2).counts
    for j in range(12):
        alone = trace_counts(part, PAPER, views.take(np.array([j])), threads=1).counts
        assert (again[:, [j]] != alone).nnz == 0
