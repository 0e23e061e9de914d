"""One tracer per trace id: plan jobs needing the same R wait for it instead of tracing it twice."""

from __future__ import annotations

import time
from collections.abc import Callable, Iterator
from contextlib import contextmanager
from typing import Any

from redis import Redis
from rq.exceptions import InvalidJobOperation, NoSuchJobError
from rq.job import Job, JobStatus

WAIT_S = 1.0
"""Seconds between two looks at a lock held by another job."""
LIVE = {JobStatus.QUEUED, JobStatus.STARTED, JobStatus.DEFERRED, JobStatus.SCHEDULED}
_RELEASE = "if redis.call('get', KEYS[1]) == ARGV[1] then return redis.call('del', KEYS[1]) end"


class TraceLock:
    """A Redis lock `vpp:trace-lock:<trace id>` owned by a job id, expiring after `ttl_s`."""

    def __init__(self, conn: Redis, trace_id: str, owner: str, ttl_s: int) -> None:
        self.conn, self.owner, self.ttl_s = conn, owner, ttl_s
        self.key = f"vpp:trace-lock:{trace_id}"

    @contextmanager
    def hold(self, ready: Callable[[], bool], report: Callable[..., None]) -> Iterator[None]:
        """Hold the lock inside the block, or enter it unlocked once `ready()` (R exists)."""
        acquired = False
        while not ready():
            if self._acquire():
                acquired = True
                break
            self._take_over_if_dead()
            report(stage="waiting", waiting_for=self.holder())
            time.sleep(WAIT_S)
        try:
            yield
        finally:
            if acquired:
                self._release(self.owner)

    def holder(self) -> str | None:
        """Job id holding the lock, if any."""
        value: Any = self.conn.get(self.key)
        return value.decode() if value is not None else None

    def _acquire(self) -> bool:
        if self.conn.set(self.key, self.owner, nx=True, ex=self.ttl_s):
            return True
        return self.holder() == self.owner

    def _take_over_if_dead(self) -> None:
        """Free the lock when its holder is no longer queued or running (failed, killed, gone)."""
        holder = self.holder()
        if holder is None:
            return
        try:
            alive = Job.fetch(holder, connection=self.conn).get_status() in LIVE
        except (NoSuchJobError, InvalidJobOperation):  # gone, or its record expired
            alive = False
        if not alive:
            self._release(holder)

    def _release(self, owner: str) -> None:
        self.conn.eval(_RELEASE, 1, self.key, owner)
