"""Who is calling: the API key's owner id (jobs are listed per key), admin or not, and the
identity that fair use counts against.

Keys are never kept: the owner id is the first 32 hex digits of the key's SHA-256. With no keys
configured the API is open: nobody owns jobs (everyone lists all) and fair use counts per
client address.
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass

from fastapi import Request

from service.auth import bearer_token
from worker.settings import Settings

OWNER_HEX = 32
"""Hex digits of a key's SHA-256 that name its owner."""


@dataclass(frozen=True)
class Caller:
    """The requester: `owner` None when the API is open; `admin` lists every key's jobs."""

    owner: str | None
    admin: bool
    fair_use_id: str


def owner_of(key: str) -> str:
    """The owner id of an API key (no way back to the key)."""
    return hashlib.sha256(key.encode("latin-1")).hexdigest()[:OWNER_HEX]


def caller(request: Request) -> Caller:
    """The caller of `request` (its bearer key was checked by the ApiKeys middleware)."""
    settings: Settings = request.app.state.settings
    token = bearer_token(request.headers.get("authorization"))
    if not settings.api_key_list() or token is None:
        host = request.client.host if request.client else "unknown"
        return Caller(owner=None, admin=True, fair_use_id=f"addr:{host}")
    owner = owner_of(token)
    return Caller(owner=owner, admin=token in settings.admin_key_list(), fair_use_id=owner)
