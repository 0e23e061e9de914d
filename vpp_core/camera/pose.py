"""Viewpoints: camera position, gaze and roll (`up`), and their camera-to-world frames.

Convention (SPEC §8, OpenCV): camera x right, y down, z forward along the gaze; `up` is
the image's up direction in world (-y). `camera_to_world` has columns x, y, z, position.

Default `up` rule: world +Z projected onto the image plane; when the gaze is within
~2.6° of ±Z (|gaze·Z| > 0.999), world +Y projected instead.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from vpp_core.errors import ViewpointError

WORLD_UP = np.array([0.0, 0.0, 1.0])
FALLBACK_UP = np.array([0.0, 1.0, 0.0])
PARALLEL_COS = 0.999
"""|gaze·up| above this counts as parallel: the roll would be ill-defined."""


@dataclass(frozen=True, eq=False)
class Viewpoints:
    """N camera poses in the mesh frame (mm)."""

    positions: np.ndarray  # (N, 3) float64 mm
    gazes: np.ndarray  # (N, 3) float64 unit
    ups: np.ndarray  # (N, 3) float64 unit, orthogonal to gaze

    def __len__(self) -> int:
        return len(self.positions)

    def rotations(self) -> np.ndarray:
        """(N, 3, 3) camera-to-world rotations, columns x, y, z."""
        y = -self.ups
        x = np.cross(y, self.gazes)
        return np.stack([x, y, self.gazes], axis=2)

    def camera_to_world(self) -> np.ndarray:
        """(N, 4, 4) homogeneous camera-to-world matrices."""
        m = np.zeros((len(self), 4, 4))
        m[:, :3, :3] = self.rotations()
        m[:, :3, 3] = self.positions
        m[:, 3, 3] = 1.0
        return m

    def take(self, index: np.ndarray) -> Viewpoints:
        """Subset (or reorder) by integer index."""
        return Viewpoints(self.positions[index], self.gazes[index], self.ups[index])

    def then(self, other: Viewpoints) -> Viewpoints:
        """These viewpoints followed by `other`'s."""
        return Viewpoints(
            np.vstack([self.positions, other.positions]),
            np.vstack([self.gazes, other.gazes]),
            np.vstack([self.ups, other.ups]),
        )


def make_viewpoints(
    positions: np.ndarray, gazes: np.ndarray, ups: np.ndarray | None = None
) -> Viewpoints:
    """Validate and orthonormalise poses; `ups` rows may be NaN to ask for the default rule."""
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    gazes = np.asarray(gazes, dtype=np.float64).reshape(-1, 3)
    if len(positions) != len(gazes):
        raise ViewpointError(f"{len(positions)} positions but {len(gazes)} gazes")
    if not (np.isfinite(positions).all() and np.isfinite(gazes).all()):
        raise ViewpointError("viewpoint position or gaze is not finite")
    gazes, norms = _norms(gazes)
    if (norms < 1e-12).any():
        raise ViewpointError(f"viewpoint {int(np.argmin(norms))}: gaze is the zero vector")
    gazes = gazes / norms[:, None]
    ups = _default_ups(gazes) if ups is None else _given_ups(gazes, ups)
    return Viewpoints(positions, gazes, ups)


def _default_ups(gazes: np.ndarray) -> np.ndarray:
    """(N, 3) default image-up vectors: +Z, or +Y when the gaze is (anti)parallel to Z."""
    ups = np.where((np.abs(gazes @ WORLD_UP) > PARALLEL_COS)[:, None], FALLBACK_UP, WORLD_UP)
    return _orthonormal(gazes, ups)


def _given_ups(gazes: np.ndarray, ups: np.ndarray) -> np.ndarray:
    """(N, 3) caller's up vectors made orthogonal to the gaze; NaN rows take the default."""
    ups = np.asarray(ups, dtype=np.float64).reshape(-1, 3).copy()
    if len(ups) != len(gazes):
        raise ViewpointError(f"{len(ups)} up vectors for {len(gazes)} viewpoints")
    missing = np.isnan(ups).any(axis=1)
    ups[missing] = _default_ups(gazes[missing])
    if not np.isfinite(ups).all():
        raise ViewpointError("viewpoint up vector is not finite")
    ups, norms = _norms(ups)
    cos = np.abs(np.einsum("ij,ij->i", ups, gazes)) / np.maximum(norms, 1e-300)
    bad = (norms < 1e-12) | (cos > PARALLEL_COS)
    if bad.any():
        raise ViewpointError(f"viewpoint {int(np.argmax(bad))}: up is zero or parallel to gaze")
    return _orthonormal(gazes, ups)


def _norms(v: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(N, 3) finite rows and their (N,) norms; rows whose norm overflows (an up of 1e154: its
    square is inf) are first divided by their largest |component|, keeping their direction."""
    with np.errstate(over="ignore"):
        norms = np.linalg.norm(v, axis=1)
    huge = ~np.isfinite(norms)
    if huge.any():
        v = v.copy()
        v[huge] /= np.abs(v[huge]).max(axis=1, keepdims=True)
        norms = np.linalg.norm(v, axis=1)
    return v, norms


def _orthonormal(gazes: np.ndarray, ups: np.ndarray) -> np.ndarray:
    """(N, 3) component of `ups` orthogonal to the unit `gazes`, normalised."""
    ortho = ups - np.einsum("ij,ij->i", ups, gazes)[:, None] * gazes
    return np.asarray(ortho / np.linalg.norm(ortho, axis=1)[:, None])
