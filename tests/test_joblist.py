"""GET /v1/jobs: each key lists its own jobs (an admin key all), newest first, in stable
cursor pages, filtered; the index expires with the job records; bad queries are 4xx."""

from __future__ import annotations

import time
from collections.abc import Iterator
from typing import Any

import pytest
from fastapi.testclient import TestClient

from vpp_core.samples import sample_stl
from worker import joblist
from worker.settings import Settings

KEYS = {"a": "key-a-0123456789", "b": "key-b-0123456789", "admin": "key-admin-0123456789"}


def auth(who: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {KEYS[who]}"}


@pytest.fixture
def keyed(svc_env: dict[str, str], monkeypatch: pytest.MonkeyPatch) -> Iterator[TestClient]:
    """The API with three keys, one of them admin (no workers: jobs stay queued)."""
    from service.app import create_app

    monkeypatch.setenv("VPP_API_KEYS", ",".join(KEYS.values()))
    monkeypatch.setenv("VPP_ADMIN_API_KEYS", KEYS["admin"])
    with TestClient(create_app(Settings())) as client:
        yield client


def upload(api: TestClient, who: str = "a") -> str:
    r = api.post("/v1/meshes", files={"file": ("b.stl", sample_stl())}, headers=auth(who))
    assert r.status_code == 201, r.text
    return str(r.json()["id"])


def submit(api: TestClient, who: str, mesh: str, count: int) -> str:
    body = {"mesh_id": mesh, "profile": "paper", "candidates": {"count": count}}
    r = api.post("/v1/plans", json=body, headers=auth(who))
    assert r.status_code == 202, r.text
    return str(r.json()["id"])


def pages(api: TestClient, who: str, limit: int, **query: Any) -> list[list[dict[str, Any]]]:
    """Every page of the listing, following next_cursor."""
    out, cursor = [], None
    while True:
        params = {"limit": limit, **query, **({"cursor": cursor} if cursor else {})}
        r = api.get("/v1/jobs", params=params, headers=auth(who))
        assert r.status_code == 200, r.text
        out.append(r.json()["items"])
        cursor = r.json()["next_cursor"]
        if cursor is None:
            return out


def test_each_key_lists_its_own_jobs_newest_first_in_pages(keyed: TestClient) -> None:
    mesh = upload(keyed)
    mine = [submit(keyed, "a", mesh, n) for n in (20, 21, 22)]
    theirs = [submit(keyed, "b", mesh, n) for n in (30, 31)]
    listed = pages(keyed, "a", 2)
    assert [len(p) for p in listed] == [2, 1]
    items = [j for p in listed for j in p]
    assert [j["id"] for j in items] == mine[::-1]
    assert all(j["kind"] == "plan" and j["status"] == "queued" for j in items)
    assert all(j["created_at"] and "progress" in j for j in items)
    assert [j["id"] for p in pages(keyed, "b", 5) for j in p] == theirs[::-1]
    everyone = [j["id"] for p in pages(keyed, "admin", 3) for j in p]
    assert everyone == (mine + theirs)[::-1]
    # the same request from another key joins the job, and the job is that key's too
    assert submit(keyed, "b", mesh, 20) == mine[0]
    assert mine[0] in [j["id"] for p in pages(keyed, "b", 5) for j in p]


def test_pages_are_stable_under_concurrent_submissions(keyed: TestClient) -> None:
    mesh = upload(keyed)
    old = [submit(keyed, "a", mesh, n) for n in (20, 21, 22, 23)]
    first = keyed.get("/v1/jobs", params={"limit": 2}, headers=auth("a")).json()
    new = submit(keyed, "a", mesh, 24)  # arrives while the client pages
    rest = keyed.get(
        "/v1/jobs", params={"limit": 2, "cursor": first["next_cursor"]}, headers=auth("a")
    ).json()
    assert [j["id"] for j in first["items"] + rest["items"]] == old[::-1]
    assert rest["next_cursor"] is None
    assert keyed.get("/v1/jobs", headers=auth("a")).json()["items"][0]["id"] == new


def test_filters(keyed: TestClient) -> None:
    mesh = upload(keyed)
    job = submit(keyed, "a", mesh, 20)

    def ids(**query: Any) -> list[str]:
        r = keyed.get("/v1/jobs", params=query, headers=auth("a"))
        assert r.status_code == 200, r.text
        return [j["id"] for j in r.json()["items"]]

    assert ids(kind="plan", status="queued", mesh_id=mesh) == [job]
    assert ids(kind="study") == ids(status="succeeded") == ids(mesh_id="0" * 64) == []
    assert ids(created_after="2000-01-01T00:00:00Z") == [job]
    assert ids(created_after="2999-01-01T00:00:00Z") == []


@pytest.mark.parametrize(
    "query",
    [
        {"cursor": "not a cursor!"},
        {"cursor": "bm8tY29sb24"},  # base64 of "no-colon"
        {"status": "done"},
        {"kind": "mesh"},
        {"mesh_id": "xyz"},
        {"limit": 0},
        {"limit": 1000},
        {"created_after": "yesterday"},
    ],
)
def test_malformed_queries_are_problems(keyed: TestClient, query: dict[str, Any]) -> None:
    r = keyed.get("/v1/jobs", params=query, headers=auth("a"))
    assert r.status_code == 422, r.text
    assert r.headers["content-type"] == "application/problem+json"


def test_listing_needs_a_key(keyed: TestClient) -> None:
    assert keyed.get("/v1/jobs").status_code == 401


def test_the_index_expires_with_the_job_records(redis_db: Any) -> None:
    settings = Settings(plan_timeout_s=1, result_ttl_s=2, failure_ttl_s=1)
    ttl = joblist.retention_s(settings)
    assert ttl == 3
    stale = joblist.now_us() - (ttl + 1) * 1_000_000  # recorded longer ago than a job lives
    redis_db.zadd(joblist.INDEX, {"old": stale})
    redis_db.zadd(joblist.owner_key("o"), {"old": stale})
    joblist.record(redis_db, settings, "new", "plan", None, "o")
    for key in (joblist.INDEX, joblist.owner_key("o")):
        assert [m.decode() for m in redis_db.zrange(key, 0, -1)] == ["new"]
        assert 0 < redis_db.ttl(key) <= ttl
    assert 0 < redis_db.ttl(joblist.record_key("new")) <= ttl
    time.sleep(ttl + 0.5)
    assert redis_db.dbsize() == 0
