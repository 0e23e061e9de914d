"""The plan viewer: its page, its bundle, and the binary geometry and per-face results it draws.

The bundle, the geometry and the scene go gzipped to a client that accepts gzip (the scene is
stored gzipped; the others are compressed once per process or per request).
"""

from __future__ import annotations

import gzip
import hashlib
from collections.abc import Callable
from functools import cache, partial
from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, Header, Response
from fastapi.responses import HTMLResponse

from service import planning
from service.deps import StoreDep
from service.models import Problem, RelatedPlans
from service.routers.plans import named_forever

router = APIRouter(tags=["viewer"])
STATIC_DIR = Path(__file__).resolve().parent.parent / "static" / "viewer"
"""The page and its bundle (built from viewer/ by `npm run build`)."""
OCTETS = "application/octet-stream"
BINARY: dict[int | str, dict[str, Any]] = {
    200: {"content": {OCTETS: {}}},
    304: {"description": "Not modified"},
    404: {"model": Problem},
}


@router.get("/v1/plans/{plan_id}/view", response_class=HTMLResponse, include_in_schema=False)
def view_plan(plan_id: str) -> HTMLResponse:
    """A 3D view of the plan in the browser (it waits for the plan's job while it runs).

    Not in the OpenAPI document: a page for people, open without an API key (it holds no data).
    """
    planning.content_id(plan_id, "plan")
    return HTMLResponse(
        (STATIC_DIR / "index.html").read_text(), headers={"Cache-Control": "no-cache"}
    )


@cache
def _bundle(name: str) -> tuple[bytes, bytes, str]:
    """(bytes, gzipped bytes, ETag) of a file of the viewer's bundle."""
    data = (STATIC_DIR / name).read_bytes()
    return data, gzip.compress(data, 9, mtime=0), f'"{hashlib.sha256(data).hexdigest()[:32]}"'


@router.get("/static/viewer/viewer.js", response_class=Response, include_in_schema=False)
def get_bundle(
    if_none_match: Annotated[str | None, Header()] = None,
    accept_encoding: Annotated[str | None, Header()] = None,
) -> Response:
    """viewer.js, gzipped where the client accepts it (before the static files' mount)."""
    data, packed, etag = _bundle("viewer.js")
    headers = {"ETag": etag, "Cache-Control": "no-cache", "Vary": "Accept-Encoding"}
    if if_none_match == etag:
        return Response(status_code=304, headers=headers)
    return _maybe_gzip(data, packed, accept_encoding, "text/javascript", headers)


def _accepts_gzip(accept_encoding: str | None) -> bool:
    """Whether an Accept-Encoding header takes gzip."""
    return "gzip" in (accept_encoding or "")


def _maybe_gzip(
    data: bytes, packed: bytes, accept_encoding: str | None, media: str, headers: dict[str, str]
) -> Response:
    """`packed` (gzip of `data`) with Content-Encoding where the client takes gzip, else `data`."""
    if _accepts_gzip(accept_encoding):
        return Response(packed, media_type=media, headers={**headers, "Content-Encoding": "gzip"})
    return Response(data, media_type=media, headers=headers)


@router.get("/v1/plans/{plan_id}/scene", response_class=Response, responses=BINARY)
def get_plan_scene(
    plan_id: str,
    store: StoreDep,
    if_none_match: Annotated[str | None, Header()] = None,
    accept_encoding: Annotated[str | None, Header()] = None,
) -> Response:
    """Per-face achieved resolution and state, the faces each viewpoint sees, and with a setup
    its floor, fixtures and keep-out volumes as triangles in the part frame (binary)."""
    gzipped = _accepts_gzip(accept_encoding)
    return _binary(
        (plan_id, "plan"), if_none_match, partial(_scene, store, plan_id, gzipped), gzipped
    )


def _binary(
    content: tuple[str, str], if_none_match: str | None, body: Callable[[], bytes], gzipped: bool
) -> Response:
    """`named_forever` binary answer whose `body` is gzipped when `gzipped`, so labelled."""
    response = named_forever(content, if_none_match, body, OCTETS)
    response.headers["Vary"] = "Accept-Encoding"
    if gzipped and response.status_code == 200:
        response.headers["Content-Encoding"] = "gzip"
    return response


def _scene(store: StoreDep, plan_id: str, gzipped: bool) -> bytes:
    """The stored gzipped scene, unpacked for a client that takes no gzip."""
    data = planning.scene_gz(store, plan_id)
    return data if gzipped else gzip.decompress(data)


@router.get("/v1/meshes/{mesh_id}/geometry", response_class=Response, responses=BINARY)
def get_mesh_geometry(
    mesh_id: str,
    store: StoreDep,
    if_none_match: Annotated[str | None, Header()] = None,
    accept_encoding: Annotated[str | None, Header()] = None,
) -> Response:
    """The mesh's vertices (float32 mm) and faces (uint32), for drawing (binary)."""
    gzipped = _accepts_gzip(accept_encoding)
    geometry = partial(_geometry, store, mesh_id, gzipped)
    return _binary((mesh_id, "mesh"), if_none_match, geometry, gzipped)


def _geometry(store: StoreDep, mesh_id: str, gzipped: bool) -> bytes:
    """The packed geometry, gzipped (level 1: fast, most of the gain) for a client that takes it."""
    data = planning.mesh_geometry(store, mesh_id)
    return gzip.compress(data, 1, mtime=0) if gzipped else data


@router.get(
    "/v1/plans/{plan_id}/related", response_model=RelatedPlans, responses={404: {"model": Problem}}
)
def get_related_plans(plan_id: str, store: StoreDep) -> RelatedPlans:
    """The same request's `density` and `visibility` plans: ids, whether computed, bodies."""
    return planning.related_plans(store, plan_id)
