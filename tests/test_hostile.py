"""Hostile input is refused fast, with a 4xx application/problem+json, before any heavy work.

`test_service_api.py` already uploads every file of ../shared/meshes/bad once under its own
name; here each is also fed to every other format's parser, and timed. The rest: meshes that
announce a huge face count, billions of rays, 10^6 explicit viewpoints, deep or huge JSON,
path traversal in ids, wrong content types. FAST is the bound "refused fast" is held to: on a
loaded 2-core machine each refusal below takes well under a tenth of it (docs/reliability.md
has the measured times); what it guards against took 2 to 20 s and gigabytes before.
"""

from __future__ import annotations

import json
import struct
import time
import tracemalloc
from pathlib import Path
from typing import Any
from urllib.parse import quote

import pytest

from service.app import create_app
from tests.conftest import MESHES, ROOT, shared_dir
from vpp_core.errors import LimitError
from vpp_core.mesh.part import load_mesh
from vpp_core.samples import sample_stl
from worker.settings import Settings

PROBLEM = "application/problem+json"
JSON = {"content-type": "application/json"}
FAST = 2.0
"""Seconds within which a hostile request must be answered (see module docstring)."""
BILLION = 10**9


def timed(call: Any) -> tuple[Any, float]:
    start = time.perf_counter()
    response = call()
    return response, time.perf_counter() - start


def refused(r: Any, *statuses: int) -> dict[str, Any]:
    """The response is a 4xx problem (one of `statuses` when given)."""
    assert 400 <= r.status_code < 500, r.text[:300]
    if statuses:
        assert r.status_code in statuses, r.text[:300]
    assert r.headers["content-type"] == PROBLEM
    body: dict[str, Any] = r.json()
    assert body["status"] == r.status_code and body["title"] and body["detail"]
    return body


def upload(api: Any, data: bytes, name: str, **form: str) -> Any:
    return api.post("/v1/meshes", files={"file": (name, data)}, data=form)


@pytest.fixture
def mesh_id(api: Any) -> str:
    return str(upload(api, sample_stl(), "part.stl").json()["id"])


# ---------------------------------------------------------------- meshes

BAD_FORMATS = ("stl", "obj", "ply", "off", "glb", "gltf")


def test_every_bad_mesh_in_every_format_is_refused_fast(api: Any) -> None:
    """Each bad file under each format's parser: 4xx problem or (valid by chance) 201."""
    files = [p for p in sorted(shared_dir(MESHES / "bad").iterdir()) if p.suffix != ".md"]
    for path in files:
        data = path.read_bytes()
        for fmt in BAD_FORMATS:
            r, took = timed(lambda d=data, n=path.name, f=fmt: upload(api, d, n, format=f))
            assert took < FAST, (path.name, fmt, took)
            if r.status_code != 201:
                refused(r, 413, 422)


def ply_header(faces: int, vertices: int = 3, encoding: str = "ascii") -> bytes:
    return (
        f"ply\nformat {encoding} 1.0\nelement vertex {vertices}\n"
        "property float x\nproperty float y\nproperty float z\n"
        f"element face {faces}\nproperty list uchar int vertex_indices\nend_header\n"
    ).encode()


ANNOUNCED = {
    "binary STL claiming 10^9 triangles": (
        b"\0" * 80 + struct.pack("<I", BILLION) + b"\0" * 500,
        "part.stl",
    ),
    "ASCII PLY claiming 10^9 faces": (
        ply_header(BILLION) + b"0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n",
        "part.ply",
    ),
    "binary PLY claiming 10^9 faces": (
        ply_header(BILLION, encoding="binary_little_endian") + struct.pack("<9f", *[0.0] * 9),
        "part.ply",
    ),
    "binary PLY claiming 10^9 vertices": (
        ply_header(1, BILLION, "binary_little_endian") + struct.pack("<9f", *[0.0] * 9),
        "part.ply",
    ),
    "OFF claiming 10^9 faces": (b"OFF\n3 1000000000 0\n0 0 0\n1 0 0\n0 1 0\n3 0 1 2\n", "p.off"),
    "OBJ with a face index of 10^9": (b"v 0 0 0\nv 1 0 0\nv 0 1 0\nf 1 2 1000000000\n", "p.obj"),
}


@pytest.mark.parametrize("name", ANNOUNCED)
def test_a_huge_announced_face_count_is_refused_without_allocating(api: Any, name: str) -> None:
    data, filename = ANNOUNCED[name]
    r, took = timed(lambda: upload(api, data, filename))
    refused(r, 422)
    assert took < FAST, took
    tracemalloc.start()
    try:
        with pytest.raises(Exception):  # noqa: B017  (LimitError or MeshError, both 422 above)
            load_mesh(data, Path(filename).suffix, max_faces=5_000_000)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 50 * 2**20, f"{peak / 2**20:.0f} MiB allocated to refuse {name}"


FACES = 2_000_000
"""Faces of the big text meshes below (15 to 160 MiB): parsed, they took 2 to 14 s and 0.5 to
3 GiB before the line counts and headers were read first."""


def big_text_mesh(fmt: str) -> bytes:
    if fmt == "obj":
        return b"v 0 0 0\nv 1 0 0\nv 0 1 0\n" + b"f 1 2 3\n" * FACES
    if fmt == "ply":
        return ply_header(FACES) + b"0 0 0\n1 0 0\n0 1 0\n" + b"3 0 1 2\n" * FACES
    facet = b"facet normal 0 0 1\nouter loop\nvertex 0 0 0\nvertex 1 0 0\nvertex 0 1 0\n"
    return b"solid x\n" + (facet + b"endloop\nendfacet\n") * FACES + b"endsolid x\n"


@pytest.mark.parametrize("fmt", ["obj", "ply", "stl"])
def test_a_text_mesh_over_the_face_limit_is_refused_before_parsing(fmt: str) -> None:
    data = big_text_mesh(fmt)
    start = time.perf_counter()
    with pytest.raises(LimitError, match=f"{FACES} faces"):
        load_mesh(data, fmt, max_faces=1000)
    assert time.perf_counter() - start < FAST


def test_a_mesh_over_the_face_limit_is_413_or_422_over_http(svc_env: dict[str, str]) -> None:
    from fastapi.testclient import TestClient

    with TestClient(create_app(Settings(max_faces=1000))) as small:
        r, took = timed(lambda: upload(small, big_text_mesh("obj"), "big.obj"))
        assert "limit" in refused(r, 422)["detail"]
        assert took < FAST


# ---------------------------------------------------------------- plan requests


def test_billions_of_rays_are_refused(api: Any, mesh_id: str) -> None:
    huge = {"width_px": 20_000, "height_px": 20_000}  # 4e8 rays per view, within the sensor limits
    body = {"mesh_id": mesh_id, "sensor": huge, "candidates": {"count": 5000}}
    r, took = timed(lambda: api.post("/v1/plans", json=body))
    assert "rays" in refused(r, 422)["detail"]
    too_wide = {"mesh_id": mesh_id, "sensor": {"width_px": BILLION, "height_px": BILLION}}
    refused(api.post("/v1/plans", json=too_wide), 422)
    study = {**body, "kind": "resolution", "resolutions": [0.5]}
    assert "rays" in refused(api.post("/v1/studies", json=study), 422)["detail"]
    assert took < FAST


def viewpoints_body(mesh_id: str, n: int) -> bytes:
    view = b'{"position":[0,0,500],"gaze":[0,0,-1]}'
    return b'{"mesh_id":"%s","candidates":{"viewpoints":[%s]}}' % (
        mesh_id.encode(),
        b",".join([view] * n),
    )


def test_a_million_viewpoints_are_refused_unread(api: Any, mesh_id: str) -> None:
    body = viewpoints_body(mesh_id, 10**6)  # 39 MB
    headers = {"content-type": "application/json"}
    r, took = timed(lambda: api.post("/v1/plans", content=body, headers=headers))
    assert "VPP_MAX_JSON_BYTES" in refused(r, 413)["detail"]
    assert took < FAST

    def stream() -> Any:  # no Content-Length: cut off while reading
        for start in range(0, len(body), 2**20):
            yield body[start : start + 2**20]

    r, took = timed(lambda: api.post("/v1/plans", content=stream(), headers=headers))
    refused(r, 413)
    assert took < FAST


def test_the_most_viewpoints_under_the_body_cap_are_refused_fast(api: Any, mesh_id: str) -> None:
    """The worst case the cap lets through: as many minimal viewpoints as fit in the cap."""
    n = Settings().max_json_bytes // 40
    body = viewpoints_body(mesh_id, n)
    assert len(body) <= Settings().max_json_bytes
    headers = {"content-type": "application/json"}
    r, took = timed(lambda: api.post("/v1/plans", content=body, headers=headers))
    assert "candidates exceed the limit" in refused(r, 422)["detail"]
    assert took < FAST, f"{n} viewpoints refused in {took:.2f} s"


@pytest.mark.parametrize("path", ["/v1/plans", "/v1/studies"])
def test_deeply_nested_json_is_refused(api: Any, path: str) -> None:
    for body in (b"[" * 10**5 + b"]" * 10**5, b'{"mesh_id":' + b"[" * 10**5 + b"]" * 10**5 + b"}"):
        r, took = timed(lambda body=body: api.post(path, content=body, headers=JSON))
        refused(r, 400, 422)
        assert took < FAST


@pytest.mark.parametrize("path", ["/v1/plans", "/v1/studies"])
def test_a_huge_json_body_is_413(api: Any, path: str) -> None:
    body = b'{"mesh_id": "' + b"a" * (5 * 2**20) + b'"}'
    r, took = timed(lambda: api.post(path, content=body, headers=JSON))
    refused(r, 413)
    assert took < FAST


def test_the_json_cap_is_a_setting(svc_env: dict[str, str], mesh_id: str) -> None:
    from fastapi.testclient import TestClient

    with TestClient(create_app(Settings(max_json_bytes=1000))) as small:
        refused(small.post("/v1/plans", content=viewpoints_body(mesh_id, 30)), 413)
        r = small.post(
            "/v1/plans", json={"mesh_id": mesh_id, "profile": "paper", "candidates": {"count": 20}}
        )
        assert r.status_code == 202, r.text


# ---------------------------------------------------------------- ids and paths

HOSTILE_IDS = [
    "../../etc/passwd",
    "..%2F..%2Fetc%2Fpasswd",
    "%2e%2e%2f%2e%2e%2fetc%2fpasswd",
    "%252e%252e%252f",
    "/etc/passwd",
    "%2Fetc%2Fpasswd",
    "..",
    "%00",
    "C:%5Cwindows%5Cwin.ini",
    "0" * 63 + "g",
    "A" * 64,
    "a" * 8000,
]


def id_routes() -> list[str]:
    """Every GET path of the committed document that has an id in it."""
    doc = json.loads((ROOT / "openapi" / "openapi.json").read_text())
    return [p for p, item in doc["paths"].items() if "{" in p and "get" in item]


def test_path_traversal_and_odd_ids_are_4xx_problems_on_every_get_route(api: Any) -> None:
    routes = id_routes()
    assert len(routes) >= 12
    for route in routes:
        for hostile in HOSTILE_IDS:
            first, *rest = route.split("{", 1)
            url = first + hostile + ("/" + rest[0].split("/", 1)[1] if "/" in rest[0] else "")
            url = url.replace("{name}", "histogram.png")
            r, took = timed(lambda url=url: api.get(url))
            refused(r, 404, 405, 414, 422)
            assert took < FAST, (url[:80], took)


def test_plot_names_cannot_leave_their_folder(api: Any, mesh_id: str) -> None:
    for name in ("../../plans/x.json", quote("../../x", safe=""), "..", "%00.png", "a" * 5000):
        refused(api.get(f"/v1/plans/{'0' * 64}/plots/{name}"), 404)
        refused(api.get(f"/v1/studies/{'0' * 64}/plots/{name}"), 404)


# ---------------------------------------------------------------- content types


def test_wrong_content_types_are_4xx_problems(api: Any, mesh_id: str) -> None:
    plan = json.dumps({"mesh_id": mesh_id}).encode()
    cases = [
        ("/v1/meshes", {"json": {"file": "solid x"}}),
        ("/v1/meshes", {"content": sample_stl(), "headers": {"content-type": "text/plain"}}),
        ("/v1/meshes", {"content": sample_stl()}),
        ("/v1/meshes", {"content": b"x", "headers": {"content-type": "multipart/form-data"}}),
        (
            "/v1/meshes",
            {"content": b"x", "headers": {"content-type": "multipart/form-data; boundary=q"}},
        ),
        ("/v1/plans", {"files": {"file": ("p.json", plan)}}),
        ("/v1/plans", {"content": plan, "headers": {"content-type": "text/plain"}}),
        ("/v1/plans", {"content": plan, "headers": {"content-type": "application/xml"}}),
        ("/v1/plans", {"content": plan}),
        ("/v1/plans", {"content": b'{"mesh_id": "\xff\xfe"}', "headers": JSON}),
        ("/v1/studies", {"content": plan, "headers": {"content-type": "text/plain"}}),
    ]
    for path, kwargs in cases:
        r, took = timed(lambda path=path, kwargs=kwargs: api.post(path, **kwargs))
        refused(r, 400, 415, 422)
        assert took < FAST
