"""FastAPI dependencies: settings, Redis, queue and store, swappable in tests."""

from __future__ import annotations

from typing import Annotated

from fastapi import Depends, Request
from redis import Redis
from rq import Queue

from worker.settings import Settings
from worker.store import Store


def get_settings(request: Request) -> Settings:
    """The app's settings (read once when the app was made)."""
    settings: Settings = request.app.state.settings
    return settings


def get_redis(request: Request) -> Redis:
    """The app's Redis connection (pooled)."""
    conn: Redis = request.app.state.redis
    return conn


def get_queue(request: Request) -> Queue:
    """The plan queue."""
    queue: Queue = request.app.state.queue
    return queue


def get_store(request: Request) -> Store:
    """The artifact store."""
    store: Store = request.app.state.store
    return store


SettingsDep = Annotated[Settings, Depends(get_settings)]
RedisDep = Annotated[Redis, Depends(get_redis)]
QueueDep = Annotated[Queue, Depends(get_queue)]
StoreDep = Annotated[Store, Depends(get_store)]
