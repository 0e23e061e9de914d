"""Webhooks and Server-Sent Events against the API served on loopback, a real forking RQ worker
and a real HTTP receiver (http.server in a thread): the terminal event arrives signed the
Standard Webhooks way (checked with the `standardwebhooks` package), undelivered events are
retried with backoff and every attempt shows on the job; /events streams progress to `done`;
callback URLs into private ranges and bad secrets are refused."""

from __future__ import annotations

import base64
import json
import threading
import time
from http.server import BaseHTTPRequestHandler, ThreadingHTTPServer
from typing import Any

import httpx
import pytest

from vpp_core.samples import sample_stl

pytestmark = pytest.mark.slow
SECRET = "whsec_" + base64.b64encode(b"0123456789abcdef0123456789abcdef").decode()
DEADLINE_S = 90.0


class Receiver:
    """An HTTP receiver on 127.0.0.1: records each POST; answers `codes` in turn, then 204."""

    def __init__(self, codes: list[int] | None = None) -> None:
        self.codes = list(codes or [])
        self.posts: list[tuple[dict[str, str], bytes]] = []
        self.times: list[float] = []
        outer = self

        class Handler(BaseHTTPRequestHandler):
            def do_POST(self) -> None:  # noqa: N802
                body = self.rfile.read(int(self.headers["content-length"]))
                outer.times.append(time.monotonic())
                outer.posts.append(({k.lower(): v for k, v in self.headers.items()}, body))
                self.send_response(outer.codes.pop(0) if outer.codes else 204)
                self.send_header("content-length", "0")
                self.end_headers()

            def log_message(self, *args: Any) -> None:
                pass

        self.server = ThreadingHTTPServer(("127.0.0.1", 0), Handler)
        self.url = f"http://127.0.0.1:{self.server.server_address[1]}/hook"
        threading.Thread(target=self.server.serve_forever, daemon=True).start()

    def close(self) -> None:
        self.server.shutdown()
        self.server.server_close()

    def wait(self, n: int) -> None:
        deadline = time.monotonic() + DEADLINE_S
        while len(self.posts) < n:
            assert time.monotonic() < deadline, f"{len(self.posts)} of {n} webhooks arrived"
            time.sleep(0.05)


@pytest.fixture
def private_ok(svc_env: dict[str, str], monkeypatch: pytest.MonkeyPatch) -> dict[str, str]:
    """The test's receiver is on loopback: allow it (API and workers), retry after 1 s; the
    workers move due retries onto the queue at each sweep, every second here (VPP_SWEEP_S;
    VPP_DEAD_WORKER_S bounds how long an idle worker blocks between sweeps)."""
    monkeypatch.setenv("VPP_CALLBACK_ALLOW_PRIVATE", "1")
    monkeypatch.setenv("VPP_CALLBACK_RETRY_S", "1")
    monkeypatch.setenv("VPP_SWEEP_S", "1")
    monkeypatch.setenv("VPP_DEAD_WORKER_S", "3")
    return svc_env


def plan_body(mesh: str, count: int = 20, **extra: Any) -> dict[str, Any]:
    return {"mesh_id": mesh, "profile": "paper", "candidates": {"count": count}, **extra}


def upload(client: httpx.Client) -> str:
    r = client.post("/v1/meshes", files={"file": ("b.stl", sample_stl())})
    assert r.status_code == 201, r.text
    return str(r.json()["id"])


def served(env: dict[str, str]) -> Any:
    from service.app import create_app
    from tests.conftest import serving
    from worker.settings import Settings

    return serving(create_app(Settings()))


def verify(secret: str, headers: dict[str, str], body: bytes) -> Any:
    """The payload, checked with the reference implementation of Standard Webhooks."""
    from standardwebhooks import Webhook

    return Webhook(secret).verify(body, headers)


def wait_job(client: httpx.Client, job: str, pred: Any) -> dict[str, Any]:
    deadline = time.monotonic() + DEADLINE_S
    while True:
        body = client.get(f"/v1/jobs/{job}").json()
        if pred(body):
            return body
        assert time.monotonic() < deadline, body
        time.sleep(0.1)


def test_terminal_event_is_signed_retried_and_recorded(
    private_ok: dict[str, str], start_workers: Any
) -> None:
    hook = Receiver(codes=[503])  # the first attempt fails: RQ retries it after backoff
    with served(private_ok) as url, httpx.Client(base_url=url, timeout=30) as client:
        mesh = upload(client)
        callback = {"url": hook.url, "secret": SECRET}
        r = client.post("/v1/plans", json=plan_body(mesh, callback=callback))
        assert r.status_code == 202, r.text
        job = r.json()["id"]
        start_workers(1)
        hook.wait(2)
        # the retry waits out its backoff (1 s), then the next sweep (every 1 s) enqueues it
        assert 1.0 <= hook.times[1] - hook.times[0] <= 1.0 + 1 + 5, hook.times
        for headers, body in hook.posts:
            payload = verify(SECRET, headers, body)
            assert payload["type"] == "job.succeeded"
            assert payload["data"]["id"] == job and payload["data"]["kind"] == "plan"
            assert payload["data"]["result_url"] == f"/v1/plans/{job}"
        assert hook.posts[0][0]["webhook-id"] == hook.posts[1][0]["webhook-id"]  # one message
        with pytest.raises(Exception, match="(?i)signature"):
            verify("whsec_" + base64.b64encode(b"x" * 32).decode(), *hook.posts[1])
        done = wait_job(client, job, lambda j: len(j["deliveries"]) == 2)
        first, second = done["deliveries"]
        assert (first["attempt"], first["status_code"], first["delivered"]) == (1, 503, False)
        assert (second["attempt"], second["status_code"], second["delivered"]) == (2, 204, True)
        # a second request for the finished plan with its own callback is told at once
        r = client.post(
            "/v1/plans", json=plan_body(mesh, callback={**callback, "url": hook.url + "2"})
        )
        assert r.json()["status"] == "succeeded"
        hook.wait(3)
        assert verify(SECRET, *hook.posts[2])["data"]["status"] == "succeeded"
    hook.close()


def test_events_stream_progress_then_done_and_resume(
    svc_env: dict[str, str], start_workers: Any
) -> None:
    with served(svc_env) as url, httpx.Client(base_url=url, timeout=60) as client:
        mesh = upload(client)
        job = client.post("/v1/plans", json=plan_body(mesh, count=40)).json()["id"]
        start_workers(1)
        events = read_events(client, f"/v1/jobs/{job}/events")
        names = [e["event"] for e in events]
        assert names[0] == "status" and names[-1] == "done" and names.count("done") == 1
        assert "progress" in names
        done = json.loads(events[-1]["data"])
        assert done["status"] == "succeeded" and done["result_url"] == f"/v1/plans/{job}"
        ids = [e["id"] for e in events]
        assert len(set(ids[:-1])) == len({e["id"] for e in events if e["event"] != "done"})
        # reconnecting after the end: only `done`, at once
        again = read_events(client, f"/v1/jobs/{job}/events", last_id=ids[-2])
        assert [e["event"] for e in again] == ["done"]
        r = client.get(f"/v1/jobs/{'0' * 64}/events")
        assert r.status_code == 404 and r.headers["content-type"] == "application/problem+json"


def test_resume_skips_the_state_already_seen(svc_env: dict[str, str]) -> None:
    with served(svc_env) as url, httpx.Client(base_url=url, timeout=30) as client:
        mesh = upload(client)
        job = client.post("/v1/plans", json=plan_body(mesh)).json()["id"]  # no worker: queued
        first = read_events(client, f"/v1/jobs/{job}/events", count=2)
        assert [e["event"] for e in first] == ["status", "progress"]
        assert json.loads(first[0]["data"]) == {"id": job, "status": "queued"}
        client.delete(f"/v1/jobs/{job}")
        again = read_events(client, f"/v1/jobs/{job}/events", last_id=first[-1]["id"])
        assert [e["event"] for e in again] == ["done"]
        assert json.loads(again[0]["data"])["status"] == "canceled"


def read_events(
    client: httpx.Client, path: str, last_id: str | None = None, count: int = 10_000
) -> list[dict[str, str]]:
    """The SSE events of `path` (comments skipped) until the stream ends or `count` came."""
    headers = {"last-event-id": last_id} if last_id else {}
    events: list[dict[str, str]] = []
    current: dict[str, str] = {}
    with client.stream("GET", path, headers=headers) as r:
        assert r.status_code == 200 and r.headers["content-type"].startswith("text/event-stream")
        for line in r.iter_lines():
            if not line:
                if current:
                    events.append(current)
                    current = {}
                if len(events) >= count:
                    break
                continue
            field, _, value = line.partition(":")
            if field:
                current[field] = value.removeprefix(" ")
    return events


BAD_CALLBACKS = [
    ({"url": "http://127.0.0.1:9/hook", "secret": SECRET}, "loopback"),
    ({"url": "http://10.1.2.3/hook", "secret": SECRET}, "private"),
    ({"url": "http://169.254.169.254/latest", "secret": SECRET}, "link-local"),
    ({"url": "http://[::1]/hook", "secret": SECRET}, "loopback"),
    ({"url": "ftp://example.com/hook", "secret": SECRET}, "url"),
    ({"url": "http://example.com/hook", "secret": "not base64!"}, "secret"),
    ({"url": "http://example.com/hook", "secret": "whsec_" + "QUJD"}, "secret"),
    ({"url": "http://example.com/hook"}, "secret"),
]


@pytest.mark.parametrize(("callback", "word"), BAD_CALLBACKS)
def test_bad_callbacks_are_refused_before_anything_is_queued(
    api: Any, callback: dict[str, str], word: str
) -> None:
    mesh = upload(api)
    r = api.post("/v1/plans", json=plan_body(mesh, callback=callback))
    assert r.status_code == 422, r.text
    assert r.headers["content-type"] == "application/problem+json"
    assert word in r.text.lower() or "loopback" in r.text.lower()
    assert api.get("/v1/jobs").json()["items"] == []
