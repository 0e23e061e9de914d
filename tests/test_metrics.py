"""GET /metrics: Prometheus text whose counts move as jobs are submitted (API process) and end
(worker's work horse), scraped before and after a plan on a real forking worker."""

from __future__ import annotations

import time
from typing import Any

import pytest
from prometheus_client.parser import text_string_to_metric_families

from vpp_core.samples import sample_stl

pytestmark = pytest.mark.slow


def scrape(api: Any) -> dict[tuple[str, tuple[tuple[str, str], ...]], float]:
    r = api.get("/metrics")
    assert r.status_code == 200 and r.headers["content-type"].startswith("text/plain"), r.text
    out = {}
    for family in text_string_to_metric_families(r.text):
        assert family.name.startswith("vpp_"), family.name
        for s in family.samples:
            out[(s.name, tuple(sorted(s.labels.items())))] = s.value
    return out


def test_counts_move_with_a_plan(api: Any, start_workers: Any, svc_env: dict[str, str]) -> None:
    before = scrape(api)
    plan = {"kind": "plan"}
    done = (("kind", "plan"), ("status", "succeeded"))
    assert before.get(("vpp_jobs_submitted_total", tuple(plan.items())), 0) == 0
    mesh = api.post("/v1/meshes", files={"file": ("b.stl", sample_stl())}).json()["id"]
    job = api.post("/v1/plans", json={"mesh_id": mesh, "candidates": {"count": 20}}).json()["id"]
    queued = scrape(api)
    assert queued[("vpp_jobs_submitted_total", tuple(plan.items()))] == 1
    assert queued[("vpp_queue_depth", (("queue", svc_env["VPP_QUEUE"]),))] == 1
    start_workers(1)
    deadline = time.monotonic() + 90
    while api.get(f"/v1/jobs/{job}").json()["status"] not in ("succeeded", "failed"):
        assert time.monotonic() < deadline
        time.sleep(0.1)
    after = scrape(api)
    while ("vpp_jobs_finished_total", done) not in after:  # the callback runs after the result
        assert time.monotonic() < deadline
        time.sleep(0.1)
        after = scrape(api)
    assert after[("vpp_jobs_finished_total", done)] == 1
    assert after[("vpp_job_duration_seconds_count", done)] == 1
    assert after[("vpp_job_duration_seconds_bucket", tuple(sorted((*done, ("le", "+Inf")))))] == 1
    assert after[("vpp_rays_traced_total", ())] > 0
    assert after[("vpp_solver_runs_total", (("status", "optimal"),))] == 1
    assert after[("vpp_stage_duration_seconds_count", (("stage", "trace"),))] == 1
    assert after[("vpp_queue_depth", (("queue", svc_env["VPP_QUEUE"]),))] == 0
