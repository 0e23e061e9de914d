"""Why a plan needs the views it has: faces that drive the count on CAD tessellations.

- sub-pixel faces: counted faces of area below p², p the pixel footprint at the working
  distance (SPEC §7), so that a face can hold at most about one ray per view;
- single-candidate faces: counted faces that exactly one candidate sees, with their rays;
  a selected view that alone sees a face with at least `WELL_SEEN_RAYS` rays (real surface,
  not a stray ray) is "forced": candidates along the normal are too few for that surface;
- internal faces: back-to-back (a face coincides with another of opposite orientation) or
  enclosed: from points just off either side of the face, none of `ESCAPE_DIRECTIONS` rays
  spread over the hemisphere leaves the part, so the face lies in a closed cavity or is
  reached only through cracks (tested on the faces seen by at most one candidate and the
  selected views' private faces, the ones that can force a view);
- per selected view, its private faces: rows it alone satisfies (without it the row's demand
  is not met). A view whose private faces are all of the kinds above is "driven" by them;
- undersampled faces: faces larger than an area element (`ELEMENT_FOOTPRINTS` pixel
  footprints) that the plan counts as seen while its rays land on less than half of their
  area, estimated from each ray's footprint at the face centre. A face counts as seen when one
  ray lands on it (SPEC §3), so a long CAD facet on a hole wall is "seen" when a view grazes
  its rim; `--max-face-area` splits such faces into elements (vpp_core.mesh.refine);
- size: a part whose area exceeds what all its candidates frame head-on at the far end of
  the depth of field (a 100 m cube: its plan sees 0.06 % of it at points), most likely read
  in the wrong units.
"""

from __future__ import annotations

import math

import numpy as np
import scipy.sparse as sp
from pydantic import BaseModel

from vpp_core.camera.pose import Viewpoints
from vpp_core.camera.sensor import Sensor
from vpp_core.cover.density import CoverModel
from vpp_core.cover.problem import COVER_TOL, coverage
from vpp_core.mesh.part import Part
from vpp_core.trace.rays import RayBackend

ESCAPE_DIRECTIONS = 64
"""Rays per side of a face in the enclosure test (Fibonacci hemisphere)."""
MAX_ESCAPE_FACES = 5_000
"""At most this many faces get the enclosure test (the most likely to force a view first):
about 0.4 ms each on 2 cores, so at 20 000 the test took 7.5 s of the bolt's plan and 8.2 s
of the counter's, more than the plan's budget keeps for what follows its cover."""
OFFSET_REL = 1e-6
"""Ray origins sit this fraction of the part's diagonal off the face."""
SUGGESTED_COVERAGE = (0.999, 0.995, 0.99, 0.98, 0.95)
"""Partial-cover fractions the hint may name, largest first."""
WELL_SEEN_RAYS = 4
"""A single-candidate face with at least this many rays is real surface, not a stray ray."""
SUGGESTED_TILT_DEG = 30
"""The candidate tilt the hint names (docs/cad-meshes.md)."""
ELEMENT_FOOTPRINTS = 30
"""The area element the hint names, in pixel footprints p² (1 mm² for the paper camera)."""
UNSAMPLED_SHARE = 0.001
"""The element hint is given when the plan's seen faces hold at least this share of the
coverable area that none of its rays lands on."""


class FaceGroup(BaseModel):
    """A set of counted faces: how many and their area (mm²)."""

    faces: int
    area_mm2: float


class SingleCandidate(FaceGroup):
    """Faces exactly one candidate sees; `one_ray` of them get a single ray from it.

    `forced_views`: selected views that alone see some face with ≥ WELL_SEEN_RAYS rays.
    """

    one_ray: int
    median_rays: float | None
    forced_views: int = 0


class Internal(BaseModel):
    """Back-to-back and enclosed faces (see the module notes); `tested` faces were ray-tested."""

    back_to_back: FaceGroup
    enclosed: FaceGroup
    tested: int
    directions: int


class Undersampled(FaceGroup):
    """Seen faces larger than `element_mm2` that the plan's rays land on less than half of;
    `unsampled_mm2`: area of all seen faces larger than `element_mm2` that no ray lands on."""

    element_mm2: float
    unsampled_mm2: float


class ViewCause(BaseModel):
    """A selected view's private faces, and how many of them are sub-pixel, single or internal."""

    id: int
    private_faces: int
    private_area_mm2: float
    weak_faces: int
    weak_area_mm2: float
    driven: bool


class Diagnostics(BaseModel):
    """Face statistics that explain the view count; `hint` names the option when it helps."""

    pixel_footprint_mm: float
    subpixel: FaceGroup
    single_candidate: SingleCandidate
    internal: Internal
    undersampled: Undersampled | None = None
    viewpoints: list[ViewCause]
    driven_views: int
    driven_area_mm2: float
    hint: str | None


def diagnose(
    part: Part,
    sensor: Sensor,
    views: Viewpoints,
    counts: sp.sparray,
    model: CoverModel,
    selected: np.ndarray,
    backend: RayBackend,
    partial: bool = False,
    normal_candidates: bool = False,
) -> Diagnostics:
    """Diagnostics of `views` `selected` (K,) given R (M, N) and the cover's rows (`model`).

    `partial`: a partial cover was asked for (no coverage hint); `normal_candidates`: the
    candidates were generated along the normals (tilt 0), so a tilt may be suggested.
    """
    areas, counted = part.areas, part.counted
    p = sensor.pixel_pitch_mm(sensor.working_distance)
    subpixel = counted & (areas < p * p)
    r = sp.csr_array(counts)
    seen_by = np.diff(r.indptr)
    single = counted & (seen_by == 1)
    private = private_rows(model.matrix, selected)
    hard = np.flatnonzero(single | (counted & (seen_by == 0)))
    mine = model.faces_of(private.indices)
    suspects = np.concatenate([mine, np.setdiff1d(hard, mine)])  # private faces first
    enclosed = np.zeros(part.n_faces, dtype=bool)
    tested = suspects[:MAX_ESCAPE_FACES]
    enclosed[tested] = enclosed_faces(part, tested, backend)
    b2b = back_to_back(part)
    weak = subpixel | single | enclosed | b2b
    causes = _causes(private, model, selected, areas, weak)
    driven = [c for c in causes if c.driven]
    driven_area = float(sum(c.private_area_mm2 for c in driven))
    first = r.indptr[:-1][single]
    rays = r.data[first]
    forced = np.intersect1d(r.indices[first[rays >= WELL_SEEN_RAYS]], selected)
    under = undersampled(part, sensor, views, r, selected, ELEMENT_FOOTPRINTS * p * p)
    coverable = float(model.areas.sum())
    reached = float(areas[counted & (seen_by > 0)].sum())  # faces some candidate's ray hits
    return Diagnostics(
        pixel_footprint_mm=p,
        subpixel=_group(subpixel, areas),
        single_candidate=SingleCandidate(
            **_group(single, areas).model_dump(),
            one_ray=int(np.count_nonzero(rays == 1)),
            median_rays=float(np.median(rays)) if rays.size else None,
            forced_views=len(forced),
        ),
        internal=Internal(
            back_to_back=_group(b2b & counted, areas),
            enclosed=_group(enclosed & counted, areas),
            tested=len(tested),
            directions=ESCAPE_DIRECTIONS,
        ),
        undersampled=under,
        viewpoints=causes,
        driven_views=len(driven),
        driven_area_mm2=driven_area,
        hint=_join(
            _size_hint(part, sensor, len(views)),
            _element_hint(under, reached),
            _tilt_hint(len(forced), len(causes)) if normal_candidates else None,
            None if partial else _hint(len(driven), len(causes), driven_area, coverable),
        ),
    )


def sampled_area(
    part: Part, sensor: Sensor, views: Viewpoints, counts: sp.csr_array, selected: np.ndarray
) -> np.ndarray:
    """(M,) mm² of each face that the rays of `views` `selected` (K,) land on, at most:
    Σ_j R_ij · a_ij, a_ij a ray's footprint at the face centre, z³ / (d fx fy cos θ) for depth
    z, distance d and incidence θ (the pixel's solid angle z cos α / fx fy, times d² / cos θ).
    z is clipped to the depth of field, where every counted ray lands: a big face's centre can
    lie out of it, even behind the camera."""
    sub = sp.csc_array(counts[:, selected])
    centres = part.vertices[part.faces].mean(axis=1)
    cos_min = math.cos(math.radians(sensor.max_incidence_deg))
    out = np.zeros(part.n_faces)
    for k, j in enumerate(selected):
        seg = slice(sub.indptr[k], sub.indptr[k + 1])
        faces = sub.indices[seg]
        d = centres[faces] - views.positions[j]
        dist = np.linalg.norm(d, axis=1)
        depth = np.clip(d @ views.gazes[j], sensor.near_mm, sensor.far_mm)
        cos = np.abs(np.einsum("ij,ij->i", part.normals[faces], d)) / dist
        footprint = depth**3 / (dist * sensor.fx * sensor.fy * np.maximum(cos, cos_min))
        out[faces] += sub.data[seg] * footprint
    return out


def undersampled(
    part: Part,
    sensor: Sensor,
    views: Viewpoints,
    counts: sp.csr_array,
    selected: np.ndarray,
    element_mm2: float,
) -> Undersampled:
    """Seen faces larger than `element_mm2` whose sampled area (`sampled_area`) is below half."""
    element_mm2 = float(f"{element_mm2:.2g}")
    areas = part.areas
    large = part.counted & (areas > element_mm2)
    large[large] = counts[np.flatnonzero(large)][:, selected].sum(axis=1) > 0
    sampled = np.minimum(sampled_area(part, sensor, views, counts, selected), areas)
    under = large & (sampled < 0.5 * areas)
    return Undersampled(
        **_group(under, areas).model_dump(),
        element_mm2=element_mm2,
        unsampled_mm2=float((areas - sampled)[large].sum()),
    )


def private_rows(matrix: sp.csr_array, selected: np.ndarray) -> sp.csc_array:
    """(M, K) bool csc: row i is private to the k-th selected view (met with it, not without)."""
    cov = coverage(matrix, selected)
    sub = sp.csc_array(matrix[:, selected])
    rows = sub.indices
    alone = (cov[rows] >= 1.0 - COVER_TOL) & (cov[rows] - sub.data < 1.0 - COVER_TOL)
    out = sp.csc_array((alone, rows, sub.indptr), shape=sub.shape)
    out.eliminate_zeros()
    return out


def back_to_back(part: Part) -> np.ndarray:
    """(M,) bool: faces on the same three vertices as another face wound the other way."""
    rep = part.representative
    dup = np.flatnonzero(rep != np.arange(part.n_faces))
    tri = part.vertices[part.faces]  # winding as in the file
    wound = np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0])
    opposite = np.einsum("ij,ij->i", wound[dup], wound[rep[dup]]) < 0
    out = np.zeros(part.n_faces, dtype=bool)
    out[dup[opposite]] = True
    out[rep[dup[opposite]]] = True
    return out


def enclosed_faces(part: Part, faces: np.ndarray, backend: RayBackend) -> np.ndarray:
    """(F,) bool: no ray from just off either side of each face (F,) escapes the part."""
    directions = _hemisphere(ESCAPE_DIRECTIONS)
    diagonal = float(np.linalg.norm(np.ptp(part.vertices, axis=0)))
    reach = 4.0 * diagonal + 1.0
    centres = part.vertices[part.faces[faces]].mean(axis=1)
    out = np.ones(len(faces), dtype=bool)
    for k, (centre, normal) in enumerate(zip(centres, part.normals[faces], strict=True)):
        if not normal.any():  # degenerate: no side to look from
            out[k] = False
            continue
        for side in (normal, -normal):
            rays = (_frame(side) @ directions.T).T.astype(np.float32)
            hit, _ = backend.first_hits(centre + OFFSET_REL * diagonal * side, rays, reach)
            if np.any(hit < 0):
                out[k] = False
                break
    return out


def _hemisphere(n: int) -> np.ndarray:
    """(n, 3) unit directions spread evenly over the hemisphere z > 0 (Fibonacci)."""
    k = np.arange(n) + 0.5
    z = 1.0 - k / n
    phi = k * math.pi * (3.0 - math.sqrt(5.0))
    s = np.sqrt(1.0 - z * z)
    return np.column_stack([s * np.cos(phi), s * np.sin(phi), z])


def _frame(normal: np.ndarray) -> np.ndarray:
    """(3, 3) rotation whose third column is the unit `normal`."""
    helper = np.array([1.0, 0.0, 0.0]) if abs(normal[0]) < 0.9 else np.array([0.0, 1.0, 0.0])
    x = np.cross(helper, normal)
    x /= np.linalg.norm(x)
    return np.column_stack([x, np.cross(normal, x), normal])


def _causes(
    private: sp.csc_array,
    model: CoverModel,
    selected: np.ndarray,
    areas: np.ndarray,
    weak: np.ndarray,
) -> list[ViewCause]:
    """One ViewCause per selected view from its private rows and their faces."""
    out = []
    row_areas = model.row_areas()
    for k, j in enumerate(selected):
        rows = private.indices[private.indptr[k] : private.indptr[k + 1]]
        faces = model.faces_of(rows)
        w = weak[faces]
        out.append(
            ViewCause(
                id=int(j),
                private_faces=len(faces),
                private_area_mm2=float(row_areas[rows].sum()),
                weak_faces=int(w.sum()),
                weak_area_mm2=float(areas[faces[w]].sum()),
                driven=bool(len(faces) and w.all()),
            )
        )
    return out


def _group(mask: np.ndarray, areas: np.ndarray) -> FaceGroup:
    """FaceGroup of the faces in `mask` (M,) bool."""
    return FaceGroup(faces=int(mask.sum()), area_mm2=float(areas[mask].sum()))


def _join(*hints: str | None) -> str | None:
    """The given hints as one text, or None."""
    return "; ".join(h for h in hints if h) or None


def _tilt_hint(forced: int, views: int) -> str | None:
    """The hint when views are forced by well-seen faces only one normal candidate sees."""
    if not forced:
        return None
    return (
        f"{forced} of {views} viewpoints are the only candidate that sees some face with "
        f"{WELL_SEEN_RAYS} or more rays (holes, pocket walls); try candidates tilted off the "
        f"normal (--tilt {SUGGESTED_TILT_DEG}, or candidates.tilt_deg): they see such faces "
        "from several poses (2-5x fewer views on machined parts), and reach more surface, "
        "which a strict cover must then cover too"
    )


def _size_hint(part: Part, sensor: Sensor, candidates: int) -> str | None:
    """The hint when the part's counted area (mm²) exceeds what all its `candidates` frame
    head-on at the far end of the depth of field, where a frame is largest: a part in the
    wrong units (a file in mm read as m has a million times its area; a plan of it is
    meaningless, every view a speck on one face), or too few candidates for its size."""
    w, h = sensor.frame_mm(sensor.far_mm)  # the largest frame, at the far limit
    area, framed = part.area_mm2, candidates * w * h
    if candidates <= 0 or area <= framed:
        return None
    lo, hi = part.bounds
    size = " × ".join(f"{e:.4g}" for e in hi - lo)
    return (
        f"the part ({size} mm, {area:.3g} mm²) has {area / framed:.3g} times the area its "
        f"{candidates} candidates frame head-on at the far end of the depth of field "
        f"({w:.0f} × {h:.0f} mm each at {sensor.far_mm:g} mm): "
        "check its units (--units, or units at upload: a file in mm read as m has a million "
        "times the area), or ask for more candidates"
    )


def _element_hint(under: Undersampled, reached: float) -> str | None:
    """The hint when seen faces larger than an element hold area that no ray lands on;
    `reached`: the area (mm²) of the counted faces some candidate's ray hits, of which the
    unsampled area is a share (a face hit by one ray counts whole in both)."""
    if reached <= 0 or under.unsampled_mm2 < UNSAMPLED_SHARE * reached:
        return None
    a, edge = f"{under.element_mm2:g}", f"{math.sqrt(under.element_mm2):.2g}"
    return (
        f"faces larger than {a} mm² count as seen when one ray lands on them: "
        f"{under.unsampled_mm2:.3g} mm² of them ({under.unsampled_mm2 / reached:.2%} of the "
        f"area the candidates reach) gets no ray from this plan, and {under.faces} get rays on "
        f"less than half of their area; split them into area elements (--max-face-area {a}, or "
        "max_face_area_mm2 at upload) so that seen means seen, or remesh the part "
        f"(--remesh {edge}, or remesh_mm) for a count that does not depend on its export"
    )


def _hint(driven: int, views: int, area: float, coverable: float) -> str | None:
    """The CLI/document hint when sub-pixel, single-candidate or internal faces force views."""
    if not driven or coverable <= 0:
        return None
    share = area / coverable
    fraction = next((f for f in SUGGESTED_COVERAGE if 1.0 - f >= share), None)
    if fraction is None:
        return None
    return (
        f"{driven} of {views} viewpoints are there only for sub-pixel, single-candidate or "
        f"internal faces ({area:.3g} mm², {share:.3%} of the coverable area); a partial cover "
        f"(--min-coverage {fraction:g}, or target.min_coverage in the plan request) leaves "
        "such faces out"
    )
