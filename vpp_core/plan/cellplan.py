"""The setup in a plan (issue 35): its ray backend, its camera predicate, and what the plan
document says about it (the setup echoed, cell-frame poses, the faces the setup hides).

`setup_occluded` (docs/cell.md) is the uncoverable faces (no candidate's valid ray hits
them, with the floor and fixtures in the scene) that either touch the setup (a vertex within
CONTACT_MM of the floor plane or of a fixture's surface) or that some candidate's valid ray
hits when the floor and fixtures are taken away (same candidates, same sensor, part alone).
"""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp

from vpp_core.camera.pose import Viewpoints
from vpp_core.camera.sensor import Sensor
from vpp_core.cell.geometry import Cell, resolve
from vpp_core.cell.reach import Allowed, check_viewpoints, predicate
from vpp_core.cell.scene import Occluders, occluders, touching
from vpp_core.mesh.part import Part
from vpp_core.plan.document import CellPose, PlanDocument, PlanRequest, SetupOccluded
from vpp_core.trace.rays import RayBackend
from vpp_core.trace.raytrace import Trace, hull_points, make_backend, trace_counts


def cell_of(request: PlanRequest, cell: Cell | None = None) -> Cell | None:
    """The resolved setup: `cell` when given, else the request's (SetupError when it names
    meshes, which only the shells can read)."""
    return cell if cell is not None else resolve(request.setup)


def setup_backend(
    part: Part, request: PlanRequest, cell: Cell | None, name: str | None = None
) -> RayBackend:
    """The ray backend `name` (default the request's) over the part and the setup's floor
    and fixtures."""
    return make_backend(part, name or request.backend, scene_occluders(part, request.sensor, cell))


def scene_occluders(part: Part, sensor: Sensor, cell: Cell | None) -> Occluders | None:
    """The setup's floor and fixtures in the part frame, the floor reaching past anything a
    ray of `sensor` or of the diagnostics (4 part diagonals) can reach."""
    diagonal = float(np.linalg.norm(np.ptp(part.vertices, axis=0)))
    return occluders(cell, part.vertices, sensor.far_mm + 4 * diagonal + 1.0)


def allowed(cell: Cell | None) -> Allowed | None:
    """The setup's camera predicate (None: anywhere)."""
    return predicate(cell)


def check_explicit(cell: Cell | None, views: Viewpoints) -> None:
    """ViewpointError when an explicit viewpoint stands where the setup forbids."""
    check_viewpoints(cell, views.positions)


def annotate(
    doc: PlanDocument,
    part: Part,
    request: PlanRequest,
    cell: Cell | None,
    views: Viewpoints,
    trace: Trace,
    threads: int | None = None,
) -> None:
    """Fill doc.setup, each viewpoint's cell pose and doc.setup_occluded (no setup: none)."""
    if cell is None:
        return
    doc.setup = cell.setup
    m = cell.part_to_cell
    for v in doc.viewpoints:
        c2w = m @ np.asarray(v.camera_to_world)
        v.cell = CellPose(
            position=cell.to_cell(np.asarray(v.position))[0].tolist(),
            gaze=cell.rotate_to_cell(np.asarray(v.gaze))[0].tolist(),
            up=cell.rotate_to_cell(np.asarray(v.up))[0].tolist(),
            camera_to_world=c2w.tolist(),
        )
    ids = np.asarray(doc.uncoverable.ids, dtype=np.int64)
    touch = touching(cell, part.vertices, part.faces, ids)
    blocked = np.zeros(len(ids), dtype=bool)
    rest = ids[~touch]
    if len(rest) and len(views) and (cell.fixtures or cell.setup.floor is not None):
        plain = make_backend(part, trace.backend)
        hull = hull_points(part.vertices[np.unique(part.faces[rest])])
        free = trace_counts(part, request.sensor, views, backend=plain, threads=threads, hull=hull)
        seen = np.diff(sp.csr_array(free.counts).indptr) > 0
        blocked[~touch] = seen[rest]
    hidden = ids[touch | blocked]
    doc.setup_occluded = SetupOccluded(
        faces=len(hidden),
        area_mm2=float(part.areas[hidden].sum()),
        ids=hidden.tolist(),
        touching=int(touch.sum()),
        blocked=int(blocked.sum()),
    )
