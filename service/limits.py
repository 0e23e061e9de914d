"""Request bodies capped, typed and checked before the routes read them (issue 34).

Per request, by the route it goes to (`service.routes`), whatever its Content-Type:

- the cap: `max_upload_bytes` + MULTIPART_SLACK_BYTES for a route taking a multipart form (the
  mesh upload), `max_json_bytes` for every other request. A declared Content-Length over it is
  answered 413 at once, unread; a body streamed without one is cut off as soon as it passes
  the cap (an HTTPException raised while the route reads it, answered by the handlers);
- the media type: a body sent to a JSON route must be `application/json` (or `+json`), one
  sent to the upload `multipart/form-data`; anything else (or none) is 415 before it is read;
- uploads at once: at most `max_uploads`; the next waits, unread, for a slot (503 with
  Retry-After after UPLOAD_WAIT_S), so the memory of uploads is bounded
  (docs/reliability.md measures it per upload);
- JSON bodies (`JsonChecks`, the innermost middleware, so `service.idempotency` takes a
  request's key while its body comes) are read within the cap, then checked in a worker
  thread, in steps that each hold the GIL briefly (`service.bodycheck`): a body with more
  values than any valid request holds (`max_values`) is 422 unparsed; the rest is validated
  against the route's body model, and a body that fails is answered 422 here with its first
  errors (`problems.validation_response`). A valid body goes on to the route, which validates
  it again. So no refused request, however built within the cap, holds the event loop long.

All answers are problem+json (`service.problems`).
"""

from __future__ import annotations

import ctypes
import ctypes.util
from collections.abc import Callable
from typing import Any

import anyio
from starlette.concurrency import run_in_threadpool
from starlette.datastructures import Headers
from starlette.exceptions import HTTPException
from starlette.requests import Request
from starlette.responses import Response
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service import bodycheck, problems, routes
from vpp_core.errors import LimitError
from worker.settings import Settings

MULTIPART = "multipart/form-data"
"""The media type of the mesh upload."""
MULTIPART_SLACK_BYTES = 64 * 1024
"""Room for the multipart envelope (boundaries, form fields) around a file of exactly the
upload limit."""
VALUES_PER_CANDIDATE = 10
"""JSON values (commas) an explicit viewpoint takes at most: position, gaze and up, 3 numbers
each, and the separator (9 commas)."""
UPLOAD_WAIT_S = 60.0
"""How long an upload waits for a free slot before it is answered 503 (s)."""
SLACK_VALUES = 1_000
"""Values of everything else in a valid request (settings, study lists of up to 100 each)."""


def max_values(settings: Settings) -> int:
    """Most JSON values (commas + 1) a valid plan or study request can hold."""
    return VALUES_PER_CANDIDATE * settings.max_candidates + SLACK_VALUES


class BodyLimits:
    """ASGI middleware, outside `service.idempotency`: body cap, media type, upload slots."""

    def __init__(self, app: ASGIApp, settings: Settings) -> None:
        self.app = app
        self.settings = settings
        self.slots: anyio.Semaphore | None = None
        """Upload slots (made in the event loop, at the first upload)."""

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        request = Request(scope)
        route = routes.operation(scope["app"], scope["method"], scope["path"])
        kind = routes.body_kind(route)
        cap = self._cap(kind)
        refusal = _refusal(request.headers, kind, cap)
        if refusal is not None:
            await problems.http_error_response(request, refusal)(scope, receive, send)
            return
        receive = _capped(receive, cap, _setting(kind))
        if kind == "form":
            await self._upload(scope, receive, send)
        else:
            await self.app(scope, receive, send)

    def _cap(self, kind: routes.BodyKind | None) -> int:
        """The body cap of a route taking `kind` (bytes)."""
        if kind == "form":
            return self.settings.max_upload_bytes + MULTIPART_SLACK_BYTES
        return self.settings.max_json_bytes

    async def _upload(self, scope: Scope, receive: Receive, send: Send) -> None:
        """Pass an upload on once one of `max_uploads` slots is free; 503 when none frees
        within UPLOAD_WAIT_S (a waiting upload's body is not read meanwhile)."""
        if self.slots is None:
            self.slots = anyio.Semaphore(self.settings.max_uploads)
        acquired = False
        with anyio.move_on_after(UPLOAD_WAIT_S):
            await self.slots.acquire()
            acquired = True
        if not acquired:
            detail = (
                f"{self.settings.max_uploads} mesh uploads are under way, the most at once "
                f"(VPP_MAX_UPLOADS), and none ended within {UPLOAD_WAIT_S} s; retry shortly"
            )
            busy = problems.problem(Request(scope), 503, "Service unavailable", detail)
            await busy(scope, receive, send)
            return
        try:
            await self.app(scope, receive, send)
        finally:
            self.slots.release()
            await run_in_threadpool(give_back_memory)


class JsonChecks:
    """ASGI middleware, innermost (inside `service.idempotency`, so a request holds its key
    while its body comes): a JSON body checked off the event loop, 422 or passed on."""

    def __init__(self, app: ASGIApp, settings: Settings) -> None:
        self.app = app
        self.max_values = max_values(settings)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        route = None
        if scope["type"] == "http" and _has_body(Headers(scope=scope)):
            route = routes.operation(scope["app"], scope["method"], scope["path"])
        if routes.body_kind(route) != "json":
            await self.app(scope, receive, send)
            return
        await self._json(scope, receive, send, route)

    async def _json(self, scope: Scope, receive: Receive, send: Send, route: Any) -> None:
        """Read a JSON body, check it in a worker thread, answer 422 or pass it on."""
        request = Request(scope)
        try:
            body = await _read(receive)
        except HTTPException as exc:  # over the cap while streaming
            await problems.http_error_response(request, exc)(scope, receive, send)
            return
        field = route.body_field
        answer = await run_in_threadpool(_check_json, request, body, field, self.max_values)
        if answer is not None:
            await answer(scope, receive, send)
            return
        await self.app(scope, _replay(body, receive), send)


def _refusal(headers: Headers, kind: routes.BodyKind | None, cap: int) -> HTTPException | None:
    """413 for a declared length over the cap, 415 for a body of the wrong media type."""
    length = headers.get("content-length", "")
    if length.isdigit() and int(length) > cap:
        return _too_large(cap, _setting(kind))
    if kind is None or not _has_body(headers):
        return None
    media = headers.get("content-type", "").split(";")[0].strip().lower()
    if kind == "form" and media != MULTIPART:
        return HTTPException(415, f"send the mesh as {MULTIPART} (a `file` part), not {media!r}")
    if kind == "json" and not (media == "application/json" or _json_suffix(media)):
        return HTTPException(415, f"send the request as application/json, not {media!r}")
    return None


def _setting(kind: routes.BodyKind | None) -> str:
    """The setting behind the cap of a route taking `kind`."""
    return "VPP_MAX_UPLOAD_BYTES" if kind == "form" else "VPP_MAX_JSON_BYTES"


def _too_large(cap: int, setting: str) -> HTTPException:
    """The 413 of a body over `cap` bytes."""
    return HTTPException(413, f"request body exceeds the limit of {cap} bytes ({setting})")


def _json_suffix(media: str) -> bool:
    """`application/<anything>+json`."""
    return media.startswith("application/") and media.endswith("+json")


def _has_body(headers: Headers) -> bool:
    """Whether the request says it carries a body (a non-zero length, or chunked)."""
    length = headers.get("content-length")
    if length is not None:
        return length.strip() not in ("", "0")
    return "chunked" in headers.get("transfer-encoding", "").lower()


def _capped(receive: Receive, cap: int, setting: str) -> Receive:
    """receive() that raises HTTPException(413) once the body passes `cap` bytes."""
    seen = 0

    async def limited() -> Message:
        nonlocal seen
        message = await receive()
        seen += len(message.get("body", b""))
        if seen > cap:
            raise _too_large(cap, setting)
        return message

    return limited


async def _read(receive: Receive) -> bytes:
    """The whole body (capped by the receive it is given)."""
    parts = []
    while True:
        message = await receive()
        parts.append(message.get("body", b""))
        if message["type"] != "http.request" or not message.get("more_body", False):
            return b"".join(parts)


def _replay(body: bytes, receive: Receive) -> Receive:
    """receive() that gives `body` once, then the client's own messages (disconnect)."""
    sent = False

    async def replay() -> Message:
        nonlocal sent
        if sent:
            return await receive()
        sent = True
        return {"type": "http.request", "body": body, "more_body": False}

    return replay


def _check_json(request: Request, body: bytes, field: Any, max_values: int) -> Response | None:
    """The 422 answer to a JSON body that is too big in values or fails validation
    (`service.bodycheck`); None for a valid one, or one that is not JSON at all (the route
    answers that as before)."""
    try:
        bodycheck.count_values(body, max_values)
        value = bodycheck.parse(body)
        errors, whole = bodycheck.stepwise_errors(
            value, lambda v: field.validate(v, loc=("body",))[1]
        )
    except LimitError as exc:
        return problems.error_response(request, exc)
    except bodycheck.NotJsonConstant as exc:
        errors, whole = [{"loc": ("body",), "msg": str(exc), "type": "json_invalid"}], True
    except (ValueError, RecursionError):
        return None
    return problems.validation_response(request, errors, whole) if errors else None


def _malloc_trim() -> Callable[[int], int] | None:
    """glibc's malloc_trim, or None elsewhere."""
    name = ctypes.util.find_library("c")
    trim = getattr(ctypes.CDLL(name), "malloc_trim", None) if name else None
    return trim


_TRIM = _malloc_trim()


def give_back_memory() -> None:
    """Return the heap's free pages to the system (glibc), after an upload's big buffers."""
    if _TRIM is not None:
        _TRIM(0)
