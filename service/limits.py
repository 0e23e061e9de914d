"""Request body cap for everything but mesh uploads: JSON bodies answered 413 before parsing.

The app-wide `max_body_size` is the upload limit (256 MiB by default), far too much for a JSON
plan request: pydantic takes about 20 s and 2.5 GiB for 10^6 explicit viewpoints (45 MB).
Bodies that are not `multipart/form-data` are capped at `max_json_bytes` instead: a declared
Content-Length over it is answered at once, unread; a body streamed without one is cut off
as soon as it passes the cap (an HTTPException raised while the route reads it, so the
problem handlers answer it).
"""

from __future__ import annotations

from starlette.datastructures import Headers
from starlette.exceptions import HTTPException
from starlette.requests import Request
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service import problems

MULTIPART = "multipart/form-data"
"""Bodies of this type (mesh uploads) keep the app-wide upload limit."""


class JsonBodyLimit:
    """ASGI middleware: non-multipart bodies over `max_bytes` get 413 problem+json."""

    def __init__(self, app: ASGIApp, max_bytes: int) -> None:
        self.app = app
        self.max_bytes = max_bytes

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        headers = Headers(scope=scope) if scope["type"] == "http" else None
        if headers is None or headers.get("content-type", "").lower().startswith(MULTIPART):
            await self.app(scope, receive, send)
            return
        detail = f"request body exceeds the limit of {self.max_bytes} bytes (VPP_MAX_JSON_BYTES)"
        length = headers.get("content-length", "")
        if length.isdigit() and int(length) > self.max_bytes:
            refused = HTTPException(413, detail)  # answered as the handlers answer one raised
            await problems.http_error_response(Request(scope), refused)(scope, receive, send)
            return
        seen = 0

        async def limited() -> Message:
            nonlocal seen
            message = await receive()
            seen += len(message.get("body", b""))
            if seen > self.max_bytes:
                raise HTTPException(413, detail)
            return message

        await self.app(scope, limited, send)
