"""Bodies of the job listing and of webhooks: a page of jobs, a callback, a delivery attempt."""

from __future__ import annotations

from datetime import datetime

from pydantic import BaseModel, ConfigDict, Field, HttpUrl, field_validator

from vpp_core.errors import VppError
from worker.webhooks import check_secret


class Callback(BaseModel):
    """Where to POST the job's terminal event (Standard Webhooks: `webhook-id`,
    `webhook-timestamp`, `webhook-signature: v1,<base64 HMAC-SHA256 of id.timestamp.body>`)."""

    model_config = ConfigDict(extra="forbid")

    url: HttpUrl = Field(
        description="http(s) URL of the receiver; not a loopback, link-local or "
        "private address unless VPP_CALLBACK_ALLOW_PRIVATE"
    )
    secret: str = Field(
        min_length=1,
        max_length=200,
        description="the signing key as Standard Webhooks gives it: `whsec_` + base64 of 24 to "
        "64 random bytes (the prefix is optional)",
    )

    @field_validator("secret")
    @classmethod
    def _secret(cls, value: str) -> str:
        try:
            check_secret(value)
        except VppError as exc:  # pydantic turns only ValueError into a 422 entry
            raise ValueError(str(exc)) from None
        return value


class Delivery(BaseModel):
    """One attempt to deliver a job's webhook."""

    url: str
    attempt: int
    at: datetime
    status_code: int | None = None
    error: str | None = None
    delivered: bool


class CloudSubmit(BaseModel):
    """The optional body of a point-cloud request: its callback."""

    model_config = ConfigDict(extra="forbid")

    callback: Callback | None = None
