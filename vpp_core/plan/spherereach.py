"""View-sphere candidates where the generated ones reach nothing (SPEC §2 amended: the pool
must reach what views on a sphere around the part reach).

The generator aims its cameras at surface samples, along tilted normals; a surface seen only
through a window in a housing, a gap between gears or past a web may be sampled by none of
them. Here `count` viewpoints on view spheres (vpp_core.candidates.sphere: around the part's
box centre, looking at it) are traced, and only those that sample rows no candidate of the pool
samples join it: greedily, the one sampling the most such weight (area that can be sampled,
CoverModel.row_weights) first, while a view adds at least a median row's area. The pool then
reaches what the sphere reaches with few extra columns. Views that only see what the pool
already samples stay out, since each extra candidate can make a patch ask for more of itself
(vpp_core.plan.adaptive); so do views adding less than a row: on the gearbox stand-in
(bench/synthetic.py) 43 views each adding 0.1-11 mm² of inner gears seen through gaps, 127 mm²
in all (0.14 % of the weight), took its plan from 155 views to 185, while on the windowed
one a handful add 100-500 mm² each (docs/quality.md).
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import scipy.sparse as sp

from vpp_core.camera.pose import Viewpoints
from vpp_core.camera.sensor import Sensor
from vpp_core.candidates.sphere import view_sphere
from vpp_core.cell.reach import Allowed
from vpp_core.cover.density import CoverModel
from vpp_core.mesh.part import Part
from vpp_core.plan.adaptive import Model, Tracer
from vpp_core.trace.raytrace import Trace, join_traces


@dataclass(frozen=True)
class Reached:
    """The pool with the sphere views that reach new rows appended, and how many were."""

    views: Viewpoints
    trace: Trace
    added: int
    traced: int


def sphere_reach(
    part: Part,
    sensor: Sensor,
    views: Viewpoints,
    trace: Trace,
    count: int,
    model_of: Model,
    trace_of: Tracer,
    *,
    allowed: Allowed | None = None,
    keep: Callable[[Viewpoints], Viewpoints] | None = None,
    deadline: float = float("inf"),
) -> Reached:
    """`views` (R in `trace`) with those of `count` view-sphere viewpoints around `part` that
    sample rows the pool does not (see module docstring); cameras only where `allowed` lets them
    be and `keep` keeps them; none when their tracing, at the pool's rate, would end after
    `deadline` (time.perf_counter() seconds)."""
    unchanged = Reached(views, trace, 0, 0)
    if count < 1 or time.perf_counter() + trace.seconds / max(len(views), 1) * count > deadline:
        return unchanged
    sphere = view_sphere(part, sensor, count, allowed=allowed)
    sphere = sphere if keep is None else keep(sphere)
    if not len(sphere):
        return unchanged
    traced = trace_of(sphere)
    joined = join_traces([trace, traced], trace.seconds + traced.seconds)
    chosen = new_reach(model_of(views.then(sphere), joined), len(views))
    if not len(chosen):
        return Reached(views, trace, 0, len(sphere))
    taken = join_traces([trace, columns(traced, chosen)], joined.seconds)
    return Reached(views.then(sphere.take(chosen)), taken, len(chosen), len(sphere))


def new_reach(model: CoverModel, n_before: int) -> np.ndarray:
    """Ascending ids (from 0, among the columns after the first `n_before`) of `model`'s new
    columns chosen greedily by the weight (mm²) they sample of the rows that none of the first
    `n_before` columns samples, while the next one adds at least a median row's area."""
    rows = model.matrix.shape[0]
    csc = sp.csc_array(model.matrix > 0, dtype=np.float64)
    known = np.zeros(rows, dtype=bool)
    known[csc.indices[: csc.indptr[n_before]]] = True
    weight = np.where(known, 0.0, model.row_weights())
    least = max(float(np.median(model.row_areas())), 1e-12) if rows else np.inf
    sampled = csc[:, n_before:]
    chosen: list[int] = []
    while sampled.shape[1]:  # ends: a chosen column's gain drops to 0 < least
        gain = sampled.T @ weight
        best = int(np.argmax(gain))
        if gain[best] < least:
            break
        chosen.append(best)
        weight[sampled.indices[sampled.indptr[best] : sampled.indptr[best + 1]]] = 0.0
    return np.sort(np.asarray(chosen, dtype=np.int64))


def columns(trace: Trace, idx: np.ndarray) -> Trace:
    """R of the views `idx` of `trace`; its rays, pixels and seconds stay those of the whole
    trace (the work done to find them)."""
    elements = None if trace.elements is None else sp.csc_array(trace.elements[:, idx])
    return replace(trace, counts=sp.csc_array(trace.counts[:, idx]), elements=elements)
