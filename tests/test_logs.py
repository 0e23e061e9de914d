"""Structured logs (worker/logs.py, service/requestid.py): X-Request-ID echoed on every answer,
a request's JSON log line carries its id, a worker's line written in a job carries the job id."""

from __future__ import annotations

import io
import json
import logging
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import pytest
from fastapi.testclient import TestClient

from worker import logs
from worker.settings import Settings


@pytest.fixture
def json_lines() -> Iterator[io.StringIO]:
    """What the root logger writes meanwhile, as JSON lines (worker.logs' handler)."""
    out = io.StringIO()
    handler = logs.handler("json", out)
    root = logging.getLogger()
    level = root.level
    root.addHandler(handler)
    root.setLevel(logging.INFO)
    yield out
    root.removeHandler(handler)
    root.setLevel(level)


def parsed(out: io.StringIO) -> list[dict[str, Any]]:
    return [json.loads(line) for line in out.getvalue().splitlines()]


def test_every_answer_echoes_its_request_id(
    svc_env: dict[str, str], monkeypatch: pytest.MonkeyPatch
) -> None:
    from service.app import create_app

    monkeypatch.setenv("VPP_API_KEYS", "key-0123456789")
    app = create_app(Settings())
    app.add_api_route("/boom", _raise)
    with TestClient(app, raise_server_exceptions=False) as api:
        for path, status in (("/livez", 200), ("/v1/jobs/" + "a" * 64, 401), ("/nowhere", 401)):
            r = api.get(path, headers={"X-Request-ID": "mes-42"})
            assert r.status_code == status and r.headers["x-request-id"] == "mes-42", path
        bearer = {"Authorization": "Bearer key-0123456789"}
        missing = api.get("/v1/jobs/" + "a" * 64, headers=bearer)
        assert missing.status_code == 404 and len(missing.headers["x-request-id"]) == 32
        made = {api.get("/livez").headers["x-request-id"] for _ in range(2)}
        assert len(made) == 2  # one per request
        odd = api.get("/livez", headers={"X-Request-ID": "x" * 129}).headers["x-request-id"]
        assert odd != "x" * 129 and len(odd) == 32  # not echoed: made anew
        boom = api.get("/boom", headers={**bearer, "X-Request-ID": "mes-500"})
        assert boom.status_code == 500 and boom.headers["x-request-id"] == "mes-500"


def _raise() -> None:
    raise RuntimeError("a bug")


def test_a_requests_json_log_line_carries_its_id(api: TestClient, json_lines: io.StringIO) -> None:
    api.get("/v1/jobs/" + "b" * 64, headers={"X-Request-ID": "mes-7"})
    lines = [x for x in parsed(json_lines) if x.get("request_id") == "mes-7"]
    assert lines and lines[-1]["logger"] == "vpp.access", parsed(json_lines)
    assert lines[-1]["message"].startswith(f"GET /v1/jobs/{'b' * 64} 404 ")
    assert {"time", "level", "message"} <= set(lines[-1])


def test_a_workers_lines_in_a_job_carry_its_id(
    svc_env: dict[str, str],
    redis_db: Any,
    start_workers: Any,
    monkeypatch: pytest.MonkeyPatch,
    tmp_path: Path,
) -> None:
    from rq import Queue

    monkeypatch.setenv("VPP_LOG_FORMAT", "json")
    job = Queue(svc_env["VPP_QUEUE"], connection=redis_db).enqueue(
        logging.warning, "written in a job"
    )
    (worker,) = start_workers(1, burst=True)
    assert worker.wait(timeout=120) == 0
    text = (tmp_path / "workers.log").read_text()
    lines = [json.loads(x) for x in text.splitlines() if x.startswith("{")]
    mine = [x for x in lines if x["message"] == "written in a job"]
    assert mine and mine[0]["job_id"] == job.id, text[-3000:]
    assert any("job_id" not in x for x in lines)  # the worker's own lines have none
