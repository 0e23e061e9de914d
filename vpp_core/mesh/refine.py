"""Area elements: a part's faces bisected until none is larger than a given area, or longer.

Coverage in SPEC §3 is counted per face: a face is seen when one valid ray lands on it. On a
CAD export, a hole wall or a pocket floor is often one long facet, seen "whole" when a single
view grazes its rim (docs/cad-meshes.md measures what that claims). Splitting such faces into
elements of bounded area and length keeps the surface and makes "seen" mean seen: an element
of area at most A and longest edge at most ELEMENT_LENGTH · sqrt(A) is a few pixels'
footprints across, so one ray on it stands for its area. The bound on length matters on CAD
exports: a 30 mm facet along a hole's wall, 0.5 mm wide, is small in area, and a view that
sees the rim end of it would otherwise stand for the whole strip.

Each face larger than the limit is bisected on its longest edge, k times over, into 2^k
children of exactly A / 2^k (k = ceil(log2(A / max_area))); a child whose longest edge is
still too long is bisected again, so the children of a sliver are halves, quarters, ... of
it. Both halves of a bisection keep their parent's winding and plane, so the children
inherit its outward normal; a midpoint is shared by every face that splits the same edge in
the same pass. A face whose neighbour is not split the same way leaves a T-junction: the
surface is unchanged, its triangulation is not conforming.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import scipy.sparse as sp

from vpp_core.errors import LimitError, MeshError
from vpp_core.mesh.part import DEFAULT_MAX_FACES, Part, part_from_children

ELEMENT_LENGTH = 2.0
"""An element's longest edge is at most ELEMENT_LENGTH · sqrt(its largest area): the
hypotenuse of a right isosceles triangle of that area, so that a square's two halves (and
every element bisection makes of them) are not split for their length."""


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


def elements(
    part: Part,
    max_area_mm2: float,
    *,
    max_edge_mm: float | None = None,
    max_faces: int = DEFAULT_MAX_FACES,
) -> Elements:
    """`part` split into elements of at most `max_area_mm2` (mm²) and edges of at most
    `max_edge_mm` (mm; default max_length(max_area_mm2), inf: area only), with the face of
    `part` each lies in (the part itself, face for face, where no face is larger or longer).
    MeshError for an area that is not a positive number, LimitError where the split gives
    more than `max_faces` faces (found while splitting: bisection stops past the limit)."""
    if not np.isfinite(max_area_mm2) or max_area_mm2 <= 0:
        raise MeshError(f"max face area must be a positive number of mm², got {max_area_mm2}")
    edge = _edge_limit(max_area_mm2, max_edge_mm)
    vertices, faces, parent = _split(part, max_area_mm2, edge, cap=max_faces + 1)
    if len(faces) > max_faces:
        least = max(
            len(faces), int(np.sum(np.left_shift(1, generations(part.areas, max_area_mm2))))
        )
        raise LimitError(
            f"splitting faces to at most {max_area_mm2:g} mm² gives at least {least} faces, "
            f"the limit is {max_faces}; ask for larger elements"
        )
    if len(faces) == part.n_faces:  # nothing was split
        return Elements(part, np.arange(part.n_faces), part.n_faces, max_area_mm2)
    longer = f" or longer than {edge:.3g} mm" if np.isfinite(edge) else ""
    count = f"{part.n_faces} faces -> {len(faces)}"
    note = f"faces larger than {max_area_mm2:g} mm²{longer} split: {count}"
    child = part_from_children(part, vertices, faces, parent, note)
    return Elements(child, parent, part.n_faces, max_area_mm2)


def generations(areas: np.ndarray, max_area_mm2: float) -> np.ndarray:
    """(M,) int64 bisections each face of `areas` (M,) mm² needs to reach `max_area_mm2`."""
    ratio = np.maximum(areas / max_area_mm2, 1.0)
    k = np.ceil(np.log2(ratio) - 1e-12).astype(np.int64)
    return np.maximum(k, 0)


def max_length(max_area_mm2: float) -> float:
    """The longest edge (mm) an element of at most `max_area_mm2` (mm²) may have."""
    return ELEMENT_LENGTH * float(np.sqrt(max(max_area_mm2, 0.0)))


def _edge_limit(max_area_mm2: float, max_edge_mm: float | None) -> float:
    """The longest edge (mm) asked for: `max_edge_mm`, by default max_length(max_area_mm2)."""
    return max_length(max_area_mm2) if max_edge_mm is None else max_edge_mm


def _split(
    part: Part, max_area_mm2: float, max_edge_mm: float, cap: int | None = None
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`bisect` of `part`'s faces to at most `max_area_mm2` (mm²) and `max_edge_mm` (mm)."""
    k = generations(part.areas, max_area_mm2)
    return bisect(part.vertices, part.faces, k, max_edge_mm, cap)


def refined_faces(part: Part, max_area_mm2: float, max_edge_mm: float | None = None) -> int:
    """How many faces `refine(part, max_area_mm2, max_edge_mm=...)` gives."""
    edge = _edge_limit(max_area_mm2, max_edge_mm)
    return len(_split(part, max_area_mm2, edge)[1])


def _edges2(tri: np.ndarray) -> np.ndarray:
    """(3, M) squared edge lengths of triangles (M, 3, 3): edge e runs from corner e to e + 1."""
    return np.stack([((tri[:, (e + 1) % 3] - tri[:, e]) ** 2).sum(axis=1) for e in range(3)])


def refine(
    part: Part,
    max_area_mm2: float,
    *,
    max_edge_mm: float | None = None,
    max_faces: int = DEFAULT_MAX_FACES,
) -> Part:
    """`part` with every face larger than `max_area_mm2` (mm²), or longer than `max_edge_mm`
    (`elements`), bisected into elements that are not (`part` itself when none is);
    LimitError when that gives more than `max_faces`."""
    return elements(part, max_area_mm2, max_edge_mm=max_edge_mm, max_faces=max_faces).part


def bisect(
    vertices: np.ndarray,
    faces: np.ndarray,
    k: np.ndarray,
    max_edge_mm: float = np.inf,
    cap: int | None = None,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Faces (M, 3) of `vertices` (V, 3) bisected on their longest edge k (M,) times over, and
    again while their longest edge exceeds `max_edge_mm`: ((V', 3) vertices, (M', 3) faces,
    (M',) parent face of each), children in parent order. With `cap`, bisection stops once
    there are more than `cap` faces (for counting: the result is then incomplete)."""
    chunks, n_vertices = [vertices], len(vertices)
    parent = np.arange(len(faces))
    done_faces, done_parents = [faces[:0]], [parent[:0]]
    while len(faces):
        v = np.concatenate(chunks) if len(chunks) > 1 else chunks[0]
        chunks = [v]
        edge2 = _edges2(v[faces])
        todo = (k > 0) | (edge2.max(axis=0) > max_edge_mm**2 * (1 + 1e-9))
        done_faces.append(faces[~todo])
        done_parents.append(parent[~todo])
        faces, parent, k, e = faces[todo], parent[todo], k[todo], edge2[:, todo].argmax(axis=0)
        if cap is not None and sum(map(len, done_faces)) + 2 * len(faces) > cap:
            done_faces.append(np.concatenate([faces, faces]))
            done_parents.append(np.concatenate([parent, parent]))
            break
        rows = np.arange(len(faces))
        a, b, c = faces[rows, e], faces[rows, (e + 1) % 3], faces[rows, (e + 2) % 3]
        ends = np.stack([np.minimum(a, b), np.maximum(a, b)], axis=1)
        split, slot = np.unique(ends, axis=0, return_inverse=True)
        chunks.append(0.5 * (v[split[:, 0]] + v[split[:, 1]]))
        mid = n_vertices + slot.ravel()
        n_vertices += len(split)
        faces = np.concatenate([np.column_stack([a, mid, c]), np.column_stack([mid, b, c])])
        parent = np.concatenate([parent, parent])
        k = np.concatenate([k - 1, k - 1])
    faces, parent = np.concatenate(done_faces), np.concatenate(done_parents)
    order = np.argsort(parent, kind="stable")  # children next to each other, in parent order
    v = np.concatenate(chunks) if len(chunks) > 1 else chunks[0]
    return v, faces[order], parent[order]
