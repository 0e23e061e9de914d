"""The setup resolved for planning: transforms as arrays, fixture and keep-out meshes loaded
and placed in the cell frame, and the point-to-mesh queries the constraints need."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from functools import cached_property

import numpy as np

from vpp_core.cell.distance import MeshDistance
from vpp_core.cell.setup import BoxShape, MeshShape, Setup
from vpp_core.errors import SetupError

MeshLoader = Callable[[MeshShape], tuple[np.ndarray, np.ndarray]]
"""load(shape) -> (vertices (n, 3) float64 mm in the mesh's own frame, faces (m, 3) int):
the CLI reads a file relative to SETUP.json, the service an uploaded mesh id."""
WINDING_CHUNK = 1 << 22
"""Point × face pairs per step of the winding number (memory ~ 30 floats each)."""


def transform(matrix: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(n, 3) points (mm) mapped by a 4×4 rigid transform."""
    p = np.asarray(points, dtype=np.float64).reshape(-1, 3)
    return np.asarray(p @ matrix[:3, :3].T + matrix[:3, 3])


def invert(matrix: np.ndarray) -> np.ndarray:
    """The inverse of a 4×4 rigid transform."""
    out = np.eye(4)
    out[:3, :3] = matrix[:3, :3].T
    out[:3, 3] = -matrix[:3, :3].T @ matrix[:3, 3]
    return out


@dataclass(frozen=True, eq=False)
class Solid:
    """A mesh of the setup placed in the cell frame."""

    name: str  # where it is in the setup, e.g. "fixtures[0]" or "keep_out[2]"
    vertices: np.ndarray  # (n, 3) float64 mm, cell frame
    faces: np.ndarray  # (m, 3) int64
    clearance_mm: float = 0.0

    @cached_property
    def _distance(self) -> MeshDistance:
        return MeshDistance(self.vertices, self.faces)

    def distance(self, points: np.ndarray, within: float | None = None) -> np.ndarray:
        """(n,) mm from each point (cell frame) to the nearest point of the surface: exact up
        to `within` (default the clearance), beyond it inf."""
        return self._distance(points, self.clearance_mm if within is None else within)

    def inside(self, points: np.ndarray) -> np.ndarray:
        """(n,) bool: the generalised winding number of the surface around each point is
        above 1/2 (robust to orientation slips; open meshes enclose what they nearly close)."""
        lo, hi = self.vertices.min(axis=0), self.vertices.max(axis=0)
        box = ((points >= lo) & (points <= hi)).all(axis=1)
        out = np.zeros(len(points), dtype=bool)
        idx = np.flatnonzero(box)
        if len(idx):
            out[idx] = np.abs(winding_numbers(self.vertices[self.faces], points[idx])) > 0.5
        return out


def winding_numbers(triangles: np.ndarray, points: np.ndarray) -> np.ndarray:
    """(n,) generalised winding numbers of triangles (m, 3, 3) around points (n, 3): the sum
    of the triangles' signed solid angles (Van Oosterom & Strackee) over 4π."""
    out = np.zeros(len(points))
    step = max(1, WINDING_CHUNK // max(len(triangles), 1))
    for s in range(0, len(points), step):
        r = triangles[None, :, :, :] - points[s : s + step, None, None, :]  # (p, m, 3, 3)
        n = np.linalg.norm(r, axis=3)
        a, b, c = r[:, :, 0], r[:, :, 1], r[:, :, 2]
        det = np.einsum("pmi,pmi->pm", a, np.cross(b, c))
        na, nb, nc = n[:, :, 0], n[:, :, 1], n[:, :, 2]
        dots = (
            na * nb * nc
            + np.einsum("pmi,pmi->pm", a, b) * nc
            + np.einsum("pmi,pmi->pm", b, c) * na
            + np.einsum("pmi,pmi->pm", c, a) * nb
        )
        out[s : s + step] = (2 * np.arctan2(det, dots)).sum(axis=1) / (4 * np.pi)
    return out


@dataclass(frozen=True, eq=False)
class Cell:
    """A Setup with its meshes loaded and placed: what planning works with."""

    setup: Setup
    fixtures: tuple[Solid, ...] = ()
    keep_out_meshes: tuple[Solid, ...] = ()
    keep_out_boxes: tuple[tuple[str, np.ndarray], ...] = field(default=())  # (name, (2, 3))

    @cached_property
    def part_to_cell(self) -> np.ndarray:
        """(4, 4) float64 rigid transform part → cell."""
        return np.asarray(self.setup.part_to_cell, dtype=np.float64)

    @cached_property
    def cell_to_part(self) -> np.ndarray:
        """(4, 4) float64 rigid transform cell → part."""
        return invert(self.part_to_cell)

    def to_cell(self, points: np.ndarray) -> np.ndarray:
        """(n, 3) part-frame points in the cell frame (mm)."""
        return transform(self.part_to_cell, points)

    def rotate_to_cell(self, vectors: np.ndarray) -> np.ndarray:
        """(n, 3) part-frame directions in the cell frame."""
        return np.asarray(np.asarray(vectors).reshape(-1, 3) @ self.part_to_cell[:3, :3].T)


def resolve(
    setup: Setup | None, load: MeshLoader | None = None, *, meshes: bool = True
) -> Cell | None:
    """The Cell of `setup` (None: no setup), its meshes read by `load` (SetupError when a mesh
    is referenced and there is no loader); `meshes` False leaves the meshes out (what can be
    checked before they are read)."""
    if setup is None:
        return None
    fixtures = tuple(
        _solid(f"fixtures[{i}]", f, load, f.clearance_mm)
        for i, f in enumerate(setup.fixtures)
        if meshes
    )
    solids, boxes = [], []
    for i, k in enumerate(setup.keep_out):
        if isinstance(k, BoxShape):
            boxes.append((f"keep_out[{i}]", np.array([k.box.min, k.box.max], dtype=np.float64)))
        elif meshes:
            solids.append(_solid(f"keep_out[{i}]", k, load, 0.0))
    return Cell(setup, fixtures, tuple(solids), tuple(boxes))


def _solid(name: str, shape: MeshShape, load: MeshLoader | None, clearance: float) -> Solid:
    """The mesh of `shape` loaded and placed in the cell frame."""
    if load is None:
        raise SetupError(f"{name}.mesh {shape.mesh!r}: meshes cannot be read here")
    vertices, faces = load(shape)
    placed = transform(np.asarray(shape.to_cell, dtype=np.float64), vertices)
    return Solid(name, placed, np.asarray(faces, dtype=np.int64).reshape(-1, 3), clearance)
