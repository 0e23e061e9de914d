"""How open each patch is, for the option that keeps recessed patches from driving the count.

A patch's openness is the largest number, over up to POINTS of its faces and both sides of
each, of DIRECTIONS directions spread evenly over the sensor's incidence cone around the
face's normal along which a ray from the face's centre leaves the part (and the setup's floor
and fixtures) without hitting anything: how widely cameras at any distance could see it. With
`target.open_min` = k > 0, a patch open along fewer than k directions is recessed: the inside
of a closed housing seen through the clearance around a shaft, a gear behind a slot, the far
end of a narrow bore. Candidates sample such a patch a slice per view, through an opening
narrower than the directions' spacing, so each such patch wants a view of its own. A recessed
patch keeps its row, but a partial cover gives it no weight (it may stay unmet); the strict
cover (min_coverage 1) still asks for it, and the plan document lists the recessed faces it
leaves unmet (`cover_rows.recessed`).

Off by default (k = 0): what a view sphere of 1 000 views sees of such patches counts in
issue 33's coverage, and k = 4 leaves some of it out (docs/quality.md, "Recessed patches":
a closed gearbox stand-in 9 views instead of 179, ADIS16480 8 instead of 95 with 96.5 %
of its area sampled on 1 mm² elements instead of 100 %).
"""

from __future__ import annotations

import numpy as np

from vpp_core.candidates.generator import normal_frames
from vpp_core.cell.scene import Occluders
from vpp_core.cover.patches import Patches
from vpp_core.mesh.part import Part
from vpp_core.trace.embree import EmbreeBackend
from vpp_core.trace.occluded import scene_part

DIRECTIONS = 64
"""Directions tried from each point: a Fibonacci spiral over the incidence cone (with the
default sensor's 75°, 4 of them are a cone of about 18° half-angle)."""
POINTS = 4
"""Faces of a patch tried at most (spread over its faces), each on both sides."""
CHUNK_RAYS = 1 << 20
"""Rays cast at once (bounds the memory of a pass)."""


def cone_directions(n: int, half_angle_deg: float) -> np.ndarray:
    """(n, 3) unit directions spread evenly (equal solid angle) over the cone of `half_angle_deg`
    around +z: a Fibonacci spiral."""
    i = np.arange(n) + 0.5
    z = 1.0 - i / n * (1.0 - np.cos(np.radians(half_angle_deg)))
    phi = np.pi * (3.0 - np.sqrt(5.0)) * i
    r = np.sqrt(np.maximum(0.0, 1.0 - z * z))
    return np.column_stack([r * np.cos(phi), r * np.sin(phi), z])


def openness(
    part: Part,
    patches: Patches,
    max_incidence_deg: float,
    occluders: Occluders | None = None,
    enough: int = DIRECTIONS,
) -> np.ndarray:
    """(P,) int: for each patch of `part`'s faces (or elements), the most DIRECTIONS open from
    one of its tried faces (module docstring), counted until `enough`: a patch that reaches
    it on one face and side is not tried further."""
    scene = EmbreeBackend(part if occluders is None else scene_part(part, occluders))
    cone = cone_directions(DIRECTIONS, max_incidence_deg)
    reach = 4.0 * float(np.linalg.norm(np.ptp(part.vertices, axis=0))) + 1.0
    offset = max(1e-3, 1e-6 * reach)
    out = np.zeros(patches.count, dtype=np.int64)
    for faces in _tried_faces(patches):
        for side in (1.0, -1.0):
            todo = np.flatnonzero((faces >= 0) & (out < enough))
            if len(todo):
                free = _open(scene, part, faces[todo], side, cone, offset, reach)
                out[todo] = np.maximum(out[todo], free)
    return out


def _tried_faces(patches: Patches) -> list[np.ndarray]:
    """POINTS arrays (P,) of face ids, -1 where a patch has fewer faces: the k-th holds each
    patch's face at k/POINTS of its faces (in face order)."""
    faces = np.flatnonzero(patches.of_face >= 0)
    owner = patches.of_face[faces]
    order = np.argsort(owner, kind="stable")
    faces, owner = faces[order], owner[order]
    counts = np.bincount(owner, minlength=patches.count)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    out = []
    for k in range(POINTS):
        pick = np.full(patches.count, -1, dtype=np.int64)
        has = counts > k
        pick[has] = faces[starts[has] + (k * counts[has]) // POINTS]
        out.append(pick)
    return out


def _open(
    scene: EmbreeBackend,
    part: Part,
    faces: np.ndarray,
    side: float,
    cone: np.ndarray,
    offset: float,
    reach: float,
) -> np.ndarray:
    """(k,) how many of the `cone` directions (about side · normal) from the centres of
    `faces` reach `reach` mm without a hit."""
    free = np.zeros(len(faces), dtype=np.int64)
    step = max(1, CHUNK_RAYS // len(cone))
    for lo in range(0, len(faces), step):
        f = faces[lo : lo + step]
        normal = side * part.normals[f]
        origin = part.vertices[part.faces[f]].mean(axis=1) + offset * normal
        d = normal_frames(normal) @ cone.T  # (k, 3, n): the cone about each normal
        d = np.ascontiguousarray(d.transpose(0, 2, 1).reshape(-1, 3), dtype=np.float32)
        o = np.repeat(origin, len(cone), axis=0).astype(np.float32)
        prim, _ = scene.first_hits(o, d, reach)
        free[lo : lo + step] = (prim.reshape(len(f), len(cone)) < 0).sum(axis=1)
    return free
