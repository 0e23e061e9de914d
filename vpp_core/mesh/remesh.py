"""Isotropic remeshing (pymeshlab, the optional `remesh` extra): same geometry, even faces.

Planning on a remesh makes the view count a property of the surface at a stated element size,
not of how the part was exported: featuretype's CAD file and a 1 mm remesh of it, both
remeshed at 1 mm, need 21 and 20 views at F = 0.99 (docs/cad-meshes.md).
"""

from __future__ import annotations

import math

import numpy as np

from vpp_core.errors import LimitError, MeshError, VppError
from vpp_core.mesh.part import DEFAULT_MAX_FACES, Part, part_from_arrays

FEATURE_DEG = 30.0
"""Edges sharper than this dihedral angle (degrees) are kept as features."""
EQUILATERAL = math.sqrt(3) / 4
"""Area of an equilateral triangle of unit edge: a remesh at edge e has about A / (this · e²)
faces."""


def remeshed_faces(part: Part, edge_mm: float) -> int:
    """About how many faces `remesh(part, edge_mm)` gives (within ~10 % on the shared parts)."""
    return math.ceil(part.area_mm2 / (EQUILATERAL * edge_mm * edge_mm))


def remesh(part: Part, edge_mm: float, *, max_faces: int = DEFAULT_MAX_FACES) -> Part:
    """`part` remeshed isotropically with edges of about `edge_mm` mm, sharp features kept;
    LimitError when that gives, or would give, more than `max_faces` faces."""
    if not math.isfinite(edge_mm) or edge_mm <= 0:
        raise MeshError(f"remesh edge length must be a positive number of mm, got {edge_mm}")
    if (guess := remeshed_faces(part, edge_mm)) > max_faces:
        raise LimitError(
            f"remeshing at {edge_mm:g} mm edges gives about {guess} faces, the limit is "
            f"{max_faces}; ask for longer edges"
        )
    vertices, faces = _pymeshlab_remesh(part, edge_mm)
    if len(faces) > max_faces:
        raise LimitError(
            f"remeshing at {edge_mm:g} mm edges gave {len(faces)} faces, the limit is {max_faces}"
        )
    note = f"remeshed at {edge_mm:g} mm edges: {part.n_faces} faces -> {len(faces)}"
    return part_from_arrays(vertices, faces, warnings=(*part.warnings, note))


def isotropic_remesh(part: Part, edge_mm: float) -> Part:
    """`part` remeshed with edges of about `edge_mm` mm, sharp features kept, unchecked."""
    return part_from_arrays(*_pymeshlab_remesh(part, edge_mm))


def _pymeshlab_remesh(
    part: Part, edge_mm: float, iterations: int = 10
) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) vertices mm and (M, 3) faces of pymeshlab's isotropic explicit remeshing."""
    try:
        import pymeshlab
    except ImportError:  # pragma: no cover - depends on the installed extras
        raise VppError("isotropic remeshing needs pymeshlab: pip install 'vpp[remesh]'") from None
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(part.vertices, part.faces))
    try:
        ms.meshing_isotropic_explicit_remeshing(
            iterations=iterations, targetlen=pymeshlab.PureValue(edge_mm), featuredeg=FEATURE_DEG
        )
    except pymeshlab.PyMeshLabException as exc:
        raise MeshError(f"isotropic remeshing failed: {exc}") from None
    out = ms.current_mesh()
    return out.vertex_matrix(), out.face_matrix()
