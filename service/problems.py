"""The one place where errors become RFC 9457 application/problem+json responses.

`install` registers the handlers and makes the OpenAPI document say so: every error response
is `application/problem+json` with the `Problem` schema (FastAPI would document
`application/json`, and its own 422 shape), and every operation lists the errors any request
can get: 401/403 (API keys), 413 (body cap), 503 (Redis or store down), 400 where it takes a
body (unparseable JSON or multipart), 429 on POSTs (fair use).
"""

from __future__ import annotations

import logging
from collections.abc import Callable, Sequence
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from redis.exceptions import RedisError
from starlette.exceptions import HTTPException

from service import requestid, routes
from vpp_core.errors import (
    ForbiddenError,
    LimitError,
    NotFoundError,
    TooLargeError,
    UnauthenticatedError,
    UnavailableError,
    VppError,
)

PROBLEM = "application/problem+json"
STATUS: list[tuple[type[VppError], int]] = [
    (TooLargeError, 413),
    (UnauthenticatedError, 401),
    (ForbiddenError, 403),
    (NotFoundError, 404),
    (UnavailableError, 503),
    (LimitError, 422),
    (VppError, 422),
]
"""HTTP status per error class, most specific first."""
RETRY_AFTER_S = 5
"""Retry-After of 503 answers outside an app with settings (else VPP_RETRY_AFTER_S)."""
TITLES = {
    400: "Bad request",
    404: "Not found",
    405: "Method not allowed",
    413: "Payload too large",
    415: "Unsupported media type",
    429: "Too many requests",
}
MAX_ERRORS = 20
"""Validation errors listed in a 422 answer; `error_count` says how many there were."""
MAX_TEXT = 200
"""Longest loc part or message of a listed validation error (characters)."""
log = logging.getLogger("vpp.service")


def problem(
    request: Request, status: int, title: str, detail: str | None, **extra: Any
) -> JSONResponse:
    """A problem+json response."""
    body = {"type": "about:blank", "title": title, "status": status, "detail": detail}
    body["instance"] = request.url.path
    headers = {"Retry-After": str(_retry_after_s(request))} if status == 503 else None
    if status == 401:
        headers = {"WWW-Authenticate": 'Bearer realm="vpp"'}
    rid = requestid.request_id(request.scope)  # also on 500s, sent outside RequestIds
    headers = {**(headers or {}), **({requestid.HEADER: rid} if rid else {})}
    return JSONResponse({**body, **extra}, status_code=status, media_type=PROBLEM, headers=headers)


def error_response(request: Request, exc: VppError) -> JSONResponse:
    """The problem+json answer to a VppError (also what middleware sends, outside the handlers)."""
    status = next(code for cls, code in STATUS if isinstance(exc, cls))
    return problem(request, status, exc.title, exc.detail)


def _retry_after_s(request: Request) -> int:
    """The app's VPP_RETRY_AFTER_S, the same as job polls send; RETRY_AFTER_S without one."""
    settings = getattr(request.app.state, "settings", None) if "app" in request.scope else None
    return int(getattr(settings, "retry_after_s", RETRY_AFTER_S))


async def _vpp_error(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, VppError)
    return error_response(request, exc)


async def _validation(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    return validation_response(request, exc.errors())


def validation_response(
    request: Request, errors: Sequence[dict[str, Any]], whole: bool = True
) -> JSONResponse:
    """The 422 answer to validation errors: the first MAX_ERRORS of them (each loc part and
    message cut to MAX_TEXT characters), `error_count`, however many there are, and
    `error_count_exact`: false when validation stopped before the body's end (a long list is
    checked in steps, `service.bodycheck`), so that more errors may follow those counted."""
    shown = [
        {"loc": [_cut(p) for p in e["loc"]], "msg": _cut(e["msg"]), "type": e["type"]}
        for e in errors[:MAX_ERRORS]
    ]
    first = shown[0] if shown else {"loc": [], "msg": "invalid request"}
    detail = f"{'.'.join(str(p) for p in first['loc'])}: {first['msg']}"
    if len(errors) > 1:
        more = "more errors" if whole else "more errors in the items checked, maybe more after"
        detail += f" (and {len(errors) - 1} {more})"
    extra = {"errors": shown, "error_count": len(errors), "error_count_exact": whole}
    return problem(request, 422, "Invalid request", detail, **extra)


def _cut(part: Any) -> Any:
    """A loc part or message, strings cut to MAX_TEXT characters."""
    if isinstance(part, str) and len(part) > MAX_TEXT:
        return part[: MAX_TEXT - 3] + "..."
    return part


def http_error_response(request: Request, exc: HTTPException) -> JSONResponse:
    """The problem+json answer to an HTTPException (also what middleware sends); a 405 lists
    every method the path answers in `Allow` (Starlette names only its first route's)."""
    title = TITLES.get(exc.status_code, "HTTP error")
    response = problem(request, exc.status_code, title, str(exc.detail))
    response.headers.update(exc.headers or {})
    if exc.status_code == 405 and "app" in request.scope:
        response.headers["Allow"] = ", ".join(routes.allowed_methods(request.app, request.url.path))
    return response


def redis_error_response(request: Request, exc: RedisError) -> JSONResponse:
    """The 503 problem+json answer to a Redis that cannot be reached (also from middleware)."""
    return problem(request, 503, "Service unavailable", f"job queue unreachable: {exc}")


async def _http(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, HTTPException)
    return http_error_response(request, exc)


async def _redis(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RedisError)
    return redis_error_response(request, exc)


async def _internal(request: Request, exc: Exception) -> JSONResponse:
    log.exception("internal error on %s %s", request.method, request.url.path)
    return problem(request, 500, "Internal error", f"{type(exc).__name__}: see the server log")


PROBLEM_SCHEMA = {"$ref": "#/components/schemas/Problem"}
"""The schema of every error response in the OpenAPI document."""
EVERY_OPERATION = {
    "401": "No usable `Authorization: Bearer <key>` header (where API keys are set)",
    "403": "The bearer token is not an API key of the service",
    "413": "The request body exceeds its limit (VPP_MAX_JSON_BYTES, VPP_MAX_UPLOAD_BYTES)",
    "503": "Redis or the store cannot be reached; retry after Retry-After seconds",
}
"""Errors any request can get, whatever the operation."""
WITH_BODY = {"400": "The body cannot be parsed (JSON or multipart)"}
"""Errors of operations that take a body."""
POSTS = {
    "429": "Fair use: too many POST requests (VPP_RATE_LIMIT per VPP_RATE_WINDOW_S) or, on job "
    "submissions, too many queued and running jobs (VPP_MAX_ACTIVE_JOBS); retry after "
    "Retry-After seconds"
}
"""Errors of POST operations (service.fairuse)."""
VALIDATION_SCHEMAS = ("HTTPValidationError", "ValidationError")
"""FastAPI's 422 schemas, replaced by Problem (its `errors` member)."""


def document_problems(doc: dict[str, Any]) -> dict[str, Any]:
    """Rewrite an OpenAPI document in place: error responses as problem+json (see module)."""
    for path_item in doc.get("paths", {}).values():
        for method, operation in path_item.items():
            responses = operation.setdefault("responses", {})
            extra = {**EVERY_OPERATION, **(WITH_BODY if "requestBody" in operation else {})}
            extra.update(POSTS if method == "post" else {})
            for code, description in extra.items():
                responses.setdefault(code, {"description": description})
            for code, response in responses.items():
                if code[0] in "45":
                    response["content"] = {PROBLEM: {"schema": PROBLEM_SCHEMA}}
    schemas = doc.get("components", {}).get("schemas", {})
    for name in VALIDATION_SCHEMAS:
        schemas.pop(name, None)
    return doc


def extend_openapi(app: FastAPI, rewrite: Callable[[dict[str, Any]], dict[str, Any]]) -> None:
    """Make `app.openapi` apply `rewrite` once to the document it builds (and then cache it);
    each call adds one rewrite after those before."""
    build = app.openapi
    done: list[dict[str, Any]] = []

    def openapi() -> dict[str, Any]:
        if not done:
            done.append(rewrite(build()))
        return done[0]

    app.openapi = openapi  # type: ignore[method-assign]


def install(app: FastAPI) -> None:
    """Register the handlers on `app` and document them in its OpenAPI document."""
    extend_openapi(app, document_problems)
    app.add_exception_handler(VppError, _vpp_error)
    app.add_exception_handler(RequestValidationError, _validation)
    app.add_exception_handler(HTTPException, _http)
    app.add_exception_handler(RedisError, _redis)
    app.add_exception_handler(Exception, _internal)
