"""The plan viewer: its page, and the binary geometry and per-face results it draws."""

from __future__ import annotations

import gzip
from pathlib import Path
from typing import Annotated, Any

from fastapi import APIRouter, Header, Response
from fastapi.responses import HTMLResponse

from service import planning
from service.deps import StoreDep
from service.models import Problem, RelatedPlans

router = APIRouter(tags=["viewer"])
STATIC_DIR = Path(__file__).resolve().parent.parent / "static" / "viewer"
"""The page and its bundle (built from viewer/ by `npm run build`)."""
IMMUTABLE = "public, max-age=31536000, immutable"
BINARY: dict[int | str, dict[str, Any]] = {
    200: {"content": {"application/octet-stream": {}}},
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


@router.get("/v1/plans/{plan_id}/scene", response_class=Response, responses=BINARY)
def get_plan_scene(
    plan_id: str,
    store: StoreDep,
    if_none_match: Annotated[str | None, Header()] = None,
    accept_encoding: Annotated[str | None, Header()] = None,
) -> Response:
    """Per-face achieved resolution and state, and the faces each viewpoint sees (binary)."""
    gzipped = "gzip" in (accept_encoding or "")
    response = _immutable(plan_id, if_none_match, lambda: _scene(store, plan_id, gzipped))
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
    mesh_id: str, store: StoreDep, if_none_match: Annotated[str | None, Header()] = None
) -> Response:
    """The mesh's vertices (float32 mm) and faces (uint32), for drawing (binary)."""
    return _immutable(mesh_id, if_none_match, lambda: planning.mesh_geometry(store, mesh_id))


@router.get(
    "/v1/plans/{plan_id}/related", response_model=RelatedPlans, responses={404: {"model": Problem}}
)
def get_related_plans(plan_id: str, store: StoreDep) -> RelatedPlans:
    """The same request's `density` and `visibility` plans: ids, whether computed, bodies."""
    return planning.related_plans(store, plan_id)


def _immutable(content: str, if_none_match: str | None, body: Any) -> Response:
    """A binary answer named forever by `content`: 304 on a matching If-None-Match."""
    etag = f'"{planning.content_id(content, "resource")}"'
    headers = {"ETag": etag, "Cache-Control": IMMUTABLE}
    if if_none_match and etag in [t.strip() for t in if_none_match.split(",")]:
        return Response(status_code=304, headers=headers)
    return Response(body(), media_type="application/octet-stream", headers=headers)
