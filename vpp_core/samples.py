"""A sample part every installation can make: a flanged bushing (mm), for demos and tests."""

from __future__ import annotations

import numpy as np
import trimesh


def flanged_bushing(sections: int = 96) -> trimesh.Trimesh:
    """A watertight flanged bushing, Ø60 mm flange, Ø30 mm sleeve, Ø16 mm bore, 40 mm tall."""
    profile = np.array(  # (radius, z) of the closed cross-section, counter-clockwise
        [[8, 0], [30, 0], [30, 8], [15, 8], [15, 40], [8, 40], [8, 0]], dtype=float
    )
    mesh = trimesh.creation.revolve(profile, sections=sections)
    mesh.fix_normals()
    return mesh


def sample_stl(sections: int = 96) -> bytes:
    """The sample part as binary STL bytes."""
    data = flanged_bushing(sections).export(file_type="stl")
    assert isinstance(data, bytes)
    return data
