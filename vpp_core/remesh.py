"""Isotropic remeshing (pymeshlab, the optional `remesh` extra): same geometry, even faces."""

from __future__ import annotations

from vpp_core.errors import VppError
from vpp_core.mesh import Part, part_from_arrays

FEATURE_DEG = 30.0
"""Edges sharper than this dihedral angle (degrees) are kept as features."""


def isotropic_remesh(part: Part, edge_mm: float, iterations: int = 10) -> Part:
    """`part` remeshed with edges of about `edge_mm` mm, sharp features kept (pymeshlab)."""
    try:
        import pymeshlab
    except ImportError:  # pragma: no cover - depends on the installed extras
        raise VppError("isotropic remeshing needs pymeshlab: pip install 'vpp[remesh]'") from None
    ms = pymeshlab.MeshSet()
    ms.add_mesh(pymeshlab.Mesh(part.vertices, part.faces))
    ms.meshing_isotropic_explicit_remeshing(
        iterations=iterations, targetlen=pymeshlab.PureValue(edge_mm), featuredeg=FEATURE_DEG
    )
    out = ms.current_mesh()
    return part_from_arrays(out.vertex_matrix(), out.face_matrix())
