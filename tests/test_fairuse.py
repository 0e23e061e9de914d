"""Fair use (service/fairuse.py): per-caller POST rate and queued + running jobs in Redis, 429
problem+json with Retry-After and the RateLimit headers; one key's flood leaves another key's
plan accepted, and the jobs run first come, first served on a real worker."""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import pytest
from fastapi.testclient import TestClient

from vpp_core.samples import sample_stl
from worker.settings import Settings

KEYS = {"flood": "key-flood-0123456789", "calm": "key-calm-0123456789"}
PROBLEM = "application/problem+json"
SMALL = {"width_px": 160, "height_px": 100}
"""A small sensor: each plan takes about a second."""


def auth(who: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {KEYS[who]}"}


@pytest.fixture
def fair(svc_env: dict[str, str], monkeypatch: pytest.MonkeyPatch) -> Iterator[TestClient]:
    """The API with two keys, 6 POSTs per 60 s and 2 active jobs each (no workers yet)."""
    from service.app import create_app

    monkeypatch.setenv("VPP_API_KEYS", ",".join(KEYS.values()))
    monkeypatch.setenv("VPP_RATE_LIMIT", "6")
    monkeypatch.setenv("VPP_RATE_WINDOW_S", "60")
    monkeypatch.setenv("VPP_MAX_ACTIVE_JOBS", "2")
    with TestClient(create_app(Settings())) as client:
        yield client


def upload(api: TestClient, who: str) -> Any:
    return api.post("/v1/meshes", files={"file": ("b.stl", sample_stl())}, headers=auth(who))


def plan(api: TestClient, who: str, mesh: str, count: int) -> Any:
    body = {"mesh_id": mesh, "sensor": SMALL, "profile": "paper", "candidates": {"count": count}}
    return api.post("/v1/plans", json=body, headers=auth(who))


def assert_429(r: Any, why: str) -> None:
    assert r.status_code == 429 and r.headers["content-type"] == PROBLEM, r.text
    assert int(r.headers["retry-after"]) >= 1 and why in r.json()["detail"], r.text


def test_a_flood_is_refused_and_another_key_runs_first_come(
    fair: TestClient, start_workers: Any
) -> None:
    mesh = upload(fair, "flood").json()["id"]
    first = upload(fair, "flood")  # POSTs 1 and 2 of 6
    assert first.headers["ratelimit-policy"] == '"post";q=6;w=60'
    assert first.headers["ratelimit"].startswith('"post";r=4;t=')
    answers = [plan(fair, "flood", mesh, 10 + i) for i in range(6)]  # POSTs 3 to 8
    assert [r.status_code for r in answers] == [202, 202, 429, 429, 429, 429]
    assert_429(answers[2], "VPP_MAX_ACTIVE_JOBS")  # 2 jobs queued: the cap
    assert_429(answers[4], "VPP_RATE_LIMIT")  # POST 7: the rate, body unread
    assert answers[4].headers["ratelimit"].startswith('"post";r=0;t=')
    calm = plan(fair, "calm", mesh, 12)  # another key: its own rate and slots
    assert calm.status_code == 202 and calm.headers["ratelimit"].startswith('"post";r=5;t=')
    order = [r.json()["id"] for r in answers[:2]] + [calm.json()["id"]]
    listed = fair.get("/v1/jobs", params={"limit": 10}, headers=auth("flood")).json()["items"]
    assert [j["id"] for j in listed] == order[1::-1]  # nothing refused was queued
    start_workers(1)
    started = [wait_started(fair, job) for job in order]
    assert started == sorted(started)  # first come, first served: the flood jumps no queue
    fair.delete(f"/v1/jobs/{order[-1]}", headers=auth("calm"))  # done: stop it


def wait_started(api: TestClient, job: str) -> float:
    """When `job` started (its RQ record), once it has."""
    from rq.job import Job

    deadline = time.monotonic() + 120
    conn = api.app.state.redis  # type: ignore[attr-defined]
    while (started := Job.fetch(job, connection=conn).started_at) is None:
        assert time.monotonic() < deadline, job
        time.sleep(0.05)
    return started.timestamp()


def test_anonymous_callers_are_counted_per_address(
    svc_env: dict[str, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from service.app import create_app

    monkeypatch.setenv("VPP_RATE_LIMIT", "2")
    with TestClient(create_app(Settings())) as api:
        assert [upload(api, "calm").status_code for _ in range(3)] == [201, 201, 429]
        assert api.post("/v1/meshes", headers={"X-Forwarded-For": "10.0.0.9"}).status_code == 429
    with TestClient(create_app(Settings()), client=("192.0.2.7", 5000)) as other:
        assert upload(other, "calm").status_code == 201


def test_failed_submissions_and_ended_jobs_free_their_slots(fair: TestClient) -> None:
    mesh = upload(fair, "calm").json()["id"]
    assert plan(fair, "calm", "0" * 64, 10).status_code == 422  # a missing mesh: no slot kept
    jobs = [plan(fair, "calm", mesh, n) for n in (10, 11, 12)]
    assert [r.status_code for r in jobs] == [202, 202, 429]
    assert fair.delete(f"/v1/jobs/{jobs[0].json()['id']}", headers=auth("calm")).is_success
    assert plan(fair, "calm", mesh, 12).status_code == 202  # the canceled job freed its slot
