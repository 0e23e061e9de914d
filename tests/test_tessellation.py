"""Tessellation invariance (issue 10): one geometry, two tessellations, the same view count.

The CAD export of the shared Hirth joint (slivers down to 1.5e-6 mm², non-manifold edges) is
planned against an isotropic remesh of it made here (pymeshlab, 1 mm edges, features kept),
with the paper's camera, 0.18 mm and 500 candidates generated on each mesh: at the defaults
(issue 33: patch rows, tilted gazes, stand-off from the target, adaptive candidates) the
counts agree within 10 % or one view, each plan sampling all the patch area its candidates
reach. Under the paper profile with the flags docs/cad-meshes.md named (tilt 30, partial
cover 0.999), the same holds on plate_holes against a 4 mm remesh (visibility), and makes
featuretype's count independent of the generator's seed (within 1).
On 1 mm² area elements (vpp_core.mesh.refine), the CAD plan also sees what it claims: traced on
the remesh, it sees what the remesh's candidates reach. Remeshed both at 2 mm before planning
(vpp_core.mesh.remesh.remesh, --remesh 2), featuretype's two exports agree within 1 at F = 0.99
(greedy covers, the camera at half its resolution).
"""

from __future__ import annotations

import numpy as np
import pytest
import scipy.sparse as sp

from tests.conftest import MESHES, shared_dir
from vpp_core.camera.sensor import Sensor
from vpp_core.mesh.part import Part, load_mesh
from vpp_core.plan.document import (
    CandidateGenerator,
    PlanDocument,
    PlanRequest,
    SolverSettings,
    Target,
)

MIN_COVERAGE = 0.999
"""The documented partial-cover setting (docs/cad-meshes.md)."""
COMPARE_COVERAGE = 0.99
"""The documented setting for comparing exports of one part with --remesh."""
HALF = Sensor(width_px=960, height_px=600)
"""The paper camera at half its resolution (the same field of view and depth of field): a
quarter of the rays, where a test compares two greedy covers of one camera."""


def partial_view_counts(pairs: list[tuple[Part, PlanRequest]]) -> list[int]:
    """Views of each (part, request) plan, each checked to cover the requested fraction;
    what each plan was made of is printed (shown when a comparison of counts fails: pymeshlab
    remeshes the same input differently depending on the folder it is installed in, 18 850
    or 18 862 faces for plate_holes at 4 mm; docs/cad-meshes.md)."""
    from vpp_core.plan.pipeline import plan

    counts = []
    for part, request in pairs:
        doc = plan(part, request)
        wanted = request.target.min_coverage
        assert doc.partial is not None and doc.partial.covered_fraction >= wanted
        counts.append(len(doc.viewpoints))
        print(plan_trail(part, doc))
    return counts


def plan_trail(part: Part, doc: PlanDocument) -> str:
    """One line on what a plan was made of: the mesh, the candidates, the rays and the cover."""
    info = doc.candidate_info
    positions = np.array([c.position for c in doc.candidates])
    return (
        f"mesh {part.id[:12]} {part.n_faces} faces; candidates {info.generated} "
        f"(dropped {info.dropped}, positions sum {positions.sum():.6f}); rays valid "
        f"{doc.rays.valid if doc.rays else None}; views {[v.id for v in doc.viewpoints]}"
    )


@pytest.fixture(scope="module")
def two_tessellations() -> tuple[Part, Part]:
    data = (shared_dir(MESHES) / "hirth_sample_small.stl").read_bytes()
    pytest.importorskip("pymeshlab")
    from vpp_core.mesh.remesh import isotropic_remesh

    cad = load_mesh(data, "stl")
    iso = isotropic_remesh(cad, 1.0)
    assert iso.area_mm2 == pytest.approx(cad.area_mm2, rel=0.03)  # the same geometry
    assert np.median(iso.areas) > 100 * np.median(cad.areas[cad.areas < 1e-3])
    return cad, iso


@pytest.mark.slow
@pytest.mark.parametrize("formulation", ["visibility", "density"])
def test_default_counts_agree_across_tessellations(two_tessellations, formulation):
    """Issue 33 item 4: nothing but the formulation (and a shorter limit than the default
    60 s for the whole plan: 6 s, by which both are proven optimal or within one view of
    their bound, measured at 0.999 met: density 8 (bound 7) and 7 (6) at 3, 6 and 15 s
    alike, 10 and 9 only at 2 s), and the two tessellations' counts agree within 10 % or one
    view, each meeting r̄ on 0.99 of the area that can be sampled and seeing 0.999 of it
    (pipeline.SEEN_SHARE)."""
    from vpp_core.plan.pipeline import plan

    request = PlanRequest(
        target=Target(formulation=formulation), solver=SolverSettings(time_limit_s=6)
    )
    docs = [plan(part, request) for part in two_tessellations]
    counts = [len(d.viewpoints) for d in docs]
    assert abs(counts[0] - counts[1]) <= max(1, 0.1 * max(counts)), counts
    for doc in docs:
        rows = doc.cover_rows
        assert rows is not None and rows.kind == "patches"
        assert rows.sampled_area is not None and rows.max_sampled_area is not None
        p = doc.partial
        assert p is not None and p.covered_fraction >= 0.99 and p.min_coverage == 0.99
        if formulation == "density":  # SEEN_SHARE; visibility: the fraction is the seen share
            assert p.seen_fraction is not None and p.seen_fraction >= 0.999


@pytest.mark.slow
def test_tilted_candidates_keep_plate_holes_counts_within_one_across_tessellations():
    """plate_holes.STL against a 4 mm remesh: along the normals 5 and 8 views at F = 0.999
    (docs/cad-meshes.md); with candidates tilted up to 30°, 5 and 6 (proven in 9 and 32 s on
    the development machine). Compared on greedy covers, which depend on the candidates and
    rows only: tilted 6 and 7, along the normals 6 and 8 (session 56, 2-core EPYC); the MIP's
    covers at a 10 s limit there were 5 and 7, so its count depended on the machine. Not at
    half the camera's resolution (HALF): there the remesh of a fresh install (18 850 faces)
    gave 6 and 8, another venv's (18 862 faces, the same pymeshlab and numpy) 6 and 7
    (session 60); at full resolution 6 and 7 on both (session 61: pymeshlab imported from
    folders of different path lengths, which is what decides the remesh)."""
    pytest.importorskip("pymeshlab")
    from vpp_core.mesh.remesh import isotropic_remesh

    cad = load_mesh((shared_dir(MESHES) / "plate_holes.STL").read_bytes(), "stl")
    iso = isotropic_remesh(cad, 4.0)
    assert iso.area_mm2 == pytest.approx(cad.area_mm2, rel=0.01) and iso.n_faces > 10 * cad.n_faces
    request = PlanRequest(
        profile="paper",
        target=Target(formulation="visibility", min_coverage=MIN_COVERAGE),
        candidates=CandidateGenerator(count=500, tilt_deg=30.0),
        solver=SolverSettings(name="greedy"),
    )
    counts = partial_view_counts([(cad, request), (iso, request)])
    assert abs(counts[0] - counts[1]) <= 1, counts


@pytest.mark.slow
def test_tilted_candidates_make_the_count_independent_of_the_seed():
    """featuretype.STL: along the normals seeds 0 and 1 give 25 and 15 views at F = 0.999
    (docs/cad-meshes.md); tilted by up to 30°, the same seeds agree within 1."""
    part = load_mesh((shared_dir(MESHES) / "featuretype.STL").read_bytes(), "stl", units="in")
    requests = [
        PlanRequest(
            profile="paper",
            target=Target(formulation="visibility", min_coverage=MIN_COVERAGE),
            candidates=CandidateGenerator(count=500, seed=seed, tilt_deg=30.0),
            solver=SolverSettings(time_limit_s=5),  # both reach 6 by 1.5 s, proven at 10 s
        )
        for seed in (0, 1)
    ]
    counts = partial_view_counts([(part, request) for request in requests])
    assert abs(counts[0] - counts[1]) <= 1 and max(counts) <= 8, counts


def seen_share(doc: PlanDocument, other: PlanDocument, part: Part) -> float:
    """Share of the area of `part` (planned in `other`) reachable by other's candidates that
    doc's viewpoints see, traced independently on `part`."""
    from vpp_core.plan.pipeline import explicit_viewpoints
    from vpp_core.trace.raytrace import trace_counts

    def seen(doc: PlanDocument, views: list) -> np.ndarray:
        counts = sp.csr_array(trace_counts(part, doc.sensor, explicit_viewpoints(views)).counts)
        return np.diff(counts.indptr) > 0

    reach = seen(other, other.candidates) & part.counted
    return float(part.areas[seen(doc, doc.viewpoints) & reach].sum() / part.areas[reach].sum())


@pytest.mark.slow
def test_area_elements_make_a_cad_plan_see_what_it_claims(two_tessellations):
    """On 1 mm² elements (--max-face-area 1), the CAD Hirth joint's plan, traced on the remesh,
    sees ≥ 99 % of what the remesh's candidates reach, and the counts agree within 1
    (docs/cad-meshes.md: 4 and 4 views, seeing 99.4 %; on the CAD faces 3 views see 97.5 %)."""
    from vpp_core.mesh.refine import refine
    from vpp_core.plan.pipeline import plan

    cad, iso = (refine(part, 1.0) for part in two_tessellations)
    assert cad.n_faces > 3 * two_tessellations[0].n_faces and cad.areas.max() <= 1.0
    request = PlanRequest(
        profile="paper",
        target=Target(formulation="visibility", min_coverage=MIN_COVERAGE),
        candidates=CandidateGenerator(count=500, tilt_deg=30.0),
        solver=SolverSettings(time_limit_s=30),
    )
    on_cad, on_iso = plan(cad, request), plan(iso, request)
    assert abs(len(on_cad.viewpoints) - len(on_iso.viewpoints)) <= 1
    assert seen_share(on_cad, on_iso, iso) >= 0.99
    assert seen_share(on_iso, on_cad, cad) >= 0.99


@pytest.mark.slow
def test_remeshing_both_exports_makes_featuretype_counts_agree():
    """featuretype.STL and a 2 mm remesh of it, each remeshed at 2 mm before planning
    (--remesh 2), at the export-comparison setting F = 0.99, with the greedy cover: 25 and 24
    views; unremeshed, the CAD export's greedy cover takes 6 views (session 56, 2-core EPYC).
    The rows are what remeshing makes agree, and the greedy cover depends on nothing else: the
    MIP's covers of these rows are time-limited and vary by up to 3 views with the machine
    (22-25 at 4-10 s across runs, session 54-55). At 1 mm (docs/cad-meshes.md) 21 and 20
    views, or 23 and 22 with another installation's remesh, from four times the faces and
    four times the remeshing time. On 1 mm² elements instead they need 17 and 21; at F = 0.999
    even remeshes can differ by 8. At half the camera's resolution (HALF), 25 and 24 too (26
    and 26 with seed 1; unremeshed 6), in 60 % of the time (session 60)."""
    pytest.importorskip("pymeshlab")
    from vpp_core.mesh.remesh import remesh

    cad = load_mesh((shared_dir(MESHES) / "featuretype.STL").read_bytes(), "stl", units="in")
    once = remesh(cad, 2.0)  # what --remesh 2 plans of the CAD export
    assert once.n_faces > 5 * cad.n_faces
    request = PlanRequest(
        profile="paper",
        sensor=HALF,
        target=Target(formulation="visibility", min_coverage=COMPARE_COVERAGE),
        candidates=CandidateGenerator(count=500, tilt_deg=30.0),
        solver=SolverSettings(name="greedy"),
    )
    # the other export is that remesh (isotropic_remesh: the same pymeshlab call), remeshed
    counts = partial_view_counts([(once, request), (remesh(once, 2.0), request)])
    assert abs(counts[0] - counts[1]) <= 1, counts
