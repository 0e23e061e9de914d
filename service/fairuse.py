"""Fair use: each caller's POST rate and its queued + running jobs, counted in Redis.

The caller is its API key (by owner id, `service.callers`), or its client address when the API
is open (behind a reverse proxy, set uvicorn's `FORWARDED_ALLOW_IPS` to the proxy's address so
the address is the client's, from `X-Forwarded-For`).
Both counts live in Redis and are changed by Lua scripts, so they are atomic and every API
process shares them:

- rate (`FairUse`, ASGI middleware inside the key check, before a body is read): at most
  `rate_limit` POST requests per `rate_window_s` fixed window, which opens at the caller's
  first POST. Every POST answer carries the IETF RateLimit headers
  (draft-ietf-httpapi-ratelimit-headers-09): `RateLimit-Policy: "post";q=<limit>;w=<window>`
  and `RateLimit: "post";r=<remaining>;t=<seconds to the window's end>`; past the limit the
  answer is 429 problem+json with `Retry-After` (the window's end), the body unread;
- jobs (`reserve` / `hold` / `release`, around each job submission): at most
  `max_active_jobs` of the caller's jobs queued or running. A submission first reserves a
  slot (a short-lived token in the caller's sorted set, the set pruned of ended jobs in the same
  script), then holds it with its job id, or releases it when the submission fails; past the
  cap, 429 with `Retry-After: retry_after_s`. Refused requests queue nothing, so one caller's
  flood leaves the queue to the others, whose jobs run first come, first served.
"""

from __future__ import annotations

import math
import time
import uuid

from redis import Redis
from redis.exceptions import RedisError
from rq.job import Job
from starlette.datastructures import MutableHeaders
from starlette.exceptions import HTTPException
from starlette.requests import Request
from starlette.responses import Response
from starlette.types import ASGIApp, Message, Receive, Scope, Send

from service import problems, routes
from service.callers import caller
from worker.settings import Settings

PREFIX = "vpp:fair"
"""Redis key prefix of the fair-use counts."""
POLICY = "post"
"""The name of the rate policy in the RateLimit headers."""
RESERVE_S = 60
"""How long a reserved job slot is kept without a job id (a submission whose process died)."""
ENDED = ("finished", "failed", "stopped", "canceled")
"""RQ statuses of jobs that no longer count; every other status (or a record) counts."""

RATE_SCRIPT = """
local n = redis.call('INCR', KEYS[1])
local ttl = redis.call('PTTL', KEYS[1])
if ttl < 0 then
  redis.call('PEXPIRE', KEYS[1], ARGV[1])
  ttl = tonumber(ARGV[1])
end
return {n, ttl}
"""
"""KEYS[1] the caller's window counter; ARGV[1] the window (ms). Returns {count, ms left}."""

RESERVE_SCRIPT = """
local now, stale, cap = tonumber(ARGV[1]), tonumber(ARGV[2]), tonumber(ARGV[3])
local ended = {}
for i = 7, #ARGV do ended[ARGV[i]] = true end
local members = redis.call('ZRANGE', KEYS[1], 0, -1, 'WITHSCORES')
for i = 1, #members, 2 do
  local id, score = members[i], tonumber(members[i + 1])
  local gone
  if string.sub(id, 1, 2) == 'r:' then
    gone = score < now - stale
  else
    local status = redis.call('HGET', ARGV[5] .. id, 'status')
    gone = (not status) or ended[status]
  end
  if gone then redis.call('ZREM', KEYS[1], id) end
end
local n = redis.call('ZCARD', KEYS[1])
if n >= cap then return {0, n} end
redis.call('ZADD', KEYS[1], now, ARGV[4])
redis.call('PEXPIRE', KEYS[1], ARGV[6])
return {1, n + 1}
"""
"""KEYS[1] the caller's slots; ARGV now (ms), reserved-slot lifetime (ms), cap, new token, RQ's
job key prefix, the set's expiry (ms), then the ended statuses. Drops ended jobs and stale
tokens, then adds the token unless the cap is reached. Returns {admitted 0/1, slots taken}."""


def rate_key(who: str) -> str:
    """The counter of `who`'s POST requests in its current window."""
    return f"{PREFIX}:rate:{who}"


def jobs_key(who: str) -> str:
    """The sorted set of `who`'s reserved slots and active job ids."""
    return f"{PREFIX}:jobs:{who}"


def rate_headers(settings: Settings, count: int, ms_left: int) -> dict[str, str]:
    """The RateLimit-Policy and RateLimit headers after `count` POSTs, `ms_left` ms to go."""
    remaining = max(0, settings.rate_limit - count)
    reset = max(1, math.ceil(ms_left / 1000))
    return {
        "RateLimit-Policy": f'"{POLICY}";q={settings.rate_limit};w={settings.rate_window_s}',
        "RateLimit": f'"{POLICY}";r={remaining};t={reset}',
    }


class FairUse:
    """ASGI middleware, inside the key check: POSTs counted per caller, 429 past the rate."""

    def __init__(self, app: ASGIApp, conn: Redis, settings: Settings) -> None:
        self.app = app
        self.settings = settings
        self.script = conn.register_script(RATE_SCRIPT)

    async def __call__(self, scope: Scope, receive: Receive, send: Send) -> None:
        if scope["type"] != "http" or scope["method"] != "POST":
            await self.app(scope, receive, send)
            return
        request = Request(scope)
        if routes.operation(scope["app"], "POST", scope["path"]) is None:
            await self.app(scope, receive, send)
            return
        try:
            count, ms_left = self._count(request)
        except RedisError as exc:
            await problems.redis_error_response(request, exc)(scope, receive, send)
            return
        headers = rate_headers(self.settings, count, ms_left)
        if count > self.settings.rate_limit:
            await _too_many(request, headers)(scope, receive, send)
            return
        await self.app(scope, receive, _with_headers(send, headers))

    def _count(self, request: Request) -> tuple[int, int]:
        """Count one POST of the request's caller: (POSTs in its window, ms the window has left)."""
        window_ms = self.settings.rate_window_s * 1000
        count, ms_left = self.script(keys=[rate_key(caller(request).fair_use_id)], args=[window_ms])
        return int(count), int(ms_left)


def _too_many(request: Request, headers: dict[str, str]) -> Response:
    """The 429 answer past the rate: Retry-After is the end of the caller's window."""
    settings: Settings = request.app.state.settings
    reset = headers["RateLimit"].rsplit("t=", 1)[1]
    detail = (
        f"more than {settings.rate_limit} POST requests in {settings.rate_window_s} s "
        f"(VPP_RATE_LIMIT, VPP_RATE_WINDOW_S); retry after {reset} s"
    )
    exc = HTTPException(429, detail, headers={**headers, "Retry-After": reset})
    return problems.http_error_response(request, exc)


def _with_headers(send: Send, headers: dict[str, str]) -> Send:
    """send() that adds `headers` to the response's start."""

    async def sending(message: Message) -> None:
        if message["type"] == "http.response.start":
            MutableHeaders(scope=message).update(headers)
        await send(message)

    return sending


def reserve(request: Request) -> str:
    """Reserve one of the caller's `max_active_jobs` slots (its token); HTTPException 429 when
    its queued and running jobs fill them."""
    state = request.app.state
    settings: Settings = state.settings
    who = caller(request).fair_use_id
    token = f"r:{uuid.uuid4().hex}"
    expiry_ms = (settings.plan_timeout_s + RESERVE_S) * 1000
    args = [_now_ms(), RESERVE_S * 1000, settings.max_active_jobs, token]
    args += [Job.redis_job_namespace_prefix, expiry_ms, *ENDED]
    script = state.redis.register_script(RESERVE_SCRIPT)
    admitted, count = script(keys=[jobs_key(who)], args=args)
    if not admitted:
        detail = (
            f"{count} of your jobs are queued or running, the most at once "
            "(VPP_MAX_ACTIVE_JOBS); submit more when one has ended"
        )
        retry = str(settings.retry_after_s)
        raise HTTPException(429, detail, headers={"Retry-After": retry})
    return token


def hold(request: Request, token: str, job_id: str) -> None:
    """Give the reserved slot `token` to the submitted job `job_id`."""
    pipe = request.app.state.redis.pipeline()
    key = jobs_key(caller(request).fair_use_id)
    pipe.zrem(key, token)
    pipe.zadd(key, {job_id: _now_ms()})
    pipe.execute()


def release(request: Request, token: str) -> None:
    """Free the reserved slot `token` (its submission failed)."""
    request.app.state.redis.zrem(jobs_key(caller(request).fair_use_id), token)


def _now_ms() -> int:
    """Milliseconds since the epoch (slot scores)."""
    return time.time_ns() // 1_000_000
