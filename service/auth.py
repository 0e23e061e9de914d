"""Access control: API keys sent as bearer tokens, checked before a request is read.

With no key configured (`VPP_API_KEYS` empty) the API is open. With keys, every request needs
`Authorization: Bearer <key>`, except the paths of `OPEN` (probes, the OpenAPI document and its
docs pages, the viewer's HTML shell and static bundle: none of them holds data). The rule:

- no `Authorization` header, or not of the form `Bearer <token>`: 401 + `WWW-Authenticate`;
- a well-formed bearer token that is not a configured key: 403.

The check is an ASGI middleware, so a refused request's body is never read (an anonymous
client cannot make the API spool a 256 MiB upload) and unknown paths are refused too. Only the
SHA-256 digests of the keys are kept; tokens are compared digest to digest with
`hmac.compare_digest`, against every key, so the time taken says nothing about the keys.
Keys and tokens are never logged nor echoed in problem details.
"""

from __future__ import annotations

import hashlib
import hmac
import re
from collections.abc import Sequence

from fastapi import Security
from fastapi.security import HTTPBearer
from starlette.datastructures import Headers
from starlette.requests import Request
from starlette.types import ASGIApp, Receive, Scope, Send

from service import problems
from vpp_core.errors import AuthError, ForbiddenError, UnauthenticatedError

OPEN = re.compile(
    r"^/(?:livez|readyz|openapi\.json|docs|docs/oauth2-redirect|redoc"
    r"|static/.*|v1/plans/[^/]+/view)$"
)
"""Paths served without a key (GET and HEAD only): nothing under them holds data."""
OPEN_METHODS = frozenset({"GET", "HEAD"})
"""Methods the open paths are open for."""
BEARER = Security(
    HTTPBearer(
        auto_error=False,
        scheme_name="bearer",
        description="An API key of the service (`VPP_API_KEYS`); needed only where keys are set.",
    )
)
"""Declares the bearer scheme in the OpenAPI document (app-wide); `ApiKeys` enforces it."""


def digest(key: str) -> bytes:
    """SHA-256 of a key or token (what is kept and compared)."""
    return hashlib.sha256(key.encode("latin-1")).digest()


def bearer_token(authorization: str | None) -> str | None:
    """The token of an `Authorization: Bearer <token>` header value; None for anything else."""
    scheme, _, token = (authorization or "").strip().partition(" ")
    token = token.strip()
    return token if scheme.lower() == "bearer" and token else None


def check(digests: Sequence[bytes], authorization: str | None) -> None:
    """Raise UnauthenticatedError or ForbiddenError unless `authorization` carries a key."""
    token = bearer_token(authorization)
    if token is None or " " in token:
        raise UnauthenticatedError("this API needs the header `Authorization: Bearer <API key>`")
    presented = digest(token)
    matched = False
    for known in digests:  # no early exit: the time does not depend on which key matched
        matched |= hmac.compare_digest(known, presented)
    if not matched:
        raise ForbiddenError("the bearer token is not a valid API key")


class ApiKeys:
    """ASGI middleware refusing requests without a configured key (a no-op without keys)."""

    def __init__(self, app: ASGIApp, keys: Sequence[str]) -> None:
        self.app = app
        self.digests = [digest(k) for k in keys]

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] == "http" and self.digests and not _open(scope):
            try:
                check(self.digests, Headers(scope=scope).get("authorization"))
            except AuthError as exc:
                await problems.error_response(Request(scope), exc)(scope, receive, send)
                return
        await self.app(scope, receive, send)


def _open(scope: Scope) -> bool:
    """True for the GET/HEAD requests of the open paths."""
    return scope["method"] in OPEN_METHODS and bool(OPEN.match(scope["path"]))
