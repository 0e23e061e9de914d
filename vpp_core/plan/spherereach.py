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

The sphere views are scouted at 1/SCOUT_SCALE of the sensor's width and height (its rays
counted as the full image's, SCOUT_SCALE² each), and only those that join are traced again at
full resolution: the stage costs about a quarter of tracing them whole, so that it fits the
budget of a slower machine after a large part's trace (docs/quality.md).
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
from vpp_core.plan.adaptive import Model
from vpp_core.trace.raytrace import Trace, join_traces

SCOUT_SCALE = 2
"""The sphere views are first traced with this many times fewer pixels across."""

TraceAt = Callable[[Viewpoints, Sensor], Trace]
"""trace_at(views, sensor) -> R of `views` through `sensor`, as the pool's was traced."""


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
    trace_at: TraceAt,
    *,
    allowed: Allowed | None = None,
    keep: Callable[[Viewpoints], Viewpoints] | None = None,
    deadline: float = float("inf"),
    fit_roll: bool = False,
) -> Reached:
    """`views` (R in `trace`, through `sensor`) with those of `count` view-sphere viewpoints
    around `part` that sample rows the pool does not (see module docstring), scouted through
    `scout_sensor(sensor)`; cameras only where `allowed` lets them be and `keep` keeps them;
    none when their scouting, at the pool's rate per pixel, would end after `deadline`
    (time.perf_counter() seconds); with `fit_roll` the cameras are turned as the generator's
    (vpp_core.candidates.roll)."""
    unchanged = Reached(views, trace, 0, 0)
    scout = scout_sensor(sensor)
    factor = sensor.n_pixels / scout.n_pixels  # full-image rays per scout ray
    per_view = trace.seconds / max(len(views), 1) / factor
    if count < 1 or time.perf_counter() + per_view * count > deadline:
        return unchanged
    sphere = view_sphere(part, sensor, count, allowed=allowed, fit_roll=fit_roll)
    sphere = sphere if keep is None else keep(sphere)
    if not len(sphere):
        return unchanged
    scouted = as_full_image(trace_at(sphere, scout), factor)
    seconds = trace.seconds + scouted.seconds
    pooled = join_traces([trace, scouted], seconds)
    chosen = new_reach(model_of(views.then(sphere), pooled), len(views))
    if not len(chosen):
        return Reached(views, trace, 0, len(sphere))
    joined = sphere.take(chosen)
    traced = trace_at(joined, sensor)
    taken = join_traces([trace, traced], seconds + traced.seconds)
    return Reached(views.then(joined), taken, len(chosen), len(sphere))


def scout_sensor(sensor: Sensor) -> Sensor:
    """`sensor` with SCOUT_SCALE times fewer pixels along each side, the same field of view
    and depth of field."""
    width = max(1, sensor.width_px // SCOUT_SCALE)
    height = max(1, sensor.height_px // SCOUT_SCALE)
    return sensor.model_copy(update={"width_px": width, "height_px": height})


def as_full_image(trace: Trace, factor: float) -> Trace:
    """R of a scout `trace` counted as the full image's: each ray stands for `factor` rays
    (the ratio of the two images' pixels)."""

    def scaled(r: sp.csc_array) -> sp.csc_array:
        return sp.csc_array(
            (np.rint(r.data * factor).astype(np.int32), r.indices, r.indptr), shape=r.shape
        )

    elements = None if trace.elements is None else scaled(trace.elements)
    return replace(trace, counts=scaled(trace.counts), elements=elements)


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
