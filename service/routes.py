"""Which routes of the app a request path goes to, and what body each takes.

FastAPI keeps included routers as wrappers; `fastapi.routing.iter_route_contexts` flattens
them into one RouteContext per operation (path regex, methods, body field). The body cap and
media-type check (`service.limits`) and the 405 `Allow` header (`service.problems`) read them
here, so a route added later is covered without a list of paths to keep up to date.
"""

from __future__ import annotations

from typing import Any, Literal

from fastapi import params
from fastapi.routing import RouteContext, iter_route_contexts

BodyKind = Literal["form", "json"]
"""A route's body: a multipart form (the mesh upload) or JSON."""


def on_path(app: Any, path: str) -> list[RouteContext]:
    """The app's operations whose path matches `path` (any method)."""
    found = []
    for route in iter_route_contexts(app.routes):
        regex = getattr(route, "path_regex", None)
        if route.methods and regex is not None and regex.match(path):
            found.append(route)
    return found


def allowed_methods(app: Any, path: str) -> list[str]:
    """Every method some route of `path` answers, sorted (a 405's `Allow`)."""
    return sorted({m for route in on_path(app, path) for m in route.methods or ()})


def operation(app: Any, method: str, path: str) -> RouteContext | None:
    """The route that answers `method` on `path`, if any."""
    return next((r for r in on_path(app, path) if method in (r.methods or ())), None)


def body_kind(route: RouteContext | None) -> BodyKind | None:
    """What body the route takes: "form", "json", or None (none, or no such route)."""
    field = getattr(route, "body_field", None) if route is not None else None
    if field is None:
        return None
    return "form" if isinstance(field.field_info, params.Form) else "json"
