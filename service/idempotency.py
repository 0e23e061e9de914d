"""`Idempotency-Key` on POST (draft-ietf-httpapi-idempotency-key-header-06): safe retries.

A POST (or PATCH) with `Idempotency-Key: <key>` is processed once per (client, key); the rules:

- a malformed key (empty, over 255 characters, not printable ASCII, the header twice): 400;
- the first request with a key is processed; a 2xx answer is remembered for
  `idempotency_ttl_s` (status, Content-Type, Location, ETag, Retry-After, Cache-Control, body);
  other answers are not (the key is freed, so a retry is processed anew: a plan refused for an
  unknown mesh goes through once the mesh is uploaded);
- a retry with the same key and the same request gets the remembered answer again, with
  `Idempotent-Replayed: true`, without being processed;
- the same key with another request (method, path and query, media type, body digest): 422;
- a request with a key whose first request is still being processed: 409.

The client is the bearer token (its SHA-256) where one is sent, else "anonymous": two API keys
never share an idempotency key. The body digest leaves out the multipart boundary, which
clients draw anew for every request, so a retried upload is the same request.

Records are small JSON strings in Redis (the queue's database), one per (client, key), under
`vpp:idem:<client>:<SHA-256 of the key>`: first `{"state": "pending"}` set with SET NX EX
`idempotency_lock_s` (the in-flight lock: a request that dies frees its key when it expires),
then the answer, with EX `idempotency_ttl_s`. It is an ASGI middleware inside the API-key check
and the body cap (`service.auth`, `service.limits`), so a refused request never takes a key,
and it sees every POST route, including ones added later; requests without the header pass
through untouched. With the header, the body is spooled (a temporary file past 1 MiB) to be
digested before the route reads it. `document` (applied with `problems.extend_openapi`)
declares the header, its answers and the replay header in the OpenAPI document.
"""

from __future__ import annotations

import base64
import hashlib
import json
import re
import secrets
import tempfile
from collections.abc import Callable
from typing import IO, Any, TypeVar

import anyio
from anyio import to_thread
from redis import Redis
from redis.exceptions import RedisError
from starlette.datastructures import Headers
from starlette.exceptions import HTTPException
from starlette.requests import ClientDisconnect, Request
from starlette.responses import Response
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service import auth, problems

HEADER = "Idempotency-Key"
REPLAYED = "Idempotent-Replayed"
"""Response header of a replayed answer (value `true`)."""
METHODS = frozenset({"POST", "PATCH"})
"""The methods the header applies to (the others are idempotent already)."""
MAX_KEY = 255
"""Longest key accepted (characters)."""
REMEMBERED = frozenset({b"content-type", b"location", b"etag", b"retry-after", b"cache-control"})
"""The response headers a replay repeats."""
MAX_REMEMBERED_BODY = 64 * 1024
"""Answers with a longer body are not remembered (ours are a few hundred bytes)."""
SPOOL_BYTES = 1 << 20
"""Bodies up to this size are spooled in memory, longer ones in a temporary file."""
READ_CHUNK = 1 << 16
"""Bytes handed to the route per receive() of a spooled body."""
PREFIX = "vpp:idem:"
"""Redis key prefix of the records."""
RELEASE = "if redis.call('get', KEYS[1]) == ARGV[1] then return redis.call('del', KEYS[1]) end"
"""Lua: free a key only while it holds our own pending record."""
KEY_CHARS = re.compile(r"^[ -~]+$")
PATTERN = r"^[!-~]([ -~]*[!-~])?$"
"""The key's schema in the OpenAPI document: printable ASCII, no blank at either end."""
T = TypeVar("T")


class MalformedKey(ValueError):
    """A malformed Idempotency-Key header."""


def parse_key(values: list[str]) -> str:
    """The key of the header's values (a bare token, or a quoted structured-field string)."""
    if len(values) != 1:
        raise MalformedKey(f"send one {HEADER} header, not {len(values)}")
    key = values[0].strip()
    if len(key) >= 2 and key[0] == key[-1] == '"':
        key = re.sub(r"\\([\"\\])", r"\1", key[1:-1])
    if not key or len(key) > MAX_KEY or not KEY_CHARS.match(key):
        raise MalformedKey(f"{HEADER} must be 1 to {MAX_KEY} printable ASCII characters")
    return key


def client_of(headers: Headers) -> str:
    """Whose keys these are: the bearer token's digest, or "anonymous"."""
    token = auth.bearer_token(headers.get("authorization"))
    return auth.digest(token).hex()[:32] if token else "anonymous"


class BodyDigest:
    """SHA-256 of a body fed in chunks, each `--<boundary>` replaced by `--` (chunk-independent)."""

    def __init__(self, boundary: str | None) -> None:
        self.sha = hashlib.sha256()
        self.sep = b"--" + boundary.encode("latin-1") if boundary else b""
        self.carry = b""

    def update(self, chunk: bytes) -> None:
        if not self.sep:
            self.sha.update(chunk)
            return
        data, start = self.carry + chunk, 0
        cut = max(0, len(data) - len(self.sep) + 1)  # a match starting before it is whole
        while 0 <= (found := data.find(self.sep, start)) < cut:
            self.sha.update(data[start:found] + b"--")
            start = found + len(self.sep)
        keep = max(start, cut)
        self.sha.update(data[start:keep])
        self.carry = data[keep:]

    def hexdigest(self) -> str:
        self.sha.update(self.carry)
        self.carry = b""
        return self.sha.hexdigest()


def boundary_of(content_type: str) -> str | None:
    """The multipart boundary of a Content-Type, if any."""
    found = re.search(r"boundary=\"?([^\";]+)\"?", content_type, re.IGNORECASE)
    return found.group(1) if found else None


async def spool_body(receive: Receive, scope: Scope) -> tuple[IO[bytes], str]:
    """The request body, spooled, and the request's fingerprint (method, path, type, body)."""
    headers = Headers(scope=scope)
    content_type = headers.get("content-type", "")
    digest = BodyDigest(boundary_of(content_type))
    spool: IO[bytes] = tempfile.SpooledTemporaryFile(max_size=SPOOL_BYTES)  # noqa: SIM115
    more = True
    try:
        while more:
            message = await receive()
            if message["type"] == "http.disconnect":
                raise ClientDisconnect
            chunk = message.get("body", b"")
            spool.write(chunk)
            digest.update(chunk)
            more = message.get("more_body", False)
    except BaseException:
        spool.close()
        raise
    spool.seek(0)
    media = content_type.partition(";")[0].strip().lower()
    path = scope["path"].encode("utf-8", "surrogateescape")
    request = [scope["method"].encode(), path, scope.get("query_string", b""), media.encode()]
    return spool, hashlib.sha256(b"\n".join([*request, digest.hexdigest().encode()])).hexdigest()


class Idempotency:
    """ASGI middleware: the rules of the module for requests with an Idempotency-Key."""

    def __init__(self, app: ASGIApp, conn: Redis, ttl_s: int, lock_s: int) -> None:
        self.app = app
        self.conn = conn
        self.ttl_s = ttl_s
        self.lock_s = lock_s

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        headers = Headers(scope=scope) if scope["type"] == "http" else None
        if headers is None or scope["method"] not in METHODS or HEADER.lower() not in headers:
            await self.app(scope, receive, send)
            return
        request = Request(scope)
        try:
            key = parse_key(headers.getlist(HEADER))
        except MalformedKey as exc:
            await problems.problem(request, 400, "Bad request", str(exc))(scope, receive, send)
            return
        name = f"{PREFIX}{client_of(headers)}:{hashlib.sha256(key.encode()).hexdigest()}"
        pending = json.dumps({"state": "pending", "token": secrets.token_hex(8)})
        try:
            record = await _sync(lambda: self._claim(name, pending))
            if record is None:
                await self._first(scope, receive, send, name, pending)
            else:
                await self._again(scope, receive, send, record)
        except RedisError as exc:
            await problems.redis_error_response(request, exc)(scope, receive, send)

    def _claim(self, name: str, pending: str) -> dict[str, Any] | None:
        """None when the key is ours now (SET NX), else the record that holds it."""
        for _ in range(3):  # a record may expire between SET NX and GET
            if self.conn.set(name, pending, nx=True, ex=self.lock_s):
                return None
            raw = self.conn.get(name)
            if raw is not None:
                record: dict[str, Any] = json.loads(raw)
                return record
        raise RedisError("idempotency record kept changing")

    async def _first(
        self, scope: Scope, receive: Receive, send: Send, name: str, pending: str
    ) -> None:
        """Process the first request with a key; remember a 2xx answer, else free the key. The
        answer goes out only then: a client retrying as soon as it has it gets the replay."""
        saved, answer = False, None
        try:
            read = await _read(scope, receive, send)
            if read is None:
                return
            spool, fingerprint = read
            answer = Answer(send)
            with spool:
                await self.app(scope, _replay(spool, receive), answer)
            if answer.rememberable():
                record = _record(fingerprint, answer.status, answer.headers, answer.body())
                await _sync(lambda: self.conn.set(name, record, ex=self.ttl_s))
                saved = True
        finally:
            if not saved:
                with anyio.CancelScope(shield=True):
                    await _sync(lambda: self.conn.eval(RELEASE, 1, name, pending))
        await answer.flush()

    async def _again(
        self, scope: Scope, receive: Receive, send: Send, record: dict[str, Any]
    ) -> None:
        """A key seen before: 409 while in flight, 422 for another request, else the replay."""
        request = Request(scope)
        if record.get("state") != "done":
            detail = f"a request with this {HEADER} is still being processed; retry later"
            await problems.problem(request, 409, "Conflict", detail)(scope, receive, send)
            return
        read = await _read(scope, receive, send)
        if read is None:
            return
        read[0].close()
        if read[1] != record["fingerprint"]:
            detail = f"this {HEADER} was used for another request (method, path or body)"
            await problems.problem(request, 422, "Idempotency key reused", detail)(
                scope, receive, send
            )
            return
        headers = {**dict(record["headers"]), REPLAYED: "true"}
        body = base64.b64decode(record["body"])
        await Response(body, status_code=record["status"], headers=headers)(scope, receive, send)


async def _read(scope: Scope, receive: Receive, send: Send) -> tuple[IO[bytes], str] | None:
    """`spool_body`, or None once a refused body is answered (413) or the client is gone."""
    try:
        return await spool_body(receive, scope)
    except ClientDisconnect:
        return None
    except HTTPException as exc:  # the body cap (service.limits) or the upload limit
        await problems.http_error_response(Request(scope), exc)(scope, receive, send)
        return None


def _record(fingerprint: str, status: int, raw: list[tuple[bytes, bytes]], body: bytes) -> str:
    """The remembered answer as a small JSON string."""
    headers = [
        (k.decode("latin-1"), v.decode("latin-1")) for k, v in raw if k.lower() in REMEMBERED
    ]
    return json.dumps(
        {
            "state": "done",
            "fingerprint": fingerprint,
            "status": status,
            "headers": headers,
            "body": base64.b64encode(body).decode(),
        },
        separators=(",", ":"),
    )


def _replay(spool: IO[bytes], receive: Receive) -> Receive:
    """receive() giving the spooled body, then the client's own messages (disconnect)."""
    done = False

    async def replay() -> Message:
        nonlocal done
        if done:
            return await receive()
        chunk = spool.read(READ_CHUNK)
        done = len(chunk) < READ_CHUNK
        return {"type": "http.request", "body": chunk, "more_body": not done}

    return replay


class Answer:
    """send() holding the route's answer back (status, headers, body up to
    MAX_REMEMBERED_BODY) until `flush`; a longer body flows at once and is not remembered."""

    def __init__(self, send: Send) -> None:
        self.send = send
        self.held: list[Message] = []
        self.status = 500
        self.headers: list[tuple[bytes, bytes]] = []
        self.size = 0
        self.streaming = False

    async def __call__(self, message: Message) -> None:
        if message["type"] == "http.response.start":
            self.status = message["status"]
            self.headers = list(message.get("headers", []))
        self.size += len(message.get("body", b""))
        self.held.append(message)
        if self.streaming or self.size > MAX_REMEMBERED_BODY:
            self.streaming = True
            await self.flush()

    def rememberable(self) -> bool:
        return 200 <= self.status < 300 and not self.streaming

    def body(self) -> bytes:
        return b"".join(m.get("body", b"") for m in self.held if m["type"] == "http.response.body")

    async def flush(self) -> None:
        held, self.held = self.held, []
        for message in held:
            await self.send(message)


async def _sync(func: Callable[[], T]) -> T:
    """A blocking Redis call off the event loop."""
    return await to_thread.run_sync(func)


PARAMETER = {
    "name": HEADER,
    "in": "header",
    "required": False,
    "description": (
        "Makes retries safe (draft-ietf-httpapi-idempotency-key-header): the first request "
        "with a key is processed and a 2xx answer remembered (24 h by default); a retry with "
        "the same key and request gets it again with `Idempotent-Replayed: true`. The same key "
        "with another request: 422; while the first is processed: 409; malformed: 400."
    ),
    "schema": {"type": "string", "minLength": 1, "maxLength": MAX_KEY, "pattern": PATTERN},
}
"""The header as an OpenAPI parameter."""
ANSWERS = {
    "400": f"Malformed request: unparseable body, or a malformed {HEADER}",
    "409": f"A request with this {HEADER} is still being processed",
    "422": f"Invalid request, or this {HEADER} was used for another request",
}
"""The errors of the rules, per status."""
REPLAYED_HEADER = {
    "description": "`true` when this is the remembered answer to an earlier request",
    "schema": {"type": "string", "enum": ["true"]},
}


def document(doc: dict[str, Any]) -> dict[str, Any]:
    """Declare the header, its errors and the replay header on every POST and PATCH (in place)."""
    for path_item in doc.get("paths", {}).values():
        for method, operation in path_item.items():
            if method.upper() not in METHODS:
                continue
            params = operation.setdefault("parameters", [])
            if not any(p.get("name") == HEADER for p in params):
                params.append(PARAMETER)
            responses = operation.setdefault("responses", {})
            for code, description in ANSWERS.items():
                responses.setdefault(code, {"description": description})
                responses[code]["content"] = {problems.PROBLEM: {"schema": problems.PROBLEM_SCHEMA}}
            for code, response in responses.items():
                if code.startswith("2"):
                    response.setdefault("headers", {})[REPLAYED] = REPLAYED_HEADER
    return doc
