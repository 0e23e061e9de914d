"""The committed OpenAPI document as clients use it: a Python client generated from
openapi/openapi.json with openapi-python-client plans the sample part end to end against the
API served by uvicorn on loopback, with a real Redis and a real forking RQ worker."""

from __future__ import annotations

import importlib
import importlib.util
import io
import json
import socket
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from types import SimpleNamespace
from typing import Any

import pytest

from tests.conftest import ROOT
from tests.test_webhooks import SECRET, Receiver
from vpp_core.samples import sample_stl

pytestmark = pytest.mark.slow

OPENAPI = ROOT / "openapi" / "openapi.json"
PACKAGE = "vpp_generated_client"
"""Name of the generated package: unlikely to shadow anything on sys.path."""
OPERATIONS = {
    "meshes": ("upload_mesh", "get_mesh"),
    "plans": ("submit_plan", "get_plan"),
    "jobs": ("get_job", "cancel_job", "list_jobs"),
}
"""Tag (the generated api subpackage) -> operation ids the test needs."""
JOB_DEADLINE_S = 60.0


def generate(document: Path, dest: Path) -> tuple[Path, str]:
    """Generate the client package of `document` under `dest`: (its folder, generator output)."""
    if importlib.util.find_spec("openapi_python_client") is None:
        pytest.skip("openapi-python-client is not installed (pip install openapi-python-client)")
    config = dest / "generator.json"
    config.write_text(json.dumps({"post_hooks": []}))  # no ruff on the generated code
    out = dest / PACKAGE
    cmd = [sys.executable, "-m", "openapi_python_client", "generate"]
    cmd += ["--path", str(document), "--output-path", str(out), "--meta", "none"]
    cmd += ["--config", str(config)]
    proc = subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)
    log = proc.stdout + proc.stderr
    assert proc.returncode == 0 and (out / "__init__.py").is_file(), log
    return out, log


@pytest.fixture
def generated(tmp_path: Path) -> Iterator[SimpleNamespace]:
    """The generated client imported from tmp_path; sys.path and sys.modules restored after."""
    pkg, log = generate(OPENAPI, tmp_path)
    wanted = [(tag, op) for tag, ops in OPERATIONS.items() for op in ops]
    missing = [f"{t}/{op}" for t, op in wanted if not (pkg / "api" / t / f"{op}.py").is_file()]
    assert not missing, f"the generator dropped {missing} from {OPENAPI.name}:\n{log}"
    sys.path.insert(0, str(tmp_path))
    importlib.invalidate_caches()
    try:
        ns = SimpleNamespace(
            **{op: importlib.import_module(f"{PACKAGE}.api.{t}.{op}") for t, op in wanted}
        )
        ns.client = importlib.import_module(PACKAGE)
        ns.models = importlib.import_module(f"{PACKAGE}.models")
        ns.types = importlib.import_module(f"{PACKAGE}.types")
        yield ns
    finally:
        sys.path.remove(str(tmp_path))
        for name in [m for m in sys.modules if m == PACKAGE or m.startswith(f"{PACKAGE}.")]:
            del sys.modules[name]
        importlib.invalidate_caches()


@pytest.fixture
def base_url(svc_env: dict[str, str], monkeypatch: pytest.MonkeyPatch) -> Iterator[str]:
    """The API served by uvicorn in a thread of this process on a loopback port of its own
    (callbacks to loopback allowed: the test's webhook receiver is there)."""
    import uvicorn

    monkeypatch.setenv("VPP_CALLBACK_ALLOW_PRIVATE", "1")

    from service.app import create_app
    from worker.settings import Settings

    sock = socket.socket(socket.AF_INET, socket.SOCK_STREAM)
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
    sock.bind(("127.0.0.1", 0))
    port = sock.getsockname()[1]
    config = uvicorn.Config(
        create_app(Settings()),
        host="127.0.0.1",
        port=port,
        loop="asyncio",
        ws="none",
        lifespan="on",
        log_level="warning",
    )
    server = uvicorn.Server(config)
    # Server.capture_signals installs no handlers outside the main thread.
    thread = threading.Thread(target=server.run, kwargs={"sockets": [sock]}, name="uvicorn")
    thread.start()
    try:
        deadline = time.monotonic() + 10
        while not server.started:
            assert thread.is_alive() and time.monotonic() < deadline, "uvicorn did not start"
            time.sleep(0.02)
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(timeout=10)
        sock.close()
        assert not thread.is_alive(), "uvicorn did not stop"


def wait_for_job(api: SimpleNamespace, client: Any, job_id: str) -> Any:
    """Poll get_job until the job has finished; its last JobOut."""
    deadline = time.monotonic() + JOB_DEADLINE_S
    while True:
        r = api.get_job.sync_detailed(job_id, client=client)
        assert r.status_code == 200, r.content
        job = r.parsed
        if str(job.status) in ("succeeded", "failed", "canceled"):
            return job
        assert time.monotonic() < deadline, f"job still {job.status}: {job.to_dict()}"
        time.sleep(0.1)


def test_generated_client_plans_the_sample_part(
    generated: SimpleNamespace, base_url: str, start_workers: Any
) -> None:
    api, m = generated, generated.models
    with api.client.Client(base_url=base_url, raise_on_unexpected_status=True) as client:
        # upload: multipart file + units
        stl = sample_stl()
        body = m.BodyUploadMesh(
            file=api.types.File(payload=io.BytesIO(stl), file_name="bushing.stl"),
            units="mm",
        )
        r = api.upload_mesh.sync_detailed(client=client, body=body)
        file_type = m.BodyUploadMesh.__annotations__.get("file")
        assert r.status_code == 201, (
            f"upload_mesh answered {r.status_code}: {r.content!r}\n"
            f"the generated BodyUploadMesh.file is typed {file_type!r}"
            + ("" if file_type == "File" else ", so it goes as a text field without filename: "
               "openapi-python-client makes a file part only of `format: binary`")
        )  # fmt: skip
        mesh = r.parsed
        assert isinstance(mesh, m.MeshSummary) and len(mesh.id) == 64 and mesh.faces > 0
        assert r.headers["location"] == f"/v1/meshes/{mesh.id}"
        got = api.get_mesh.sync(mesh.id, client=client)
        assert isinstance(got, m.MeshSummary) and got.to_dict() == mesh.to_dict()

        # submit: the candidates union takes the generator form; a webhook callback
        receiver = Receiver()
        submit = m.PlanSubmit.from_dict(
            {
                "mesh_id": mesh.id,
                "profile": "paper",
                "candidates": {"count": 30},
                "target": {"resolution_mm": 0.5},
            }
        )
        submit.callback = m.Callback(url=receiver.url, secret=SECRET)
        r = api.submit_plan.sync_detailed(client=client, body=submit)
        assert r.status_code == 202, (r.status_code, r.content)
        accepted = r.parsed
        assert isinstance(accepted, m.JobAccepted) and str(accepted.status) == "queued"

        start_workers(1)
        job = wait_for_job(api, client, accepted.id)
        assert str(job.status) == "succeeded", f"job {job.status}: {job.to_dict()}"
        assert job.result_url == f"/v1/plans/{accepted.id}"
        receiver.wait(1)  # the callback's webhook, signed
        assert json.loads(receiver.posts[0][1])["data"]["id"] == accepted.id
        assert receiver.posts[0][0]["webhook-signature"].startswith("v1,")
        receiver.close()

        # the listing: the plan, newest first, filtered by kind
        page = api.list_jobs.sync(client=client, kind=m.ListJobsKindType0("plan"), limit=5)
        assert isinstance(page, m.JobPage) and [j.id for j in page.items] == [accepted.id]
        assert str(page.items[0].kind) == "plan" and page.next_cursor is None

        # the plan document, parsed by the generated models
        r = api.get_plan.sync_detailed(accepted.id, client=client)
        assert r.status_code == 200, (r.status_code, r.content)
        doc = r.parsed
        assert isinstance(doc, m.PlanDocument), type(doc)
        assert doc.viewpoints and str(doc.solver.status) == "optimal"
        for vp in doc.viewpoints:
            assert len(vp.camera_to_world) == 4 and all(len(row) == 4 for row in vp.camera_to_world)
        assert 0 < doc.metrics.coverage.area <= 1
        etag = r.headers["etag"]
        again = api.get_plan.sync_detailed(accepted.id, client=client, if_none_match=etag)
        assert again.status_code == 304 and again.parsed is None

        # a finished job is left as it is by cancel
        r = api.cancel_job.sync_detailed(accepted.id, client=client)
        assert r.status_code == 200 and str(r.parsed.status) == "succeeded", r.content

        # unknown ids: problem details, parsed as the Problem model
        r = api.get_job.sync_detailed("0" * 64, client=client)
        assert r.status_code == 404, (r.status_code, r.content)
        assert isinstance(r.parsed, m.Problem) and r.parsed.status == 404, r.content
        assert r.headers["content-type"].startswith("application/problem+json")
