"""Access control (VPP_API_KEYS): 401 without a bearer key, 403 with a wrong one, open probes.

The app is the real one on the test Redis and a fresh store; no workers, so the "normal answer"
of a resource that needs a finished job is its 404 problem (what the same request gets on an
open API), and submissions answer 202 with their job queued.
"""

from __future__ import annotations

import logging
from collections.abc import Iterator
from typing import Any

import pytest

from service.app import create_app
from vpp_core.samples import sample_stl
from worker.settings import Settings

PROBLEM = "application/problem+json"
KEY = "vpp-test-key-6f1d2c9a8b7e"
OTHER_KEY = "vpp-second-key-0a9b8c7d"
WRONG = "vpp-wrong-key-deadbeef00"
ZERO = "0" * 64
"""A well-formed id that names nothing."""


def auth(key: str) -> dict[str, str]:
    return {"Authorization": f"Bearer {key}"}


@pytest.fixture
def locked(svc_env: dict[str, str]) -> Iterator[Any]:
    """A TestClient of the app with two API keys configured."""
    from fastapi.testclient import TestClient

    settings = Settings(api_keys=f"{KEY}, {OTHER_KEY}")
    with TestClient(create_app(settings), raise_server_exceptions=False) as client:
        yield client


@pytest.fixture
def mesh_id(locked: Any) -> str:
    r = locked.post("/v1/meshes", files={"file": ("p.stl", sample_stl())}, headers=auth(KEY))
    assert r.status_code == 201, r.text
    return str(r.json()["id"])


def endpoints(mesh: str) -> list[tuple[str, str, dict[str, Any], int]]:
    """(method, path, request kwargs, status with a right key) per endpoint family."""
    plan = {"mesh_id": mesh, "profile": "paper", "candidates": {"count": 20}}
    study = {**plan, "kind": "resolution", "resolutions": [0.5, 1.0]}
    upload = {"files": {"file": ("p.stl", sample_stl())}}
    return [
        ("POST", "/v1/meshes", upload, 201),
        ("GET", f"/v1/meshes/{mesh}", {}, 200),
        ("POST", "/v1/plans", {"json": plan}, 202),
        ("GET", f"/v1/plans/{ZERO}", {}, 404),
        ("GET", f"/v1/plans/{ZERO}/plots/histogram.png", {}, 404),
        ("GET", f"/v1/jobs/{ZERO}", {}, 404),
        ("DELETE", f"/v1/jobs/{ZERO}", {}, 404),
        ("POST", "/v1/studies", {"json": study}, 202),
        ("GET", f"/v1/studies/{ZERO}", {}, 404),
        ("GET", f"/v1/studies/{ZERO}/rows.csv", {}, 404),
        ("GET", f"/v1/studies/{ZERO}/plots", {}, 404),
        ("POST", f"/v1/plans/{ZERO}/point-cloud", {}, 404),
        ("GET", f"/v1/plans/{ZERO}/point-cloud", {}, 404),
        ("GET", f"/v1/plans/{ZERO}/point-cloud/stats", {}, 404),
        ("GET", f"/v1/plans/{ZERO}/point-cloud/neighbours.png", {}, 404),
        ("GET", "/v1/no-such-route", {}, 404),
    ]


def assert_problem(r: Any, status: int) -> dict[str, Any]:
    assert r.status_code == status, r.text
    assert r.headers["content-type"] == PROBLEM
    body: dict[str, Any] = r.json()
    assert body["status"] == status and body["title"] and body["detail"]
    return body


def test_every_endpoint_needs_a_key(locked: Any, mesh_id: str) -> None:
    for method, path, kwargs, _ in endpoints(mesh_id):
        r = locked.request(method, path, **kwargs)
        assert_problem(r, 401)
        assert r.headers["www-authenticate"].startswith("Bearer")


def test_a_wrong_key_is_403(locked: Any, mesh_id: str) -> None:
    for method, path, kwargs, _ in endpoints(mesh_id):
        body = assert_problem(locked.request(method, path, headers=auth(WRONG), **kwargs), 403)
        assert WRONG not in body["detail"]


def test_a_right_key_gets_the_normal_answer(locked: Any, mesh_id: str) -> None:
    for key in (KEY, OTHER_KEY):  # either configured key (rotation)
        for method, path, kwargs, status in endpoints(mesh_id):
            r = locked.request(method, path, headers=auth(key), **kwargs)
            assert r.status_code == status, (method, path, r.text)


@pytest.mark.parametrize(
    "header",
    ["", "Bearer", "Bearer ", "Basic dXNlcjpwYXNz", f"Token {KEY}", f"Bearer {KEY} extra", KEY],
)
def test_a_malformed_header_is_401(locked: Any, header: str) -> None:
    r = locked.get(f"/v1/jobs/{ZERO}", headers={"Authorization": header})
    assert_problem(r, 401)


def test_the_scheme_is_case_insensitive_and_blanks_are_ignored(locked: Any) -> None:
    r = locked.get(f"/v1/jobs/{ZERO}", headers={"Authorization": f"bearer   {KEY}  "})
    assert_problem(r, 404)


def test_a_non_ascii_token_is_403_not_500(locked: Any) -> None:
    token = "Bearer caf\xe9".encode("latin-1")
    assert_problem(locked.get(f"/v1/jobs/{ZERO}", headers={"Authorization": token}), 403)


def test_probes_docs_and_viewer_shell_are_open(locked: Any) -> None:
    for path in ("/livez", "/readyz", "/openapi.json", "/docs"):
        assert locked.get(path).status_code == 200, path
    assert locked.post("/livez").status_code == 401  # open paths are open for GET/HEAD only


def test_viewer_shell_and_bundle_paths_are_exempt() -> None:
    from service.auth import OPEN

    assert OPEN.match(f"/v1/plans/{ZERO}/view")
    assert OPEN.match("/static/viewer/index.js")
    for path in (f"/v1/plans/{ZERO}", f"/v1/plans/{ZERO}/scene", f"/v1/plans/{ZERO}/view/x"):
        assert not OPEN.match(path), path


def test_a_refused_upload_is_not_read(locked: Any) -> None:
    """401 comes before the body: a huge anonymous upload is refused on its headers."""
    chunks_read = 0

    def body() -> Iterator[bytes]:
        nonlocal chunks_read
        for _ in range(64):
            chunks_read += 1
            yield b"x" * 2**20

    headers = {"content-type": "multipart/form-data; boundary=b"}
    assert_problem(locked.post("/v1/meshes", content=body(), headers=headers), 401)
    assert chunks_read <= 2


def test_no_key_configured_keeps_the_api_open(api: Any) -> None:
    assert_problem(api.get(f"/v1/jobs/{ZERO}"), 404)
    assert_problem(api.get(f"/v1/jobs/{ZERO}", headers=auth(WRONG)), 404)


def test_keys_never_reach_the_logs(
    locked: Any, mesh_id: str, caplog: pytest.LogCaptureFixture
) -> None:
    caplog.set_level(logging.DEBUG)
    for key in (WRONG, KEY):
        for method, path, kwargs, _ in endpoints(mesh_id):
            locked.request(method, path, headers=auth(key), **kwargs)
    text = caplog.text + "".join(str(r.__dict__) for r in caplog.records)
    assert caplog.records, "expected some log records (httpx logs each request)"
    for key in (WRONG, KEY, OTHER_KEY):
        assert key not in text


def test_settings_hide_the_keys(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("VPP_API_KEYS", f" {KEY} ,{OTHER_KEY},,")
    settings = Settings()
    assert settings.api_key_list() == [KEY, OTHER_KEY]
    assert KEY not in repr(settings) and KEY not in str(settings.model_dump())
    with pytest.raises(ValueError) as err:
        Settings(api_keys=f"{KEY},with space")
    assert KEY not in str(err.value)
    assert Settings(api_keys="").api_key_list() == []


def test_openapi_declares_the_bearer_scheme(locked: Any) -> None:
    doc = locked.get("/openapi.json").json()
    assert doc["components"]["securitySchemes"]["bearer"] == {
        "type": "http",
        "scheme": "bearer",
        "description": doc["components"]["securitySchemes"]["bearer"]["description"],
    }
    for path, item in doc["paths"].items():
        for method, operation in item.items():
            assert operation["security"] == [{"bearer": []}], (method, path)
            assert {"401", "403"} <= set(operation["responses"]), (method, path)
