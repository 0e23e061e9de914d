"""Log lines as text or JSON (`VPP_LOG_FORMAT`), each with the ids of what it belongs to.

Two context variables name the work a line is written for: `REQUEST_ID` (set by the API's
`service.requestid` middleware for each request) and `JOB_ID` (set by the worker while a job
runs). `IdsFilter` copies both onto every record of the root handler, so every line carries
them, whoever logs it (the service, RQ, uvicorn, a library). `configure` installs that handler:
JSON lines (`time`, `level`, `logger`, `message`, `request_id`, `job_id`, `exc_info`) or text
(`time level logger [request …] [job …] message`).
"""

from __future__ import annotations

import json
import logging
import sys
from contextvars import ContextVar
from datetime import UTC, datetime
from typing import Literal

REQUEST_ID: ContextVar[str | None] = ContextVar("vpp_request_id", default=None)
"""The id of the API request being answered (None outside one)."""
JOB_ID: ContextVar[str | None] = ContextVar("vpp_job_id", default=None)
"""The id of the job being run (None outside one)."""
TEXT = "%(asctime)s %(levelname)s %(name)s%(ids)s %(message)s"
"""The text line; `ids` is ` [request …] [job …]` where they are set."""


class IdsFilter(logging.Filter):
    """Puts the request and job ids of the current context on each record (never drops one)."""

    def filter(self, record: logging.LogRecord) -> bool:
        request_id, job_id = REQUEST_ID.get(), JOB_ID.get()
        record.request_id, record.job_id = request_id, job_id
        named = (("request", request_id), ("job", job_id))
        record.ids = "".join(f" [{name} {value}]" for name, value in named if value)
        return True


class JsonFormatter(logging.Formatter):
    """One JSON object per line: time (UTC, ISO 8601), level, logger, message, the ids set."""

    def format(self, record: logging.LogRecord) -> str:
        line = {
            "time": datetime.fromtimestamp(record.created, UTC).isoformat(timespec="milliseconds"),
            "level": record.levelname,
            "logger": record.name,
            "message": record.getMessage(),
        }
        for key in ("request_id", "job_id"):
            if getattr(record, key, None):
                line[key] = getattr(record, key)
        if record.exc_info:
            line["exc_info"] = self.formatException(record.exc_info)
        return json.dumps(line, ensure_ascii=False)


def handler(fmt: Literal["text", "json"], stream: object = None) -> logging.Handler:
    """A stream handler (stderr by default) writing `fmt` lines with the ids."""
    out = logging.StreamHandler(stream or sys.stderr)  # type: ignore[arg-type]
    out.addFilter(IdsFilter())
    out.setFormatter(JsonFormatter() if fmt == "json" else logging.Formatter(TEXT))
    return out


def configure(fmt: Literal["text", "json"], level: int = logging.INFO) -> None:
    """Make the root logger write `fmt` lines at `level` (replacing its handlers)."""
    logging.basicConfig(level=level, handlers=[handler(fmt)], force=True)
