"""The setup's occluders in the part frame, and the part faces the setup touches.

The floor is a square of two triangles in the plane z = floor.z_mm of the cell, reaching
`reach_mm` beyond the part on every side: a ray between a camera and a part point at most
reach_mm away (the sensor's far limit) stays over it, so a finite quad blocks like the
plane. Fixtures are their meshes as placed. Both go to the part frame; the ray backends
trace them with the part (vpp_core.trace.occluded) and a ray whose first hit is one of them
counts for no face.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vpp_core.cell.geometry import Cell, Solid, transform

CONTACT_MM = 0.05
"""A part face with a vertex within this distance of the floor plane or of a fixture's
surface touches the setup (`setup_occluded` when no candidate sees it)."""


@dataclass(frozen=True, eq=False)
class Occluders:
    """Triangles that block rays but are not part surface (part frame, mm)."""

    vertices: np.ndarray  # (n, 3) float64
    faces: np.ndarray  # (m, 3) int64
    names: tuple[str, ...]  # what they are: "floor", "fixtures[0]", ...


def floor_quad(cell: Cell, part_vertices: np.ndarray, reach_mm: float) -> np.ndarray:
    """(4, 3) corners (cell frame, mm) of the floor under the part, reach_mm beyond it."""
    assert cell.setup.floor is not None
    xy = cell.to_cell(part_vertices)[:, :2]
    lo, hi = xy.min(axis=0) - reach_mm, xy.max(axis=0) + reach_mm
    z = cell.setup.floor.z_mm
    return np.array([[lo[0], lo[1], z], [hi[0], lo[1], z], [hi[0], hi[1], z], [lo[0], hi[1], z]])


def occluders(cell: Cell | None, part_vertices: np.ndarray, reach_mm: float) -> Occluders | None:
    """The floor quad and the fixtures in the part frame (None: nothing occludes)."""
    if cell is None:
        return None
    vertices, faces, names = [], [], []
    offset = 0
    if cell.setup.floor is not None:
        vertices.append(floor_quad(cell, part_vertices, reach_mm))
        faces.append(np.array([[0, 1, 2], [0, 2, 3]]))
        names.append("floor")
        offset = 4
    for solid in cell.fixtures:
        vertices.append(solid.vertices)
        faces.append(solid.faces + offset)
        names.append(solid.name)
        offset += len(solid.vertices)
    if not faces:
        return None
    v = transform(cell.cell_to_part, np.vstack(vertices))
    return Occluders(v, np.vstack(faces).astype(np.int64), tuple(names))


def touching(
    cell: Cell | None, vertices: np.ndarray, faces: np.ndarray, ids: np.ndarray
) -> np.ndarray:
    """(k,) bool: part faces `ids` (of the part's vertices (V, 3), faces (M, 3)) with a vertex
    within CONTACT_MM of the floor plane or of a fixture's surface."""
    out = np.zeros(len(ids), dtype=bool)
    if cell is None or not len(ids):
        return out
    corners = cell.to_cell(vertices[faces[ids]].reshape(-1, 3))
    if cell.setup.floor is not None:
        near = np.abs(corners[:, 2] - cell.setup.floor.z_mm) <= CONTACT_MM
        out |= near.reshape(-1, 3).any(axis=1)
    for solid in cell.fixtures:
        near = _near(solid, corners)
        out |= near.reshape(-1, 3).any(axis=1)
    return out


def _near(solid: Solid, points: np.ndarray) -> np.ndarray:
    """(n,) bool: points within CONTACT_MM of the solid's surface (cell frame)."""
    return np.asarray(solid.distance(points, CONTACT_MM) <= CONTACT_MM)
