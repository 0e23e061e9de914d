"""Request ids: every request gets one, every answer says it, every log line carries it.

`RequestIds`, the outermost middleware, takes the client's `X-Request-ID` when it is a usable
id (1 to MAX_LENGTH printable ASCII characters, no spaces) or makes one (32 hex digits), keeps
it in `worker.logs.REQUEST_ID` for the log lines written while the request is answered and in
the request's state, adds `X-Request-ID` to the answer (errors and refusals included: the
500 answers Starlette's outer error middleware sends get it from `service.problems`), and logs
one line per request on `vpp.access` (method, path, status, milliseconds).
"""

from __future__ import annotations

import logging
import time
import uuid

from starlette.datastructures import Headers, MutableHeaders
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from worker.logs import REQUEST_ID

HEADER = "X-Request-ID"
MAX_LENGTH = 128
"""Longest client request id kept; a longer one is replaced."""
log = logging.getLogger("vpp.access")


def usable(value: str) -> bool:
    """Whether a client's X-Request-ID can be kept (and echoed, and logged) as it is."""
    printable = value.isascii() and value.isprintable() and " " not in value
    return 0 < len(value) <= MAX_LENGTH and printable


def request_id(scope: Scope) -> str | None:
    """The id RequestIds gave the request of `scope` (None outside it)."""
    state = scope.get("state") or {}
    found = state.get("request_id") if isinstance(state, dict) else None
    return str(found) if found else None


class RequestIds:
    """ASGI middleware, outermost: the request id kept, echoed and logged (see module)."""

    def __init__(self, app: ASGIApp) -> None:
        self.app = app

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http":
            await self.app(scope, receive, send)
            return
        given = Headers(scope=scope).get(HEADER)
        rid = given if given is not None and usable(given) else uuid.uuid4().hex
        scope.setdefault("state", {})["request_id"] = rid
        REQUEST_ID.set(rid)  # this request's task only: each request runs in its own context
        status = 500
        start = time.perf_counter()

        async def sending(message: Message) -> None:
            nonlocal status
            if message["type"] == "http.response.start":
                status = message["status"]
                MutableHeaders(scope=message)[HEADER] = rid
            await send(message)

        try:
            await self.app(scope, receive, sending)
        finally:
            ms = (time.perf_counter() - start) * 1000
            log.info("%s %s %d %.1f ms", scope["method"], scope["path"], status, ms)
