"""The planning mesh of a file: loaded (vpp_core.mesh.part), remeshed isotropically if asked
(vpp_core.mesh.remesh), split into area elements if asked (vpp_core.mesh.refine), within the
face limit."""

from __future__ import annotations

from vpp_core.errors import MeshError
from vpp_core.mesh.labels import FaceLabels, parse_label_array
from vpp_core.mesh.part import DEFAULT_MAX_FACES, Part, load_mesh, with_labels
from vpp_core.mesh.refine import refine
from vpp_core.mesh.remesh import remesh


def load_part(
    data: bytes,
    file_type: str,
    units: str,
    *,
    remesh_mm: float | None = None,
    max_face_area_mm2: float | None = None,
    max_faces: int = DEFAULT_MAX_FACES,
    labels: bytes | None = None,
) -> Part:
    """`load_mesh` (with `labels`: a label array for the file's faces, JSON or .npy, in place
    of the file's own), then `remesh` to `remesh_mm` (mm edges), then `refine` to
    `max_face_area_mm2` (mm²; faces keep their labels), each when given. A remesh drops the
    file's labels (its faces are new)."""
    part = load_mesh(data, file_type, units, max_faces=max_faces)
    if labels is not None:
        part = with_labels(part, FaceLabels(parse_label_array(labels, part.n_faces)))
    if remesh_mm is not None:
        if labels is not None:
            raise MeshError("face labels cannot follow a remesh: leave out remesh_mm or labels")
        part = remesh(part, remesh_mm, max_faces=max_faces)
    if max_face_area_mm2 is not None:
        part = refine(part, max_face_area_mm2, max_faces=max_faces)
    return part
