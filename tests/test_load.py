"""A short run of bench/load.py's mixed load (uploads, plans, polls) against uvicorn on loopback
with real forking workers: no 5xx, no transport error, every plan computed once."""

from __future__ import annotations

import asyncio
import threading

import httpx
import pytest

from tests.conftest import bench_module
from vpp_core.samples import sample_stl

pytestmark = pytest.mark.slow


def test_a_short_mixed_load_gets_no_5xx_and_computes_each_plan_once(
    live_api, start_workers, redis_db, tmp_path
) -> None:
    load = bench_module("load")
    start_workers(2, ready=True)
    r = httpx.post(f"{live_api}/v1/meshes", files={"file": ("b.stl", sample_stl())}, timeout=60)
    tally = asyncio.run(load.drive(live_api, r.json()["id"], clients=20, duration=3, distinct=4))
    lines = {x["endpoint"]: x for x in tally.lines()}
    assert set(lines) == {endpoint for _, endpoint in load.MIX}, lines
    assert tally.server_errors() == 0, lines
    assert all(x["errors"] == 0 for x in lines.values()), lines
    assert 2 <= len(tally.plans) <= 5  # the common plan and up to 4 distinct ones
    statuses = load.wait_jobs(live_api, tally.plans, timeout=120)
    assert statuses == {"succeeded": len(tally.plans)}
    runs = load.job_runs(tmp_path / "workers.log", "plan", tally.plans)
    assert {job: load.computed(r) for job, r in runs.items()} == dict.fromkeys(tally.plans, 1)


def test_the_load_only_targets_loopback() -> None:
    load = bench_module("load")
    with pytest.raises(ValueError, match="loopback"):
        asyncio.run(load.drive("http://example.org:80", "0" * 64, duration=0.1))
    with pytest.raises(SystemExit, match="loopback"):
        load.check_loopback_redis("redis://10.0.0.1:6379/8")


def test_job_runs_waits_for_the_line_rq_writes_after_the_status(tmp_path) -> None:
    # RQ marks a job finished, then logs "Successfully completed": a job polled as succeeded
    # may not have its line yet (a fresh-clone run counted a plan computed 0 times)
    load, log, job = bench_module("load"), tmp_path / "workers.log", "ab" * 32
    log.write_text("")
    line = f"Successfully completed plan {job[:12]} job in 0:00:01.500000s on worker w1\n"
    threading.Timer(0.3, log.write_text, args=(line,)).start()
    assert load.job_runs(log, "plan", {job}, wait_s=0.0) == {job: []}
    assert load.job_runs(log, "plan", {job}, wait_s=10.0) == {job: [1.5]}
