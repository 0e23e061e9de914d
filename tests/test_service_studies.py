"""Studies, plan plots and point clouds through the API, with real forking RQ workers."""

from __future__ import annotations

import io

import numpy as np
import pytest
import trimesh

from tests.test_service_jobs import submit, upload_sample, wait
from vpp_core.mesh.part import load_mesh
from vpp_core.plan.document import PlanRequest
from vpp_core.report.studies import resolution_sweep
from vpp_core.samples import sample_stl

pytestmark = pytest.mark.slow
SMALL = {"width_px": 320, "height_px": 200}


def test_resolution_study_job_serves_json_csv_and_plots(api, start_workers) -> None:
    mesh = upload_sample(api)
    body = {
        "mesh_id": mesh,
        "kind": "resolution",
        "resolutions": [1.2, 2.5],
        "sensor": SMALL,
        "profile": "paper",
        "candidates": {"count": 40},
    }
    r = api.post("/v1/studies", json=body)
    assert r.status_code == 202, r.text
    study = r.json()["id"]
    assert r.headers["Location"] == f"/v1/jobs/{study}"
    assert api.post("/v1/studies", json=body).json()["id"] == study  # same request, same job
    start_workers(1)
    job = wait(api, study)
    assert job["status"] == "succeeded", job
    assert job["result_url"] == f"/v1/studies/{study}"
    doc = api.get(f"/v1/studies/{study}").json()
    assert doc["kind"] == "resolution" and len(doc["rows"]) == 4
    # the same rows as the study run in-process
    request = PlanRequest.model_validate(
        {"sensor": SMALL, "profile": "paper", "candidates": {"count": 40}}
    )
    local = resolution_sweep(load_mesh(sample_stl(), "stl"), request, [1.2, 2.5])
    assert [r["viewpoints"] for r in doc["rows"]] == [r.viewpoints for r in local.rows]
    csv = api.get(f"/v1/studies/{study}/rows.csv")
    assert csv.headers["content-type"].startswith("text/csv") and len(csv.text.splitlines()) == 5
    links = api.get(f"/v1/studies/{study}/plots").json()["plots"]
    assert f"/v1/studies/{study}/plots/sweep.png" in links
    for link in links:
        png = api.get(link)
        assert png.headers["content-type"] == "image/png" and png.content.startswith(b"\x89PNG")
    missing = api.get(f"/v1/studies/{study}/plots/../../meshes/{mesh}.json")
    assert missing.status_code == 404


def test_plan_plots_and_point_cloud(api, start_workers) -> None:
    mesh = upload_sample(api)
    plan = submit(api, {"mesh_id": mesh, "sensor": SMALL, "profile": "paper",
                        "candidates": {"count": 30}, "target": {"resolution_mm": 1.5}})  # fmt: skip
    start_workers(1)
    assert wait(api, plan)["status"] == "succeeded"
    for name in ("histogram.png", "cameras.png"):
        png = api.get(f"/v1/plans/{plan}/plots/{name}")
        assert png.status_code == 200 and png.content.startswith(b"\x89PNG")
    assert api.get(f"/v1/plans/{plan}/plots/other.png").status_code == 404
    assert api.get(f"/v1/plans/{plan}/point-cloud").status_code == 404  # not asked for yet
    r = api.post(f"/v1/plans/{plan}/point-cloud")
    assert r.status_code == 202, r.text
    job = wait(api, r.json()["id"])
    assert job["status"] == "succeeded", job
    assert job["result_url"] == f"/v1/plans/{plan}/point-cloud"
    stats = api.get(f"/v1/plans/{plan}/point-cloud/stats").json()
    doc = api.get(f"/v1/plans/{plan}").json()
    assert len(stats["per_view"]) == len(doc["viewpoints"])
    ply = api.get(f"/v1/plans/{plan}/point-cloud")
    cloud = trimesh.load(io.BytesIO(ply.content), file_type="ply")
    assert len(cloud.vertices) == stats["points"] > 0
    lo, hi = np.array(api.get(f"/v1/meshes/{mesh}").json()["bounds_mm"])
    assert (cloud.vertices >= lo - 1e-3).all() and (cloud.vertices <= hi + 1e-3).all()
    assert api.get(f"/v1/plans/{plan}/point-cloud/neighbours.png").content.startswith(b"\x89PNG")


@pytest.mark.parametrize(
    "patch, status",
    [
        ({"kind": "resolution", "resolutions": [0.2, -1]}, 422),
        ({"kind": "decimation", "ratios": [2.0]}, 422),
        ({"kind": "sideways"}, 422),
        ({"kind": "resolution", "candidates": {"count": 10**6}}, 422),
    ],
)
def test_bad_studies_are_refused_before_any_work(api, patch, status) -> None:
    mesh = upload_sample(api)
    r = api.post("/v1/studies", json={"mesh_id": mesh, **patch})
    assert r.status_code == status, r.text
    assert r.headers["content-type"].startswith("application/problem+json")


def test_point_cloud_of_an_unknown_plan_is_404(api) -> None:
    r = api.post(f"/v1/plans/{'0' * 64}/point-cloud")
    assert r.status_code == 404 and r.headers["content-type"].startswith("application/problem")
