"""Shared fixtures: synthetic parts built from arrays, and paths to the shared data."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from vpp_core.mesh import Part, part_from_arrays

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
MESHES = SHARED / "meshes"
ORLIB = SHARED / "data" / "orlib-scp"


def shared_dir(path: Path) -> Path:
    """The shared data folder, or skip the test with a message when it is absent."""
    if not path.is_dir():
        pytest.skip(f"shared data not found at {path} (see README: tests read ../shared)")
    return path


def plate(side: float = 20.0, z: float = 0.0, n: int = 1, tilt_deg: float = 0.0) -> tuple:
    """(vertices, faces) of a square plate of `side` mm at height z, normal +Z, n×n quads.

    Tilted by `tilt_deg` about the X axis through its centre.
    """
    t = np.linspace(-side / 2, side / 2, n + 1)
    xx, yy = np.meshgrid(t, t, indexing="ij")
    v = np.column_stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)])
    a = np.radians(tilt_deg)
    rot = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    v = v @ rot.T + [0, 0, z]
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a0, b0, c0, d0 = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    f = np.vstack(
        [
            np.column_stack([a0.ravel(), b0.ravel(), c0.ravel()]),
            np.column_stack([a0.ravel(), c0.ravel(), d0.ravel()]),
        ]
    )
    return v, f


def plate_part(**kw: float) -> Part:
    """A plate as a Part (mm)."""
    v, f = plate(**kw)
    return part_from_arrays(v, f)


@pytest.fixture
def tmp_cwd(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """Run in a temporary directory."""
    monkeypatch.chdir(tmp_path)
    return tmp_path
