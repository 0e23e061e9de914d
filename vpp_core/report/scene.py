"""A plan's 3D scene for the browser viewer: geometry and per-face results as packed typed arrays.

Per face i: the achieved resolution r*_i (mm, SPEC §5, inf where no selected view reaches it)
and a state for the colour legend; per selected view (visiting order): the faces it sees
(R_ij > 0), as CSR offsets into one id array. `pack` lays named arrays out so that a browser
can view them with zero copies (`new Float32Array(buffer, offset, length)`):

    b"VPPS" | uint32 LE header length | header JSON (utf-8) | padding | arrays, 8-byte aligned

header = {"arrays": {name: {"dtype", "shape", "offset"}}, ...meta}, offsets from the file start.
"""

from __future__ import annotations

import json
import struct
from dataclasses import dataclass
from typing import Any

import numpy as np
import scipy.sparse as sp

from vpp_core.cell.geometry import Cell, transform
from vpp_core.cell.scene import floor_quad
from vpp_core.cover.density import density_sum, meets
from vpp_core.errors import VppError
from vpp_core.mesh.part import Part
from vpp_core.plan.document import PlanDocument
from vpp_core.plan.metrics import resolution_mm, seen
from vpp_core.plan.regionsdoc import face_regions

MAGIC = b"VPPS"
ALIGN = 8
DTYPES = ("float32", "uint32", "uint8")
"""Array types a browser reads natively (little-endian)."""

MET, UNMET, UNCOVERED, UNCOVERABLE, EXCLUDED = range(5)
"""Face states: r* ≤ r̄; seen by the plan but r* > r̄; seen by some candidate but by no selected
view; counted but seen by no candidate; not counted (degenerate or duplicate face)."""
STATE_NAMES = ("met", "unmet", "uncovered", "uncoverable", "excluded")
"""With regions, `met` is against each face's own target and ignored faces are `excluded`."""


@dataclass(frozen=True, eq=False)
class FaceResults:
    """Per-face results of a selection J* (K views, in visiting order)."""

    resolution_mm: np.ndarray  # (M,) float32 achieved r* in mm, inf where δ* = 0
    state: np.ndarray  # (M,) uint8, one of MET … EXCLUDED
    view_offsets: np.ndarray  # (K+1,) uint32 CSR offsets into view_faces
    view_faces: np.ndarray  # (nnz,) uint32 faces seen by each selected view, ascending


def face_results(
    counts: sp.sparray,
    areas: np.ndarray,
    counted: np.ndarray,
    selected: np.ndarray,
    target_mm: float | np.ndarray,
) -> FaceResults:
    """Results per face of R (M, N) for the views `selected` (K,), areas (M,) mm², r̄ in mm
    (one, or (M,) each face's own)."""
    r = sp.csc_array(counts)
    sub = sp.csc_array(r[:, selected])
    sub.sort_indices()  # the viewer's faces per view, in order
    achieved = density_sum(sub, areas)  # δ_ij of J* only
    state = np.full(r.shape[0], UNMET, np.uint8)
    state[meets(achieved, 1.0 / target_mm)] = MET
    state[~seen(sub)] = UNCOVERED
    state[~seen(r)] = UNCOVERABLE
    state[~counted] = EXCLUDED
    return FaceResults(
        resolution_mm=resolution_mm(achieved).astype(np.float32),
        state=state,
        view_offsets=sub.indptr.astype(np.uint32),
        view_faces=sub.indices.astype(np.uint32),
    )


def geometry_arrays(part: Part) -> dict[str, np.ndarray]:
    """The part for drawing: vertices (V, 3) float32 mm and faces (M, 3) uint32."""
    return {
        "vertices": part.vertices.astype(np.float32),
        "faces": part.faces.astype(np.uint32),
    }


def result_arrays(results: FaceResults) -> dict[str, np.ndarray]:
    """The per-face and per-view arrays of `results`, by name."""
    return {
        "resolution_mm": results.resolution_mm,
        "state": results.state,
        "view_offsets": results.view_offsets,
        "view_faces": results.view_faces,
    }


def pack(arrays: dict[str, np.ndarray], **meta: Any) -> bytes:
    """Named arrays (float32, uint32 or uint8) and JSON metadata as one binary scene file."""
    layout: dict[str, dict[str, Any]] = {}
    blobs: list[bytes] = []
    bases: list[int] = []
    for name, a in arrays.items():
        if a.dtype.name not in DTYPES:
            raise VppError(f"array {name}: dtype {a.dtype} is not one of {DTYPES}")
        data = np.ascontiguousarray(a, a.dtype.newbyteorder("<")).tobytes()
        layout[name] = {"dtype": a.dtype.name, "shape": list(a.shape), "offset": 0}
        bases.append(sum(len(b) for b in blobs))
        blobs.append(data + bytes(-len(data) % ALIGN))
    doc = {"arrays": layout, **meta}
    size = 0
    while True:  # the offsets are in the header, so its padded length is found by iteration
        for rec, base in zip(layout.values(), bases, strict=True):
            rec["offset"] = size + base
        text = json.dumps(doc, separators=(",", ":"), allow_nan=False).encode()
        total = len(MAGIC) + 4 + len(text)
        total += -total % ALIGN
        if total == size:
            head = MAGIC + struct.pack("<I", len(text)) + text
            return head + bytes(size - len(head)) + b"".join(blobs)
        size = total


def unpack(data: bytes) -> tuple[dict[str, Any], dict[str, np.ndarray]]:
    """Inverse of `pack`: (metadata, arrays)."""
    if data[:4] != MAGIC:
        raise VppError("not a vpp scene file")
    (n,) = struct.unpack("<I", data[4:8])
    doc = json.loads(data[8 : 8 + n])
    arrays = {}
    for name, rec in doc.pop("arrays").items():
        dtype = np.dtype(rec["dtype"]).newbyteorder("<")
        count = int(np.prod(rec["shape"]))
        arrays[name] = np.frombuffer(data, dtype, count, rec["offset"]).reshape(rec["shape"])
    return doc, arrays


def plan_scene(
    part: Part, doc: PlanDocument, counts: sp.sparray, cell: Cell | None = None
) -> bytes:
    """The packed per-face results of the plan `doc` on `part` with R (M, N), and the
    setup `cell`'s floor, fixtures and keep-out meshes to draw (`setup_arrays`)."""
    selected = np.array([v.id for v in doc.viewpoints], dtype=np.int64)
    region, target, ignored = face_regions(doc, part.n_faces)
    counted = part.counted & ~ignored
    results = face_results(counts, part.areas, counted, selected, target)
    arrays = result_arrays(results)
    meta: dict[str, Any] = {}
    if doc.regions is not None:  # per face: its region (0 = default, k = regions[k-1]), r̄_f
        arrays["region"] = (region + 1).astype(np.uint32)
        arrays["target_mm"] = target.astype(np.float32)
        meta["regions"] = [
            {"name": r.name, "resolution_mm": r.resolution_mm, "ignore": r.ignore}
            for r in doc.regions.regions
        ]
    return pack(
        {**arrays, **arm_of(doc), **setup_arrays(part, doc, cell)},
        **meta,
        faces=part.n_faces,
        views=selected.tolist(),
        target_mm=doc.target.resolution_mm,
        formulation=doc.target.formulation,
        states=list(STATE_NAMES),
    )


def selected_face_results(
    part: Part, doc: PlanDocument, threads: int | None = None, backend: Any = None
) -> FaceResults:
    """The per-face results of `doc` on `part` without the candidates' R: its selected
    viewpoints traced again (the plan's sensor; `backend`, with the setup's occluders where the
    plan has a setup, else the plan's backend on the part alone), uncoverable faces from the
    document's ids. What `plan_scene` gives from the whole R (for the CLI's plots)."""
    from vpp_core.camera.pose import make_viewpoints
    from vpp_core.trace.raytrace import make_backend, trace_counts

    vps = doc.viewpoints
    views = make_viewpoints(
        np.array([v.position for v in vps]).reshape(-1, 3),
        np.array([v.gaze for v in vps]).reshape(-1, 3),
        np.array([v.up for v in vps]).reshape(-1, 3),
    )
    backend = backend or (make_backend(part, doc.rays.backend) if len(vps) else None)
    counts = (
        trace_counts(part, doc.sensor, views, backend=backend, threads=threads).counts
        if len(vps)
        else sp.csc_array((part.n_faces, 0), dtype=np.int32)
    )
    results = face_results(
        counts, part.areas, part.counted, np.arange(len(vps)), doc.target.resolution_mm
    )
    state = results.state.copy()
    state[state == UNCOVERABLE] = UNCOVERED  # unseen by the selection: R of the rest unknown
    ids = np.asarray(doc.uncoverable.ids, dtype=np.int64)
    state[ids[part.counted[ids]]] = UNCOVERABLE
    state[~part.counted] = EXCLUDED
    return FaceResults(results.resolution_mm, state, results.view_offsets, results.view_faces)


FLOOR_MARGIN = 0.25
"""The floor drawn reaches this share of the drawn things' extent beyond them on every side."""


def setup_arrays(part: Part, doc: PlanDocument, cell: Cell | None) -> dict[str, np.ndarray]:
    """The setup for drawing, as float32 triangle soups (T, 3, 3) mm in the part frame:
    `setup_floor` (2 triangles: a square of the floor plane under the part, its fixtures and
    the plan's cameras, FLOOR_MARGIN of their extent beyond them), `setup_fixtures` and
    `setup_keep_out` (meshes, and boxes as 12 triangles each); only those the setup has."""
    if cell is None:
        return {}
    out: dict[str, np.ndarray] = {}
    to_part = cell.cell_to_part
    fixtures = [s.vertices[s.faces] for s in cell.fixtures]
    keep_out = [s.vertices[s.faces] for s in cell.keep_out_meshes]
    keep_out += [box_triangles(b) for _, b in cell.keep_out_boxes]
    if cell.setup.floor is not None:
        points = [part.vertices, np.array([v.position for v in doc.viewpoints]).reshape(-1, 3)]
        points += [transform(to_part, t.reshape(-1, 3)) for t in fixtures]
        p = np.vstack(points)
        xy = cell.to_cell(p)[:, :2]
        reach = FLOOR_MARGIN * float(np.linalg.norm(np.ptp(xy, axis=0)))
        quad = transform(to_part, floor_quad(cell, p, reach))
        out["setup_floor"] = quad[[0, 1, 2, 0, 2, 3]].reshape(2, 3, 3).astype(np.float32)
    for name, soups in (("setup_fixtures", fixtures), ("setup_keep_out", keep_out)):
        if soups:
            tri = transform(to_part, np.vstack(soups).reshape(-1, 3))
            out[name] = tri.reshape(-1, 3, 3).astype(np.float32)
    return out


def box_triangles(box: np.ndarray) -> np.ndarray:
    """(12, 3, 3) the faces of the axis-aligned box (2, 3) [min, max] as triangles."""
    corners = np.array([[box[(i >> k) & 1, k] for k in range(3)] for i in range(8)])
    quads = [(0, 2, 3, 1), (4, 5, 7, 6), (0, 1, 5, 4), (2, 6, 7, 3), (0, 4, 6, 2), (1, 3, 7, 5)]
    return np.array([corners[[a, b, c, a, c, d]] for a, b, c, d in quads]).reshape(12, 3, 3)


def arm_of(doc: PlanDocument) -> dict[str, np.ndarray]:
    """The arm at each selected viewpoint (vpp_core.report.armscene), when the plan has one."""
    setup = doc.setup
    joints = [v.joints for v in doc.viewpoints]
    if setup is None or setup.robot is None or not joints or any(j is None for j in joints):
        return {}
    from vpp_core.report.armscene import arm_arrays

    return arm_arrays(setup.robot, np.asarray(setup.part_to_cell), np.array(joints))


def geometry_scene(part: Part) -> bytes:
    """The packed geometry of `part` (vertices in mm, faces) with its id and bounds."""
    return pack(geometry_arrays(part), mesh_id=part.id, bounds_mm=part.bounds.tolist())
