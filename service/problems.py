"""The one place where errors become RFC 9457 application/problem+json responses."""

from __future__ import annotations

import logging
from typing import Any

from fastapi import FastAPI, Request
from fastapi.exceptions import RequestValidationError
from fastapi.responses import JSONResponse
from redis.exceptions import RedisError
from starlette.exceptions import HTTPException

from vpp_core.errors import (
    LimitError,
    NotFoundError,
    TooLargeError,
    UnavailableError,
    VppError,
)

PROBLEM = "application/problem+json"
STATUS: list[tuple[type[VppError], int]] = [
    (TooLargeError, 413),
    (NotFoundError, 404),
    (UnavailableError, 503),
    (LimitError, 422),
    (VppError, 422),
]
"""HTTP status per error class, most specific first."""
RETRY_AFTER_S = 5
"""Retry-After of 503 answers."""
TITLES = {404: "Not found", 405: "Method not allowed", 413: "Payload too large"}
log = logging.getLogger("vpp.service")


def problem(
    request: Request, status: int, title: str, detail: str | None, **extra: Any
) -> JSONResponse:
    """A problem+json response."""
    body = {"type": "about:blank", "title": title, "status": status, "detail": detail}
    body["instance"] = request.url.path
    headers = {"Retry-After": str(RETRY_AFTER_S)} if status == 503 else None
    return JSONResponse({**body, **extra}, status_code=status, media_type=PROBLEM, headers=headers)


async def _vpp_error(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, VppError)
    status = next(code for cls, code in STATUS if isinstance(exc, cls))
    return problem(request, status, exc.title, exc.detail)


async def _validation(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, RequestValidationError)
    errors = [{"loc": list(e["loc"]), "msg": e["msg"], "type": e["type"]} for e in exc.errors()]
    first = errors[0] if errors else {"loc": [], "msg": "invalid request"}
    detail = f"{'.'.join(str(p) for p in first['loc'])}: {first['msg']}"
    return problem(request, 422, "Invalid request", detail, errors=errors)


async def _http(request: Request, exc: Exception) -> JSONResponse:
    assert isinstance(exc, HTTPException)
    title = TITLES.get(exc.status_code, "HTTP error")
    response = problem(request, exc.status_code, title, str(exc.detail))
    response.headers.update(exc.headers or {})
    return response


async def _redis(request: Request, exc: Exception) -> JSONResponse:
    return problem(request, 503, "Service unavailable", f"job queue unreachable: {exc}")


async def _internal(request: Request, exc: Exception) -> JSONResponse:
    log.exception("internal error on %s %s", request.method, request.url.path)
    return problem(request, 500, "Internal error", f"{type(exc).__name__}: see the server log")


def install(app: FastAPI) -> None:
    """Register the handlers on `app`."""
    app.add_exception_handler(VppError, _vpp_error)
    app.add_exception_handler(RequestValidationError, _validation)
    app.add_exception_handler(HTTPException, _http)
    app.add_exception_handler(RedisError, _redis)
    app.add_exception_handler(Exception, _internal)
