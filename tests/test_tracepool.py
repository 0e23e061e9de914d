"""The tracing thread pool outlives a trace: reused, safe after a fork, usable after an error."""

from __future__ import annotations

import multiprocessing

import numpy as np
import pytest

from tests.conftest import look_down, plate_part
from vpp_core.camera.sensor import Sensor
from vpp_core.trace.raytrace import ORDER_VIEWS_PER_THREAD, make_backend, trace_counts

PAPER = Sensor()


def _views(n: int):
    """n cameras above the plate at slightly different heights, looking down."""
    return look_down(*[(0.0, 0.0, 450.0 + 10 * k) for k in range(n)])


def _plate_counts() -> np.ndarray:
    """R (dense) of a plate seen by 3 views, on 2 threads."""
    return trace_counts(plate_part(side=20.0, n=8), PAPER, _views(3), threads=2).counts.toarray()


def test_a_forked_child_traces_after_its_parent_did():
    parent = _plate_counts()  # this process's pool is running before the fork
    with multiprocessing.get_context("fork").Pool(1) as pool:
        child = pool.apply_async(_plate_counts).get(timeout=60)  # the parent's threads: a hang
    assert parent.sum() > 0 and (child == parent).all()


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


def test_tick_comes_before_the_first_view_is_done_and_can_stop_the_trace():
    # the plan job's look at the other chunks: it must not wait for a whole view
    part, views = plate_part(side=20.0, n=8), _views(4)
    seen: list[int] = []

    def tick() -> None:
        raise KeyboardInterrupt("a chunk failed elsewhere")

    with pytest.raises(KeyboardInterrupt):
        trace_counts(part, PAPER, views, threads=2, progress=seen.append, tick=tick)
    assert seen == []  # stopped at the first block, before any view was finished
    ticks: list[None] = []
    trace_counts(
        part, PAPER, views, threads=2, progress=seen.append, tick=lambda: ticks.append(None)
    )
    assert sum(seen) == 4 and len(ticks) >= 4


@pytest.mark.parametrize("backend", ["raster", "packets", "embree"])
def test_a_view_outside_the_depth_range_sees_nothing(backend: str) -> None:
    # the plate fills the frame (several blocks of rays) from 100 and 900 mm, outside the
    # paper camera's 300-700 mm: no ray is valid. packets raised IndexError merging the blocks
    part = plate_part(side=300.0, n=8)
    views = look_down((0.0, 0.0, 100.0), (0.0, 0.0, 450.0), (0.0, 0.0, 900.0))
    trace = trace_counts(part, PAPER, views, backend=make_backend(part, backend), threads=2)
    seen = np.diff(trace.counts.indptr)  # faces seen per view
    assert seen[0] == seen[2] == 0 and seen[1] > 0


def test_views_are_done_as_the_trace_goes_not_at_its_end():
    # tasks go out largest first within groups of views: over all 40 views at once, the
    # views' last (smaller) blocks came after all full ones, and one view was done by then
    part, views = plate_part(side=300.0, n=8), _views(40)
    backend = make_backend(part, "packets")
    blocks, done_at = [0], []  # blocks traced when each view was done

    def tick() -> None:
        blocks[0] += 1

    trace_counts(
        part,
        PAPER,
        views,
        backend=backend,
        threads=2,
        tick=tick,
        progress=lambda n: done_at.extend([blocks[0]] * n),
    )
    assert blocks[0] > 4 * len(views) and len(done_at) == len(views)  # views of several blocks
    halfway = sum(b <= blocks[0] / 2 for b in done_at)
    assert halfway >= min(ORDER_VIEWS_PER_THREAD * 2, len(views) // 4), done_at
