"""Sample inputs every installation can make: a flanged bushing (mm) and a viewpoint-like cover."""

from __future__ import annotations

import numpy as np
import scipy.sparse as sp
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


def window_cover(
    rows: int = 200_000,
    cols: int = 2_000,
    *,
    width: float = 0.02,
    drop: float = 0.05,
    values: tuple[float, float] | None = (0.26, 0.55),
    seed: int = 0,
) -> sp.csr_array:
    """(rows, cols) viewpoint-like cover matrix: each column a circular window of width·rows
    rows around a random centre, a `drop` fraction of its entries removed, coefficients uniform
    in `values` (all ones when None)."""
    rng = np.random.default_rng(seed)
    w = max(1, round(width * rows))
    centres = rng.integers(0, rows, size=cols)
    r = (centres[:, None] - w // 2 + np.arange(w)[None, :]) % rows  # (cols, w)
    c = np.broadcast_to(np.arange(cols)[:, None], r.shape)
    keep = rng.random(r.shape) >= drop
    r, c = r[keep], c[keep]
    v = np.ones(r.size) if values is None else rng.uniform(*values, size=r.size)
    return sp.csr_array(sp.coo_array((v, (r, c)), shape=(rows, cols)))
