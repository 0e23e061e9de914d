"""The artifact store: bytes under content-addressed keys, outliving Redis (the database of record).

Keys are slash-separated relative paths such as `meshes/<sha256>.npz`. A put is atomic: a reader
sees the whole old value or the whole new one, never a part. Backends: the filesystem
(`file:///abs/dir` or a plain path), an S3-compatible object store (`s3://bucket/prefix`,
see `worker.s3store`) and memory (`memory://`, for tests). Opened with a Redis connection, a
store counts its failures (`vpp_store_errors_total{operation}`, worker.metrics): `CountedStore`.
"""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from contextlib import suppress
from pathlib import Path
from typing import Protocol, TypeVar
from urllib.parse import urlparse

from redis import Redis
from redis.exceptions import RedisError

from vpp_core.errors import NotFoundError, UnavailableError
from worker import metrics
from worker.s3store import S3Store
from worker.storekey import check_key


class Store(Protocol):
    """Bytes under keys; `get` of a missing key raises NotFoundError."""

    url: str

    def put(self, key: str, data: bytes) -> None:
        """Store `data` under `key` atomically (replacing any old value)."""
        ...

    def get(self, key: str) -> bytes:
        """The bytes under `key`; NotFoundError when absent."""
        ...

    def exists(self, key: str) -> bool:
        """Whether `key` holds a value."""
        ...

    def ping(self) -> None:
        """Raise UnavailableError when the store cannot be reached or written."""
        ...


class FileStore:
    """A directory; atomic writes by a temporary file in the same directory and os.replace."""

    def __init__(self, root: str | os.PathLike[str]) -> None:
        self.root = Path(root).expanduser().resolve()
        self.url = self.root.as_uri()

    def _path(self, key: str) -> Path:
        return self.root / check_key(key)

    def put(self, key: str, data: bytes) -> None:
        """Write a hidden `.tmp-*` file (never a valid key, so never served), fsync it, and
        rename it over the key; a full or failing disk is UnavailableError naming the key."""
        path = self._path(key)
        tmp = None
        try:
            path.parent.mkdir(parents=True, exist_ok=True)
            fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=".tmp-")
            with os.fdopen(fd, "wb") as f:
                f.write(data)
                f.flush()
                os.fsync(f.fileno())
            os.replace(tmp, path)
        except BaseException as exc:
            if tmp is not None:
                Path(tmp).unlink(missing_ok=True)
            if isinstance(exc, OSError):
                raise UnavailableError(f"store {self.url}: cannot write {key}: {exc}") from None
            raise

    def get(self, key: str) -> bytes:
        try:
            return self._path(key).read_bytes()
        except FileNotFoundError:
            raise NotFoundError(f"no artifact {key!r} in the store") from None

    def exists(self, key: str) -> bool:
        return self._path(key).is_file()

    def ping(self) -> None:
        try:
            self.root.mkdir(parents=True, exist_ok=True)
            with tempfile.TemporaryFile(dir=self.root):
                pass
        except OSError as exc:
            raise UnavailableError(f"store {self.url} is not writable: {exc}") from None


class MemoryStore:
    """A dict: the in-memory twin for tests of one process."""

    url = "memory://"

    def __init__(self) -> None:
        self._data: dict[str, bytes] = {}

    def put(self, key: str, data: bytes) -> None:
        self._data[check_key(key)] = bytes(data)

    def get(self, key: str) -> bytes:
        try:
            return self._data[check_key(key)]
        except KeyError:
            raise NotFoundError(f"no artifact {key!r} in the store") from None

    def exists(self, key: str) -> bool:
        return check_key(key) in self._data

    def ping(self) -> None:
        return None


T = TypeVar("T")


class CountedStore:
    """A store whose failures are counted in Redis (`vpp_store_errors_total{operation}`: a full
    disk, an object store down or refusing) and raised as before; a missing key is no failure,
    and a Redis that cannot count does not hide the store's error."""

    def __init__(self, inner: Store, conn: Redis) -> None:
        self.inner, self.conn, self.url = inner, conn, inner.url

    def __getattr__(self, name: str) -> object:
        """The backend's own attributes (a FileStore's `root`, an S3Store's `endpoint_url`)."""
        return getattr(self.inner, name)

    def put(self, key: str, data: bytes) -> None:
        self._counted("put", lambda: self.inner.put(key, data))

    def get(self, key: str) -> bytes:
        return self._counted("get", lambda: self.inner.get(key))

    def exists(self, key: str) -> bool:
        return self._counted("exists", lambda: self.inner.exists(key))

    def ping(self) -> None:
        self._counted("ping", self.inner.ping)

    def _counted(self, operation: str, call: Callable[[], T]) -> T:
        try:
            return call()
        except NotFoundError:
            raise
        except Exception:
            with suppress(RedisError):
                metrics.inc(self.conn, "store_errors_total", {"operation": operation})
            raise


def open_store(url: str, conn: Redis | None = None, endpoint_url: str | None = None) -> Store:
    """The store at `url`: `file:///dir` or a path, `s3://bucket/prefix` (at `endpoint_url`,
    else the default of worker.s3store), or `memory://`; its failures counted in the metrics
    when `conn` (Redis) is given."""
    parsed = urlparse(url)
    store: Store
    if parsed.scheme in ("", "file"):
        store = FileStore(parsed.path if parsed.scheme else url)
    elif parsed.scheme == "s3":
        store = S3Store(url, endpoint_url)
    elif parsed.scheme == "memory":
        store = MemoryStore()
    else:
        raise ValueError(f"unsupported store URL {url!r}: use file:///dir, s3://bucket/prefix")
    return CountedStore(store, conn) if conn is not None else store
