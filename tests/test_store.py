"""The artifact stores: one contract for the directory, memory and a real S3 server (SeaweedFS)."""

from __future__ import annotations

import os
import socket
import threading
import time
import uuid
from collections.abc import Iterator
from pathlib import Path

import pytest

from tests.conftest import S3_BUCKET as BUCKET
from tests.s3server import free_ports
from vpp_core.errors import NotFoundError, UnavailableError
from worker.s3store import S3Store
from worker.settings import get_settings
from worker.store import FileStore, MemoryStore, Store, open_store
from worker.storekey import check_key

BAD_KEYS = ["../x", "a/../b", "/abs", "a//b", "", "x/", ".hidden", "a b", "a\\b"]
MB = bytes(range(256)) * 4096


@pytest.fixture(autouse=True)
def aws_env(monkeypatch: pytest.MonkeyPatch) -> Iterator[None]:
    """Fixed dummy credentials and no ambient endpoint or settings cache."""
    for name in ("AWS_ENDPOINT_URL", "AWS_SESSION_TOKEN", "AWS_PROFILE", "VPP_S3_ENDPOINT_URL"):
        monkeypatch.delenv(name, raising=False)
    monkeypatch.setenv("AWS_ACCESS_KEY_ID", "vpp-test")
    monkeypatch.setenv("AWS_SECRET_ACCESS_KEY", "vpp-test-secret")
    monkeypatch.setenv("AWS_REGION", "us-east-1")
    get_settings.cache_clear()
    yield
    get_settings.cache_clear()


@pytest.fixture(params=["file", "memory", "s3"])
def store(request: pytest.FixtureRequest, tmp_path: Path) -> Store:
    """Each backend, empty; S3 under a fresh prefix of the session bucket."""
    if request.param == "file":
        return FileStore(tmp_path / "store")
    if request.param == "memory":
        return MemoryStore()
    endpoint = request.getfixturevalue("s3_endpoint")
    return S3Store(f"s3://{BUCKET}/run-{uuid.uuid4().hex[:12]}", endpoint_url=endpoint)


def closed_port_store() -> S3Store:
    """An S3 store whose endpoint refuses connections."""
    return S3Store("s3://b/p", endpoint_url=f"http://127.0.0.1:{free_ports(1)[0]}", timeout_s=0.25)


# -- the contract, on every backend ---------------------------------------------------------------


@pytest.mark.parametrize(
    "key, data",
    [("a.bin", b""), ("meshes/ab/cd.npz", bytes(range(256))), ("big/one-MB.bin", MB)],
)
def test_put_get_round_trip(store: Store, key: str, data: bytes) -> None:
    store.put(key, data)
    assert store.get(key) == data
    assert store.exists(key)


def test_overwrite_replaces_the_value(store: Store) -> None:
    store.put("k", b"old value")
    store.put("k", b"new")
    assert store.get("k") == b"new"


def test_missing_key(store: Store) -> None:
    assert not store.exists("nope/x.bin")
    with pytest.raises(NotFoundError, match="nope/x.bin"):
        store.get("nope/x.bin")
    store.put("nope/y.bin", b"1")
    assert not store.exists("nope/x.bin")
    assert not store.exists("nope")  # a "directory" is not a key


@pytest.mark.parametrize("key", BAD_KEYS)
def test_bad_keys_are_refused(store: Store, key: str) -> None:
    with pytest.raises(ValueError, match="bad store key"):
        store.put(key, b"x")
    with pytest.raises(ValueError, match="bad store key"):
        store.get(key)
    with pytest.raises(ValueError, match="bad store key"):
        store.exists(key)


def test_ping_ok(store: Store) -> None:
    store.ping()


# -- the file store: atomic puts ------------------------------------------------------------------


def test_file_put_failing_mid_write_keeps_old_value(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    store = FileStore(tmp_path)
    store.put("d/k", b"old")

    def broken_fsync(fd: int) -> None:
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(os, "fsync", broken_fsync)
    with pytest.raises(UnavailableError, match="cannot write d/k: .*No space left"):
        store.put("d/k", b"new value, half written")
    assert store.get("d/k") == b"old"
    assert [p.name for p in (tmp_path / "d").iterdir()] == ["k"]  # no temporary file left


def test_file_put_interrupted_leaves_no_temp(
    tmp_path: Path, monkeypatch: pytest.MonkeyPatch
) -> None:
    store = FileStore(tmp_path)

    def interrupted(src: str, dst: str) -> None:
        raise KeyboardInterrupt

    monkeypatch.setattr(os, "replace", interrupted)
    with pytest.raises(KeyboardInterrupt):
        store.put("k", b"data")
    assert not store.exists("k")
    assert list(tmp_path.iterdir()) == []


def test_file_temp_names_are_never_keys(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    store, seen = FileStore(tmp_path), []
    real_replace = os.replace

    def spy(src: str, dst: str) -> None:
        seen.append(Path(src).relative_to(tmp_path).as_posix())
        real_replace(src, dst)

    monkeypatch.setattr(os, "replace", spy)
    store.put("meshes/m.npz", b"1")
    assert len(seen) == 1 and seen[0].startswith("meshes/.tmp-")
    with pytest.raises(ValueError):
        check_key(seen[0])


def test_file_readers_see_whole_values(tmp_path: Path) -> None:
    store = FileStore(tmp_path)
    values = (b"a" * 200_000, b"b" * 300_000)
    store.put("k", values[0])
    torn: list[int] = []
    done = threading.Event()

    def read() -> None:
        while not done.is_set():
            if store.get("k") not in values:
                torn.append(1)

    reader = threading.Thread(target=read)
    reader.start()
    for i in range(40):
        store.put("k", values[i % 2])
    done.set()
    reader.join()
    assert not torn


def test_file_ping_unwritable(tmp_path: Path) -> None:
    (tmp_path / "f").write_bytes(b"")
    with pytest.raises(UnavailableError, match="not writable"):
        FileStore(tmp_path / "f").ping()


# -- the S3 store: errors and configuration -------------------------------------------------------


def test_s3_unreachable_is_unavailable_quickly() -> None:
    store = closed_port_store()
    for op in (store.ping, lambda: store.put("k", b"1"), lambda: store.get("k")):
        start = time.monotonic()
        with pytest.raises(UnavailableError) as info:
            op()
        assert time.monotonic() - start < 3
        detail = info.value.detail
        assert "\n" not in detail and "Debug source" not in detail and store.url in detail
        assert info.value.__cause__ is None and info.value.__suppress_context__
    with pytest.raises(UnavailableError):
        store.exists("k")


def test_s3_stalled_server_times_out() -> None:
    with socket.create_server(("127.0.0.1", 0)) as silent:  # accepts connections, never answers
        endpoint = f"http://127.0.0.1:{silent.getsockname()[1]}"
        store = S3Store("s3://b/p", endpoint_url=endpoint, timeout_s=0.25)
        start = time.monotonic()
        with pytest.raises(UnavailableError):
            store.ping()
        assert time.monotonic() - start < 3


def test_s3_missing_bucket_fails_ping(s3_endpoint: str) -> None:
    store = S3Store("s3://no-such-bucket/p", endpoint_url=s3_endpoint, timeout_s=2)
    with pytest.raises(UnavailableError, match="NoSuchBucket"):
        store.ping()


def test_s3_prefix_isolates(s3_endpoint: str) -> None:
    a = S3Store(f"s3://{BUCKET}/iso-{uuid.uuid4().hex[:8]}", endpoint_url=s3_endpoint)
    b = S3Store(f"s3://{BUCKET}/iso-{uuid.uuid4().hex[:8]}", endpoint_url=s3_endpoint)
    a.put("k", b"a")
    assert not b.exists("k")


def test_s3_endpoint_from_settings_then_env(monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.setenv("AWS_ENDPOINT_URL", "http://env:9000")
    assert S3Store("s3://b").endpoint_url == "http://env:9000"
    monkeypatch.setenv("VPP_S3_ENDPOINT_URL", "http://settings:8333")
    get_settings.cache_clear()
    assert S3Store("s3://b").endpoint_url == "http://settings:8333"
    assert S3Store("s3://b", endpoint_url="http://arg:1").endpoint_url == "http://arg:1"


@pytest.mark.parametrize("url", ["s3://", "s3:///p", "s3://b/../x", "s3://b/p?x=1", "s3://b/a//c"])
def test_s3_bad_urls(url: str) -> None:
    with pytest.raises(ValueError):
        S3Store(url, endpoint_url="http://127.0.0.1:1")


# -- open_store -----------------------------------------------------------------------------------


def test_open_store_dispatch(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    monkeypatch.chdir(tmp_path)
    plain = open_store("rel/dir")
    assert isinstance(plain, FileStore) and plain.root == tmp_path / "rel" / "dir"
    uri = open_store((tmp_path / "abs").as_uri())
    assert isinstance(uri, FileStore) and uri.root == tmp_path / "abs"
    assert isinstance(open_store("memory://"), MemoryStore)
    monkeypatch.setenv("AWS_ENDPOINT_URL", "http://127.0.0.1:1")
    s3 = open_store("s3://bucket/some/prefix/")
    assert isinstance(s3, S3Store) and s3.url == "s3://bucket/some/prefix"
    with pytest.raises(ValueError, match="unsupported store URL"):
        open_store("ftp://host/x")
