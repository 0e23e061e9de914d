"""The plan's poses for the cell: a flat CSV table and robot-friendly JSON (position +
quaternion), in visiting order, in mm or m.

The quaternion (w, x, y, z; unit, w >= 0) is the rotation of the viewpoint's camera_to_world
(columns: the camera's x, y, z axes in the frame). Frames: `part` is the mesh's frame (the
document's top-level poses), `cell` the plan's viewpoints' `cell` poses (setup.part_to_cell
applied); a plan without a setup has the two frames equal.
"""

from __future__ import annotations

import csv
import io
import json
from typing import Literal

import numpy as np

from vpp_core.plan.document import PlanDocument

Unit = Literal["mm", "m"]
Frame = Literal["cell", "part"]
SCALE: dict[str, float] = {"mm": 1.0, "m": 1e-3}
"""Factor from the plan's mm to each unit."""
COLUMNS = ["index", "x", "y", "z", "qw", "qx", "qy", "qz"]
FRAME_NOTES = {
    "part": "the part (mesh) frame",
    "cell": "the cell frame: setup.part_to_cell applied (identity without a setup)",
}


def quaternion(rotation: np.ndarray) -> np.ndarray:
    """(w, x, y, z) unit quaternion of a 3×3 rotation matrix, w >= 0 (Shepperd's method)."""
    r = np.asarray(rotation, dtype=np.float64)
    tr = np.trace(r)
    i = int(np.argmax([tr, r[0, 0], r[1, 1], r[2, 2]]))
    if i == 0:
        s = 2.0 * np.sqrt(max(1.0 + tr, 0.0))
        q = [s / 4, (r[2, 1] - r[1, 2]) / s, (r[0, 2] - r[2, 0]) / s, (r[1, 0] - r[0, 1]) / s]
    else:
        a, b, c = (i - 1, i % 3, (i + 1) % 3)
        s = 2.0 * np.sqrt(max(1.0 + r[a, a] - r[b, b] - r[c, c], 0.0))
        q = [0.0, 0.0, 0.0, 0.0]
        q[0] = (r[c, b] - r[b, c]) / s
        q[1 + a] = s / 4
        q[1 + b] = (r[b, a] + r[a, b]) / s
        q[1 + c] = (r[c, a] + r[a, c]) / s
    out = np.asarray(q) / np.linalg.norm(q)
    return np.asarray(out if out[0] >= 0 else -out)


def rotation(q: np.ndarray) -> np.ndarray:
    """3×3 rotation matrix of a unit quaternion (w, x, y, z)."""
    w, x, y, z = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def pose_rows(doc: PlanDocument, unit: Unit = "mm", frame: Frame = "cell") -> list[list[float]]:
    """One row per viewpoint in visiting order: index, x, y, z (unit), qw, qx, qy, qz."""
    rows = []
    for i, v in enumerate(doc.viewpoints):
        pose = v.cell if frame == "cell" and v.cell is not None else v
        c2w = np.asarray(pose.camera_to_world)
        xyz = (np.asarray(pose.position) * SCALE[unit]).tolist()
        rows.append([i, *xyz, *quaternion(c2w[:3, :3]).tolist()])
    return rows


def poses_csv(doc: PlanDocument, unit: Unit = "mm", frame: Frame = "cell") -> str:
    """The poses as CSV with a header row (COLUMNS); floats at full precision."""
    out = io.StringIO()
    writer = csv.writer(out, lineterminator="\n")
    writer.writerow(COLUMNS)
    for row in pose_rows(doc, unit, frame):
        writer.writerow([int(row[0]), *(repr(float(x)) for x in row[1:])])
    return out.getvalue()


def poses_json(doc: PlanDocument, unit: Unit = "mm", frame: Frame = "cell") -> str:
    """The poses as JSON: {frame, unit, poses: [{index, id, position {x,y,z},
    orientation {w,x,y,z}}], tour figures}."""
    poses = [
        {
            "index": int(r[0]),
            "id": v.id,
            "position": dict(zip("xyz", r[1:4], strict=True)),
            "orientation": dict(zip("wxyz", r[4:8], strict=True)),
        }
        for r, v in zip(pose_rows(doc, unit, frame), doc.viewpoints, strict=True)
    ]
    tour = doc.tour
    home = None if tour is None or tour.home is None else np.asarray(tour.home, dtype=float)
    if home is not None and frame == "cell" and doc.setup is not None:
        m = np.asarray(doc.setup.part_to_cell)
        home = m[:3, :3] @ home + m[:3, 3]
    body = {
        "format": "vpp-poses/1",
        "frame": frame,
        "frame_note": FRAME_NOTES[frame],
        "unit": unit,
        "mesh_id": doc.mesh.id,
        "home": None if home is None else _scaled(home.tolist(), unit),
        "cycle_time_s": None if tour is None else tour.cycle_time_s,
        "poses": poses,
    }
    return json.dumps(body, indent=1)


def _scaled(xyz: list[float], unit: Unit) -> dict[str, float]:
    """{x, y, z} of a mm position in `unit`."""
    return dict(zip("xyz", (float(c) * SCALE[unit] for c in xyz), strict=True))
