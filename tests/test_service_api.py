"""The HTTP API without workers: uploads, validation, limits, problem+json, health, drift."""

from __future__ import annotations

import json
from pathlib import Path

import pytest
import trimesh

from service.app import create_app
from service.openapi import text as openapi_text
from tests.conftest import MESHES, ROOT, shared_dir
from vpp_core.mesh.part import load_mesh
from vpp_core.samples import flanged_bushing, sample_stl
from worker.settings import Settings

PROBLEM = "application/problem+json"


def upload(api, data: bytes, name: str = "part.stl", units: str = "mm"):
    return api.post("/v1/meshes", files={"file": (name, data)}, data={"units": units})


def assert_problem(r, status: int) -> dict:
    assert r.status_code == status, r.text
    assert r.headers["content-type"] == PROBLEM
    body = r.json()
    assert body["status"] == status and body["title"] and body["detail"]
    return body


def test_upload_returns_summary_location_and_etag(api) -> None:
    r = upload(api, sample_stl())
    assert r.status_code == 201
    body = r.json()
    assert r.headers["location"] == f"/v1/meshes/{body['id']}"
    assert r.headers["etag"] == f'"{body["id"]}"'
    assert body["faces"] == len(flanged_bushing().faces)
    assert body["area_mm2"] == pytest.approx(flanged_bushing().area, rel=1e-6)  # STL is float32
    assert sum(body["bounds_mm"], []) == pytest.approx([-30, -30, 0, 30, 30, 40], abs=1e-6)
    assert api.get(r.headers["location"]).json() == body


def test_same_geometry_in_another_format_is_the_same_mesh(api) -> None:
    stl = sample_stl()
    first = upload(api, stl).json()
    mesh = trimesh.load_mesh(trimesh.util.wrap_as_stream(stl), file_type="stl")
    again = upload(api, mesh.export(file_type="ply"), "part.ply")
    assert again.status_code == 201
    assert again.json()["id"] == first["id"]
    stored = sorted(p.name for p in (Path(api.app.state.store.root) / "meshes").iterdir())
    assert stored == [f"{first['id']}.json", f"{first['id']}.npz"]  # nothing stored twice
    assert upload(api, stl, units="cm").json()["id"] != first["id"]  # 10× bigger: another part


@pytest.mark.parametrize(
    "field, value, note, area_rel",
    [
        ("max_face_area_mm2", "2", "faces larger than 2 mm² or longer than 2.83 mm split", 1e-9),
        ("remesh_mm", "3", "remeshed at 3 mm edges", 0.01),
    ],
)
def test_upload_can_remesh_or_split_faces(api, field, value, note, area_rel) -> None:
    if field == "remesh_mm":
        pytest.importorskip("pymeshlab")
    stl = sample_stl()
    plain = upload(api, stl).json()
    r = api.post("/v1/meshes", files={"file": ("part.stl", stl)}, data={field: value})
    assert r.status_code == 201, r.text
    body = r.json()
    assert body["id"] != plain["id"] and body["faces"] > plain["faces"]
    assert body["area_mm2"] == pytest.approx(plain["area_mm2"], rel=area_rel)
    assert any(w.startswith(note) for w in body["warnings"])
    assert api.get(f"/v1/meshes/{body['id']}").json() == body
    ply = api.get(f"/v1/meshes/{body['id']}/mesh.ply")  # what is planned, exactly
    assert ply.status_code == 200 and load_mesh(ply.content, "ply").id == body["id"]
    again = api.get(
        f"/v1/meshes/{body['id']}/mesh.ply", headers={"If-None-Match": ply.headers["ETag"]}
    )
    assert again.status_code == 304
    assert_problem(api.get(f"/v1/meshes/{'0' * 64}/mesh.ply"), 404)
    for bad in ("0", "-1", "nan", "big"):
        r = api.post("/v1/meshes", files={"file": ("p.stl", stl)}, data={field: bad})
        assert field in json.dumps(assert_problem(r, 422)["errors"])


def test_unknown_mesh_is_404_problem(api) -> None:
    assert_problem(api.get("/v1/meshes/" + "0" * 64), 404)
    assert_problem(api.get("/v1/nowhere"), 404)
    for odd in ("..", "..%2F..%2Fetc", "A" * 64, "x"):
        assert_problem(api.get(f"/v1/meshes/{odd}"), 404)
        assert_problem(api.get(f"/v1/plans/{odd}"), 404)
        assert_problem(api.get(f"/v1/jobs/{odd}"), 404)


def test_oversized_upload_is_413(svc_env, monkeypatch) -> None:
    from fastapi.testclient import TestClient

    with TestClient(create_app(Settings(max_upload_bytes=10_000))) as small:
        body = assert_problem(upload(small, sample_stl()), 413)  # ~57 kB
        assert "limit" in body["detail"]
        assert upload(small, flanged_bushing(8).export(file_type="stl")).status_code == 201
    with TestClient(create_app(Settings(max_faces=5_000))) as few:
        form = {"max_face_area_mm2": "0.5"}
        r = few.post("/v1/meshes", files={"file": ("p.stl", sample_stl())}, data=form)
        assert "the limit is 5000" in assert_problem(r, 422)["detail"]


def test_every_bad_mesh_gets_4xx_problem_never_5xx(api) -> None:
    bad = sorted(shared_dir(MESHES / "bad").iterdir())
    outcomes = {}
    for path in bad:
        if path.suffix.lower() in (".csv", ".md", ".txt"):
            continue
        r = upload(api, path.read_bytes(), path.name)
        assert r.status_code < 500, (path.name, r.text)
        if r.status_code != 201:
            assert_problem(r, r.status_code)
        outcomes[path.name] = r.status_code
    assert any(code == 422 for code in outcomes.values()), outcomes


def test_plan_request_validation_is_422_with_errors(api) -> None:
    mesh = upload(api, sample_stl()).json()["id"]
    cases = [
        {"mesh_id": mesh, "sensor": {"fov_x_deg": 190}},
        {"mesh_id": mesh, "target": {"resolution_mm": -1}},
        {"mesh_id": mesh, "candidates": {"count": 0}},
        {"mesh_id": mesh, "solver": {"name": "magic"}},
        {"mesh_id": mesh, "backend": "optix"},
        {"mesh_id": mesh, "surprise": 1},
        {"mesh_id": "not-a-hash"},
    ]
    for body in cases:
        problem = assert_problem(api.post("/v1/plans", json=body), 422)
        assert problem["errors"], body
    r = api.post("/v1/plans", content=b"{not json", headers={"content-type": "application/json"})
    assert_problem(r, 422)


def test_plan_refusals_before_any_job(api, redis_db) -> None:
    mesh = upload(api, sample_stl()).json()["id"]
    unknown = {"mesh_id": "f" * 64}
    assert "no such mesh" in assert_problem(api.post("/v1/plans", json=unknown), 422)["detail"]
    many = {"mesh_id": mesh, "candidates": {"count": 10**6}}
    assert "limit" in assert_problem(api.post("/v1/plans", json=many), 422)["detail"]
    parallel_up = {"position": [0, 0, 500], "gaze": [0, 0, -1], "up": [0, 0, 1]}
    bad_view = {"mesh_id": mesh, "candidates": {"viewpoints": [parallel_up]}}
    assert_problem(api.post("/v1/plans", json=bad_view), 422)
    assert redis_db.keys("rq:job:*") == []  # nothing was enqueued


def test_submit_is_202_with_location_and_joins_the_same_job(api, redis_db) -> None:
    mesh = upload(api, sample_stl()).json()["id"]
    body = {"mesh_id": mesh, "profile": "paper", "candidates": {"count": 20}}
    first = api.post("/v1/plans", json=body)
    assert first.status_code == 202
    job = first.json()
    assert first.headers["location"] == f"/v1/jobs/{job['id']}"
    assert job["status"] == "queued" and first.headers["retry-after"] == "1"
    # defaults written out are the same request: same id, still one job in the queue
    explicit = {**body, "target": {"resolution_mm": 0.18, "formulation": "density"}}
    assert api.post("/v1/plans", json=explicit).json()["id"] == job["id"]
    assert len(redis_db.keys("rq:job:*")) == 1
    polled = api.get(f"/v1/jobs/{job['id']}")
    assert polled.json()["status"] == "queued" and polled.headers["retry-after"] == "1"
    assert_problem(api.get(f"/v1/plans/{job['id']}"), 404)  # not computed yet


def test_unknown_job_is_404(api) -> None:
    assert_problem(api.get("/v1/jobs/" + "a" * 64), 404)
    assert_problem(api.delete("/v1/jobs/" + "a" * 64), 404)


def test_health(api) -> None:
    assert api.get("/livez").json() == {"status": "ok"}
    ready = api.get("/readyz")
    assert ready.status_code == 200 and ready.json()["checks"] == {"redis": "ok", "store": "ok"}


def test_readyz_is_503_when_redis_or_store_is_down(tmp_path: Path) -> None:
    from fastapi.testclient import TestClient

    blocker = tmp_path / "file"
    blocker.write_text("not a directory")
    settings = Settings(redis_url="redis://127.0.0.1:1/0", store_url=str(blocker / "store"))
    with TestClient(create_app(settings)) as client:
        assert client.get("/livez").status_code == 200
        r = client.get("/readyz")
        assert r.status_code == 503 and r.headers["retry-after"]
        checks = r.json()["checks"]
        assert checks["redis"].startswith("down") and checks["store"].startswith("down")
        # a request that needs Redis: 503 problem, not a 500
        assert_problem(client.get("/v1/jobs/" + "a" * 64), 503)


def test_committed_openapi_matches_the_app() -> None:
    committed = (ROOT / "openapi" / "openapi.json").read_text()
    assert committed == openapi_text(), (
        "regenerate: python -m service.openapi > openapi/openapi.json"
    )
    ops = {
        op["operationId"]
        for path in json.loads(committed)["paths"].values()
        for op in path.values()
    }
    assert ops == {
        "upload_mesh", "get_mesh", "get_mesh_ply", "get_mesh_geometry", "get_labels",
        "submit_plan", "get_job", "cancel_job", "get_plan", "get_plan_plot", "get_plan_scene",
        "get_related_plans", "submit_point_cloud", "get_point_cloud", "get_point_cloud_stats",
        "get_point_cloud_plot", "submit_study", "get_study", "get_study_csv",
        "list_study_plots", "get_study_plot", "list_jobs", "job_events", "get_metrics",
        "get_poses_csv", "get_poses_json",
    }  # fmt: skip


def test_sample_part_is_watertight() -> None:
    mesh = trimesh.load_mesh(trimesh.util.wrap_as_stream(sample_stl()), file_type="stl")
    assert mesh.is_watertight and mesh.volume > 0
