"""Plans through the API with real forking RQ workers on a real Redis: results, reuse, fan-out,
cancel and failure."""

from __future__ import annotations

import os
import time

import pytest
from rq.registry import StartedJobRegistry

from vpp_core.mesh.part import load_mesh
from vpp_core.plan.document import PlanDocument, PlanRequest
from vpp_core.plan.pipeline import plan
from vpp_core.samples import sample_stl

pytestmark = pytest.mark.slow


def upload_sample(api) -> str:
    r = api.post("/v1/meshes", files={"file": ("bushing.stl", sample_stl())})
    assert r.status_code == 201, r.text
    return str(r.json()["id"])


def submit(api, body: dict) -> str:
    r = api.post("/v1/plans", json=body)
    assert r.status_code == 202, r.text
    return str(r.json()["id"])


def wait(api, job: str, until=("succeeded", "failed", "canceled"), timeout: float = 120) -> dict:
    """Poll the job until its status is in `until`; its last body."""
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        body = api.get(f"/v1/jobs/{job}").json()
        if body["status"] in until:
            return body
        time.sleep(0.1)
    raise AssertionError(f"job {job} still {body['status']} after {timeout} s: {body}")


def served_plan(api, job: str) -> PlanDocument:
    """The plan job's document as served, once the job has succeeded (it must)."""
    done = wait(api, job)
    assert done["status"] == "succeeded", done
    return PlanDocument.model_validate_json(api.get(done["result_url"]).content)


def same_plan(a: PlanDocument, b: PlanDocument) -> None:
    """Everything but timings and ray rates is identical."""
    drop = {"timings_s": True, "rays": {"cast_per_s", "trace_s", "reused"}, "solver": {"time_s"}}
    drop |= {"tour": {"time_s"}, "adaptive": {"__all__": {"seconds"}}}
    assert a.model_dump(exclude=drop) == b.model_dump(exclude=drop)


def test_plan_matches_in_process_planner_and_two_workers_share_chunks(api, start_workers) -> None:
    mesh = upload_sample(api)
    body = {
        "mesh_id": mesh,
        "profile": "paper",  # chunks and workers, not plan quality: the quick strict cover
        "candidates": {"count": 80, "seed": 3},
        "target": {"resolution_mm": 0.3},
    }
    start_workers(2, ready=True)  # both listen before the chunks are queued
    job = submit(api, body)
    done = wait(api, job)
    assert done["status"] == "succeeded", done
    assert done["result_url"] == f"/v1/plans/{job}"
    workers = {c["worker"] for c in done["chunks"]}
    assert len(done["chunks"]) == 8 and len(workers) == 2, done["chunks"]
    served = PlanDocument.model_validate_json(api.get(done["result_url"]).content)
    request = PlanRequest.model_validate({k: v for k, v in body.items() if k != "mesh_id"})
    local = plan(load_mesh(sample_stl(), "stl"), request, threads=1)
    same_plan(served, local)
    assert served.solver.status == "optimal" and not served.rays.reused


def test_a_default_plan_traced_on_area_elements_by_chunks_matches_in_process(
    api, start_workers
) -> None:
    """The default rows split the bushing's larger faces into area elements: the workers'
    chunks trace the elements and the served plan is the in-process one."""
    mesh = upload_sample(api)
    body = {
        "mesh_id": mesh,
        "candidates": {"count": 48, "seed": 3, "adaptive": False},
        "target": {"resolution_mm": 0.3, "min_coverage": 1.0},
    }
    job = submit(api, body)
    start_workers(2)
    done = wait(api, job)
    assert done["status"] == "succeeded", done
    assert len(done["chunks"]) > 1
    served = PlanDocument.model_validate_json(api.get(done["result_url"]).content)
    assert served.cover_rows is not None and served.cover_rows.element_mm2 is not None
    request = PlanRequest.model_validate({k: v for k, v in body.items() if k != "mesh_id"})
    local = plan(load_mesh(sample_stl(), "stl"), request, threads=1)
    same_plan(served, local)


def test_identical_request_is_answered_from_the_store_and_new_target_reuses_r(
    api, start_workers
) -> None:
    mesh = upload_sample(api)
    # the paper profile: its stand-off does not follow the target and it has no adaptive
    # rounds (the default's follow R), so that another target reuses R and another backend's
    # R gives the same plan (a strict cover: a partial one may leave out another of two equal
    # faces); and it is the quick one (reuse, not plan quality, is tested here)
    body = {"mesh_id": mesh, "profile": "paper", "candidates": {"count": 30}}
    job = submit(api, body)
    start_workers(1)
    first = wait(api, job)
    assert first["status"] == "succeeded"
    again = api.post("/v1/plans", json=body)
    assert again.status_code == 202 and again.json() == {"id": job, "status": "succeeded"}
    assert api.get(f"/v1/jobs/{job}").json()["started_at"] == first["started_at"]  # not rerun
    other = submit(api, {**body, "target": {"resolution_mm": 0.05, "formulation": "density"}})
    second = wait(api, other)
    assert second["status"] == "succeeded" and second["chunks"] == []  # no ray tracing
    doc = api.get(second["result_url"]).json()
    assert doc["rays"]["reused"] is True and doc["timings_s"]["trace"] == 0
    assert doc["target"]["resolution_mm"] == 0.05
    r = api.get(second["result_url"], headers={"If-None-Match": f'"{other}"'})
    assert r.status_code == 304
    # another ray backend is another R (traced anew), and as few views: the backends differ
    # in rays on triangle edges, which may tip a patch's 3-ray threshold between tied covers
    embree = wait(api, submit(api, {**body, "backend": "embree"}))
    assert embree["status"] == "succeeded" and embree["chunks"] != []
    docs = [api.get(s["result_url"]).json() for s in (first, embree)]
    assert [d["rays"]["backend"] for d in docs] == ["raster", "embree"]
    assert [d["solver"]["status"] for d in docs] == ["optimal", "optimal"]
    assert len(docs[0]["viewpoints"]) == len(docs[1]["viewpoints"])


def test_cancel_stops_a_running_job_and_a_resubmission_resumes(
    api, start_workers, redis_db
) -> None:
    mesh = upload_sample(api)
    body = {"mesh_id": mesh, "profile": "paper", "candidates": {"count": 600, "seed": 1}}
    body["solver"] = {"name": "greedy"}  # the trace is what is cancelled (the MIP of 600: 18 s)
    job = submit(api, body)
    start_workers(1)
    deadline = time.monotonic() + 60
    while True:  # until some chunks are traced
        state = api.get(f"/v1/jobs/{job}").json()
        if state["progress"].get("stage") == "trace" and state["progress"]["done"] >= 20:
            break
        assert time.monotonic() < deadline, state
        time.sleep(0.05)
    assert state["status"] == "running" and state["progress"]["total"] >= 500
    r = api.delete(f"/v1/jobs/{job}")
    assert r.status_code == 200 and r.json()["status"] == "canceled", r.json()
    time.sleep(1.0)
    assert wait(api, job)["status"] == "canceled"
    assert (
        StartedJobRegistry(os.environ["VPP_QUEUE"], connection=redis_db).get_job_ids() == []
    )  # nothing runs
    resumed = submit(api, body)
    assert resumed == job
    done = wait(api, job)
    assert done["status"] == "succeeded"
    assert any(c["worker"] == "store" for c in done["chunks"])  # traced before the cancel


def test_a_plans_chunks_are_named_in_its_records_before_they_are_queued(svc_env, redis_db):
    # A cancel stops the chunks the plan's records name. When the records were published after
    # the chunks were queued, a plan stopped in between left queued chunks no sweep found.
    from rq import Queue
    from rq.job import Job

    from worker import jobs
    from worker.settings import Settings
    from worker.store import open_store

    settings = Settings()
    queue = Queue(svc_env["VPP_QUEUE"], connection=redis_db)
    plan_job = queue.enqueue(print, job_id="a-plan")
    ctx = jobs.Context(
        settings, open_store(settings.store_url), plan_job, queue, jobs._Meta(plan_job)
    )
    named_when_queued = []
    enqueue_many = queue.enqueue_many

    def enqueue_and_look(calls, **kw):  # what a cancel would read at this moment
        records = Job.fetch("a-plan", connection=redis_db).get_meta().get("chunks", [])
        named_when_queued.append({c.job_id for c in calls} <= {r.get("job") for r in records})
        return enqueue_many(calls, **kw)

    queue.enqueue_many = enqueue_and_look
    chunks = jobs._Chunks(ctx, "mesh", "trace", n_views=25, size=10, backend="raster")
    assert named_when_queued == [True]
    assert set(queue.job_ids) == {"a-plan"} | {r["job"] for r in chunks.records}
    assert len(chunks.records) == 3


def test_a_failed_chunk_fails_the_plan_with_its_reason(api, start_workers, monkeypatch) -> None:
    monkeypatch.setenv("VPP_CHUNK_TIMEOUT_S", "1")
    monkeypatch.setenv("VPP_CHUNK_VIEWS", "200")
    mesh = upload_sample(api)
    big = {"width_px": 3840, "height_px": 2400}  # 200 views of 9 Mpx, one Embree ray per pixel
    body = {
        "mesh_id": mesh,
        "sensor": big,
        "backend": "embree",
        "profile": "paper",
    }  # on the part: about 7 s
    job = submit(api, body | {"candidates": {"count": 400, "seed": 2}})
    start_workers(2)
    done = wait(api, job)
    assert done["status"] == "failed", done
    assert "chunk" in done["error"]["detail"] and "timeout" in done["error"]["detail"].lower()
    assert api.get(f"/v1/plans/{job}").status_code == 404
    # the plan job stopped tracing its own chunk when it saw the other one fail
    statuses = sorted(c["status"] for c in done["chunks"])
    assert statuses == ["failed", "running"], done["chunks"]


def test_a_job_that_ends_while_its_state_is_read_is_succeeded(api, monkeypatch) -> None:
    # The state used to look in the store first, then at the job: a job ending in between
    # (its document written, then its status set) read as "succeeded, result missing".
    from worker import artifacts, queue

    job = submit(
        api, {"mesh_id": upload_sample(api), "profile": "paper", "candidates": {"count": 40}}
    )
    real = queue._status

    def ends_now(rq_job):  # the worker writes the document and finishes as we look
        api.app.state.store.put(artifacts.plan_key(job), b"{}")
        return "succeeded" if real(rq_job) is not None else None

    monkeypatch.setattr(queue, "_status", ends_now)
    assert api.get(f"/v1/jobs/{job}").json()["status"] == "succeeded"


def test_workers_share_an_s3_store(svc_env, s3_endpoint, monkeypatch, start_workers) -> None:
    from fastapi.testclient import TestClient

    from service.app import create_app
    from tests.conftest import S3_BUCKET
    from worker.settings import Settings

    env = {
        "VPP_STORE_URL": f"s3://{S3_BUCKET}/{os.getpid()}-{time.time_ns()}",
        "VPP_S3_ENDPOINT_URL": s3_endpoint,
        "AWS_ACCESS_KEY_ID": "vpp-test",
        "AWS_SECRET_ACCESS_KEY": "vpp-test-secret",
    }
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    with TestClient(create_app(Settings())) as api:
        assert api.get("/readyz").json()["checks"]["store"] == "ok"
        mesh = upload_sample(api)
        job = submit(api, {"mesh_id": mesh, "profile": "paper", "candidates": {"count": 40}})
        start_workers(2)
        done = wait(api, job)
        assert done["status"] == "succeeded", done
        assert api.get(done["result_url"]).json()["solver"]["status"] == "optimal"


def test_bad_meshes_that_upload_plan_to_an_end(api, start_workers) -> None:
    from tests.conftest import MESHES, shared_dir

    jobs = {}
    for path in sorted(shared_dir(MESHES / "bad").iterdir()):
        r = api.post("/v1/meshes", files={"file": (path.name, path.read_bytes())})
        assert r.status_code < 500, (path.name, r.text)
        if r.status_code == 201:
            jobs[path.name] = submit(
                api, {"mesh_id": r.json()["id"], "profile": "paper", "candidates": {"count": 10}}
            )
    assert jobs, "no bad mesh was accepted: nothing to plan"
    start_workers(2)
    for name, job in jobs.items():
        done = wait(api, job, timeout=60)  # never stuck
        assert done["status"] in ("succeeded", "failed"), (name, done)
        if done["status"] == "failed":
            assert done["error"]["detail"], (name, done)
