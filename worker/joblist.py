"""Which jobs exist, newest first, and whose they are: the Redis index behind `GET /v1/jobs`.

Each submission records its job (`record`): a hash `vpp:job:<id>` (kind, mesh id, creation
time) and the job id in the sorted set `vpp:jobs` and in its owner's `vpp:jobs:owner:<owner>`,
scored by the creation time in microseconds since the epoch. Everything expires with the job
records: the hash after `retention_s` (the longest a job may run plus the longer of the result
and failure TTLs), and each write drops the set members older than that and renews the sets'
own expiry, so the index never outgrows the jobs Redis keeps.

Pages are cut by keyset (`Cursor`: the last item's score and id), so jobs submitted while a
client pages never shift or repeat the items it has not read yet.
"""

from __future__ import annotations

import base64
import binascii
import time
from collections.abc import Iterator
from dataclasses import dataclass
from datetime import UTC, datetime
from typing import Literal

from redis import Redis

from vpp_core.errors import VppError
from worker.settings import Settings

Kind = Literal["plan", "study", "point-cloud"]
INDEX = "vpp:jobs"
"""Sorted set of every job id, scored by creation time (µs)."""
SCAN_BATCH = 200
"""Index entries read from Redis at a time while a page is filled."""


def owner_key(owner: str) -> str:
    """The sorted set of the jobs `owner` submitted."""
    return f"{INDEX}:owner:{owner}"


def record_key(job_id: str) -> str:
    """The hash of one job's listing record (kind, mesh id, created)."""
    return f"vpp:job:{job_id}"


def retention_s(settings: Settings) -> int:
    """How long a listing entry lives (s): the longest run plus the longer record TTL."""
    return settings.plan_timeout_s + max(settings.result_ttl_s, settings.failure_ttl_s)


def now_us() -> int:
    """Microseconds since the epoch (the index score)."""
    return time.time_ns() // 1000


@dataclass(frozen=True)
class Entry:
    """A job's listing record."""

    id: str
    kind: str
    mesh_id: str | None
    created_at: datetime


def record(
    conn: Redis,
    settings: Settings,
    job_id: str,
    kind: Kind,
    mesh_id: str | None,
    owner: str | None,
) -> None:
    """Index a submitted job (a job submitted again keeps its first time) under `owner` too."""
    ttl = retention_s(settings)
    now = now_us()
    keys = [INDEX] + ([owner_key(owner)] if owner else [])
    pipe = conn.pipeline()
    pipe.hsetnx(record_key(job_id), "created", now)
    pipe.hset(record_key(job_id), mapping={"kind": kind, "mesh_id": mesh_id or ""})
    pipe.expire(record_key(job_id), ttl)
    for key in keys:
        pipe.zadd(key, {job_id: now}, nx=True)
        pipe.zremrangebyscore(key, "-inf", now - ttl * 1_000_000)
        pipe.expire(key, ttl)
    pipe.execute()


def entry(conn: Redis, job_id: str) -> Entry | None:
    """The listing record of `job_id`, or None when it expired or was never made."""
    stored: dict[bytes, bytes] = conn.hgetall(record_key(job_id))  # type: ignore[assignment]
    raw = {k.decode(): v.decode() for k, v in stored.items()}
    if "created" not in raw:
        return None
    created = datetime.fromtimestamp(int(raw["created"]) / 1e6, UTC)
    return Entry(job_id, raw.get("kind", "plan"), raw.get("mesh_id") or None, created)


@dataclass(frozen=True)
class Cursor:
    """Where a page ended: the score and id of its last item (opaque base64url to clients)."""

    score: int
    id: str

    def encode(self) -> str:
        return base64.urlsafe_b64encode(f"{self.score}:{self.id}".encode()).decode().rstrip("=")

    @classmethod
    def decode(cls, text: str) -> Cursor:
        """The cursor a page gave; VppError for anything else."""
        try:
            raw = base64.urlsafe_b64decode(text + "=" * (-len(text) % 4)).decode("ascii")
            score, job_id = raw.split(":", 1)
            if not job_id or len(job_id) > 128:
                raise ValueError(job_id)
            return cls(int(score), job_id)
        except (ValueError, binascii.Error, UnicodeDecodeError):
            raise VppError(f"cursor {text[:80]!r} is not one a page of /v1/jobs gave") from None


def scan(
    conn: Redis, owner: str | None, after: Cursor | None, created_after: datetime | None
) -> Iterator[tuple[str, int]]:
    """(job id, score) of the index (or `owner`'s), newest first, strictly past `after` in
    (score, id) descending order, created after `created_after`."""
    key = owner_key(owner) if owner else INDEX
    high: float | str = after.score if after else "+inf"
    low: float | str = "-inf"
    if created_after is not None:
        low = f"({int(created_after.timestamp() * 1_000_000)}"
    offset = 0
    while True:
        batch: list[tuple[bytes, float]] = conn.zrevrangebyscore(  # type: ignore[assignment]
            key, high, low, start=offset, num=SCAN_BATCH, withscores=True
        )
        for member, score in batch:
            job_id = member.decode()
            if after and int(score) == after.score and job_id >= after.id:
                continue
            yield job_id, int(score)
        if len(batch) < SCAN_BATCH:
            return
        offset += SCAN_BATCH
