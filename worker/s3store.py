"""The artifact store on an S3-compatible object store (AWS S3, SeaweedFS, MinIO) through obstore.

`s3://bucket/prefix` names the bucket and the key prefix. The endpoint comes from the argument,
else `VPP_S3_ENDPOINT_URL`, else `AWS_ENDPOINT_URL` (none: AWS itself); credentials come from the
usual AWS_* variables and the region from AWS_REGION / AWS_DEFAULT_REGION (default us-east-1).
An object put is atomic by nature: readers see the whole old object or the whole new one.
"""

from __future__ import annotations

import os
import re
from collections.abc import Callable
from datetime import timedelta
from typing import TYPE_CHECKING, TypeVar
from urllib.parse import urlparse

import obstore
from obstore.exceptions import BaseError as ObstoreError
from obstore.store import S3Store as _ObS3

from vpp_core.errors import NotFoundError, UnavailableError
from worker.storekey import check_key

if TYPE_CHECKING:
    from obstore.store import ClientConfig, RetryConfig, S3Config

T = TypeVar("T")

_PROBE = ".vpp-ping"
"""A prefix no key can have (keys never start with a dot): `ping` lists it, finding nothing."""
_ERROR_CODE = re.compile(r"<Code>([A-Za-z]+)</Code>")


class S3Store:
    """A bucket and key prefix of an S3-compatible object store."""

    def __init__(self, url: str, endpoint_url: str | None = None, timeout_s: float = 10.0) -> None:
        """Open `s3://bucket/prefix`; `timeout_s` bounds connecting, stalls and retries."""
        bucket, prefix = _parse_url(url)
        self.url = f"s3://{bucket}/{prefix}" if prefix else f"s3://{bucket}"
        self.endpoint_url = endpoint_url or _default_endpoint()
        self._store = _ObS3(
            bucket,
            prefix=prefix or None,
            config=_config(self.endpoint_url),
            client_options=_client_options(self.endpoint_url, timeout_s),
            retry_config=_retry_config(timeout_s),
        )

    def put(self, key: str, data: bytes) -> None:
        """Store `data` under `key` as one object (multipart above 5 MB, still atomic)."""
        path = check_key(key)
        self._call(lambda: obstore.put(self._store, path, bytes(data)))

    def get(self, key: str) -> bytes:
        """The bytes under `key`; NotFoundError when absent."""
        path = check_key(key)
        try:
            return self._call(lambda: obstore.get(self._store, path).bytes().to_bytes())
        except FileNotFoundError:
            raise NotFoundError(f"no artifact {key!r} in the store") from None

    def exists(self, key: str) -> bool:
        """Whether `key` holds an object (a HEAD request)."""
        path = check_key(key)
        try:
            self._call(lambda: obstore.head(self._store, path))
        except FileNotFoundError:
            return False
        return True

    def ping(self) -> None:
        """Raise UnavailableError when the server, bucket or credentials fail (a read-only list)."""
        try:
            self._call(lambda: next(iter(obstore.list(self._store, _PROBE, chunk_size=1)), None))
        except FileNotFoundError as exc:
            raise UnavailableError(f"object store {self.url}: {_detail(exc)}") from None

    def _call(self, op: Callable[[], T]) -> T:
        """`op()`, with every store failure but a missing object turned into UnavailableError."""
        try:
            return op()
        except FileNotFoundError:
            raise
        except (ObstoreError, OSError) as exc:
            raise UnavailableError(f"object store {self.url}: {_detail(exc)}") from None


def _parse_url(url: str) -> tuple[str, str]:
    """(bucket, prefix) of `s3://bucket/prefix`; ValueError when malformed."""
    parsed = urlparse(url)
    prefix = parsed.path.strip("/")
    if parsed.scheme != "s3" or not parsed.netloc or parsed.query or parsed.fragment:
        raise ValueError(f"bad S3 store URL {url!r}: use s3://bucket/prefix")
    if prefix:
        check_key(prefix)
    return parsed.netloc, prefix


def _default_endpoint() -> str | None:
    """The endpoint of the settings (VPP_S3_ENDPOINT_URL), else of AWS_ENDPOINT_URL."""
    from worker.settings import get_settings

    return get_settings().s3_endpoint_url or os.environ.get("AWS_ENDPOINT_URL") or None


def _config(endpoint: str | None) -> S3Config:
    """Region (AWS_REGION, AWS_DEFAULT_REGION, else us-east-1) and endpoint; the rest from env."""
    region = os.environ.get("AWS_REGION") or os.environ.get("AWS_DEFAULT_REGION") or "us-east-1"
    config: S3Config = {"region": region}
    if endpoint:
        config["endpoint"] = endpoint
    return config


def _client_options(endpoint: str | None, timeout_s: float) -> ClientConfig:
    """HTTP options: plain http only for an http:// endpoint; connect and stall timeouts."""
    wait = timedelta(seconds=timeout_s)
    return {
        "allow_http": bool(endpoint and endpoint.startswith("http://")),
        "connect_timeout": wait,
        "read_timeout": wait,
        "timeout": max(wait * 10, timedelta(seconds=60)),
    }


def _retry_config(timeout_s: float) -> RetryConfig:
    """Retry connection errors and 5xx for at most `timeout_s` after the first attempt."""
    return {"max_retries": 5, "retry_timeout": timedelta(seconds=timeout_s)}


def _detail(exc: BaseException) -> str:
    """One line from obstore's multi-line error: its summary and the S3 error code if any."""
    lines = str(exc).strip().splitlines()
    line = lines[0].split("<?xml", 1)[0].rstrip(" :") if lines else type(exc).__name__
    code = _ERROR_CODE.search(str(exc))
    return f"{line} ({code.group(1)})"[:400] if code else line[:400]
