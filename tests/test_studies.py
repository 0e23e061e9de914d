"""The studies (SPEC §5, paper Fig. 3): rows against fresh plans and independent re-traces."""

from __future__ import annotations

import json

import numpy as np
import pytest
import trimesh

from tests.test_plan_claims import SMALL, _c2w, recount, stepped_part
from vpp_core.errors import VppError
from vpp_core.mesh.part import Part, part_from_arrays
from vpp_core.plan.document import CandidateGenerator, PlanRequest, Target
from vpp_core.plan.pipeline import element_area, plan
from vpp_core.report.plots import study_plots
from vpp_core.report.studies import decimation_study, resolution_sweep, study_csv

RESOLUTIONS = [0.9, 1.4, 2.5]
"""mm: around this small sensor's 1.1 mm pitch at 500 mm, so the density count changes."""


def request(**target: object) -> PlanRequest:
    return PlanRequest(
        sensor=SMALL,
        target=Target(**target),  # type: ignore[arg-type]
        candidates=CandidateGenerator(count=30, seed=3, standoff_mm=500, adaptive=False, sphere=0),
    )  # a sweep shares one pool: the fresh plans must not grow theirs or move the stand-off


@pytest.fixture(scope="module")
def part() -> Part:
    return stepped_part()


@pytest.fixture(scope="module")
def sweep(part: Part):
    return resolution_sweep(part, request(), RESOLUTIONS)


def test_sweep_counts_equal_fresh_plans(part, sweep) -> None:
    assert len(sweep.rows) == 2 * len(RESOLUTIONS)
    for row in sweep.rows:
        doc = plan(part, request(resolution_mm=row.resolution_mm, formulation=row.formulation))
        assert row.viewpoints == len(doc.viewpoints) == len(row.poses)
        assert row.solver.status == doc.solver.status == "optimal"
        assert [p.id for p in row.poses] == [v.id for v in doc.viewpoints]
        assert row.coverage.area == pytest.approx(doc.metrics.coverage.area)
        assert row.resolution.met_area == pytest.approx(doc.metrics.resolution.met_area)
    density = {r.resolution_mm: r.viewpoints for r in sweep.rows if r.formulation == "density"}
    assert density[0.9] > density[2.5], density  # finer targets need more views here


def test_sweep_traces_once_per_set_of_elements(part, monkeypatch) -> None:
    import vpp_core.report.studies as studies

    calls = []
    real = studies.trace_counts

    def counting(*args, **kw):
        calls.append(1)
        return real(*args, **kw)

    monkeypatch.setattr(studies, "trace_counts", counting)
    resolutions = [1.0, 1.2, 1.5, 2.0]
    study = resolution_sweep(part, request(), resolutions)
    # once per set of area elements the rows' targets split this box's faces into
    assert len(calls) == len({element_area(part, r) for r in resolutions}) > 1
    # ten-solve accounting: one time per row; visibility solved once, reused
    assert len(study.timings_s.solve_s) == len(study.rows)


def test_study_document_and_csv_have_the_contract_names(sweep) -> None:
    doc = json.loads(sweep.model_dump_json())
    assert doc["kind"] == "resolution"
    for row in doc["rows"]:
        assert {
            "resolution_mm",
            "formulation",
            "viewpoints",
            "coverage",
            "resolution",
            "solver",
        } <= set(row)
        assert set(row["coverage"]) == {"faces", "area"}
        assert set(row["resolution"]) == {"met_faces", "met_area"}
        assert set(row["solver"]) == {"status", "gap"}
        assert "ratio" not in row
    lines = study_csv(sweep).splitlines()
    assert lines[0].startswith("resolution_mm,formulation,viewpoints")
    assert len(lines) == 1 + len(sweep.rows)


def fine_part() -> Part:
    """The stepped part subdivided to a few thousand faces, so decimation has work to do."""
    base = stepped_part()
    v, f = trimesh.remesh.subdivide_to_size(base.vertices, base.faces, max_edge=8.0)
    return part_from_arrays(v, f)


def test_decimation_rows_equal_an_independent_retrace_on_the_original() -> None:
    part = fine_part()
    study = decimation_study(part, request(resolution_mm=1.2), [1.0, 0.2])
    assert [r.ratio for r in study.rows] == [1.0, 1.0, 0.2, 0.2]
    assert study.rows[0].planning_faces == part.n_faces
    assert study.rows[2].planning_faces < 0.3 * part.n_faces
    counted, areas = part.counted, part.areas
    for row in study.rows:
        r = recount(part, SMALL, np.array([_c2w(p) for p in row.poses])).toarray()
        seen = r.any(axis=1)
        assert row.coverage.faces == pytest.approx(seen[counted].mean(), abs=2e-3)
        area = (areas * counted * seen).sum() / (areas * counted).sum()
        assert row.coverage.area == pytest.approx(area, abs=2e-3)
        with np.errstate(divide="ignore", invalid="ignore"):
            delta = np.sqrt(r / areas[:, None]).sum(axis=1)
        met = (areas * counted * (delta >= 1 / 1.2 * (1 - 1e-9))).sum() / (areas * counted).sum()
        assert row.resolution.met_area == pytest.approx(met, abs=5e-3)


@pytest.mark.parametrize(
    "values, match", [([], "1 to"), ([0.5, -1.0], "positive"), ([float("nan")], "positive")]
)
def test_bad_resolutions_are_refused(part, values, match) -> None:
    with pytest.raises(VppError, match=match):
        resolution_sweep(part, request(), values)


def test_bad_ratios_are_refused(part) -> None:
    with pytest.raises(VppError, match=r"\(0, 1\]"):
        decimation_study(part, request(), [1.5])


def test_study_plots_are_pngs(sweep) -> None:
    pngs = study_plots(sweep)
    assert set(pngs) == {"sweep.png", *(f"histogram-{r:g}mm.png" for r in RESOLUTIONS)}
    for data in pngs.values():
        assert data.startswith(b"\x89PNG") and len(data) > 10_000
