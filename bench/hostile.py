"""How fast the API refuses hostile requests (the figures of docs/reliability.md).

    VPP_REDIS_URL=redis://127.0.0.1:6379/13 python -m bench.hostile [--repeat 5]
    VPP_REDIS_URL=redis://127.0.0.1:6379/13 python -m bench.hostile --served [--only W] [--meshes]

In-process (TestClient) against the app on that Redis (nothing is enqueued: every request
below is refused) and a temporary store. Per case: status, and the median and worst
wall-clock seconds of the request alone (bodies are built beforehand), and the process's
peak RSS growth over the whole run. The core mesh cases call `load_mesh` directly.

`--served` runs the issue-34 cases (`bench.hostile_served`) against a real uvicorn server in
a child process instead: status, media type, body size, seconds, the slowest `/livez` answer
meanwhile, and the server's peak RSS growth and RSS afterwards; `--meshes` adds uploads of a
real 4.9 M-triangle mesh as binary STL, binary and ASCII PLY and OBJ (written to a temporary
folder first: about 1 GB).
"""

from __future__ import annotations

import argparse
import resource
import statistics
import struct
import tempfile
import time
from collections.abc import Callable
from typing import Any

from fastapi.testclient import TestClient  # noqa: TID251

from service.app import create_app
from vpp_core.errors import VppError
from vpp_core.mesh.part import load_mesh
from vpp_core.samples import sample_stl
from worker.settings import Settings

JSON = {"content-type": "application/json"}


def viewpoints(mesh: str, n: int) -> bytes:
    view = b'{"position":[0,0,500],"gaze":[0,0,-1]}'
    return b'{"mesh_id":"%s","candidates":{"viewpoints":[%s]}}' % (
        mesh.encode(),
        b",".join([view] * n),
    )


def stream(body: bytes) -> Callable[[], Any]:
    def chunks() -> Any:
        for i in range(0, len(body), 2**20):
            yield body[i : i + 2**20]

    return chunks


def cases(client: TestClient, mesh: str, cap: int) -> dict[str, Callable[[], Any]]:
    million = viewpoints(mesh, 10**6)
    under_cap = viewpoints(mesh, cap // 40)
    nested = b"[" * 10**5 + b"]" * 10**5
    stl = b"\0" * 80 + struct.pack("<I", 10**9) + b"\0" * 500
    obj = b"v 0 0 0\nv 1 0 0\nv 0 1 0\n" + b"f 1 2 3\n" * 6_000_000
    rays = {"mesh_id": mesh, "sensor": {"width_px": 20000, "height_px": 20000}}
    return {
        f"10^6 viewpoints ({len(million) / 1e6:.0f} MB, Content-Length)": lambda: client.post(
            "/v1/plans", content=million, headers=JSON
        ),
        "10^6 viewpoints, streamed (no Content-Length)": lambda: client.post(
            "/v1/plans", content=stream(million)(), headers=JSON
        ),
        f"{cap // 40} viewpoints ({len(under_cap) / 1e6:.1f} MB, under the cap)": lambda: (
            client.post("/v1/plans", content=under_cap, headers=JSON)
        ),
        "10^5 nested arrays": lambda: client.post("/v1/plans", content=nested, headers=JSON),
        "4e8 rays per view × 500 candidates": lambda: client.post("/v1/plans", json=rays),
        "binary STL announcing 10^9 triangles": lambda: client.post(
            "/v1/meshes", files={"file": ("a.stl", stl)}
        ),
        f"OBJ with 6e6 faces ({len(obj) / 1e6:.0f} MB), over 5e6": lambda: client.post(
            "/v1/meshes", files={"file": ("a.obj", obj)}
        ),
    }


def core_cases() -> dict[str, Callable[[], Any]]:
    facet = b"facet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\n"
    ascii_stl = b"solid x\n" + (facet + b"endloop\nendfacet\n") * 2_000_000 + b"endsolid x\n"
    return {
        f"load_mesh: ASCII STL, 2e6 facets ({len(ascii_stl) / 1e6:.0f} MB), limit 1000": lambda: (
            load_mesh(ascii_stl, "stl", max_faces=1000)
        ),
    }


def measure(call: Callable[[], Any], repeat: int) -> tuple[str, list[float]]:
    times, status = [], ""
    for _ in range(repeat):
        start = time.perf_counter()
        try:
            status = str(call().status_code)
        except VppError as exc:
            status = type(exc).__name__
        times.append(time.perf_counter() - start)
    return status, times


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeat", type=int, default=5)
    parser.add_argument("--served", action="store_true", help="issue-34 cases, real server")
    parser.add_argument("--only", help="--served: the cases whose name holds this word")
    parser.add_argument(
        "--meshes", action="store_true", help="--served: also real STL/PLY/OBJ meshes at the limits"
    )
    args = parser.parse_args()
    if args.served:
        from bench.hostile_served import run_served

        run_served(args.only, args.meshes)
        return
    settings = Settings(store_url=tempfile.mkdtemp(), queue="vpp-bench-hostile")
    rss0 = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss
    with TestClient(create_app(settings)) as client:
        mesh = client.post("/v1/meshes", files={"file": ("p.stl", sample_stl())}).json()["id"]
        table = {**cases(client, mesh, settings.max_json_bytes), **core_cases()}
        print("| case | answer | median s | worst s |\n|---|---|---|---|")
        for name, call in table.items():
            status, times = measure(call, args.repeat)
            print(f"| {name} | {status} | {statistics.median(times):.3f} | {max(times):.3f} |")
    grown = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - rss0) / 1024
    print(f"\npeak RSS growth over the run: {grown:.0f} MiB (bodies built in memory included)")


if __name__ == "__main__":
    main()
