"""Recessed patches (vpp_core.cover.access, `target.open_min`): how open a patch is,
recomputed with trimesh's own ray queries, and what a plan does with the patches seen only
through a peephole."""

from __future__ import annotations

from dataclasses import replace

import numpy as np
import pytest
import trimesh

from tests.test_quality import SMALL
from vpp_core.cover.access import DIRECTIONS, cone_directions, openness
from vpp_core.cover.density import CoverModel
from vpp_core.mesh.part import Part, part_from_arrays
from vpp_core.plan.adaptive import target_rows
from vpp_core.plan.document import CandidateGenerator, PlanRequest, SolverSettings, Target
from vpp_core.plan.pipeline import cover_patches, plan

OPEN_MIN = 4
"""The `target.open_min` docs/quality.md measures."""


def test_cone_directions_spread_evenly_over_the_cone():
    d = cone_directions(DIRECTIONS, 75.0)
    assert np.allclose(np.linalg.norm(d, axis=1), 1.0)
    assert d[:, 2].min() >= np.cos(np.radians(75.0)) - 1e-12
    # equal solid angle: z uniform over [cos 75°, 1], azimuths balanced
    assert d[:, 2].mean() == pytest.approx((1 + np.cos(np.radians(75.0))) / 2, abs=1e-9)
    assert np.abs(d[:, :2].mean(axis=0)).max() < 0.03


def housing(hole_mm: float) -> Part:
    """A closed 40 x 30 x 20 mm box of 2 mm slabs (separate bodies, as an assembly exports
    them) whose lid has a square hole of `hole_mm` in its middle."""
    slabs = [
        ([40, 30, 2], [0, 0, 1]),  # floor
        ([2, 30, 20], [-19, 0, 10]),
        ([2, 30, 20], [19, 0, 10]),
        ([36, 2, 20], [0, -14, 10]),
        ([36, 2, 20], [0, 14, 10]),
    ]
    h = hole_mm / 2
    side = (36 - hole_mm) / 2
    for x in (-(h + side / 2), h + side / 2):  # the lid: four plates around the hole
        slabs.append(([side, 26, 2], [x, 0, 19]))
    for y in (-(h + (13 - h) / 2), h + (13 - h) / 2):
        slabs.append(([hole_mm, 13 - h, 2], [0, y, 19]))
    boxes = []
    for extents, centre in slabs:
        box = trimesh.creation.box(extents)
        box.apply_translation(centre)
        boxes.append(box)
    mesh = trimesh.util.concatenate(boxes)
    vertices, faces = trimesh.remesh.subdivide_to_size(mesh.vertices, mesh.faces, max_edge=2.0)
    return part_from_arrays(vertices, faces)


def tangents(normals: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(K, 3) unit u ⟂ n (n × x, or n × y where n is near x) and v = n × u, per unit normal."""
    u = np.cross(normals, np.where(np.abs(normals[:, :1]) < 0.9, [[1.0, 0, 0]], [[0, 1.0, 0]]))
    u /= np.linalg.norm(u, axis=1, keepdims=True)
    return u, np.cross(normals, u)


def independent_recessed(
    part: Part, of_face: np.ndarray, max_incidence_deg: float, open_min: int = OPEN_MIN
) -> np.ndarray:
    """(P,) bool recessed patches of `part`'s faces grouped by `of_face` (M,) (-1: none),
    counted with trimesh's ray queries over every tried face and side, without stopping
    early (the rule of vpp_core.cover.access, written out)."""
    mesh = trimesh.Trimesh(part.vertices, part.faces, process=False)
    cone = cone_directions(DIRECTIONS, max_incidence_deg)
    tried = []  # (patch, face, side) of every tried face and side
    for p in range(of_face.max() + 1):
        faces = np.flatnonzero(of_face == p)
        for face in faces[(np.arange(min(4, len(faces))) * len(faces)) // 4]:
            tried += [(p, face, 1.0), (p, face, -1.0)]
    patch, face, side = (np.array(column) for column in zip(*tried, strict=True))
    n = side[:, None] * part.normals[face]  # (T, 3)
    frames = np.stack([*tangents(n), n], axis=1)  # (T, 3, 3): rows u, v, n
    rays = np.einsum("kj,tjd->tkd", cone, frames).reshape(-1, 3)  # (T·K, 3)
    centres = part.vertices[part.faces[face]].mean(axis=1) + 1e-3 * n
    origins = np.repeat(centres, len(cone), axis=0)
    hit = mesh.ray.intersects_any(origins, rays).reshape(len(face), len(cone))
    best = np.zeros(of_face.max() + 1, dtype=int)
    np.maximum.at(best, patch, (~hit).sum(axis=1))
    return best < open_min


def test_a_peephole_leaves_the_inside_recessed_and_an_opening_does_not():
    target = Target(resolution_mm=1.2)
    peephole, opening = housing(3.0), housing(20.0)
    for part, inside_open in ((peephole, False), (opening, True)):
        patches = cover_patches(part, target)
        counts = openness(part, patches, SMALL.max_incidence_deg)
        again = independent_recessed(part, patches.of_face, SMALL.max_incidence_deg)
        assert np.array_equal(counts < OPEN_MIN, again)
        top = patches.normals[:, 2] > 0.99
        outside = top & (patches.centres[:, 2] > 19.5)  # the lid's top: open all round
        assert outside.any() and (counts[outside] == DIRECTIONS).all()
        floor = top & (patches.centres[:, 2] < 2.5) & (np.abs(patches.centres[:, :2]) < 5).all(1)
        assert floor.any() and bool((counts[floor] >= OPEN_MIN).all()) == inside_open


def test_recessed_rows_are_never_targets_of_adaptive_rounds():
    import scipy.sparse as sp

    # rows 0 and 1 are each sampled by one candidate (and private to it); row 1 is recessed
    matrix = sp.csr_array(np.array([[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [1.0, 1.0, 1.0]]))
    model = CoverModel(
        matrix,
        np.arange(3),
        np.arange(3),
        np.ones(3, bool),
        np.zeros(0, np.int64),
        np.ones(3),
        recessed=np.array([False, True, False]),
    )
    assert target_rows(model, np.array([0, 1])).tolist() == [0]
    assert model.row_weights().tolist() == [1.0, 0.0, 1.0]
    # a patch weighs what can be sampled of it: its area times its best candidate's share
    shares = replace(model, reach=np.array([0.5, 1.0, 0.02]))
    assert shares.row_weights().tolist() == [0.5, 0.0, 0.02]


def peephole_request(open_min: int | None = None) -> PlanRequest:
    """The peephole housing's plan under SMALL at 1.2 mm from 60 candidates (no adaptive
    rounds: one pool whatever `open_min`, so that the rows' weights compare), with `open_min`
    where given."""
    target = {"resolution_mm": 1.2} | ({} if open_min is None else {"open_min": open_min})
    return PlanRequest(
        sensor=SMALL,
        target=Target(**target),
        candidates=CandidateGenerator(count=60, seed=1, adaptive=False),
        solver=SolverSettings(time_limit_s=20),
    )


def test_the_plan_gives_recessed_rows_no_weight_and_lists_what_it_leaves_of_them():
    part = housing(3.0)
    doc = plan(part, peephole_request(open_min=OPEN_MIN))
    default = plan(part, peephole_request())  # the default: no patch is recessed
    rows = doc.cover_rows
    assert rows is not None and rows.recessed is not None and rows.recessed_area
    assert default.cover_rows is not None and default.cover_rows.recessed_area == 0
    assert rows.recessed.faces > 0  # the inside: some candidates see it through the hole
    # the recessed patches, recomputed: their faces are the ones listed (those left unmet)
    of_face = np.asarray(rows.patch_of_face)
    patches = cover_patches(part, doc.target)
    assert np.array_equal(patches.of_face, of_face)
    inside = independent_recessed(part, of_face, SMALL.max_incidence_deg)
    listed = np.asarray(rows.recessed.ids)
    assert inside[of_face[listed]].all()
    counted = part.areas[part.counted].sum()
    assert rows.recessed_area == pytest.approx(
        part.areas[inside[of_face] & part.counted].sum() / counted
    )
    # the partial cover's area is the open rows': none of the listed faces is in it
    assert doc.partial is not None and not set(listed) & set(doc.partial.left_out.ids)
    assert doc.partial.covered_fraction >= doc.target.min_coverage
    assert doc.partial.coverable_area_mm2 < default.partial.coverable_area_mm2
    assert len(doc.viewpoints) < len(default.viewpoints)  # 8 against 11 (2-core Xeon, HiGHS 1.16)


def test_the_setups_floor_closes_what_faces_it():
    from vpp_core.cell.geometry import resolve
    from vpp_core.cell.setup import Setup
    from vpp_core.plan.cellplan import scene_occluders

    box = trimesh.creation.box([40, 30, 10])
    box.apply_translation([0, 0, 5.5])  # 0.5 mm above the floor at z = 0
    vertices, faces = trimesh.remesh.subdivide_to_size(box.vertices, box.faces, max_edge=4.0)
    part = part_from_arrays(vertices, faces)
    patches = cover_patches(part, Target(resolution_mm=1.2))
    cell = resolve(Setup.model_validate({"floor": {"z_mm": 0}}))
    free = openness(part, patches, SMALL.max_incidence_deg)
    floored = openness(part, patches, SMALL.max_incidence_deg, scene_occluders(part, SMALL, cell))
    bottom = patches.normals[:, 2] < -0.99
    top = patches.normals[:, 2] > 0.99
    assert bottom.any() and (free[bottom] == DIRECTIONS).all()
    assert (floored[bottom] < OPEN_MIN).all()
    assert (floored[top] == DIRECTIONS).all()
