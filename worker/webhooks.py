"""Webhooks: tell a client's receiver that its job ended, signed the Standard Webhooks way.

A submission with `callback: {url, secret}` registers it on the job (`register`, a Redis list
that expires with the job's records). When the job reaches a terminal status (RQ's success,
failure and stopped callbacks in worker.jobhooks; the API's cancel; a submission that finds the
job done) `notify` enqueues `dispatch` on the webhooks queue (`<queue>-webhooks`, which the
workers take from first): nothing of the delivery runs in the job itself. `dispatch` waits out
RQ's bookkeeping, and once the job is terminal takes the callbacks (each registered one is told
once) and enqueues one `deliver` per callback, retried by RQ with exponential backoff
(`backoff_s`) for up to `callback_max_age_s`. Every attempt is recorded on the job (`attempts`).

Signing (standardwebhooks.com): headers `webhook-id`, `webhook-timestamp` (Unix s) and `webhook-
signature: v1,<base64 HMAC-SHA256(key, "<id>.<timestamp>.<body>")>`, the key being the
base64-decoded secret (an optional `whsec_` prefix dropped). Hand-written (a dozen lines, no
extra dependency); the tests check it with the `standardwebhooks` package's verifier.

SSRF: a callback URL must be http(s) and its host must resolve only to global addresses (no
loopback, link-local, private, shared, reserved or multicast), checked at submission and again
before every attempt, unless `callback_allow_private`. Redirects are not followed.
"""

from __future__ import annotations

import base64
import binascii
import hashlib
import hmac
import ipaddress
import json
import socket
import time
import uuid
from datetime import UTC, datetime
from typing import Any
from urllib.parse import urlsplit

import httpx
from redis import Redis
from rq import Queue, Retry, get_current_job

from vpp_core.errors import VppError
from worker import joblist
from worker.settings import Settings, get_settings

SECRET_PREFIX = "whsec_"
SECRET_BYTES = (24, 64)
"""Accepted length of the decoded secret (bytes), as Standard Webhooks recommends."""
TIMEOUT_S = 10.0
"""Connect and read timeout of one delivery attempt."""
SETTLE_S = 10.0
"""How long `dispatch` waits for RQ to record a job's end after the job's callback ran."""
SETTLE_POLL_S = 0.1
TERMINAL = ("succeeded", "failed", "canceled")
KEEP_ATTEMPTS = 100
"""Delivery attempts kept per job (the latest)."""


def callbacks_key(job_id: str) -> str:
    return f"vpp:callbacks:{job_id}"


def attempts_key(job_id: str) -> str:
    return f"vpp:deliveries:{job_id}"


def queue_name(plan_queue: str) -> str:
    """The webhooks queue beside a plan queue."""
    return f"{plan_queue}-webhooks"


def check_secret(secret: str) -> bytes:
    """The HMAC key of a Standard Webhooks secret; VppError unless it is base64 of 24–64 bytes."""
    text = secret.removeprefix(SECRET_PREFIX)
    try:
        key = base64.b64decode(text + "=" * (-len(text) % 4), validate=True)
    except (binascii.Error, ValueError):
        raise VppError("callback.secret must be base64 (optionally after `whsec_`)") from None
    if not SECRET_BYTES[0] <= len(key) <= SECRET_BYTES[1]:
        raise VppError(f"callback.secret must decode to {SECRET_BYTES} bytes, not {len(key)}")
    return key


def sign(secret: str, msg_id: str, timestamp: int, body: bytes) -> str:
    """The `webhook-signature` header value of `body`."""
    signed = f"{msg_id}.{timestamp}.".encode() + body
    digest = hmac.new(check_secret(secret), signed, hashlib.sha256).digest()
    return "v1," + base64.b64encode(digest).decode()


def check_url(url: str, allow_private: bool) -> None:
    """VppError unless `url` is http(s) to a host that resolves to global addresses only."""
    parts = urlsplit(url)
    if parts.scheme not in ("http", "https") or not parts.hostname:
        raise VppError(f"callback.url {url[:200]!r} must be an http or https URL")
    if allow_private:
        return
    port = parts.port or (443 if parts.scheme == "https" else 80)
    try:
        infos = socket.getaddrinfo(parts.hostname, port, proto=socket.IPPROTO_TCP)
    except (OSError, UnicodeError):
        raise VppError(f"callback.url host {parts.hostname!r} does not resolve") from None
    for info in infos:
        address = ipaddress.ip_address(str(info[4][0]).split("%")[0])
        if not address.is_global or address.is_multicast:
            raise VppError(
                f"callback.url host {parts.hostname!r} is at {address}, a loopback, link-local "
                "or private address: refused (VPP_CALLBACK_ALLOW_PRIVATE allows it)"
            )


def register(conn: Redis, settings: Settings, job_id: str, url: str, secret: str) -> None:
    """Ask for `job_id`'s terminal event at `url` (the same url and secret once)."""
    entry = json.dumps({"url": url, "secret": secret}, sort_keys=True)
    pipe = conn.pipeline()
    pipe.lrem(callbacks_key(job_id), 0, entry)
    pipe.rpush(callbacks_key(job_id), entry)
    pipe.expire(callbacks_key(job_id), joblist.retention_s(settings))
    pipe.execute()


def notify(conn: Redis, plan_queue: str, job_id: str) -> None:
    """Have a worker deliver `job_id`'s webhooks if it has ended (cheap; never blocks)."""
    if conn.exists(callbacks_key(job_id)):
        Queue(queue_name(plan_queue), connection=conn).enqueue_call(
            dispatch, args=(job_id,), description=f"webhooks of {job_id[:12]}", result_ttl=600
        )


def dispatch(job_id: str) -> int:
    """Enqueue the deliveries of `job_id`'s terminal event; how many (0 while it is not over)."""
    from worker.queue import state  # the job's state as clients see it
    from worker.store import open_store

    rq_job = get_current_job()
    assert rq_job is not None, "dispatch runs as an RQ job"
    conn, settings = rq_job.connection, get_settings()
    store = open_store(settings.store_url, conn, settings.s3_endpoint_url)
    deadline = time.monotonic() + SETTLE_S
    current = state(conn, store, job_id)
    while current.status == "running" and time.monotonic() < deadline:
        time.sleep(SETTLE_POLL_S)  # its callback runs before RQ marks it failed or stopped
        current = state(conn, store, job_id)
    if current.status not in TERMINAL:
        return 0  # retried after its worker died: its next end notifies again
    pipe = conn.pipeline()
    pipe.lrange(callbacks_key(job_id), 0, -1)
    pipe.delete(callbacks_key(job_id))
    entries = [json.loads(e) for e in pipe.execute()[0]]
    body = json.dumps(event(conn, store, current), separators=(",", ":")).encode()
    queue = Queue(rq_job.origin, connection=conn)
    intervals = backoff_s(settings)
    for cb in entries:
        queue.enqueue_call(
            deliver,
            args=(job_id, f"msg_{uuid.uuid4().hex}", body, cb["url"], cb["secret"]),
            description=f"webhook of {job_id[:12]}",
            retry=Retry(max=len(intervals), interval=intervals),
            result_ttl=600,
            failure_ttl=joblist.retention_s(settings),
        )
    return len(entries)


def event(conn: Redis, store: Any, current: Any) -> dict[str, Any]:
    """The webhook payload: `{type, timestamp, data}`, data the job as `GET /v1/jobs/{id}`."""
    listed = joblist.entry(conn, current.id)
    kind = listed.kind if listed else "plan"
    data = {
        "id": current.id,
        "kind": kind,
        "status": current.status,
        "progress": current.progress,
        "error": current.error,
        "result_url": result_url(store, kind, current.id)
        if current.status == "succeeded"
        else None,
        "created_at": _iso(current.created_at or (listed.created_at if listed else None)),
        "ended_at": _iso(current.ended_at),
    }
    now = datetime.now(UTC).isoformat().replace("+00:00", "Z")
    return {"type": f"job.{current.status}", "timestamp": now, "data": data}


def result_url(store: Any, kind: str, job_id: str) -> str:
    """Where a finished job's result is served."""
    from worker import artifacts as art

    if kind == "study":
        return f"/v1/studies/{job_id}"
    if kind == "point-cloud":
        return f"/v1/plans/{art.get_cloud_plan(store, job_id)}/point-cloud"
    return f"/v1/plans/{job_id}"


def _iso(value: datetime | None) -> str | None:
    return value.replace(tzinfo=value.tzinfo or UTC).isoformat() if value else None


def backoff_s(settings: Settings) -> list[int]:
    """Seconds before each retry: doubling from `callback_retry_s` until they add up to
    `callback_max_age_s`."""
    out: list[int] = []
    wait = settings.callback_retry_s
    while sum(out) < settings.callback_max_age_s:
        out.append(min(wait, settings.callback_max_age_s - sum(out)))
        wait *= 2
    return out


def deliver(job_id: str, msg_id: str, body: bytes, url: str, secret: str) -> int:
    """POST the signed event once; its status code. Raises (RQ retries) unless 2xx."""
    settings = get_settings()
    rq_job = get_current_job()
    conn = rq_job.connection if rq_job else Redis.from_url(settings.redis_url or "")
    attempt = 1
    if rq_job is not None:
        attempt = rq_job.meta["attempt"] = int(rq_job.meta.get("attempt", 0)) + 1
        rq_job.save_meta()  # type: ignore[no-untyped-call]
    timestamp = int(time.time())
    headers = {
        "content-type": "application/json",
        "webhook-id": msg_id,
        "webhook-timestamp": str(timestamp),
        "webhook-signature": sign(secret, msg_id, timestamp, body),
    }
    status: int | None = None
    error: str | None = None
    try:
        check_url(url, settings.callback_allow_private)
        response = httpx.post(url, content=body, headers=headers, timeout=TIMEOUT_S)
        status = response.status_code
        if not 200 <= status < 300:
            error = f"the receiver answered {status}"
    except (httpx.HTTPError, VppError) as exc:
        error = str(exc) or type(exc).__name__
    record_attempt(conn, settings, job_id, url, attempt, status, error)
    if error:
        raise RuntimeError(f"webhook to {url} not delivered: {error}")
    return int(status or 0)


def record_attempt(
    conn: Redis,
    settings: Settings,
    job_id: str,
    url: str,
    attempt: int,
    status: int | None,
    error: str | None,
) -> None:
    """Append one attempt to the job's delivery record (kept as long as the job's)."""
    at = datetime.now(UTC).isoformat()
    rec = {"url": url, "attempt": attempt, "at": at, "status_code": status, "error": error}
    rec["delivered"] = error is None
    pipe = conn.pipeline()
    pipe.rpush(attempts_key(job_id), json.dumps(rec))
    pipe.ltrim(attempts_key(job_id), -KEEP_ATTEMPTS, -1)
    pipe.expire(attempts_key(job_id), joblist.retention_s(settings))
    pipe.execute()


def attempts(conn: Redis, job_id: str) -> list[dict[str, Any]]:
    """The delivery attempts of `job_id`'s webhooks, oldest first."""
    return [json.loads(r) for r in conn.lrange(attempts_key(job_id), 0, -1)]
