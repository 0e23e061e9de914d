"""Outward normals for closed shells; see vpp_core.mesh.part for the rules."""

from __future__ import annotations

import numpy as np
from numpy.typing import NDArray
from scipy import sparse
from scipy.sparse import csgraph
from scipy.spatial import cKDTree

TOPOLOGY_MERGE_REL = 1e-8
"""Vertices closer than this times the bounding-box diagonal count as one vertex when deciding
which shells are closed (CAD exports write 'the same' vertex with round-off differences); the
canonical geometry and the id keep every distinct vertex."""

F64 = NDArray[np.float64]
I64 = NDArray[np.int64]
Bool = NDArray[np.bool_]


def orientation_signs(
    vertices: F64, faces: I64, counted: Bool, rep: I64, degenerate: Bool
) -> tuple[F64, list[str]]:
    """(M,) +-1 per face so closed shells point outward, and notes on what changed."""
    topo = _topology_ids(vertices)[faces]
    edges = _EdgeTable(topo, _in_topology(topo, faces, rep))
    stray = degenerate & edges.has_free_edge(len(faces))
    if stray.any():  # zero-area faces that close no T-junction would only open their shell
        edges = _EdgeTable(topo, (edges.used > 0) & ~stray)
    comp, n_comp = edges.shells(len(faces))
    shells = np.bincount(comp[counted], minlength=n_comp) > 0  # shells holding a counted face
    signs = np.ones(len(faces))
    open_c = edges.unbalanced(comp, signs, n_comp)
    fixable = shells & open_c & ~edges.nonmanifold(comp, n_comp)
    fixed = np.zeros(n_comp, dtype=bool)
    if fixable.any():
        trial = edges.propagate_signs(comp, fixable)
        fixed = fixable & ~edges.unbalanced(comp, trial, n_comp)
        signs = np.where(fixed[comp], trial, signs)
        open_c &= ~fixed
    vol = np.bincount(comp, _signed_volume_terms(vertices, faces) * signs * edges.used, n_comp)
    inverted = shells & ~open_c & (vol < 0)
    signs = np.where(inverted[comp], -signs, signs)
    n_closed = int((shells & ~open_c).sum())
    notes = _orientation_notes(int(shells.sum()), n_closed, int(fixed.sum()), int(inverted.sum()))
    return signs, notes


def _orientation_notes(n_shells: int, n_closed: int, n_fixed: int, n_inverted: int) -> list[str]:
    """Human-readable orientation report."""
    notes = []
    of_closed = f"of {n_closed} closed shells"
    if n_fixed:
        notes.append(f"inconsistent winding: normals made consistent on {n_fixed} {of_closed}")
    if n_inverted:
        notes.append(f"inverted winding: normals flipped on {n_inverted} {of_closed}")
    if n_closed < n_shells:
        n_open = n_shells - n_closed
        notes.append(f"{n_open} of {n_shells} shells are open: normals follow the file's winding")
    return notes


def _topology_ids(vertices: F64) -> I64:
    """(V,) vertex ids after merging vertices closer than TOPOLOGY_MERGE_REL * bbox diagonal."""
    n = len(vertices)
    radius = TOPOLOGY_MERGE_REL * float(np.linalg.norm(np.ptp(vertices, axis=0)))
    pairs = cKDTree(vertices).query_pairs(radius, output_type="ndarray")
    if len(pairs) == 0:
        return np.arange(n, dtype=np.int64)
    graph = sparse.coo_matrix((np.ones(len(pairs)), (pairs[:, 0], pairs[:, 1])), shape=(n, n))
    labels: I64 = csgraph.connected_components(graph, directed=False)[1].astype(np.int64)
    return labels


def _in_topology(topo: I64, faces: I64, rep: I64) -> Bool:
    """(M,) faces that take part in edge balance: 3 distinct vertices, not a same-winding copy.

    Collinear zero-area faces stay in (they may close T-junctions); a duplicate with opposite
    winding stays in (two solids glued face to face), an identical copy does not.
    """
    distinct = (topo[:, 0] != topo[:, 1]) & (topo[:, 1] != topo[:, 2]) & (topo[:, 2] != topo[:, 0])
    copy = (rep != np.arange(len(faces))) & (faces == faces[rep]).all(axis=1)
    used: Bool = distinct & ~copy
    return used


def _signed_volume_terms(vertices: F64, faces: I64) -> F64:
    """(M,) signed tetrahedron volumes (mm^3) of each face with the bounding-box centre."""
    tri = vertices[faces] - 0.5 * (vertices.min(axis=0) + vertices.max(axis=0))
    terms: F64 = np.einsum("ij,ij->i", tri[:, 0], np.cross(tri[:, 1], tri[:, 2])) / 6.0
    return terms


class _EdgeTable:
    """Directed edges of the faces in the edge balance, grouped by undirected edge."""

    def __init__(self, topo: I64, used: Bool) -> None:
        """Build the (3m,) edge arrays from (M, 3) topological faces and the (M,) used mask."""
        self.used = used.astype(np.float64)
        ids = np.flatnonzero(used)
        f = topo[ids]
        a = np.concatenate([f[:, 0], f[:, 1], f[:, 2]])
        b = np.concatenate([f[:, 1], f[:, 2], f[:, 0]])
        self.face = np.tile(ids, 3)
        self.direction = np.where(a < b, 1.0, -1.0)
        key = np.minimum(a, b) * (int(topo.max()) + 1) + np.maximum(a, b)
        _, self.edge, self.count = np.unique(key, return_inverse=True, return_counts=True)
        self.order = np.argsort(self.edge, kind="stable")
        self.start = np.cumsum(self.count) - self.count

    def shells(self, n_faces: int) -> tuple[I64, int]:
        """(M,) label of the edge-connected shell of every face, and the number of labels."""
        group_first = self.face[self.order[self.start]][self.edge]
        graph = sparse.coo_matrix(
            (np.ones(len(self.face)), (self.face, group_first)), shape=(n_faces, n_faces)
        )
        n, labels = csgraph.connected_components(graph, directed=False)
        return labels.astype(np.int64), int(n)

    def has_free_edge(self, n_faces: int) -> Bool:
        """(M,) True for faces with an edge that no other face in the table uses."""
        free = self.face[self.count[self.edge] == 1]
        return np.bincount(free, minlength=n_faces) > 0

    def unbalanced(self, comp: I64, signs: F64, n_comp: int) -> Bool:
        """(n_comp,) True where some edge is not used equally often in both directions."""
        net = np.bincount(self.edge, self.direction * signs[self.face], len(self.count))
        bad = net[self.edge] != 0
        return np.bincount(comp[self.face[bad]], minlength=n_comp) > 0

    def nonmanifold(self, comp: I64, n_comp: int) -> Bool:
        """(n_comp,) True where some edge is not shared by exactly two faces."""
        bad = self.count[self.edge] != 2
        return np.bincount(comp[self.face[bad]], minlength=n_comp) > 0

    def propagate_signs(self, comp: I64, targets: Bool) -> F64:
        """(M,) +-1 making winding consistent in target (manifold) shells, by BFS over faces."""
        n_faces = len(comp)
        pairs = self.start[self.count == 2]
        first, second = self.order[pairs], self.order[pairs + 1]
        pick = targets[comp[self.face[first]]]
        first, second = first[pick], second[pick]
        f0, f1 = self.face[first], self.face[second]
        # weight 1: the two faces agree (opposite edge directions); 2: one must be flipped
        weight = np.where(self.direction[first] != self.direction[second], 1, 2)
        roots = f0[np.unique(comp[f0], return_index=True)[1]]
        rows = np.concatenate([f0, np.full(len(roots), n_faces)])
        cols = np.concatenate([f1, roots])
        vals = np.concatenate([weight, np.ones(len(roots), dtype=np.int64)])
        shape = (n_faces + 1, n_faces + 1)
        graph = sparse.coo_matrix((vals, (rows, cols)), shape=shape).tocsr()
        graph = (graph + graph.T).tocsr()
        bfs, pred = csgraph.breadth_first_order(graph, n_faces, directed=False)
        nodes = bfs[1:]
        parents = pred[nodes]
        rel = np.asarray(graph[nodes, parents]).ravel()
        s = [1.0] * (n_faces + 1)
        for node, parent, r in zip(nodes.tolist(), parents.tolist(), rel.tolist(), strict=True):
            s[node] = s[parent] if r == 1 else -s[parent]
        return np.asarray(s[:n_faces])
