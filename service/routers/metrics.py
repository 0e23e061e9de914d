"""GET /metrics: Prometheus text format (worker.metrics: counted in Redis by every process)."""

from __future__ import annotations

from fastapi import APIRouter, Response
from prometheus_client import CONTENT_TYPE_LATEST

from service.deps import RedisDep, SettingsDep
from worker import metrics, webhooks

router = APIRouter(tags=["health"])


@router.get(
    "/metrics",
    response_class=Response,
    responses={200: {"content": {CONTENT_TYPE_LATEST: {}}}},
)
def get_metrics(conn: RedisDep, settings: SettingsDep) -> Response:
    """Job, queue, stage, ray and solver metrics of every API and worker process (`vpp_*`)."""
    queues = (settings.queue, webhooks.queue_name(settings.queue))
    return Response(metrics.render(conn, queues), media_type=CONTENT_TYPE_LATEST)
