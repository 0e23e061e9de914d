"""`python -m service.openapi > openapi/openapi.json`: the committed API contract."""

from __future__ import annotations

import json
from typing import Any

from service.app import create_app
from worker.settings import Settings


def document() -> dict[str, Any]:
    """The app's OpenAPI document (independent of the local settings)."""
    app = create_app(Settings(redis_url="redis://127.0.0.1:6379/0", store_url="memory://"))
    return app.openapi()


def text() -> str:
    """The document as committed: sorted keys, 2-space indent, trailing newline."""
    return json.dumps(document(), indent=2, sort_keys=True) + "\n"


if __name__ == "__main__":
    print(text(), end="")
