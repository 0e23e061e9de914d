"""The setup in a plan (issue 35): its ray backend, its camera predicate, and what the plan
document says about it (the setup echoed, cell-frame poses, the faces the setup hides).

`setup_occluded` (docs/cell.md) is the uncoverable faces (no candidate's valid ray hits
them, with the floor and fixtures in the scene) that the setup hides, each for the first of:
- `touching`: a vertex within CONTACT_MM of the floor plane or of a fixture's surface;
- `blocked`: one of the plan's candidates sees it when the floor and fixtures are taken away
  (the part alone);
- `unreachable`: one of the candidates that the request's generator places without a setup
  sees it (the part alone): the setup forbids those cameras (below the floor's clearance,
  outside the workspace, in a keep-out, near a fixture) or blocks their aim, so that none of
  the plan's stands there.
"Sees" is one ray per camera and face, to the face's centroid: inside the image, depth in
[near, far], incidence at most max_incidence, and that face its first hit (the part's own
mesh). A checker re-traces it with any ray caster; it costs one ray per camera and face.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numpy as np

from vpp_core.camera.pose import Viewpoints
from vpp_core.camera.sensor import Sensor
from vpp_core.cell.geometry import Cell, resolve
from vpp_core.cell.reach import Allowed, check_viewpoints, predicate
from vpp_core.cell.scene import Occluders, occluders, touching
from vpp_core.mesh.part import Part
from vpp_core.plan.document import CellPose, PlanDocument, PlanRequest, SetupOccluded
from vpp_core.trace.rays import RayBackend
from vpp_core.trace.raytrace import Trace, make_backend


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
    unconstrained: Callable[[RayBackend], Viewpoints] | None = None,
) -> None:
    """Fill doc.setup, each viewpoint's cell pose and doc.setup_occluded (no setup: none);
    `unconstrained(backend)` gives the candidates the request would have without a setup."""
    if cell is None:
        return
    doc.setup = cell.setup
    m = cell.part_to_cell
    for v in doc.viewpoints:
        v.cell = CellPose(
            position=cell.to_cell(np.asarray(v.position))[0].tolist(),
            gaze=cell.rotate_to_cell(np.asarray(v.gaze))[0].tolist(),
            up=cell.rotate_to_cell(np.asarray(v.up))[0].tolist(),
            camera_to_world=(m @ np.asarray(v.camera_to_world)).tolist(),
        )
    ids = np.asarray(doc.uncoverable.ids, dtype=np.int64)
    touch = touching(cell, part.vertices, part.faces, ids)
    plain = make_backend(part, trace.backend)
    blocked = ~touch & _seen(part, request.sensor, views, ids, ~touch, plain)
    unreachable = np.zeros(len(ids), dtype=bool)
    rest = ~touch & ~blocked
    if rest.any() and unconstrained is not None:
        unreachable = rest & _seen(part, request.sensor, unconstrained(plain), ids, rest, plain)
    hidden = ids[touch | blocked | unreachable]
    doc.setup_occluded = SetupOccluded(
        faces=len(hidden),
        area_mm2=float(part.areas[hidden].sum()),
        ids=hidden.tolist(),
        touching=int(touch.sum()),
        blocked=int(blocked.sum()),
        unreachable=int(unreachable.sum()),
    )


def _seen(
    part: Part,
    sensor: Sensor,
    views: Viewpoints,
    ids: np.ndarray,
    which: np.ndarray,
    backend: RayBackend,
) -> np.ndarray:
    """(len(ids),) bool: faces ids[which] that some view sees along the ray to the face's
    centroid: within the image, depth in [near, far], incidence at most max_incidence, and
    the face the first hit on `backend`; False elsewhere. One ray per view and face."""
    out = np.zeros(len(ids), dtype=bool)
    if not which.any() or not len(views):
        return out
    centres = part.vertices[part.faces[ids]].mean(axis=1)
    rep = part.representative
    rotations = views.rotations()
    half_x, half_y = sensor.width_px / 2 / sensor.fx, sensor.height_px / 2 / sensor.fy
    cos_min = math.cos(math.radians(sensor.max_incidence_deg))
    for j in range(len(views)):
        todo = np.flatnonzero(which & ~out)
        if not len(todo):
            break
        d = centres[todo] - views.positions[j]
        cam = d @ rotations[j]
        z = cam[:, 2]
        dist = np.linalg.norm(d, axis=1)
        unit = d / np.maximum(dist, 1e-12)[:, None]
        ok = (z >= sensor.near_mm) & (z <= sensor.far_mm)
        ok &= (np.abs(cam[:, 0]) <= z * half_x) & (np.abs(cam[:, 1]) <= z * half_y)
        ok &= np.abs(np.einsum("ij,ij->i", unit, part.normals[ids[todo]])) >= cos_min
        k = np.flatnonzero(ok)
        if not len(k):
            continue
        prim, _ = backend.first_hits(
            views.positions[j], unit[k].astype(np.float32), float(dist[k].max()) * 1.01 + 1.0
        )
        hit = (prim >= 0) & (rep[np.maximum(prim, 0)] == rep[ids[todo[k]]])
        out[todo[k[hit]]] = True
    return out
