"""What a store key may be: slash-separated relative paths of safe characters, no `..`.

Every store backend (worker.store's file and memory stores, worker.s3store) checks its keys
here, so the URL dispatch in worker.store can import the backends and none imports it back.
"""

from __future__ import annotations

import re

_KEY = re.compile(r"^[A-Za-z0-9][A-Za-z0-9._-]*(/[A-Za-z0-9][A-Za-z0-9._-]*)*$")


def check_key(key: str) -> str:
    """The key itself, or ValueError when it could escape the store (.., absolute, odd chars)."""
    if not _KEY.match(key) or ".." in key.split("/"):
        raise ValueError(f"bad store key {key!r}")
    return key
