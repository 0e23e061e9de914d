"""Where a camera centre may be: one predicate for every source of viewpoints.

A centre (part frame, mm) is allowed when, in the cell frame, it is at least
floor.clearance_mm above the floor, inside the workspace (box: min <= p <= max; cylinder:
radial distance <= radius_mm, z_min_mm <= z <= z_max_mm), inside no keep-out (box: strictly
inside min < p < max; mesh: generalised winding number > 1/2), and neither inside a fixture
nor nearer than its clearance_mm to its surface. The generator, its retries, the adaptive
candidates and the view sphere drop centres it refuses; an explicit viewpoint it refuses is
a ViewpointError naming the constraint and the viewpoint.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np

from vpp_core.cell.geometry import Cell, Solid
from vpp_core.cell.setup import BoxShape, Cylinder
from vpp_core.errors import ViewpointError

Allowed = Callable[[np.ndarray], np.ndarray]
"""allowed(positions (k, 3) part frame, mm) -> (k,) bool."""


def constraints(cell: Cell) -> list[tuple[str, Allowed]]:
    """(name, test on cell-frame points) of each constraint of the setup, in a fixed order."""
    setup = cell.setup
    out: list[tuple[str, Allowed]] = []
    if setup.floor is not None:
        f = setup.floor
        out.append(
            (
                f"floor (z >= {f.z_mm:g} + clearance {f.clearance_mm:g} mm)",
                _above(f.z_mm + f.clearance_mm),
            )
        )
    ws = setup.workspace
    if isinstance(ws, BoxShape):
        out.append(("workspace box", _in_box(np.array([ws.box.min, ws.box.max]))))
    elif ws is not None:
        out.append(("workspace cylinder", _in_cylinder(ws.cylinder)))
    for name, box in cell.keep_out_boxes:
        out.append((f"{name} box", _outside_box(box)))
    for solid in cell.keep_out_meshes:
        out.append((f"{solid.name} mesh", _outside_mesh(solid)))
    for solid in cell.fixtures:
        out.append((f"{solid.name} (clearance {solid.clearance_mm:g} mm)", _clear_of(solid)))
    return out


def _above(z: float) -> Allowed:
    """Test: z >= `z`."""
    return lambda p: np.asarray(p[:, 2] >= z)


def _in_box(box: np.ndarray) -> Allowed:
    """Test: min <= p <= max on every axis (box (2, 3))."""
    return lambda p: np.asarray(((p >= box[0]) & (p <= box[1])).all(axis=1))


def _outside_box(box: np.ndarray) -> Allowed:
    """Test: not strictly inside the box (2, 3)."""
    return lambda p: np.asarray(~((p > box[0]) & (p < box[1])).all(axis=1))


def _in_cylinder(c: Cylinder) -> Allowed:
    """Test: within radius_mm of the vertical axis through centre and z_min <= z <= z_max."""
    centre, r2 = np.array(c.centre), c.radius_mm**2

    def test(p: np.ndarray) -> np.ndarray:
        radial = ((p[:, :2] - centre) ** 2).sum(axis=1) <= r2
        return np.asarray(radial & (p[:, 2] >= c.z_min_mm) & (p[:, 2] <= c.z_max_mm))

    return test


def _outside_mesh(solid: Solid) -> Allowed:
    """Test: outside the solid (winding number)."""
    return lambda p: np.asarray(~solid.inside(p))


def _clear_of(solid: Solid) -> Allowed:
    """Test: outside the solid and at least its clearance from its surface."""

    def test(p: np.ndarray) -> np.ndarray:
        ok = np.asarray(solid.distance(p) >= solid.clearance_mm)
        ok[ok] &= ~solid.inside(p[ok])
        return ok

    return test


def allowed_mask(cell: Cell | None, positions: np.ndarray) -> np.ndarray:
    """(k,) bool: the setup allows a camera centre at each position (part frame, mm)."""
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    ok = np.asarray(np.isfinite(positions).all(axis=1))
    if cell is None:
        return ok
    p = cell.to_cell(np.where(ok[:, None], positions, 0.0))
    for _, test in constraints(cell):
        idx = np.flatnonzero(ok)
        if not len(idx):
            break
        ok[idx] = test(p[idx])
    return ok


def predicate(cell: Cell | None) -> Allowed | None:
    """allowed_mask bound to `cell`, or None when there is no setup (everything allowed)."""
    if cell is None:
        return None
    return lambda positions: allowed_mask(cell, positions)


def first_violation(cell: Cell | None, positions: np.ndarray) -> list[str | None]:
    """Per position (part frame, mm), the name of the first constraint it violates or None."""
    positions = np.asarray(positions, dtype=np.float64).reshape(-1, 3)
    out: list[str | None] = [None] * len(positions)
    if cell is None:
        return out
    p = cell.to_cell(positions)
    for name, test in constraints(cell):
        bad = np.flatnonzero(~test(p))
        for i in bad:
            out[i] = out[i] or name
    return out


def check_viewpoints(cell: Cell | None, positions: np.ndarray) -> None:
    """ViewpointError naming the first explicit viewpoint the setup forbids, and why."""
    for i, name in enumerate(first_violation(cell, positions)):
        if name is not None:
            raise ViewpointError(
                f"viewpoint {i} at {np.round(positions[i], 3).tolist()} (part frame, mm) "
                f"violates the setup's {name}"
            )
