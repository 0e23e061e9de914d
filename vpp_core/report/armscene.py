"""The arm at each selected viewpoint, for the viewer: link shapes once, link poses per view.

Arrays (packed into the plan scene, vpp_core.report.scene):

    arm_vertices  (V, 3) float32  every link's collision shapes in its own link frame, mm
    arm_faces     (F, 3) uint32   triangles into arm_vertices
    arm_link      (V,)   uint8    the link each vertex rides on
    arm_frames    (K, L, 4, 4) float32  link frames in the part frame at each selected view
                                  (visiting order of the document's viewpoints), row-major

A vertex v of link l at view k is drawn at arm_frames[k, l] · v.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from vpp_core.robot.collision import link_shapes
from vpp_core.robot.model import RobotSpec, load_robot
from vpp_core.robot.urdf import link_frames


def _triangles(shape: Any) -> tuple[np.ndarray, np.ndarray]:
    """(vertices, faces) of a link shape in its link frame (mm)."""
    import trimesh

    g = shape.geometry
    kind = type(g).__name__
    if kind == "BVHModel":
        v, f = shape.points, shape.faces
    elif kind == "Box":
        m = trimesh.creation.box(2 * np.abs(shape.points).max(axis=0))
        v, f = m.vertices, m.faces
    elif kind == "Sphere":
        m = trimesh.creation.icosphere(2, shape.radius)
        v, f = m.vertices, m.faces
    elif kind == "Capsule":  # ends ±h/2 along z, radius r
        h = float(np.ptp(shape.points[:, 2]))
        m = trimesh.creation.capsule(height=h, radius=shape.radius, count=[12, 12])
        v, f = m.vertices, m.faces
    else:  # cylinder: rim points at ±h/2
        h = float(np.ptp(shape.points[:, 2]))
        r = float(np.linalg.norm(shape.points[0, :2]))
        m = trimesh.creation.cylinder(radius=r, height=h, sections=16)
        v, f = m.vertices, m.faces
    v = np.asarray(v) @ shape.origin[:3, :3].T + shape.origin[:3, 3]
    return v, np.asarray(f)


def arm_arrays(
    spec: RobotSpec, part_to_cell: np.ndarray, joints_deg: np.ndarray
) -> dict[str, np.ndarray]:
    """The viewer's arm arrays for joint vectors (K, n) in deg (mm for prismatic joints)."""
    robot = load_robot(spec)
    verts, faces, links = [], [], []
    count = 0
    for link, shapes in enumerate(link_shapes(robot)):
        for s in shapes:
            v, f = _triangles(s)
            verts.append(v)
            faces.append(f + count)
            links.append(np.full(len(v), link))
            count += len(v)
    q = np.where(robot.chain.prismatic, joints_deg, np.radians(joints_deg))
    frames = np.linalg.inv(part_to_cell) @ robot.base_to_cell @ link_frames(robot.chain, q)
    return {
        "arm_vertices": np.vstack(verts).astype(np.float32),
        "arm_faces": np.vstack(faces).astype(np.uint32),
        "arm_link": np.concatenate(links).astype(np.uint8),
        "arm_frames": frames.astype(np.float32),
    }
