"""Idempotency: 50 identical requests at once give one computation; the Idempotency-Key rules
(draft-ietf-httpapi-idempotency-key-header-06) on every POST, against the real Redis."""

from __future__ import annotations

import asyncio
import json
import os
import re
import threading
import time
from collections.abc import AsyncIterator, Callable
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any

import httpx
import pytest
from fastapi.testclient import TestClient

from service.app import create_app
from service.idempotency import HEADER, MAX_KEY, PREFIX, REPLAYED
from vpp_core.samples import sample_stl
from worker.settings import Settings

PROBLEM = "application/problem+json"
SMALL = {"width_px": 320, "height_px": 200}
CLIENTS = 50
NOOP_S = 0.05
"""A job run shorter than this returned its stored result without computing (bench/load.py)."""


def upload(client, key: str | None = None) -> httpx.Response:
    headers = {HEADER: key} if key else {}
    return client.post("/v1/meshes", files={"file": ("bushing.stl", sample_stl())}, headers=headers)


def mesh_of(client) -> str:
    r = upload(client)
    assert r.status_code == 201, r.text
    return str(r.json()["id"])


def plan_body(mesh: str, seed: int = 0) -> dict[str, Any]:
    return {
        "mesh_id": mesh,
        "sensor": SMALL,
        "profile": "paper",
        "candidates": {"count": 20, "seed": seed},
    }


def records(redis_db) -> list[bytes]:
    return [redis_db.get(k) for k in redis_db.keys(f"{PREFIX}*")]


def assert_problem(r: httpx.Response, status: int) -> dict:
    assert r.status_code == status, r.text
    assert r.headers["content-type"] == PROBLEM
    return dict(r.json())


def queued_jobs(redis_db) -> int:
    return int(redis_db.llen(f"rq:queue:{os.environ['VPP_QUEUE']}"))


# ------------------------------------------------------------------------- the header's rules


def test_a_retried_plan_gets_the_remembered_answer_without_being_processed(api, redis_db) -> None:
    body = plan_body(mesh_of(api))
    first = api.post("/v1/plans", json=body, headers={HEADER: "plan-1"})
    assert first.status_code == 202 and REPLAYED.lower() not in first.headers
    assert queued_jobs(redis_db) == 1
    redis_db.delete(f"rq:queue:{os.environ['VPP_QUEUE']}")  # if it were processed again...
    redis_db.delete(f"rq:job:{first.json()['id']}")
    again = api.post("/v1/plans", json=body, headers={HEADER: "plan-1"})
    assert again.status_code == 202 and again.headers[REPLAYED] == "true"
    assert again.json() == first.json()
    for name in ("location", "retry-after", "content-type"):
        assert again.headers[name] == first.headers[name]
    assert queued_jobs(redis_db) == 0  # ...it would be enqueued anew: it was not
    fresh = api.post("/v1/plans", json=body)  # without the key: processed (and enqueued)
    assert REPLAYED.lower() not in fresh.headers and queued_jobs(redis_db) == 1


def test_a_retried_upload_is_replayed_though_its_multipart_boundary_differs(api) -> None:
    first = upload(api, "mesh-1")
    assert first.status_code == 201
    store = Path(api.app.state.store.root) / "meshes"
    for path in store.iterdir():
        path.unlink()  # a processed retry would store the mesh again
    again = upload(api, "mesh-1")  # httpx draws a new boundary for every request
    assert again.status_code == 201 and again.headers[REPLAYED] == "true"
    assert again.content == first.content
    assert again.headers["location"] == first.headers["location"]
    assert again.headers["etag"] == first.headers["etag"]
    assert list(store.iterdir()) == []


def test_studies_and_point_clouds_are_replayed(api, redis_db) -> None:
    mesh = mesh_of(api)
    study = {"mesh_id": mesh, "kind": "resolution", "resolutions": [1.2], "sensor": SMALL}
    answers = [api.post("/v1/studies", json=study, headers={HEADER: "s"}) for _ in range(2)]
    assert [a.status_code for a in answers] == [202, 202] and answers[0].json() == answers[1].json()
    assert answers[1].headers[REPLAYED] == "true"
    plan = api.post("/v1/plans", json=plan_body(mesh)).json()["id"]
    cloud = f"/v1/plans/{plan}/point-cloud"
    early = api.post(cloud, headers={HEADER: "c"})  # the plan is not computed yet: 404...
    assert_problem(early, 404)
    api.app.state.store.put(f"plans/{plan}.json", b"{}")  # ...now "it is" (the route checks)
    answers = [api.post(cloud, headers={HEADER: "c"}) for _ in range(2)]  # not remembered: runs
    assert [a.status_code for a in answers] == [202, 202] and answers[0].json() == answers[1].json()
    assert REPLAYED.lower() not in answers[0].headers and answers[1].headers[REPLAYED] == "true"


def test_the_same_key_with_another_request_is_422(api) -> None:
    mesh = mesh_of(api)
    assert api.post("/v1/plans", json=plan_body(mesh), headers={HEADER: "k"}).status_code == 202
    other = api.post("/v1/plans", json=plan_body(mesh, seed=1), headers={HEADER: "k"})
    assert "another request" in assert_problem(other, 422)["detail"]
    study = {"mesh_id": mesh, "kind": "resolution", "resolutions": [1.2]}
    assert_problem(api.post("/v1/studies", json=study, headers={HEADER: "k"}), 422)  # path
    assert_problem(upload(api, "k"), 422)
    assert api.post("/v1/plans", json=plan_body(mesh), headers={HEADER: "k"}).status_code == 202


def test_a_retry_while_the_first_is_processed_is_409(api, redis_db) -> None:
    body = json.dumps(plan_body(mesh_of(api))).encode()
    headers = {HEADER: "slow", "content-type": "application/json"}

    async def scenario() -> list[httpx.Response]:
        gate = asyncio.Event()

        async def slow_body() -> AsyncIterator[bytes]:  # the first request's body, held back
            yield body[:10]
            await gate.wait()
            yield body[10:]

        transport = httpx.ASGITransport(app=api.app)
        async with httpx.AsyncClient(transport=transport, base_url="http://test") as client:
            first = asyncio.create_task(
                client.post("/v1/plans", content=slow_body(), headers=headers)
            )
            deadline = time.monotonic() + 10
            while not records(redis_db):  # the first holds the key, reading its body
                assert time.monotonic() < deadline
                await asyncio.sleep(0.01)
            same = await client.post("/v1/plans", content=body, headers=headers)
            other = await client.post("/v1/plans", content=body[:-1] + b" }", headers=headers)
            gate.set()
            return [
                same,
                other,
                await first,
                await client.post("/v1/plans", content=body, headers=headers),
            ]

    same, other, first, later = asyncio.run(scenario())
    assert "still being processed" in assert_problem(same, 409)["detail"]
    assert_problem(other, 409)
    assert first.status_code == 202 and later.status_code == 202
    assert later.headers[REPLAYED] == "true" and later.json() == first.json()


def test_the_answer_goes_out_once_it_is_remembered(api, redis_db) -> None:
    body = json.dumps(plan_body(mesh_of(api))).encode()
    headers = {"content-type": "application/json", "idempotency-key": "sent"}
    scope = {
        "type": "http",
        "asgi": {"version": "3.0"},
        "http_version": "1.1",
        "method": "POST",
        "scheme": "http",
        "path": "/v1/plans",
        "raw_path": b"/v1/plans",
        "root_path": "",
        "query_string": b"",
        "headers": [(k.encode(), v.encode()) for k, v in headers.items()],
        "client": ("127.0.0.1", 1),
        "server": ("test", 80),
    }
    states: list[str] = []

    async def receive() -> dict:
        return {"type": "http.request", "body": body, "more_body": False}

    async def send(message: dict) -> None:
        if message["type"] == "http.response.start":  # a client could retry from here on
            assert message["status"] == 202
            states.extend(json.loads(r)["state"] for r in records(redis_db))

    asyncio.run(api.app(scope, receive, send))
    assert states == ["done"]  # so a retry gets the replay, not 409


@pytest.mark.parametrize(
    "key", ["", "   ", "a" * (MAX_KEY + 1), "tab\tkey", "del\x7fkey", "clé", '"unterminated']
)
def test_a_malformed_key_is_400(api, redis_db, key: str) -> None:
    r = api.post("/v1/plans", json={"mesh_id": "0" * 64}, headers={HEADER: key.encode("latin-1")})
    if key == '"unterminated':  # not a structured-field string: a bare key with a quote, valid
        assert r.status_code == 422 and "mesh" in r.json()["detail"]
        return
    assert HEADER in assert_problem(r, 400)["detail"]
    assert records(redis_db) == []


def test_two_headers_are_400_and_the_longest_key_and_a_quoted_one_are_fine(api) -> None:
    two = [("content-type", "application/json"), (HEADER, "a"), (HEADER, "b")]
    r = api.post("/v1/plans", content=b"{}", headers=two)
    assert "one Idempotency-Key" in assert_problem(r, 400)["detail"]
    body = plan_body(mesh_of(api))
    assert api.post("/v1/plans", json=body, headers={HEADER: "x" * MAX_KEY}).status_code == 202
    first = api.post("/v1/plans", json=body, headers={HEADER: "quoted"})
    again = api.post("/v1/plans", json=body, headers={HEADER: '"quoted"'})  # RFC 8941 string
    assert again.headers[REPLAYED] == "true" and again.json() == first.json()


def test_errors_are_not_remembered_and_free_the_key(api, redis_db) -> None:
    unknown = plan_body("0" * 64)
    assert_problem(api.post("/v1/plans", json=unknown, headers={HEADER: "e"}), 422)
    assert_problem(api.post("/v1/plans", json=unknown, headers={HEADER: "e"}), 422)
    assert records(redis_db) == []
    r = api.post("/v1/plans", json=plan_body(mesh_of(api)), headers={HEADER: "e"})
    assert r.status_code == 202 and REPLAYED.lower() not in r.headers


def test_keys_belong_to_their_api_key(svc_env, redis_db) -> None:
    with TestClient(create_app(Settings(api_keys="alice-key,bob-key"))) as api:
        alice = {"Authorization": "Bearer alice-key", HEADER: "shared"}
        bob = {"Authorization": "Bearer bob-key", HEADER: "shared"}
        files = {"file": ("b.stl", sample_stl())}
        r = api.post("/v1/meshes", files=files, headers={"Authorization": "Bearer alice-key"})
        body = plan_body(r.json()["id"])
        a = api.post("/v1/plans", json=body, headers=alice)
        b = api.post("/v1/plans", json={**body, "candidates": {"count": 21}}, headers=bob)
        assert a.status_code == b.status_code == 202 and a.json() != b.json()
        again = api.post("/v1/plans", json=body, headers=alice)
        assert again.headers[REPLAYED] == "true" and again.json() == a.json()
        assert api.post("/v1/plans", json=body, headers={HEADER: "shared"}).status_code == 401
    stored = b"".join(k for k in redis_db.keys(f"{PREFIX}*"))
    assert b"alice" not in stored and b"bob" not in stored  # digests, not keys


def test_records_are_small_and_expire_after_the_ttl(svc_env, redis_db) -> None:
    with TestClient(create_app(Settings(idempotency_ttl_s=1))) as api:
        r = upload(api, "ttl")
        body = plan_body(r.json()["id"])  # the key is the upload's: for a plan, 422
        assert api.post("/v1/plans", json=body, headers={HEADER: "ttl"}).status_code == 422
        (name,) = redis_db.keys(f"{PREFIX}*")
        assert 0 < redis_db.pttl(name) <= 1000 and len(redis_db.get(name)) < 1000
        time.sleep(1.2)
        assert records(redis_db) == []
        assert api.post("/v1/plans", json=body, headers={HEADER: "ttl"}).status_code == 202
    assert Settings().idempotency_ttl_s == 24 * 3600


def test_requests_without_the_key_and_other_methods_store_nothing(api, redis_db) -> None:
    body = plan_body(mesh_of(api))
    job = api.post("/v1/plans", json=body).json()["id"]
    assert api.get(f"/v1/jobs/{job}", headers={HEADER: "g"}).status_code == 200
    assert api.delete(f"/v1/jobs/{job}", headers={HEADER: "d"}).status_code == 200
    assert records(redis_db) == []


def test_a_body_over_the_cap_is_413_and_frees_the_key(svc_env, redis_db) -> None:
    with TestClient(create_app(Settings(max_json_bytes=100))) as api:

        def chunks():  # no Content-Length: cut off as it streams
            yield b'{"mesh_id": "' + b"0" * 200 + b'"}'

        headers = {HEADER: "big", "content-type": "application/json"}
        assert_problem(api.post("/v1/plans", content=chunks(), headers=headers), 413)
        assert records(redis_db) == []


def test_the_openapi_document_declares_the_header_on_every_post(api) -> None:
    doc = api.get("/openapi.json").json()
    posts = {p: ops["post"] for p, ops in doc["paths"].items() if "post" in ops}
    assert set(posts) == {
        "/v1/meshes",
        "/v1/plans",
        "/v1/studies",
        "/v1/plans/{plan_id}/point-cloud",
    }
    for op in posts.values():
        (param,) = [p for p in op["parameters"] if p["name"] == HEADER]
        assert param["in"] == "header" and param["schema"]["maxLength"] == MAX_KEY
        assert {"400", "409", "422"} <= set(op["responses"])
        ok = next(r for code, r in op["responses"].items() if code.startswith("2"))
        assert REPLAYED in ok["headers"]
    for path, ops in doc["paths"].items():
        for method, op in ops.items():
            if method != "post":
                names = [p["name"] for p in op.get("parameters", [])]
                assert HEADER not in names, (method, path)


# ----------------------------------------------------------- 50 clients at once, real workers


def at_once(base: str, n: int, call: Callable[[httpx.Client, int], Any]) -> list[Any]:
    """call(client, i) from n threads, each with its own connection, released together."""
    barrier = threading.Barrier(n)

    def one(i: int) -> Any:
        with httpx.Client(base_url=base, timeout=120) as client:
            barrier.wait(30)
            return call(client, i)

    with ThreadPoolExecutor(n) as pool:
        return list(pool.map(one, range(n)))


def wait_job(base: str, job: str, timeout: float = 180) -> dict:
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        state = httpx.get(f"{base}/v1/jobs/{job}", timeout=30).json()
        if state["status"] in ("succeeded", "failed", "canceled"):
            return dict(state)
        time.sleep(0.1)
    raise AssertionError(f"job {job} not done after {timeout} s: {state}")


def computations(log: Path, kind: str, job: str) -> int:
    """How many runs of job `job` computed it, from RQ's `Successfully completed <kind> <id12>
    job in H:MM:SS.f` lines: a run that finds its result stored returns in about a millisecond
    (see docs/reliability.md: a request can re-enqueue a job that ended while it waited)."""
    pattern = rf"Successfully completed {kind} {job[:12]} job in (\d+):(\d+):([\d.]+)s"
    times = [
        int(h) * 3600 + int(m) * 60 + float(s) for h, m, s in re.findall(pattern, log.read_text())
    ]
    return sum(1 for t in times if t >= NOOP_S)


def post_all(base: str, path: str, body: dict | None) -> tuple[str, list[str]]:
    """POST `body` to `path` from CLIENTS clients at once: the one id, the statuses it had."""
    answers = at_once(base, CLIENTS, lambda c, i: c.post(path, json=body))
    assert [a.status_code for a in answers] == [202] * CLIENTS, {a.text for a in answers}
    ids = {a.json()["id"] for a in answers}
    assert len(ids) == 1, ids
    (job,) = ids
    assert {a.headers["location"] for a in answers} == {f"/v1/jobs/{job}"}
    return job, [a.json()["status"] for a in answers]


@pytest.mark.slow
def test_50_identical_requests_at_once_are_computed_once(
    live_api, start_workers, redis_db, tmp_path
) -> None:
    base = live_api
    mesh = {a.json()["id"] for a in at_once(base, CLIENTS, lambda c, i: upload(c))}
    assert len(mesh) == 1  # 50 uploads of one mesh: one id, stored once
    (mesh_id,) = mesh
    assert sorted(p.name for p in Path(os.environ["VPP_STORE_URL"], "meshes").iterdir()) == [
        f"{mesh_id}.json",
        f"{mesh_id}.npz",
    ]
    start_workers(2, ready=True)
    log = tmp_path / "workers.log"
    body = {**plan_body(mesh_id), "candidates": {"count": 40}}
    plan, statuses = post_all(base, "/v1/plans", body)
    assert set(statuses) <= {"queued", "running"}, statuses
    assert wait_job(base, plan)["status"] == "succeeded"
    docs = at_once(base, CLIENTS, lambda c, i: c.get(f"/v1/plans/{plan}").content)
    assert len(set(docs)) == 1 and json.loads(docs[0])["viewpoints"]
    # the same study from 50 clients, and the plan's point cloud from 50 clients
    study_body = {"mesh_id": mesh_id, "kind": "resolution", "resolutions": [1.2, 2.5]}
    study, _ = post_all(
        base, "/v1/studies", {**study_body, "sensor": SMALL, "candidates": {"count": 20}}
    )
    cloud, _ = post_all(base, f"/v1/plans/{plan}/point-cloud", None)
    assert wait_job(base, study)["status"] == "succeeded"
    assert wait_job(base, cloud)["status"] == "succeeded"
    studies = at_once(base, CLIENTS, lambda c, i: c.get(f"/v1/studies/{study}").content)
    clouds = at_once(base, CLIENTS, lambda c, i: c.get(f"/v1/plans/{plan}/point-cloud").content)
    assert len(set(studies)) == 1 and len(set(clouds)) == 1 and clouds[0].startswith(b"ply")
    time.sleep(0.5)  # the workers' last log lines
    kinds = (("plan", plan), ("study", study), ("cloud", cloud))
    assert [computations(log, kind, job) for kind, job in kinds] == [1, 1, 1], log.read_text()
    # and once more from 50 clients: answered from the store, nothing runs again
    _, statuses = post_all(base, "/v1/plans", body)
    assert set(statuses) == {"succeeded"}
    time.sleep(0.5)
    assert computations(log, "plan", plan) == 1


@pytest.mark.slow
def test_50_clients_with_one_idempotency_key_get_one_answer(live_api, redis_db) -> None:
    base = live_api
    with httpx.Client(base_url=base, timeout=60) as client:
        mesh = upload(client).json()["id"]
    body = plan_body(mesh)
    answers = at_once(
        base, CLIENTS, lambda c, i: c.post("/v1/plans", json=body, headers={HEADER: "once"})
    )
    codes = sorted({a.status_code for a in answers})
    assert set(codes) <= {202, 409}, {a.text for a in answers}
    accepted = [a for a in answers if a.status_code == 202]
    fresh = [a for a in accepted if REPLAYED.lower() not in a.headers]
    assert len(fresh) == 1 and {a.json()["id"] for a in accepted} == {fresh[0].json()["id"]}
    assert all(a.headers["content-type"] == PROBLEM for a in answers if a.status_code == 409)
    again = httpx.post(f"{base}/v1/plans", json=body, headers={HEADER: "once"}, timeout=60)
    assert again.headers[REPLAYED] == "true" and again.json() == fresh[0].json()
    assert queued_jobs(redis_db) == 1


def test_a_non_ascii_path_with_a_key_is_404_not_500(api) -> None:  # found by schemathesis
    r = api.post("/v1/plans/%E7%92%A4X/point-cloud", headers={HEADER: "odd"})
    assert_problem(r, 404)
