"""Area elements: a part's faces bisected until none is larger than a given area.

Coverage in SPEC §3 is counted per face: a face is seen when one valid ray lands on it. On a
CAD export, a hole wall or a pocket floor is often one long facet, seen "whole" when a single
view grazes its rim (docs/cad-meshes.md measures what that claims). Splitting such faces into
elements of bounded area keeps the surface and makes "seen" mean seen: an element of area
`max_area_mm2` is a few pixels' footprints across, so one ray on it stands for its area.

Each face larger than the limit is bisected on its longest edge, k times over, into 2^k
children of exactly A / 2^k (k = ceil(log2(A / max_area))). Both halves of a bisection keep
their parent's winding and plane, so the children inherit its outward normal; a midpoint is
shared by every face that splits the same edge. A face whose neighbour is not split the same
way leaves a T-junction: the surface is unchanged, its triangulation is not conforming.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from vpp_core.errors import LimitError, MeshError
from vpp_core.mesh.part import DEFAULT_MAX_FACES, Part, part_from_children


@dataclass(frozen=True, eq=False)
class Elements:
    """A part's faces split into area elements: the elements as a Part and the face of the
    part each lies in (the default cover's rows are made of elements, its reports of faces)."""

    part: Part  # (E faces) the elements, in the part's plane and winding
    parent: np.ndarray  # (E,) int64 the face of the part each element lies in
    faces: int  # M, the faces of the part
    max_area_mm2: float  # the largest element area asked for, mm²

    def lift(self, counts: sp.sparray) -> sp.csc_array:
        """(M, N) int32 per-face sums of the element rows of `counts` (E, N)."""
        e = len(self.parent)
        ones = np.ones(e, dtype=np.int32)
        lift = sp.csr_array((ones, (self.parent, np.arange(e))), shape=(self.faces, e))
        return sp.csc_array(lift @ sp.csc_array(counts), dtype=np.int32)


def elements(part: Part, max_area_mm2: float, *, max_faces: int = DEFAULT_MAX_FACES) -> Elements:
    """`part` split into elements of at most `max_area_mm2` (mm²; `refine`), with the face of
    `part` each lies in (the part itself, face for face, where no face is larger)."""
    if not _splits(part, max_area_mm2, max_faces):
        return Elements(part, np.arange(part.n_faces), part.n_faces, max_area_mm2)
    k = generations(part.areas, max_area_mm2)
    vertices, faces, parent = bisect(part.vertices, part.faces, k)
    note = f"faces larger than {max_area_mm2:g} mm² split: {part.n_faces} faces -> {len(faces)}"
    child = part_from_children(part, vertices, faces, parent, note)
    return Elements(child, parent, part.n_faces, max_area_mm2)


def generations(areas: np.ndarray, max_area_mm2: float) -> np.ndarray:
    """(M,) int64 bisections each face of `areas` (M,) mm² needs to reach `max_area_mm2`."""
    ratio = np.maximum(areas / max_area_mm2, 1.0)
    k = np.ceil(np.log2(ratio) - 1e-12).astype(np.int64)
    return np.maximum(k, 0)


def refined_faces(part: Part, max_area_mm2: float) -> int:
    """How many faces `refine(part, max_area_mm2)` gives, computed without refining."""
    k = generations(part.areas, max_area_mm2)
    return int(np.sum(np.left_shift(1, k)))


def refine(part: Part, max_area_mm2: float, *, max_faces: int = DEFAULT_MAX_FACES) -> Part:
    """`part` with every face larger than `max_area_mm2` (mm²) bisected into elements that
    are not (`part` itself when none is); LimitError when that gives more than `max_faces`."""
    return elements(part, max_area_mm2, max_faces=max_faces).part


def _splits(part: Part, max_area_mm2: float, max_faces: int) -> bool:
    """Whether some face of `part` is larger than `max_area_mm2` (mm²); MeshError
    for a limit that is not a positive number, LimitError where the split gives more than
    `max_faces` faces."""
    if not np.isfinite(max_area_mm2) or max_area_mm2 <= 0:
        raise MeshError(f"max face area must be a positive number of mm², got {max_area_mm2}")
    total = refined_faces(part, max_area_mm2)
    if total > max_faces:
        raise LimitError(
            f"splitting faces to at most {max_area_mm2:g} mm² gives {total} faces, the limit "
            f"is {max_faces}; ask for larger elements"
        )
    return total > part.n_faces


def bisect(
    vertices: np.ndarray, faces: np.ndarray, k: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Faces (M, 3) of `vertices` (V, 3) bisected on their longest edge k (M,) times over:
    ((V', 3) vertices, (M', 3) faces, (M',) parent face of each), children in parent order."""
    chunks, n_vertices = [vertices], len(vertices)
    parent = np.arange(len(faces))
    while (todo := k > 0).any():
        v = np.concatenate(chunks) if len(chunks) > 1 else chunks[0]
        chunks = [v]
        f = faces[todo]
        tri = v[f]
        edge2 = np.stack([((tri[:, (e + 1) % 3] - tri[:, e]) ** 2).sum(axis=1) for e in range(3)])
        e = edge2.argmax(axis=0)  # edge e runs from corner e to corner e + 1
        rows = np.arange(len(f))
        a, b, c = f[rows, e], f[rows, (e + 1) % 3], f[rows, (e + 2) % 3]
        ends = np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1)
        split, slot = np.unique(ends, axis=0, return_inverse=True)
        chunks.append(0.5 * (v[split[:, 0]] + v[split[:, 1]]))
        mid = n_vertices + slot.ravel()
        n_vertices += len(split)
        halves = [np.column_stack([a, mid, c]), np.column_stack([mid, b, c])]
        faces = np.concatenate([faces[~todo], *halves])
        parent = np.concatenate([parent[~todo], parent[todo], parent[todo]])
        k = np.concatenate([k[~todo], k[todo] - 1, k[todo] - 1])
    order = np.argsort(parent, kind="stable")  # children next to each other, in parent order
    v = np.concatenate(chunks) if len(chunks) > 1 else chunks[0]
    return v, faces[order], parent[order]
