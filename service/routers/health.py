"""/livez and /readyz (out of the schema): liveness checks nothing, readiness Redis + store."""

from __future__ import annotations

from fastapi import APIRouter
from fastapi.responses import JSONResponse

from service.deps import RedisDep, SettingsDep, StoreDep
from vpp_core.errors import UnavailableError

router = APIRouter(include_in_schema=False)


@router.get("/livez")
def livez() -> dict[str, str]:
    """The process answers."""
    return {"status": "ok"}


@router.get("/readyz")
def readyz(conn: RedisDep, store: StoreDep, settings: SettingsDep) -> JSONResponse:
    """Redis answers and the store can be written; 503 + Retry-After otherwise."""
    checks: dict[str, str] = {}
    try:
        conn.ping()
        checks["redis"] = "ok"
    except Exception as exc:
        checks["redis"] = f"down: {exc}"
    try:
        store.ping()
        checks["store"] = "ok"
    except UnavailableError as exc:
        checks["store"] = f"down: {exc.detail}"
    ok = all(v == "ok" for v in checks.values())
    headers = None if ok else {"Retry-After": str(settings.retry_after_s)}
    body = {"status": "ok" if ok else "unavailable", "checks": checks}
    return JSONResponse(body, status_code=200 if ok else 503, headers=headers)
