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
    job = api.post(
        "/v1/plans", json={"mesh_id": mesh, "profile": "paper", "candidates": {"count": 20}}
    ).json()["id"]
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


def test_store_failures_are_counted_by_operation(api: Any, svc_env: dict[str, str]) -> None:
    """Every operation has its error series from the start (0); an upload into a store that
    cannot write (its `meshes` folder is a file) is a 503 and one failed `put`."""
    from pathlib import Path

    before = scrape(api)
    for op in ("put", "get", "exists", "ping"):
        assert before[("vpp_store_errors_total", (("operation", op),))] == 0
    root = Path(svc_env["VPP_STORE_URL"])
    root.mkdir(parents=True, exist_ok=True)
    (root / "meshes").write_bytes(b"not a folder")
    r = api.post("/v1/meshes", files={"file": ("b.stl", sample_stl())})
    assert r.status_code == 503 and r.headers["content-type"] == "application/problem+json", r.text
    after = scrape(api)
    assert after[("vpp_store_errors_total", (("operation", "put"),))] == 1
    assert after[("vpp_store_errors_total", (("operation", "get"),))] == 0


def test_the_prometheus_profile_scrapes_the_api_and_alerts_on_its_metrics(api: Any) -> None:
    """docker/compose.yaml's `monitoring` profile: Prometheus scrapes the API service's port at
    /metrics with the key file its entrypoint writes, and every `vpp_` metric its alert rules
    use is one that /metrics serves (in a scrape, or declared: counters appear with a sample)."""
    import re
    from pathlib import Path

    import yaml

    docker = Path(__file__).resolve().parent.parent / "docker"
    compose = yaml.safe_load((docker / "compose.yaml").read_text())
    prom = compose["services"]["prometheus"]
    assert prom["profiles"] == ["monitoring"]
    mounts = {v.split(":")[1]: v.split(":")[0] for v in prom["volumes"] if v.startswith("./")}
    config = yaml.safe_load((docker / mounts["/etc/prometheus/prometheus.yml"]).read_text())
    (job,) = config["scrape_configs"]
    assert job["metrics_path"] == "/metrics"
    assert job["static_configs"][0]["targets"] == ["api:8000"]
    assert compose["services"]["api"]["command"][-1] == "8000"
    assert job["authorization"]["credentials_file"] in " ".join(prom["entrypoint"])
    rules_file = config["rule_files"][0]
    assert rules_file in mounts
    rules = yaml.safe_load((docker / mounts[rules_file]).read_text())
    used = {
        name
        for group in rules["groups"]
        for rule in group["rules"]
        for name in re.findall(r"\bvpp_\w+", rule["expr"])
    }
    from worker import metrics

    served = {name for name, _ in scrape(api)} | {f"vpp_{name}" for name in metrics.HELP}
    assert used and used <= served, used - served
