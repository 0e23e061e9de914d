"""Issue 34's hostile requests against a real server (`python -m bench.hostile --served`).

A uvicorn child process serves `service.app:create_app` with default settings on the Redis of
VPP_REDIS_URL and a temporary store. Each case sends its request(s) from threads while another
thread asks `/livez` every 20 ms; per case: status, media type and size of the answer, seconds,
the slowest `/livez` answer meanwhile, the server's peak RSS growth (VmHWM, reset before each
case through /proc/<pid>/clear_refs), its RSS 1 s after the case and the largest peak RSS of a
child process of the server meanwhile (an upload parsed apart). Big bodies are streamed
from generators with a Content-Length, so the client holds none of them.
"""

from __future__ import annotations

import math
import os
import socket
import subprocess
import sys
import tempfile
import threading
import time
from collections.abc import Callable, Iterator
from concurrent.futures import ThreadPoolExecutor
from typing import Any

import httpx
import numpy as np

from vpp_core.samples import sample_stl

MB = 10**6
CHUNK = 1 << 20
Body = tuple[int, Callable[[], Iterator[bytes]]]
"""A streamed body: its length and a generator of its bytes."""


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def start_server(port: int, env: dict[str, str]) -> subprocess.Popen[bytes]:
    """uvicorn serving the app (settings from VPP_*), once /livez answers."""
    cmd = [sys.executable, "-m", "uvicorn", "--factory", "service.app:create_app"]
    cmd += ["--port", str(port), "--log-level", "warning"]
    proc = subprocess.Popen(cmd, env={**os.environ, **env})
    for _ in range(300):
        try:
            httpx.get(f"http://127.0.0.1:{port}/livez", timeout=1)
            return proc
        except httpx.HTTPError:
            time.sleep(0.1)
    proc.kill()
    raise RuntimeError("the server did not start")


def rss_mib(pid: int, field: str = "VmRSS") -> float:
    """A /proc/<pid>/status memory field (VmRSS, VmHWM) in MiB."""
    with open(f"/proc/{pid}/status") as fh:
        line = next(x for x in fh if x.startswith(field + ":"))
    return int(line.split()[1]) / 1024


def reset_peak(pid: int) -> None:
    """Make VmHWM start again from the current RSS."""
    with open(f"/proc/{pid}/clear_refs", "w") as fh:
        fh.write("5")


def children(pid: int) -> list[int]:
    """The child processes of `pid`, started by any of its threads (Linux /proc)."""
    found = []
    for task in os.listdir(f"/proc/{pid}/task"):
        try:
            with open(f"/proc/{pid}/task/{task}/children") as fh:
                found += [int(c) for c in fh.read().split()]
        except OSError:
            pass
    return found


class LivezWatch:
    """Asks /livez every 20 ms in a thread; `worst` is the slowest answer (s), `child_mib`
    the largest peak RSS (VmHWM) seen of any child process of `pid` meanwhile (an upload's
    parsing child, service/parsing.py), read as often."""

    def __init__(self, base: str, pid: int | None = None) -> None:
        self.base, self.worst, self.done = base, 0.0, threading.Event()
        self.pid, self.child_mib = pid, 0.0
        self.thread = threading.Thread(target=self._run, daemon=True)

    def _run(self) -> None:
        with httpx.Client(timeout=120) as client:
            while not self.done.is_set():
                start = time.perf_counter()
                client.get(self.base + "/livez")
                self.worst = max(self.worst, time.perf_counter() - start)
                self._children()
                time.sleep(0.02)

    def _children(self) -> None:
        """Update `child_mib` from the children's VmHWM (ones gone meanwhile are skipped)."""
        for child in children(self.pid) if self.pid else []:
            try:
                self.child_mib = max(self.child_mib, rss_mib(child, "VmHWM"))
            except (OSError, StopIteration):
                pass

    def __enter__(self) -> LivezWatch:
        self.thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self.done.set()
        self.thread.join()


def multipart(size: int, chunk: Callable[[int], bytes], name: str = "part.stl") -> Body:
    """A multipart/form-data body of one file of `size` bytes made by `chunk(n)`."""
    head = (
        f'--b0undary\r\nContent-Disposition: form-data; name="file"; filename="{name}"\r\n'
        "Content-Type: application/octet-stream\r\n\r\n"
    ).encode()
    tail = b"\r\n--b0undary--\r\n"

    def gen() -> Iterator[bytes]:
        yield head
        left = size
        while left:
            n = min(CHUNK, left)
            yield chunk(n)
            left -= n
        yield tail

    return len(head) + size + len(tail), gen


def zero_stl(triangles: int) -> Body:
    """A binary STL of `triangles` zero-area triangles (all zeros but the count), multipart."""
    header = b"\0" * 80 + triangles.to_bytes(4, "little")
    size = len(header) + 50 * triangles
    first = [True]

    def chunk(n: int) -> bytes:
        if first[0]:
            first[0] = False
            return header + b"\0" * (n - len(header))
        return b"\0" * n

    return multipart(size, chunk)


def post(base: str, path: str, body: Body | bytes, ctype: str) -> httpx.Response:
    """POST a body (bytes, or streamed with its Content-Length)."""
    headers = {"content-type": ctype}
    if isinstance(body, bytes):
        return httpx.post(base + path, content=body, headers=headers, timeout=600)
    headers["content-length"] = str(body[0])
    return httpx.post(base + path, content=body[1](), headers=headers, timeout=600)


MULTIPART = "multipart/form-data; boundary=b0undary"
JSON = "application/json"


def json_cases(mesh: str) -> dict[str, Callable[[str], Any]]:
    """Plan requests: NaN up, 900 000 invalid viewpoints, 300 000 `{}`, multipart on JSON."""
    nan = b'{"mesh_id":"%s","candidates":{"viewpoints":[' % mesh.encode()
    nan += b'{"position":[0,0,500],"gaze":[0,0,-1],"up":[NaN,1,0]}]}}'
    invalid = b"[" + b",".join([b"1"] * 900_000) + b"]"
    empties = b'{"mesh_id":"%s","candidates":[%s]}' % (mesh.encode(), b",".join([b"{}"] * 300_000))
    rand = multipart(200 * MB, os.urandom)
    ones = b'{"mesh_id":"%s","candidates":[%s]}' % (mesh.encode(), b",".join([b"1"] * 50_000))
    good = b'{"position":[1.5,2.5,500.5],"gaze":[0.1,0.2,-1],"up":[0,1,0]}'
    bad = b'{"position":[0,0,1],"gaze":[0,0,-1],%s}' % b",".join(b'"k%d":1' % i for i in range(9))
    mixed = b'{"mesh_id":"%s","candidates":[%s]}' % (
        mesh.encode(),
        b",".join([good] * 2_500 + [bad] * 2_300),
    )
    valid = b'{"mesh_id":"%s","candidates":[%s]}' % (mesh.encode(), b",".join([good] * 5_000))
    return {
        "NaN in up": lambda b: post(b, "/v1/plans", nan, JSON),
        f"900 000 invalid viewpoints ({len(invalid) / MB:.1f} MB)": lambda b: post(
            b, "/v1/plans", b'{"mesh_id":"%s","candidates":%s}' % (mesh.encode(), invalid), JSON
        ),
        f"300 000 {{}} viewpoints ({len(empties) / MB:.1f} MB)": lambda b: post(
            b, "/v1/plans", empties, JSON
        ),
        "50 000 invalid viewpoints (under the value count)": lambda b: post(
            b, "/v1/plans", ones, JSON
        ),
        "2 500 valid then 2 300 viewpoints with 9 unknown keys each": lambda b: post(
            b, "/v1/plans", mixed, JSON
        ),
        f"5 000 valid viewpoints with up ({len(valid) / MB:.2f} MB)": lambda b: post(
            b, "/v1/plans", valid, JSON
        ),
        "200 MB multipart to /v1/plans": lambda b: post(b, "/v1/plans", rand, MULTIPART),
        "4 x 200 MB multipart to /v1/plans at once": lambda b: at_once(
            4, lambda: post(b, "/v1/plans", multipart(200 * MB, os.urandom), MULTIPART)
        ),
    }


GRID_FACES = 4_900_000
"""Triangles of the generated meshes: under the 5 M face limit, about 200 MB as text."""


def grid(faces: int) -> tuple[np.ndarray, np.ndarray]:
    """(V, 3) float32 mm and (M, 3) int64 of a wavy n × n grid of about `faces` triangles
    (all of non-zero area, vertices shared): a real mesh as big as the limits allow."""
    n = int(math.ceil(math.sqrt(faces / 2)))
    t = np.arange(n + 1, dtype=np.float64)
    xx, yy = np.meshgrid(t, t, indexing="ij")
    zz = 5 * np.sin(xx / 40) * np.cos(yy / 30)
    v = np.column_stack([xx.ravel(), yy.ravel(), zz.ravel()]).astype(np.float32)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1], idx[1:, :-1], idx[1:, 1:], idx[:-1, 1:]
    f = np.vstack([np.column_stack([a.ravel(), b.ravel(), c.ravel()]),
                   np.column_stack([a.ravel(), c.ravel(), d.ravel()])])  # fmt: skip
    return v, f


def write_meshes(folder: str, faces: int = GRID_FACES) -> dict[str, str]:
    """The grid as binary STL, binary PLY, ASCII PLY and OBJ files in `folder`; paths by format."""
    v, f = grid(faces)
    paths = {k: os.path.join(folder, f"grid.{k.split()[0]}") for k in ("stl", "ply", "obj")}
    paths["ply ascii"] = os.path.join(folder, "grid_ascii.ply")
    tri = np.zeros(len(f), dtype=[("n", "<f4", 3), ("v", "<f4", (3, 3)), ("a", "<u2")])
    tri["v"] = v[f]
    with open(paths["stl"], "wb") as fh:
        fh.write(b"\0" * 80 + len(f).to_bytes(4, "little") + tri.tobytes())
    del tri
    head = "ply\nformat {} 1.0\nelement vertex %d\nproperty float x\nproperty float y\n"
    head += "property float z\nelement face %d\nproperty list uchar int vertex_indices\n"
    head += "end_header\n"
    with open(paths["ply"], "wb") as fh:
        fh.write((head.format("binary_little_endian") % (len(v), len(f))).encode())
        fh.write(v.astype("<f4").tobytes())
        rows = np.zeros(len(f), dtype=[("k", "u1"), ("i", "<i4", 3)])
        rows["k"], rows["i"] = 3, f
        fh.write(rows.tobytes())
    with open(paths["ply ascii"], "w") as fh:
        fh.write(head.format("ascii") % (len(v), len(f)))
        np.savetxt(fh, v, fmt="%.4f")
        np.savetxt(fh, np.column_stack([np.full(len(f), 3), f]), fmt="%d")
    with open(paths["obj"], "w") as fh:
        np.savetxt(fh, v, fmt="v %.4f %.4f %.4f")
        np.savetxt(fh, f + 1, fmt="f %d %d %d")
    return paths


def file_multipart(path: str, name: str) -> Body:
    """A multipart body of the file at `path`, streamed from disk, named `name`."""
    with open(path, "rb") as fh:
        size = fh.seek(0, os.SEEK_END)
    reader: list[Any] = []

    def chunk(n: int) -> bytes:
        if not reader:
            reader.append(open(path, "rb"))  # noqa: SIM115 (closed at its end)
        data = reader[0].read(n)
        if len(data) < n or reader[0].tell() == size:
            reader[0].close()
        return data

    return multipart(size, chunk, name)


def mesh_cases(paths: dict[str, str]) -> dict[str, Callable[[str], Any]]:
    """Uploads of real meshes at the limits: the grid as STL, PLY (binary, ASCII) and OBJ."""
    out: dict[str, Callable[[str], Any]] = {}
    for kind, path in paths.items():
        mb = os.path.getsize(path) / MB
        name = os.path.basename(path)
        out[f"{mb:.0f} MB {kind.upper()} of {GRID_FACES / 1e6:.1f} M triangles"] = (
            lambda b, path=path, name=name: post(
                b, "/v1/meshes", file_multipart(path, name), MULTIPART
            )
        )
    return out


def upload_cases() -> dict[str, Callable[[str], Any]]:
    """Mesh uploads: random bytes, zero-area STL, four at once, over the cap."""
    return {
        "200 MB random bytes upload": lambda b: post(
            b, "/v1/meshes", multipart(200 * MB, os.urandom), MULTIPART
        ),
        "200 MB STL of 4 M zero-area triangles": lambda b: post(
            b, "/v1/meshes", zero_stl(4_000_000), MULTIPART
        ),
        "4 x 200 MB random uploads at once": lambda b: at_once(
            4, lambda: post(b, "/v1/meshes", multipart(200 * MB, os.urandom), MULTIPART)
        ),
        "257 MiB upload (over the cap)": lambda b: post(
            b, "/v1/meshes", multipart(257 * 2**20, lambda n: b"\0" * n), MULTIPART
        ),
    }


def method_cases() -> dict[str, Callable[[str], Any]]:
    """405 answers and their Allow header."""
    some = "0" * 64
    return {
        "PUT /v1/jobs/{id}": lambda b: httpx.put(f"{b}/v1/jobs/{some}"),
        "PUT /v1/plans/{id}/point-cloud": lambda b: httpx.put(f"{b}/v1/plans/{some}/point-cloud"),
    }


def at_once(n: int, call: Callable[[], httpx.Response]) -> httpx.Response:
    """`n` calls from threads at once; the answers' statuses joined, the first answer."""
    with ThreadPoolExecutor(n) as pool:
        answers = list(pool.map(lambda _: call(), range(n)))
    answers[0].extensions["statuses"] = "/".join(str(r.status_code) for r in answers)
    return answers[0]


def describe(r: httpx.Response) -> str:
    """status (all statuses of several), media type, body size, Allow if any."""
    status = r.extensions.get("statuses", str(r.status_code))
    allow = f" Allow: {r.headers['allow']}" if "allow" in r.headers else ""
    kind = r.headers.get("content-type", "-").split(";")[0]
    return f"{status} {kind} {len(r.content)} B{allow}"


def run_served(only: str | None, meshes: bool = False) -> None:
    """Start the server, run each case, print a markdown table (`meshes`: with the real
    meshes of `mesh_cases`, about 1 GB of files written first)."""
    port, store = free_port(), tempfile.mkdtemp()
    env = {"VPP_STORE_URL": store, "VPP_QUEUE": "vpp-bench-hostile"}
    proc = start_server(port, env)
    base = f"http://127.0.0.1:{port}"
    try:
        mesh = post(base, "/v1/meshes", multipart_bytes(sample_stl()), MULTIPART).json()["id"]
        table = {**json_cases(mesh), **upload_cases(), **method_cases()}
        if meshes or (only and "triangles" in only):
            table |= mesh_cases(write_meshes(store))
        print(f"server RSS at start: {rss_mib(proc.pid):.0f} MiB")
        head = "| case | answer | s | slowest /livez s | peak RSS growth MiB | RSS after MiB |"
        print(head + " child peak RSS MiB |\n" + "|---" * 7 + "|")
        for name, call in table.items():
            if only and only.lower() not in name.lower():
                continue
            time.sleep(1)
            before = rss_mib(proc.pid)
            reset_peak(proc.pid)
            with LivezWatch(base, proc.pid) as watch:
                start = time.perf_counter()
                answer = describe(call(base))
                took = time.perf_counter() - start
            grown = rss_mib(proc.pid, "VmHWM") - before
            time.sleep(1)
            after = rss_mib(proc.pid)
            cells = [name, answer, f"{took:.2f}", f"{watch.worst:.3f}", f"{grown:.0f}"]
            child = f"{watch.child_mib:.0f}" if watch.child_mib else "-"
            print("| " + " | ".join([*cells, f"{after:.0f}", child]) + " |", flush=True)
    finally:
        proc.terminate()
        proc.wait()


def multipart_bytes(data: bytes, name: str = "part.stl") -> bytes:
    """A small multipart body holding `data` as the file."""
    size, gen = multipart(len(data), lambda n: data, name)
    return b"".join(gen())
