"""The viewer's scene data: packing, per-face results against independent sums, and the API."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from tests.test_service_jobs import submit, upload_sample, wait
from vpp_core.errors import VppError
from vpp_core.mesh.part import load_mesh
from vpp_core.plan.document import PlanRequest
from vpp_core.plan.pipeline import candidates_for, finish
from vpp_core.report.scene import (
    EXCLUDED,
    MET,
    UNCOVERABLE,
    UNCOVERED,
    UNMET,
    face_results,
    geometry_scene,
    pack,
    plan_scene,
    unpack,
)
from vpp_core.samples import sample_stl
from vpp_core.trace.raytrace import make_backend, trace_counts
from worker import artifacts as art

SMALL = {"width_px": 320, "height_px": 200}


def test_pack_round_trips_aligned_arrays_and_metadata() -> None:
    arrays = {
        "a": np.array([1.5, np.inf, -2.0], np.float32),
        "b": np.arange(7, dtype=np.uint8),
        "c": np.arange(12, dtype=np.uint32).reshape(4, 3),
        "empty": np.zeros(0, np.uint32),
    }
    data = pack(arrays, name="x" * 37, values=[1, 2])
    meta, back = unpack(data)
    assert meta == {"name": "x" * 37, "values": [1, 2]}
    for name, a in arrays.items():
        assert back[name].dtype == a.dtype and back[name].shape == a.shape
        np.testing.assert_array_equal(back[name], a)
    import json
    import struct

    (n,) = struct.unpack("<I", data[4:8])
    for rec in json.loads(data[8 : 8 + n])["arrays"].values():
        assert rec["offset"] % 8 == 0  # a browser views every array in place


def test_pack_refuses_types_a_browser_cannot_view() -> None:
    with pytest.raises(VppError, match="float64"):
        pack({"x": np.zeros(3)})
    with pytest.raises(VppError, match="scene"):
        unpack(b"nope" + bytes(8))


def _planned(formulation: str = "density", resolution: float = 1.0):  # type: ignore[no-untyped-def]
    part = load_mesh(sample_stl(), "stl")
    request = PlanRequest.model_validate(
        {
            "sensor": SMALL,
            "candidates": {"count": 40},
            "target": {
                "resolution_mm": resolution,
                "formulation": formulation,
                "rows": "faces",
                "min_coverage": 1.0,
            },
        }
    )
    backend = make_backend(part)
    views, info = candidates_for(part, request, backend)
    trace = trace_counts(part, request.sensor, views, backend=backend)
    doc = finish(part, request, views, info, trace, backend=backend)
    return part, doc, trace.counts


@pytest.mark.parametrize("formulation", ["density", "visibility"])
def test_face_results_match_dense_sums_and_the_plan_metrics(formulation: str) -> None:
    part, doc, counts = _planned(formulation)
    selected = np.array([v.id for v in doc.viewpoints])
    res = face_results(counts, part.areas, part.counted, selected, doc.target.resolution_mm)
    # achieved density by hand, dense: Σ_j∈J* sqrt(R_ij / A_i)
    dense = counts.toarray().astype(float)
    with np.errstate(divide="ignore", invalid="ignore"):
        delta = np.where(dense > 0, np.sqrt(dense / part.areas[:, None]), 0.0)
    achieved = delta[:, selected].sum(axis=1)
    expect = np.where(achieved > 0, 1 / np.where(achieved > 0, achieved, 1), np.inf)
    np.testing.assert_allclose(res.resolution_mm, expect.astype(np.float32), rtol=1e-6)
    # states against the plan document's own metrics (metrics.evaluate, separate code)
    counted = part.counted
    n = counted.sum()
    s = res.state
    m = doc.metrics
    assert np.isclose((s[counted] == MET).sum() / n, m.resolution.met_faces)
    assert np.isclose(np.isin(s[counted], [MET, UNMET]).sum() / n, m.coverage.faces)
    assert np.flatnonzero(s == UNCOVERABLE).tolist() == doc.uncoverable.ids
    assert (s == EXCLUDED).sum() == (~counted).sum()
    assert (s == MET).any() and (s == UNCOVERABLE).any()
    assert not (s == UNCOVERED).any()  # a strict cover leaves no seen face out
    # the faces each selected view sees, in visiting order
    for k, j in enumerate(selected):
        faces = res.view_faces[res.view_offsets[k] : res.view_offsets[k + 1]]
        assert faces.tolist() == np.flatnonzero(dense[:, j] > 0).tolist()


def test_a_partial_cover_marks_the_faces_it_leaves_out_as_uncovered() -> None:
    part, doc, counts = _planned()
    selected = np.array([v.id for v in doc.viewpoints])[:1]  # one view: most faces left out
    res = face_results(counts, part.areas, part.counted, selected, doc.target.resolution_mm)
    seen_by_first = np.zeros(part.n_faces, bool)
    seen_by_first[res.view_faces] = True
    seen_any = counts.toarray().sum(axis=1) > 0
    assert (res.state == UNCOVERED).sum() == (seen_any & ~seen_by_first & part.counted).sum() > 0


def test_scene_files_carry_the_plan_and_the_geometry() -> None:
    part, doc, counts = _planned()
    meta, arrays = unpack(plan_scene(part, doc, counts))
    assert meta["views"] == [v.id for v in doc.viewpoints]
    assert meta["target_mm"] == doc.target.resolution_mm and meta["faces"] == part.n_faces
    assert len(arrays["view_offsets"]) == len(doc.viewpoints) + 1
    meta, geo = unpack(geometry_scene(part))
    assert meta["mesh_id"] == part.id
    np.testing.assert_allclose(geo["vertices"], part.vertices, rtol=1e-6, atol=1e-5)
    np.testing.assert_array_equal(geo["faces"], part.faces)


# ------------------------------------------------------------------------------ through the API


@pytest.mark.slow
def test_viewer_resources_through_the_api(api, start_workers, svc_env) -> None:
    mesh = upload_sample(api)
    body = {"mesh_id": mesh, "sensor": SMALL, "profile": "paper", "candidates": {"count": 30},
            "target": {"resolution_mm": 1.5}}  # fmt: skip
    plan = submit(api, body)
    page = api.get(f"/v1/plans/{plan}/view")  # served at once: it waits for the job itself
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert "/static/viewer/viewer.js" in page.text
    js = api.get("/static/viewer/viewer.js")
    assert js.status_code == 200 and "javascript" in js.headers["content-type"]
    assert api.get(f"/v1/plans/{plan}/scene").status_code == 404  # not computed yet
    start_workers(1)
    assert wait(api, plan)["status"] == "succeeded"
    doc = api.get(f"/v1/plans/{plan}").json()

    scene = api.get(f"/v1/plans/{plan}/scene")  # gzip on the wire, stored so
    assert scene.headers["content-type"] == "application/octet-stream"
    assert scene.headers["content-encoding"] == "gzip"
    plain = api.get(f"/v1/plans/{plan}/scene", headers={"Accept-Encoding": "identity"})
    assert "content-encoding" not in plain.headers and plain.content == scene.content
    meta, arrays = unpack(scene.content)
    assert meta["views"] == [v["id"] for v in doc["viewpoints"]]
    assert len(arrays["state"]) == doc["mesh"]["faces"]
    assert (
        api.get(f"/v1/plans/{plan}/scene", headers={"If-None-Match": f'"{plan}"'}).status_code
        == 304
    )

    geo = api.get(f"/v1/meshes/{mesh}/geometry")
    gmeta, garrays = unpack(geo.content)
    assert gmeta["mesh_id"] == mesh and len(garrays["faces"]) == doc["mesh"]["faces"]
    assert geo.headers["etag"] == f'"{mesh}"'

    # a plan stored before the viewer existed: its scene is built from R on first request
    stored = Path(svc_env["VPP_STORE_URL"]) / art.scene_key(plan)
    stored.unlink()
    assert api.get(f"/v1/plans/{plan}/scene").content == scene.content
    assert stored.exists()

    related = api.get(f"/v1/plans/{plan}/related").json()["plans"]
    assert [r["formulation"] for r in related] == ["density", "visibility"]
    assert related[0]["id"] == plan and related[0]["available"]
    assert not related[1]["available"]
    other = api.post("/v1/plans", json=related[1]["request"])  # the body it offers names it
    assert other.json()["id"] == related[1]["id"]
    assert api.get(f"/v1/plans/{plan}/view").text == page.text


@pytest.mark.parametrize(
    "path",
    [
        "/v1/plans/{bad}/view",
        "/v1/plans/{bad}/scene",
        "/v1/plans/{bad}/related",
        "/v1/meshes/{bad}/geometry",
    ],
)
@pytest.mark.parametrize("bad", ["0" * 64, "..%2F..%2Fetc", "ABC"])
def test_viewer_resources_of_unknown_ids_are_404_problems(api, path: str, bad: str) -> None:
    r = api.get(path.format(bad=bad))
    if bad == "0" * 64 and path.endswith("/view"):
        assert r.status_code == 200  # the page of a plan not submitted yet says so itself
        return
    assert r.status_code == 404, r.text
    assert r.headers["content-type"] == "application/problem+json"
