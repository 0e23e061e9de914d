"""Isotropic remeshing before planning (vpp_core.mesh.remesh.remesh, vpp_core.mesh.tessellate):
the same surface with even faces, within the face limit; checked against the analytic profile."""

from __future__ import annotations

import numpy as np
import pytest

from vpp_core.errors import LimitError, MeshError
from vpp_core.mesh.part import load_mesh
from vpp_core.mesh.tessellate import load_part
from vpp_core.samples import sample_stl

pytest.importorskip("pymeshlab")
from vpp_core.mesh.remesh import remesh, remeshed_faces  # noqa: E402

PROFILE = np.array([[8, 0], [30, 0], [30, 8], [15, 8], [15, 40], [8, 40], [8, 0]], dtype=float)
"""(radius, z) mm of the sample bushing's cross-section (vpp_core.samples.flanged_bushing)."""


def profile_distance(points: np.ndarray) -> np.ndarray:
    """(n,) mm from each point (n, 3) of a solid of revolution about z to PROFILE, in (r, z)."""
    rz = np.column_stack([np.hypot(points[:, 0], points[:, 1]), points[:, 2]])
    best = np.full(len(rz), np.inf)
    for a, b in zip(PROFILE[:-1], PROFILE[1:], strict=True):
        t = np.clip((rz - a) @ (b - a) / ((b - a) @ (b - a)), 0, 1)
        best = np.minimum(best, np.linalg.norm(rz - (a + t[:, None] * (b - a)), axis=1))
    return best


def edge_lengths(part) -> np.ndarray:
    """(M, 3) mm: the length of each face's edges."""
    corners = part.vertices[part.faces]
    return np.linalg.norm(corners - np.roll(corners, 1, axis=1), axis=2)


def test_remesh_keeps_the_surface_and_evens_the_faces():
    part = load_mesh(sample_stl(), "stl")
    out = remesh(part, 2.0)
    assert out.area_mm2 == pytest.approx(part.area_mm2, rel=0.01)
    assert profile_distance(out.vertices).max() < 0.05  # 96 sections: chord error 0.016 mm
    assert profile_distance(part.vertices).max() < 1e-5  # the check itself (STL: float32)
    assert 1.6 < np.median(edge_lengths(out)) < 2.4 and edge_lengths(out).max() < 4.0
    assert edge_lengths(part).max() > 30.0  # the input: strips as long as the sleeve
    assert out.n_faces == pytest.approx(remeshed_faces(part, 2.0), rel=0.2)
    assert out.warnings[-1] == f"remeshed at 2 mm edges: {part.n_faces} faces -> {out.n_faces}"
    # the bore, the flange's top and the sleeve's top stay where they were: features kept
    for z in (8.0, 40.0):
        assert np.isclose(out.vertices[:, 2], z, atol=1e-6).sum() >= 20


def test_remesh_refuses_bad_edges_and_checks_the_face_limit_first():
    part = load_mesh(sample_stl(), "stl")
    for bad in (0.0, -1.0, float("nan"), float("inf")):
        with pytest.raises(MeshError, match="positive"):
            remesh(part, bad)
    guess = remeshed_faces(part, 0.5)
    with pytest.raises(LimitError, match=f"about {guess} faces, the limit is 1000"):
        remesh(part, 0.5, max_faces=1000)


def test_load_part_remeshes_then_splits_into_elements():
    part = load_part(sample_stl(), "stl", "mm", remesh_mm=3.0, max_face_area_mm2=1.0)
    assert part.areas.max() <= 1.0 + 1e-9
    assert part.warnings[-2].startswith("remeshed at 3 mm edges")
    assert part.warnings[-1].startswith("faces larger than 1 mm² or longer than 2 mm split")
